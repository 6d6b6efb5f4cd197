"""Fetch public datasets from their official servers: ``ferroslam download``.

* TUM RGB-D: ``https://cvg.cit.tum.de/rgbd/dataset/freiburgN/rgbd_dataset_freiburgN_NAME.tgz``
  (names like ``freiburg1_xyz``, ``fr1_xyz`` or ``rgbd_dataset_freiburg1_xyz``), extracted
  to ``DIR/rgbd_dataset_freiburg1_xyz/``.
* EuRoC MAV (ASL zip): ``http://robotics.ethz.ch/~asl-datasets/ijrr_euroc_mav_dataset/
  ROOM/NAME/NAME.zip`` (``MH_01_easy`` ... ``V2_03_difficult``; ``V1_01`` is enough),
  extracted to ``DIR/NAME/mav0/``. The server is known to us over plain http only (whether
  it offers https could not be checked), so EuRoC needs the archive's ``sha256`` or an
  https mirror (``url``).
* KITTI odometry needs a (free) login, so :func:`kitti_instructions` says what to fetch.

Downloads go to ``<archive>.part`` and resume with an HTTP ``Range`` request; the byte count
must match the server's ``Content-Length`` (and ``sha256`` when one is given) before the
file is renamed and extracted (:func:`ferroslam.archives.extract_archive`: no member may
escape the folder). Only ``http://`` and ``https://`` addresses are fetched; plain http,
which anyone on the path can alter, needs ``sha256``, and a redirect from https to http is
refused for the same reason. A download stops past :data:`MAX_DOWNLOAD_BYTES`. Standard
library (``urllib``) and tqdm only.
"""

from __future__ import annotations

import hashlib
import http.client
import os
import re
import socket
import ssl
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

from tqdm import tqdm

from ._files import check_target
from .archives import extract_archive

__all__ = [
    "DATASETS",
    "DatasetSource",
    "DownloadError",
    "EUROC_SEQUENCES",
    "MAX_DOWNLOAD_BYTES",
    "download",
    "fetch_dataset",
    "kitti_instructions",
    "resolve",
]

DATASETS = ("tum", "euroc", "kitti")
TUM_URL = "https://cvg.cit.tum.de/rgbd/dataset/freiburg{n}/rgbd_dataset_freiburg{n}_{rest}.tgz"
EUROC_URL = "http://robotics.ethz.ch/~asl-datasets/ijrr_euroc_mav_dataset/{room}/{name}/{name}.zip"
EUROC_SEQUENCES = (
    "MH_01_easy", "MH_02_easy", "MH_03_medium", "MH_04_difficult", "MH_05_difficult",
    "V1_01_easy", "V1_02_medium", "V1_03_difficult",
    "V2_01_easy", "V2_02_medium", "V2_03_difficult",
)
_EUROC_ROOMS = {"MH": "machine_hall", "V1": "vicon_room1", "V2": "vicon_room2"}
_TUM_NAME = re.compile(r"^(?:rgbd_dataset_)?(?:freiburg|fr)([123])[_/]([a-z0-9_]+?)(?:\.tgz)?$")
_CHUNK = 1 << 16
_SHA256_HEX = re.compile(r"^[0-9a-fA-F]{64}$")

MAX_DOWNLOAD_BYTES = 16 << 30
"""Default cap on one download (16 GiB). The largest archives the command knows are a few GB
(EuRoC sequences 1-3 GB zipped, TUM ``.tgz`` files smaller), so a genuine archive stays far
below it, while a wrong address or a server sending an endless body stops here instead of
filling the disk."""


class DownloadError(RuntimeError):
    """A download failed: offline, HTTP error, truncated transfer or checksum mismatch.
    The message says what happened and what to do."""


@dataclass(frozen=True)
class DatasetSource:
    """Where one sequence comes from and where it ends up.

    ``url``: the official archive; ``archive_name``: its file name; ``subdir``: folder under
    the destination to extract into (``""``: the archive has its own top folder);
    ``sequence``: the sequence folder (relative to the destination) after extraction;
    ``marker``: a file or folder the sequence folder must contain.
    """

    dataset: str
    name: str
    url: str
    archive_name: str
    subdir: str
    sequence: str
    marker: str


