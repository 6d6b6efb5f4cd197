"""Safe extraction of dataset archives (``.tar``, ``.tgz``, ``.tar.bz2``, ``.tar.xz``, ``.zip``).

Archives come from the network (``ferroslam download``) or the package (the demo sample);
either way a member must not write outside the destination folder, and a small archive must
not fill the disk. These checks are made on every member before anything is written, each
refusal a ``ValueError`` naming the archive and the member:

* names: absolute paths, ``..`` components and drive letters;
* kinds: links (symbolic or hard) and special files (devices, FIFOs);
* shape: a file and a folder of the same name (in either order);
* destination: a path that leads outside the destination through a symbolic link already
  there (``dest/data -> /elsewhere`` with a member ``data/x``);
* size: members announcing more than ``max_bytes`` in total.

While writing, the bytes actually written are counted against ``max_bytes`` too (the count,
not the header, is what fills the disk), and a file or folder already in the destination
where the archive puts the other kind is refused naming the member.
"""

from __future__ import annotations

import lzma
import tarfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import IO, Callable, Optional, Union

from ._files import atomic_output

__all__ = ["MAX_EXTRACTED_BYTES", "extract_archive"]

PathLike = Union[str, Path]
_TAR_SUFFIXES = (".tar", ".tgz", ".tar.gz", ".tar.bz2", ".tbz2", ".tar.xz", ".txz")
_BLOCK_BYTES = 1 << 20

MAX_EXTRACTED_BYTES = 64 << 30
"""Default cap on the bytes one archive may write (64 GiB). The largest archives
``ferroslam download`` knows unpack to a few GB (EuRoC sequences are 1-3 GB zipped, TUM
``.tgz`` files up to ~3 GB unpacked), so a genuine dataset stays far below it, while an archive
bomb (gigabytes of zeros from a few megabytes) stops here instead of filling the disk."""


@dataclass(frozen=True)
class _Member:
    """One archive entry, reduced to what the format-independent checks and writing need."""

    name: str  # as stored in the archive, for messages
    rel: PurePosixPath  # checked path relative to the destination
    is_dir: bool
    size_bytes: int  # as announced by the header
    info: object  # the TarInfo / ZipInfo, handed back to the archive's open function


def _checked_name(archive: Path, name: str) -> PurePosixPath:
    """``name`` as a relative path inside the destination, or ``ValueError``."""
    pure = PurePosixPath(name.replace("\\", "/"))
    if (pure.is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0])
            or not pure.parts):
        raise ValueError(f"{archive}: unsafe member path {name!r} (outside the destination)")
    return pure


def _refuse_link(archive: Path, name: str) -> ValueError:
    return ValueError(f"{archive}: member {name!r} is a link or special file (refused)")


def _size_text(n_bytes: int) -> str:
    return f"{n_bytes} bytes ({n_bytes / (1 << 30):.1f} GiB)"


def _check_shape(archive: Path, members: list[_Member]) -> None:
    """Refuse a file and a folder of the same name: extracting both would fail halfway
    (or silently drop one), whichever comes first in the archive."""
    files = {m.rel: m.name for m in members if not m.is_dir}
    for m in members:
        folders = list(m.rel.parents)[:-1] + ([m.rel] if m.is_dir else [])  # without "."
        for folder in folders:
            if folder in files:
                raise ValueError(f"{archive}: member {m.name!r} needs a folder {str(folder)!r} "
                                 f"but member {files[folder]!r} is a file of that name")


def _escaping_link(dest: Path, dest_real: Path, rel: PurePosixPath) -> Optional[Path]:
    """The first symbolic link already on the way from ``dest`` to ``dest / rel`` that
    leads outside ``dest_real`` (writing through it would escape the folder), or ``None``."""
    path = dest
    for part in rel.parts:
        path = path / part
        if path.is_symlink() and not path.resolve().is_relative_to(dest_real):
            return path
    return None


def _check_members(archive: Path, dest: Path, members: list[_Member], max_bytes: int) -> None:
    """All checks that need no writing (see the module doc), so a refusal writes nothing."""
    _check_shape(archive, members)
    dest_real = dest.resolve()
    for m in members:
        link = _escaping_link(dest, dest_real, m.rel)
        if link is not None:
            raise ValueError(f"{archive}: member {m.name!r} would be written outside "
                             f"{dest} through the symbolic link {link} -> {link.resolve()}")
    announced = sum(m.size_bytes for m in members if not m.is_dir)
    if announced > max_bytes:
        raise ValueError(f"{archive}: members announce {_size_text(announced)}, more than "
                         f"the limit of {_size_text(max_bytes)}; this looks like an archive bomb")


