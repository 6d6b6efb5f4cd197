"""``ferroslam download`` against a local HTTP server (127.0.0.1) serving archives built here:
name resolution, resume with Range, size and checksum checks, extraction, offline errors,
KITTI instructions; and the safe extraction rules of ``ferroslam.archives``."""

from __future__ import annotations

import hashlib
import io
import random
import socket
import tarfile
import threading
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from ferroslam import cli
from ferroslam.archives import extract_archive
from ferroslam.download import DownloadError, download, fetch_dataset, resolve


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
    """Serves ``server.files[path]`` with Range support; knobs on the server object:
    ``ranges`` (honour Range), ``cut`` (close after this many body bytes)."""

    def log_message(self, *args):  # keep pytest output clean
        pass

    def do_GET(self):  # noqa: N802 (http.server API)
        server = self.server
        server.requests.append((self.path, self.headers.get("Range")))
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
        self.send_header("Content-Length", str(len(body)))
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        self.end_headers()
        if server.cut is not None:
            body = body[: server.cut]
        self.wfile.write(body)


@pytest.fixture()
def server():
    srv = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    srv.files, srv.requests, srv.ranges, srv.cut = {}, [], True, None
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    srv.url = f"http://127.0.0.1:{srv.server_address[1]}"
    yield srv
    srv.shutdown()
    srv.server_close()


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
                           progress=False)
    assert folder == tmp_path / "rgbd_dataset_freiburg1_xyz"
    assert (folder / "rgb" / "blob.bin").read_bytes() == TUM_FILES[
        "rgbd_dataset_freiburg1_xyz/rgb/blob.bin"]
    assert not (tmp_path / "rgbd_dataset_freiburg1_xyz.tgz").exists()  # archive removed
    folder = fetch_dataset("euroc", "V1_01_easy", tmp_path, url=server.url + "/b.zip",
                           progress=False, keep_archive=True)
    assert folder == tmp_path / "V1_01_easy"
    assert (folder / "mav0" / "cam0" / "data.csv").read_bytes() == EUROC_FILES[
        "mav0/cam0/data.csv"]
    assert (tmp_path / "V1_01_easy.zip").is_file()


def test_resume_after_partial_file(server, tmp_path):
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = data
    target = tmp_path / "a.tgz"
    (tmp_path / "a.tgz.part").write_bytes(data[:1000])
    download(server.url + "/a.tgz", target, progress=False,
             sha256=hashlib.sha256(data).hexdigest())
    assert target.read_bytes() == data and not (tmp_path / "a.tgz.part").exists()
    assert server.requests[-1] == ("/a.tgz", "bytes=1000-")


def test_interrupted_transfer_is_reported_then_resumed(server, tmp_path):
    data = _tgz(TUM_FILES)
    server.files["/a.tgz"] = data
    server.cut = 5000  # the connection drops after 5000 bytes of the body
    target = tmp_path / "a.tgz"
    with pytest.raises(DownloadError, match=f"incomplete, 5000 of {len(data)} bytes.*resume"):
        download(server.url + "/a.tgz", target, progress=False)
    assert (tmp_path / "a.tgz.part").stat().st_size == 5000 and not target.exists()
    server.cut = None
    download(server.url + "/a.tgz", target, progress=False)
    assert target.read_bytes() == data
    assert server.requests[-1][1] == "bytes=5000-"


def test_complete_part_and_server_without_ranges(server, tmp_path):
    data = _zip(EUROC_FILES)
    server.files["/b.zip"] = data
    (tmp_path / "b.zip.part").write_bytes(data)  # finished earlier, not yet renamed: 416
    download(server.url + "/b.zip", tmp_path / "b.zip", progress=False)
    assert (tmp_path / "b.zip").read_bytes() == data
    server.ranges = False  # 200 with the whole body: the part is restarted, not appended
    (tmp_path / "c.zip.part").write_bytes(b"garbage")
    download(server.url + "/b.zip", tmp_path / "c.zip", progress=False)
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
        fetch_dataset("tum", "fr1_xyz", tmp_path, url=server.url + "/a.tgz", progress=False)
    server.files["/b.zip"] = _zip(EUROC_FILES)[:-30]  # truncated zip
    with pytest.raises(ValueError, match="damaged or truncated zip"):
        fetch_dataset("euroc", "V1_01", tmp_path, url=server.url + "/b.zip", progress=False)


def test_http_404_and_offline(server, tmp_path):
    with pytest.raises(DownloadError, match="HTTP 404.*sequence name"):
        download(server.url + "/missing.tgz", tmp_path / "m.tgz", progress=False)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DownloadError, match="cannot reach 127.0.0.1.*internet connection"):
        download(f"http://127.0.0.1:{port}/a.tgz", tmp_path / "a.tgz", progress=False,
                 timeout=5)


def test_cli_download(server, tmp_path, capsys):
    server.files["/a.tgz"] = _tgz(TUM_FILES)
    assert cli.main(["download", "tum", "freiburg1_xyz", "--to", str(tmp_path),
                     "--url", server.url + "/a.tgz", "--silent"]) == 0
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