def resolve(dataset: str, name: str) -> DatasetSource:
    """The source of ``name`` in ``dataset`` (``"tum"`` or ``"euroc"``).

    Raises:
        ValueError: unknown dataset, a name that does not fit the dataset's pattern
            (the message lists the expected form), or ``"kitti"`` (see
            :func:`kitti_instructions`).
    """
    if dataset == "tum":
        m = _TUM_NAME.match(name.strip().lower())
        if m is None:
            raise ValueError(
                f"unknown TUM sequence name {name!r}: expected freiburgN_NAME, frN_NAME or "
                "rgbd_dataset_freiburgN_NAME with N in 1-3, e.g. freiburg1_xyz "
                "(list: https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download)"
            )
        n, rest = m.groups()
        folder = f"rgbd_dataset_freiburg{n}_{rest}"
        return DatasetSource("tum", folder, TUM_URL.format(n=n, rest=rest), f"{folder}.tgz",
                             "", folder, "rgb.txt")
    if dataset == "euroc":
        matches = [s for s in EUROC_SEQUENCES if s.lower().startswith(name.strip().lower())]
        if len(name.strip()) < 5 or len(matches) != 1:
            raise ValueError(f"unknown EuRoC sequence {name!r}: expected one of "
                             f"{', '.join(EUROC_SEQUENCES)} (a prefix such as V1_01 is enough)")
        full = matches[0]
        url = EUROC_URL.format(room=_EUROC_ROOMS[full[:2]], name=full)
        return DatasetSource("euroc", full, url, f"{full}.zip", full, full, "mav0")
    if dataset == "kitti":
        raise ValueError("KITTI needs a login; see kitti_instructions()")
    raise ValueError(f"unknown dataset {dataset!r}: expected one of {', '.join(DATASETS)}")


def kitti_instructions(name: str, dest: Union[str, Path]) -> str:
    """What to do by hand for KITTI odometry sequence ``name`` (e.g. ``"00"``)."""
    seq = name.strip().zfill(2) if name.strip().isdigit() else name.strip()
    dest = Path(dest)
    return f"""\
KITTI cannot be downloaded automatically: its archives need a (free) account.
  1. Register at https://www.cvlibs.net/datasets/kitti/user_register.php and log in.
  2. On https://www.cvlibs.net/datasets/kitti/eval_odometry.php download
     "odometry data set (grayscale, 22 GB)"  data_odometry_gray.zip,
     "odometry data set (calibration files)" data_odometry_calib.zip and
     "odometry ground truth poses (4 MB)"    data_odometry_poses.zip.
  3. Unzip all three into {dest} (they share the top folder dataset/), giving
     {dest / 'dataset' / 'sequences' / seq}/image_0, image_1, calib.txt, times.txt and
     {dest / 'dataset' / 'poses' / seq}.txt (ground truth: sequences 00-10 only).
  4. Run: ferroslam run {dest / 'dataset' / 'sequences' / seq} --sensor stereo"""


def _checked_sha256(sha256: Optional[str]) -> Optional[str]:
    """``sha256`` in lower case, checked to be 64 hex characters before anything is fetched
    (a typo would otherwise show only as a mismatch after the whole download)."""
    if sha256 is None:
        return None
    if not _SHA256_HEX.match(sha256.strip()):
        raise ValueError(f"sha256 must be 64 hexadecimal characters, got {sha256!r}")
    return sha256.strip().lower()


def _check_url(url: str, sha256: Optional[str]) -> None:
    """Refuse, before any network access, addresses that are not http(s) (``file:`` would
    read local files, ``data:`` anything) and plain http without a checksum: anyone on the
    path could replace the archive, and only ``sha256`` would notice."""
    scheme = urllib.parse.urlparse(url).scheme.lower()
    if scheme not in ("http", "https"):
        raise ValueError(f"{url}: only http:// and https:// addresses can be downloaded")
    if scheme == "http" and sha256 is None:
        raise DownloadError(
            f"{url} is plain http, which anyone on the way can alter: pass the archive's "
            "published checksum with --sha256 HEX, or an https:// mirror with --url")


