"""``ferroslam download`` against a local HTTP(S) server (127.0.0.1) serving archives built
here: name resolution, resume with Range, size and checksum checks, extraction, offline and
certificate errors, the http/https rules, size caps, KITTI instructions; and the safe
extraction rules of ``ferroslam.archives``. Plain-http downloads pass ``sha256``, as the
module requires."""

from __future__ import annotations

import hashlib
import os
import io
import random
import re
import shutil
import socket
import ssl
import subprocess
import tarfile
import threading
import urllib.request
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path, PurePosixPath

import pytest

from ferroslam import archives, cli
from ferroslam.archives import extract_archive
from ferroslam.download import DownloadError, download, fetch_dataset, resolve


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _tgz(files: dict) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def _zip(files: dict) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


TUM_FILES = {
    "rgbd_dataset_freiburg1_xyz/rgb.txt": b"# color images\n1.0 rgb/1.0.png\n",
    "rgbd_dataset_freiburg1_xyz/depth.txt": b"# depth maps\n1.0 depth/1.0.png\n",
    "rgbd_dataset_freiburg1_xyz/rgb/blob.bin": random.Random(0).randbytes(100_000),
}
EUROC_FILES = {"mav0/cam0/data.csv": b"#timestamp [ns],filename\n", "mav0/body.yaml": b"x: 1\n"}


class _Handler(BaseHTTPRequestHandler):
    """Serves ``server.files[path]`` with Range support, and ``server.redirects[path]`` as a
    302 to that address; knobs on the server object: ``ranges`` (honour Range), ``cut``
    (close after this many body bytes), ``length`` (send Content-Length)."""

    def log_message(self, *args):  # keep pytest output clean
        pass

    def do_GET(self):  # noqa: N802 (http.server API)
        server = self.server
        server.requests.append((self.path, self.headers.get("Range")))
        if self.path in server.redirects:
            self.send_response(302)
            self.send_header("Location", server.redirects[self.path])
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        data = server.files.get(self.path)
        if data is None:
            self.send_error(404)
            return
        start, status = 0, 200
        rng = self.headers.get("Range")
        if rng and server.ranges:
            start = int(rng.split("=")[1].rstrip("-"))
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            status = 206
        body = data[start:]
        self.send_response(status)
        if server.length:
            self.send_header("Content-Length", str(len(body)))
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        self.end_headers()
        if server.cut is not None:
            body = body[: server.cut]
        self.wfile.write(body)


def _serve(context=None):
    """A running server on 127.0.0.1 (TLS with ``context``); stopped after the test."""
    srv = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    srv.files, srv.redirects, srv.requests = {}, {}, []
    srv.ranges, srv.cut, srv.length = True, None, True
    if context is not None:
        srv.socket = context.wrap_socket(srv.socket, server_side=True)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    srv.url = f"{'https' if context else 'http'}://127.0.0.1:{srv.server_address[1]}"
    yield srv
    srv.shutdown()
    srv.server_close()


@pytest.fixture()
def server():
    yield from _serve()