def _write_file(archive: Path, m: _Member, source: IO[bytes], target: Path, room_bytes: int,
                max_bytes: int) -> int:
    """Copy ``source`` to ``target`` and return the bytes written, counted as they are
    written; past ``room_bytes`` the file is deleted and ``ValueError`` raised."""
    written = 0
    # Through the one writer: a link or FIFO already at the target is never written through.
    with source, atomic_output(target) as tmp, open(tmp, "wb") as f:
        for block in iter(lambda: source.read(_BLOCK_BYTES), b""):
            written += len(block)
            if written > room_bytes:  # raised inside: the partial file is removed
                raise ValueError(f"{archive}: extracting member {m.name!r} goes past the "
                                 f"limit of {_size_text(max_bytes)} in total; genuine "
                                 "datasets are far smaller, so this looks like an archive "
                                 "bomb")
            f.write(block)
    return written


def _write_members(archive: Path, dest: Path, members: list[_Member],
                   open_member: Callable[[object], IO[bytes]], max_bytes: int) -> list[Path]:
    """Check ``members`` (:func:`_check_members`), then create their folders and files."""
    _check_members(archive, dest, members, max_bytes)
    written, total_bytes = [], 0
    for m in members:
        target = dest / m.rel
        try:
            if m.is_dir:
                target.mkdir(parents=True, exist_ok=True)
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            total_bytes += _write_file(archive, m, open_member(m.info), target,
                                       max_bytes - total_bytes, max_bytes)
        except (FileExistsError, NotADirectoryError, IsADirectoryError) as err:
            raise ValueError(f"{archive}: member {m.name!r} clashes with "
                             f"{err.filename or target}, "
                             "already in the destination as a file where a folder is needed "
                             "or the reverse; move it away") from None
        written.append(target)
    return written


def _extract_tar(archive: Path, dest: Path, max_bytes: int) -> list[Path]:
    try:
        with tarfile.open(archive, "r:*") as tar:
            members = []
            for info in tar.getmembers():  # reads the whole index: a truncated file fails here
                rel = _checked_name(archive, info.name)
                if not (info.isfile() or info.isdir()):
                    raise _refuse_link(archive, info.name)
                members.append(_Member(info.name, rel, info.isdir(), info.size, info))
            written = _write_members(archive, dest, members, tar.extractfile, max_bytes)
            # Read to the end of the compressed stream: its checksum (gzip CRC, bzip2, xz)
            # is verified only there, and damage inside stored data shows only then.
            while tar.fileobj is not None and tar.fileobj.read(_BLOCK_BYTES):
                pass
    except (tarfile.TarError, EOFError, OSError, zlib.error, lzma.LZMAError) as err:
        if isinstance(err, OSError) and err.errno is not None:  # the disk, not the data
            raise
        raise ValueError(f"{archive}: damaged or truncated tar archive ({err})") from None
    return written


def _extract_zip(archive: Path, dest: Path, max_bytes: int) -> list[Path]:
    try:
        with zipfile.ZipFile(archive) as zf:
            members = []
            for info in zf.infolist():
                rel = _checked_name(archive, info.filename)
                mode = (info.external_attr >> 16) & 0o170000
                if mode not in (0, 0o100000, 0o040000):  # unset, regular file, directory
                    raise _refuse_link(archive, info.filename)
                members.append(_Member(info.filename, rel, info.is_dir(), info.file_size, info))
            return _write_members(archive, dest, members, zf.open, max_bytes)  # CRC at the end
    except (zipfile.BadZipFile, EOFError, zipfile.LargeZipFile, zlib.error) as err:
        raise ValueError(f"{archive}: damaged or truncated zip archive ({err})") from None


def extract_archive(archive: PathLike, dest: PathLike, *,
                    max_bytes: int = MAX_EXTRACTED_BYTES) -> list[Path]:
    """Extract ``archive`` (tar with any compression, or zip) into folder ``dest``.

    Returns the written files. ``dest`` is created if needed; existing files are replaced.
    ``max_bytes`` caps the total size of the extracted files (default
    :data:`MAX_EXTRACTED_BYTES`).

    Raises:
        FileNotFoundError: ``archive`` does not exist.
        ValueError: unknown archive type, damaged/truncated archive (CRC or stream error),
            an unsafe or conflicting member, or more than ``max_bytes`` (see the module doc).
            Nothing is written for a refusal found by the checks made before writing; past
            ``max_bytes`` while writing, the file being written is deleted.
    """
    archive, dest = Path(archive), Path(dest)
    if not archive.is_file():
        raise FileNotFoundError(f"archive not found: {archive}")
    dest.mkdir(parents=True, exist_ok=True)
    name = archive.name.lower()
    if name.endswith(".zip") or (not name.endswith(_TAR_SUFFIXES) and zipfile.is_zipfile(archive)):
        return _extract_zip(archive, dest, max_bytes)
    if name.endswith(_TAR_SUFFIXES) or _is_tar(archive):
        return _extract_tar(archive, dest, max_bytes)
    raise ValueError(f"{archive}: not a tar or zip archive")


def _is_tar(archive: Path) -> bool:
    try:
        return tarfile.is_tarfile(archive)
    except (tarfile.TarError, EOFError, OSError, zlib.error, lzma.LZMAError):
        return False
