"""Safe extraction of dataset archives (``.tar``, ``.tgz``, ``.tar.bz2``, ``.tar.xz``, ``.zip``).

Archives come from the network (``ferroslam download``) or the package (the demo sample);
either way a member must not write outside the destination folder. Every member name is
checked before anything is written: absolute paths, ``..`` components, drive letters, links
(symbolic or hard) and special files (devices, FIFOs) are refused with ``ValueError``
naming the archive and the member.
"""

from __future__ import annotations

import lzma
import shutil
import tarfile
import zipfile
import zlib
from pathlib import Path, PurePosixPath
from typing import Union

__all__ = ["extract_archive"]

PathLike = Union[str, Path]
_TAR_SUFFIXES = (".tar", ".tgz", ".tar.gz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")


def _checked_name(archive: Path, name: str) -> PurePosixPath:
    """``name`` as a relative path inside the destination, or ``ValueError``."""
    pure = PurePosixPath(name.replace("\\", "/"))
    if (pure.is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0])
            or not pure.parts):
        raise ValueError(f"{archive}: unsafe member path {name!r} (outside the destination)")
    return pure


def _extract_tar(archive: Path, dest: Path) -> list[Path]:
    written = []
    try:
        with tarfile.open(archive, "r:*") as tar:
            members = tar.getmembers()  # reads the whole index: a truncated file fails here
            for m in members:
                rel = _checked_name(archive, m.name)
                if not (m.isfile() or m.isdir()):
                    raise ValueError(
                        f"{archive}: member {m.name!r} is a link or special file (refused)")
            for m in members:
                target = dest / _checked_name(archive, m.name)
                if m.isdir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                source = tar.extractfile(m)
                assert source is not None  # regular file
                with source, open(target, "wb") as f:
                    shutil.copyfileobj(source, f, 1 << 20)
                written.append(target)
            # Read to the end of the compressed stream: its checksum (gzip CRC, bzip2, xz)
            # is verified only there, and damage inside stored data shows only then.
            while tar.fileobj is not None and tar.fileobj.read(1 << 20):
                pass
    except (tarfile.TarError, EOFError, OSError, zlib.error, lzma.LZMAError) as err:
        if isinstance(err, OSError) and err.errno is not None:  # the disk, not the data
            raise
        raise ValueError(f"{archive}: damaged or truncated tar archive ({err})") from None
    return written


def _extract_zip(archive: Path, dest: Path) -> list[Path]:
    written = []
    try:
        with zipfile.ZipFile(archive) as zf:
            infos = zf.infolist()
            for info in infos:
                _checked_name(archive, info.filename)
                mode = (info.external_attr >> 16) & 0o170000
                if mode not in (0, 0o100000, 0o040000):  # unset, regular file, directory
                    raise ValueError(
                        f"{archive}: member {info.filename!r} is a link or special file (refused)")
            for info in infos:
                target = dest / _checked_name(archive, info.filename)
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(info) as source, open(target, "wb") as f:
                    shutil.copyfileobj(source, f, 1 << 20)  # CRC checked at the end
                written.append(target)
    except (zipfile.BadZipFile, EOFError, zipfile.LargeZipFile, zlib.error) as err:
        raise ValueError(f"{archive}: damaged or truncated zip archive ({err})") from None
    return written


def extract_archive(archive: PathLike, dest: PathLike) -> list[Path]:
    """Extract ``archive`` (tar with any compression, or zip) into folder ``dest``.

    Returns the written files. ``dest`` is created if needed; existing files are replaced.

    Raises:
        FileNotFoundError: ``archive`` does not exist.
        ValueError: unknown archive type, damaged/truncated archive (CRC or stream error),
            or an unsafe member (see the module doc); nothing is written for unsafe names,
            since all names are checked first.
    """
    archive, dest = Path(archive), Path(dest)
    if not archive.is_file():
        raise FileNotFoundError(f"archive not found: {archive}")
    dest.mkdir(parents=True, exist_ok=True)
    name = archive.name.lower()
    if name.endswith(".zip") or (not name.endswith(_TAR_SUFFIXES) and zipfile.is_zipfile(archive)):
        return _extract_zip(archive, dest)
    if name.endswith(_TAR_SUFFIXES) or _is_tar(archive):
        return _extract_tar(archive, dest)
    raise ValueError(f"{archive}: not a tar or zip archive")


def _is_tar(archive: Path) -> bool:
    try:
        return tarfile.is_tarfile(archive)
    except (tarfile.TarError, EOFError, OSError, zlib.error, lzma.LZMAError):
        return False