@pytest.fixture()
def tls_server(tmp_path_factory):
    """An https server with a fresh self-signed certificate (so clients that verify fail)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make a test certificate")
    folder = tmp_path_factory.mktemp("tls")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:prime256v1", "-nodes", "-days", "1", "-subj",
                    "/CN=127.0.0.1", "-keyout", str(folder / "key.pem"),
                    "-out", str(folder / "cert.pem")], check=True, capture_output=True)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(folder / "cert.pem", folder / "key.pem")
    yield from _serve(context)


@pytest.fixture()
def no_network(monkeypatch):
    """Any request made through urllib fails the test."""
    def refuse(*args, **kwargs):
        raise AssertionError("network access")
    monkeypatch.setattr(urllib.request.OpenerDirector, "open", refuse)


def test_resolve_official_urls():
    tum = resolve("tum", "fr1_xyz")
    assert tum.url == ("https://cvg.cit.tum.de/rgbd/dataset/freiburg1/"
                       "rgbd_dataset_freiburg1_xyz.tgz")
    assert resolve("tum", "rgbd_dataset_freiburg3_long_office_household").sequence == (
        "rgbd_dataset_freiburg3_long_office_household")
    assert resolve("tum", "freiburg2_desk").archive_name == "rgbd_dataset_freiburg2_desk.tgz"
    euroc = resolve("euroc", "V1_01")
    assert euroc.url == ("http://robotics.ethz.ch/~asl-datasets/ijrr_euroc_mav_dataset/"
                         "vicon_room1/V1_01_easy/V1_01_easy.zip")
    assert resolve("euroc", "mh_04_difficult").url.endswith(
        "/machine_hall/MH_04_difficult/MH_04_difficult.zip")


@pytest.mark.parametrize("dataset,name,expected", [
    ("tum", "freiburg4_xyz", "freiburgN_NAME"),
    ("tum", "../../etc", "freiburgN_NAME"),
    ("euroc", "V3_01", "V1_01_easy"),
    ("euroc", "V", "a prefix"),
    ("nuscenes", "x", "tum, euroc, kitti"),
])
def test_resolve_bad_names_say_what_is_expected(dataset, name, expected):
    with pytest.raises(ValueError, match=expected):
        resolve(dataset, name)


def test_fetch_tum_tgz_and_euroc_zip(server, tmp_path):
    server.files["/a.tgz"] = _tgz(TUM_FILES)
    server.files["/b.zip"] = _zip(EUROC_FILES)
    folder = fetch_dataset("tum", "freiburg1_xyz", tmp_path, url=server.url + "/a.tgz",
                           sha256=_sha(server.files["/a.tgz"]), progress=False)
    assert folder == tmp_path / "rgbd_dataset_freiburg1_xyz"
    assert (folder / "rgb" / "blob.bin").read_bytes() == TUM_FILES[
        "rgbd_dataset_freiburg1_xyz/rgb/blob.bin"]
    assert not (tmp_path / "rgbd_dataset_freiburg1_xyz.tgz").exists()  # archive removed
    folder = fetch_dataset("euroc", "V1_01_easy", tmp_path, url=server.url + "/b.zip",
                           sha256=_sha(server.files["/b.zip"]).upper(), progress=False,
                           keep_archive=True)
    assert folder == tmp_path / "V1_01_easy"
    assert (folder / "mav0" / "cam0" / "data.csv").read_bytes() == EUROC_FILES[
        "mav0/cam0/data.csv"]
    assert (tmp_path / "V1_01_easy.zip").is_file()


def test_resume_after_partial_file(server, tmp_path):
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = data
    target = tmp_path / "a.tgz"
    (tmp_path / "a.tgz.part").write_bytes(data[:1000])
    download(server.url + "/a.tgz", target, progress=False, sha256=_sha(data))
    assert target.read_bytes() == data and not (tmp_path / "a.tgz.part").exists()
    assert server.requests[-1] == ("/a.tgz", "bytes=1000-")


def test_planted_part_link_and_fifo_target_are_not_written_through(server, tmp_path):
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = data
    victim = tmp_path / "victim"
    victim.write_bytes(b"keep me")
    (tmp_path / "a.tgz.part").symlink_to(victim)
    download(server.url + "/a.tgz", tmp_path / "a.tgz", progress=False, sha256=_sha(data))
    assert victim.read_bytes() == b"keep me" and (tmp_path / "a.tgz").read_bytes() == data
    os.mkfifo(tmp_path / "b.tgz")
    with pytest.raises(ValueError, match="b.tgz: is a FIFO, not a regular file"):
        download(server.url + "/a.tgz", tmp_path / "b.tgz", progress=False, sha256=_sha(data))
    assert not (tmp_path / "b.tgz.part").exists()


def test_interrupted_transfer_is_reported_then_resumed(server, tmp_path):
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = data
    server.cut = 5000  # the connection drops after 5000 bytes of the body
    target = tmp_path / "a.tgz"
    with pytest.raises(DownloadError, match=f"incomplete, 5000 of {len(data)} bytes.*resume"):
        download(server.url + "/a.tgz", target, progress=False, sha256=_sha(data))
    assert (tmp_path / "a.tgz.part").stat().st_size == 5000 and not target.exists()
    server.cut = None
    download(server.url + "/a.tgz", target, progress=False, sha256=_sha(data))
    assert target.read_bytes() == data
    assert server.requests[-1][1] == "bytes=5000-"


def test_complete_part_and_server_without_ranges(server, tmp_path):
    data = _zip(EUROC_FILES)
    server.files["/b.zip"] = data
    (tmp_path / "b.zip.part").write_bytes(data)  # finished earlier, not yet renamed: 416
    download(server.url + "/b.zip", tmp_path / "b.zip", progress=False, sha256=_sha(data))
    assert (tmp_path / "b.zip").read_bytes() == data
    server.ranges = False  # 200 with the whole body: the part is restarted, not appended
    (tmp_path / "c.zip.part").write_bytes(b"garbage")
    download(server.url + "/b.zip", tmp_path / "c.zip", progress=False, sha256=_sha(data))
    assert (tmp_path / "c.zip").read_bytes() == data


def test_checksum_mismatch_deletes_the_download(server, tmp_path):
    server.files["/a.tgz"] = _tgz(TUM_FILES)
    with pytest.raises(DownloadError, match="sha256 mismatch"):
        download(server.url + "/a.tgz", tmp_path / "a.tgz", sha256="0" * 64, progress=False)
    assert not (tmp_path / "a.tgz").exists() and not (tmp_path / "a.tgz.part").exists()


def test_corrupt_archive_is_a_clear_error(server, tmp_path):
    data = bytearray(_tgz(TUM_FILES))
    data[len(data) // 2: len(data) // 2 + 64] = bytes(64)  # damaged in the middle
    server.files["/a.tgz"] = bytes(data)
    with pytest.raises(ValueError, match="damaged or truncated.*delete .*download again"):
        fetch_dataset("tum", "fr1_xyz", tmp_path, url=server.url + "/a.tgz",
                      sha256=_sha(bytes(data)), progress=False)
    server.files["/b.zip"] = _zip(EUROC_FILES)[:-30]  # truncated zip
    with pytest.raises(ValueError, match="damaged or truncated zip"):
        fetch_dataset("euroc", "V1_01", tmp_path, url=server.url + "/b.zip",
                      sha256=_sha(server.files["/b.zip"]), progress=False)


def test_http_404_and_offline(server, tmp_path):
    with pytest.raises(DownloadError, match="HTTP 404.*sequence name"):
        download(server.url + "/missing.tgz", tmp_path / "m.tgz", progress=False,
                 sha256="0" * 64)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DownloadError, match="cannot reach 127.0.0.1.*internet connection"):
        download(f"http://127.0.0.1:{port}/a.tgz", tmp_path / "a.tgz", progress=False,
                 sha256="0" * 64, timeout=5)


def test_cli_download(server, tmp_path, capsys):
    server.files["/a.tgz"] = _tgz(TUM_FILES)
    assert cli.main(["download", "tum", "freiburg1_xyz", "--to", str(tmp_path),
                     "--url", server.url + "/a.tgz", "--sha256", _sha(server.files["/a.tgz"]),
                     "--silent"]) == 0
    out = capsys.readouterr().out
    assert "ferroslam run" in out and "rgbd_dataset_freiburg1_xyz --sensor rgbd" in out
    assert cli.main(["download", "kitti", "5", "--to", str(tmp_path)]) == 3
    err = capsys.readouterr().err
    assert "user_register" in err and str(Path("dataset") / "sequences" / "05") in err
    assert cli.main(["download", "tum", "freiburg9_xyz", "--to", str(tmp_path)]) == 1
    assert "expected freiburgN_NAME" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["../evil.txt", "/abs/evil.txt", "a/../../evil.txt",
                                  "C:/evil.txt"])
def test_extract_refuses_path_traversal(tmp_path, name):
    for kind, data in (("tgz", _tgz({"ok.txt": b"1", name: b"x"})),
                       ("zip", _zip({"ok.txt": b"1", name: b"x"}))):
        archive = tmp_path / f"bad.{kind}"
        archive.write_bytes(data)
        dest = tmp_path / f"out_{kind}"
        with pytest.raises(ValueError, match="unsafe member path"):
            extract_archive(archive, dest)
        assert not (dest / "ok.txt").exists()  # names are checked before anything is written
    assert not (tmp_path.parent / "evil.txt").exists()


def test_extract_refuses_links(tmp_path):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        link = tarfile.TarInfo("seq/link")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(link)
    archive = tmp_path / "link.tgz"
    archive.write_bytes(buf.getvalue())
    with pytest.raises(ValueError, match="link or special file"):
        extract_archive(archive, tmp_path / "out")
    with pytest.raises(ValueError, match="not a tar or zip"):
        (tmp_path / "x.bin").write_bytes(b"hello")
        extract_archive(tmp_path / "x.bin", tmp_path / "out")


def _write(tmp_path: Path, kind: str, files: dict) -> Path:
    archive = tmp_path / f"in.{kind}"
    archive.write_bytes(_tgz(files) if kind == "tgz" else _zip(files))
    return archive


@pytest.mark.parametrize("kind", ["tgz", "zip"])
def test_extract_refuses_writing_through_a_link_in_the_destination(tmp_path, kind):
    outside, dest = tmp_path / "outside", tmp_path / "dest"
    outside.mkdir()
    dest.mkdir()
    (dest / "data").symlink_to(outside, target_is_directory=True)
    archive = _write(tmp_path, kind, {"ok.txt": b"1", "data/x": b"evil"})
    with pytest.raises(ValueError, match=f"'data/x'.*symbolic link {re.escape(str(dest))}"):
        extract_archive(archive, dest)
    assert list(outside.iterdir()) == [] and not (dest / "ok.txt").exists()
    (dest / "data").unlink()  # a link that stays inside the destination is fine
    (dest / "inside").mkdir()
    (dest / "data").symlink_to(dest / "inside", target_is_directory=True)
    extract_archive(archive, dest)
    assert (dest / "inside" / "x").read_bytes() == b"evil"


@pytest.mark.parametrize("kind", ["tgz", "zip"])
@pytest.mark.parametrize("files", [{"a": b"file", "a/b": b"in folder a"},
                                   {"a/b": b"in folder a", "a": b"file"}])
def test_extract_refuses_a_file_and_a_folder_of_the_same_name(tmp_path, kind, files):
    archive = _write(tmp_path, kind, files)
    with pytest.raises(ValueError, match="'a/b' needs a folder 'a' but member 'a' is a file"):
        extract_archive(archive, tmp_path / "out")
    assert not (tmp_path / "out" / "a").exists()


def test_extract_names_a_member_clashing_with_the_destination(tmp_path):
    (tmp_path / "out" / "a").mkdir(parents=True)  # a folder where the archive has a file
    archive = _write(tmp_path, "zip", {"a": b"file"})
    with pytest.raises(ValueError, match="member 'a' clashes with .*out.a, already"):
        extract_archive(archive, tmp_path / "out")


@pytest.mark.parametrize("kind", ["tgz", "zip"])
def test_extract_caps_the_total_size(tmp_path, kind):
    archive = _write(tmp_path, kind, {"a.bin": bytes(60_000), "b.bin": bytes(60_000)})
    assert archive.stat().st_size < 2_000  # compresses 60x: a small bomb
    with pytest.raises(ValueError, match="announce 120000 bytes.*limit of 100000 bytes"):
        extract_archive(archive, tmp_path / "out", max_bytes=100_000)
    assert not (tmp_path / "out" / "a.bin").exists()  # refused before writing
    assert len(extract_archive(archive, tmp_path / "out", max_bytes=120_000)) == 2
    assert archives.MAX_EXTRACTED_BYTES == 64 << 30


def test_extract_counts_the_bytes_written_not_the_header(tmp_path):
    """A member longer than its header says is stopped by the count and deleted."""
    member = archives._Member("big.bin", PurePosixPath("big.bin"), False, 10, None)
    target = tmp_path / "big.bin"
    with pytest.raises(ValueError, match="'big.bin' goes past the limit of 1000 bytes"):
        archives._write_file(tmp_path / "in.zip", member, io.BytesIO(bytes(5_000)), target,
                             room_bytes=1_000, max_bytes=1_000)
    assert not target.exists()


def test_download_refuses_an_announced_size_over_the_cap(server, tmp_path):
    data = random.Random(1).randbytes(10_000)
    server.files["/a.tgz"] = data
    with pytest.raises(DownloadError, match="announces 10000 bytes.*limit of 1000 bytes"):
        download(server.url + "/a.tgz", tmp_path / "a.tgz", sha256=_sha(data),
                 progress=False, max_bytes=1_000)
    assert not (tmp_path / "a.tgz.part").exists()


def test_download_stops_an_unannounced_body_at_the_cap(server, tmp_path):
    data = random.Random(2).randbytes(1_000_000)
    server.files["/a.tgz"], server.length = data, False  # no Content-Length: read to the end
    with pytest.raises(DownloadError, match="more than the limit of 100000 bytes.*deleted"):
        download(server.url + "/a.tgz", tmp_path / "a.tgz", sha256=_sha(data),
                 progress=False, max_bytes=100_000)
    assert not (tmp_path / "a.tgz.part").exists() and not (tmp_path / "a.tgz").exists()
    download(server.url + "/a.tgz", tmp_path / "a.tgz", sha256=_sha(data), progress=False)
    assert (tmp_path / "a.tgz").read_bytes() == data  # under the default cap


def test_plain_http_needs_sha256_before_any_request(server, tmp_path, capsys):
    server.files["/a.tgz"] = _tgz(TUM_FILES)
    with pytest.raises(DownloadError, match="plain http.*--sha256.*https"):
        download(server.url + "/a.tgz", tmp_path / "a.tgz", progress=False)
    assert server.requests == [] and not (tmp_path / "a.tgz.part").exists()
    assert cli.main(["download", "tum", "fr1_xyz", "--to", str(tmp_path),
                     "--url", server.url + "/a.tgz"]) == 1
    assert "ferroslam: error: " in capsys.readouterr().err and server.requests == []


def test_official_euroc_address_needs_sha256(tmp_path, no_network):
    assert resolve("euroc", "V1_01").url.startswith("http://")  # see download.py's doc
    with pytest.raises(DownloadError, match="--sha256"):
        fetch_dataset("euroc", "V1_01", tmp_path, progress=False)


@pytest.mark.parametrize("url", ["file:///etc/passwd", "data:,hello", "ftp://127.0.0.1/a.tgz",
                                 "127.0.0.1/a.tgz"])
def test_download_refuses_other_schemes(tmp_path, no_network, url):
    with pytest.raises(ValueError, match=f"{url}: only http:// and https://"):
        download(url, tmp_path / "a.tgz", sha256="0" * 64, progress=False)


@pytest.mark.parametrize("sha256", ["xyz", "0" * 63, "g" * 64, ""])
def test_sha256_is_checked_before_downloading(tmp_path, no_network, capsys, sha256):
    with pytest.raises(ValueError, match="sha256 must be 64 hexadecimal"):
        download("https://example.org/a.tgz", tmp_path / "a.tgz", sha256=sha256,
                 progress=False)
    with pytest.raises(ValueError, match="sha256 must be 64 hexadecimal"):
        fetch_dataset("tum", "fr1_xyz", tmp_path, sha256=sha256, progress=False)
    assert cli.main(["download", "tum", "fr1_xyz", "--to", str(tmp_path),
                     "--sha256", sha256]) == 1
    assert "sha256 must be 64 hexadecimal" in capsys.readouterr().err


def test_redirect_from_https_to_http_is_refused(tls_server, server, tmp_path, monkeypatch):
    monkeypatch.setattr(ssl, "_create_default_https_context", ssl._create_unverified_context)
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = tls_server.files["/a.tgz"] = data
    tls_server.redirects["/down"] = server.url + "/a.tgz"
    with pytest.raises(DownloadError, match="redirects to http://.*refused"):
        download(tls_server.url + "/down", tmp_path / "a.tgz", sha256=_sha(data),
                 progress=False)
    assert server.requests == [] and not (tmp_path / "a.tgz.part").exists()
    tls_server.redirects["/moved"] = tls_server.url + "/a.tgz"  # staying on https is fine
    download(tls_server.url + "/moved", tmp_path / "a.tgz", progress=False)
    assert (tmp_path / "a.tgz").read_bytes() == data


def test_untrusted_certificate_is_named_as_such(tls_server, tmp_path):
    tls_server.files["/a.tgz"] = _tgz(TUM_FILES)
    with pytest.raises(DownloadError, match=r"TLS certificate of 127\.0\.0\.1:\d+ could not "
                                            "be verified.*CA certificates") as err:
        download(tls_server.url + "/a.tgz", tmp_path / "a.tgz", progress=False, timeout=5)
    assert "internet connection" not in str(err.value)