class _NoDowngradeRedirect(urllib.request.HTTPRedirectHandler):
    """Follows redirects, except from https to anything else: the certificate check that
    made the https address trustworthy would silently be lost."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        old_scheme = urllib.parse.urlparse(req.full_url).scheme.lower()
        new_scheme = urllib.parse.urlparse(newurl).scheme.lower()
        if new_scheme not in ("http", "https") or (old_scheme == "https" and new_scheme != "https"):
            raise DownloadError(f"{req.full_url} redirects to {newurl}: refused (from https "
                                "a redirect must stay on https, from http go to http(s))")
        return super().redirect_request(req, fp, code, msg, headers, newurl)


def _network_error(url: str, reason: object) -> DownloadError:
    """A certificate problem said as such (retrying would not help), else offline."""
    host = urllib.parse.urlparse(url).netloc
    if isinstance(reason, ssl.SSLCertVerificationError):
        return DownloadError(
            f"the TLS certificate of {host} could not be verified ({reason.verify_message}): "
            "the system's CA certificates may be outdated (update them, or set SSL_CERT_FILE "
            "to your organisation's CA bundle behind an inspecting proxy), or the server is "
            "not who it claims to be")
    return DownloadError(
        f"cannot reach {host} ({reason}): check the internet connection or proxy "
        f"(HTTPS_PROXY) and run the same command again; a partial download resumes"
    )


def _open(url: str, start: int, timeout: float):
    request = urllib.request.Request(url, headers={"User-Agent": "ferroslam-download"})
    if start:
        request.add_header("Range", f"bytes={start}-")
    opener = urllib.request.build_opener(_NoDowngradeRedirect)
    try:
        return opener.open(request, timeout=timeout)
    except urllib.error.HTTPError as err:
        if err.code == 416 and start:  # nothing left to send: the part may be complete
            return err
        raise DownloadError(f"{url}: HTTP {err.code} {err.reason}"
                            + (" (check the sequence name)" if err.code == 404 else "")) from None
    except (urllib.error.URLError, socket.timeout, ConnectionError, ssl.SSLError) as err:
        raise _network_error(url, getattr(err, "reason", err)) from None


_CONTENT_RANGE = re.compile(r"^bytes\s+(?:(\d+)-\d+|\*)/(\d+|\*)$")


def _content_range(value: Optional[str]) -> tuple[Optional[int], Optional[int]]:
    """``(first byte, total size)`` of ``Content-Range: bytes a-b/total`` (``None`` if
    unknown or absent; ``bytes */total`` has no first byte)."""
    m = _CONTENT_RANGE.match((value or "").strip())
    if m is None:
        return None, None
    first, total = m.groups()
    return (None if first is None else int(first)), (None if total == "*" else int(total))


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def download(
    url: str,
    path: Union[str, Path],
    *,
    sha256: Optional[str] = None,
    progress: bool = True,
    timeout: float = 30.0,
    max_bytes: int = MAX_DOWNLOAD_BYTES,
) -> Path:
    """Download ``url`` to ``path`` with resume; return ``path``.

    Bytes go to ``path + ".part"``; an existing part is continued with ``Range: bytes=N-``
    (a server that ignores ranges sends everything again: the part is restarted). The
    transfer is complete when the part holds the size announced by the server
    (``Content-Length`` / ``Content-Range``); then ``sha256`` (hex) is checked, if given,
    and the part is renamed to ``path``. ``url`` must be https, or http with ``sha256``.
    A file larger than ``max_bytes`` is refused when announced, or stopped and deleted.

    Raises:
        ValueError: ``url`` is not http(s), or ``sha256`` is not 64 hex characters.
        DownloadError: plain http without ``sha256``, a redirect from https to http,
            offline / unreachable host (``URLError``, timeout), certificate not verified,
            HTTP error, more than ``max_bytes`` (announced, or received: the part is
            deleted), transfer shorter than announced (the part is kept: call again to
            resume), more bytes than announced, or checksum mismatch (the file is deleted).
    """
    sha256 = _checked_sha256(sha256)
    _check_url(url, sha256)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(path.name + ".part")
    # The part is appended to across calls (resume), so it cannot go through atomic_output;
    # it gets the same refusals: no special file, and a link there is dropped, not followed.
    check_target(path)
    check_target(part)
    if part.is_symlink():
        part.unlink()
    for attempt in (0, 1):  # a part the server does not continue is restarted once
        start = part.stat().st_size if part.is_file() else 0
        response = _open(url, start, timeout)
        with response:
            status = getattr(response, "status", None) or response.getcode()
            first, total = _content_range(response.headers.get("Content-Range"))
            if status == 416 and total == start:  # the part is already complete
                break
            if status == 416 or (status == 206 and first != start):
                if attempt:
                    raise DownloadError(f"{url}: the server does not resume {part} "
                                        f"correctly; delete it and run again")
                part.unlink()
                continue
            if status != 206:  # 200: the whole file (a server without range support)
                start = 0
                length = response.headers.get("Content-Length", "")
                total = int(length) if length.isdigit() else None
            if total is not None and total > max_bytes:
                raise DownloadError(f"{url}: the server announces {total} bytes, more than the "
                                    f"limit of {max_bytes} bytes; check the address")
            _receive(response, part, start, total, progress, path.name, url, max_bytes)
            break
    size = part.stat().st_size
    if total is not None and size != total:
        raise DownloadError(
            f"{url}: transfer incomplete, {size} of {total} bytes in {part}; run the same "
            "command again to resume" if size < total else
            f"{url}: received {size} bytes but the server announced {total}; delete {part}"
        )
    if sha256 is not None:
        actual = _sha256(part)
        if actual != sha256:
            part.unlink()
            raise DownloadError(f"{url}: sha256 mismatch (got {actual}, expected {sha256}); "
                                "the download was deleted, run the command again")
    check_target(path)  # again: it may have changed during the transfer
    part.replace(path)
    return path


def _receive(response, part: Path, start: int, total: Optional[int], progress: bool,
             label: str, url: str, max_bytes: int) -> None:
    """Append the body to ``part``, counting bytes as they arrive: a server need not
    announce a size, so only the count stops an endless body (the part is then deleted)."""
    bar = tqdm(total=total, initial=start, unit="B", unit_scale=True, unit_divisor=1024,
               desc=label, disable=not progress)
    size = start
    try:
        flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | (os.O_APPEND if start else os.O_TRUNC)
        with os.fdopen(os.open(part, flags, 0o666), "wb") as f:
            while size <= max_bytes:
                try:
                    block = response.read(_CHUNK)
                except (socket.timeout, ConnectionError) as err:
                    raise _network_error(url, err) from None
                except http.client.IncompleteRead:
                    break  # the size check reports it; the part is kept for a resume
                if not block:
                    break
                f.write(block)
                size += len(block)
                bar.update(len(block))
    finally:
        bar.close()
    if size > max_bytes:
        part.unlink()
        raise DownloadError(f"{url}: the server sent more than the limit of {max_bytes} "
                            f"bytes; stopped and deleted {part}; check the address")


def fetch_dataset(
    dataset: str,
    name: str,
    dest: Union[str, Path],
    *,
    url: Optional[str] = None,
    sha256: Optional[str] = None,
    keep_archive: bool = False,
    progress: bool = True,
    timeout: float = 30.0,
) -> Path:
    """Download and extract one sequence into ``dest``; return the sequence folder.

    ``url`` replaces the official address (a mirror). An archive already complete in
    ``dest`` is not fetched again. After extraction the archive is deleted unless
    ``keep_archive``.

    Raises:
        ValueError: unknown dataset or name (see :func:`resolve`), ``sha256`` not 64 hex
            characters, damaged archive or unsafe member paths (see
            :mod:`ferroslam.archives`).
        DownloadError: see :func:`download` (the official EuRoC address is plain http:
            it needs ``sha256`` or an https ``url``).
    """
    sha256 = _checked_sha256(sha256)
    source = resolve(dataset, name)
    dest = Path(dest).expanduser()
    archive = dest / source.archive_name
    if not archive.is_file():
        download(url or source.url, archive, sha256=sha256, progress=progress,
                 timeout=timeout)
    elif sha256 is not None and _sha256(archive) != sha256:
        raise DownloadError(f"{archive}: sha256 mismatch; delete it and run again")
    try:
        extract_archive(archive, dest / source.subdir if source.subdir else dest)
    except ValueError as err:
        raise ValueError(f"{err}; delete {archive} and download again") from None
    folder = dest / source.sequence
    if not (folder / source.marker).exists():  # archive with an extra top folder
        found = sorted(folder.glob(f"*/{source.marker}"))
        if len(found) != 1:
            raise ValueError(f"{archive} did not contain {source.sequence}/{source.marker} "
                             f"(the {source.dataset} layout); check the archive")
        folder = found[0].parent
    if not keep_archive:
        archive.unlink()
    return folder
