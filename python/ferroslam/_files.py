"""The one way files are written and read: every file ferroslam writes goes through
:func:`atomic_output`, every run folder through :class:`StagedFolder`, and readers check
their input with :func:`regular_file` / :func:`read_bounded_text`.

Writing (:func:`atomic_output`):

* missing parent folders are created;
* a target that exists and is not a regular file is refused before anything is written:
  a directory (``IsADirectoryError``), a FIFO, a character or block device or a socket
  (``ValueError``), each naming the path; ``/dev/null`` is never replaced;
* a **symlink at the target is replaced by the file, never written through**: the data goes
  to a temporary file created (``O_EXCL``, so never through a planted link) beside the
  target and ``os.replace`` renames it over the link itself; what the link pointed to is
  left untouched;
* the target changes only when the write succeeded; on failure the temporary file is
  removed and a previous file stays as it was.

Run folders (:class:`StagedFolder`): a run writes into a fresh hidden folder inside
``--out`` (``.staging-*``: the same filesystem as the results, so moves are renames even
when ``--out`` is a mount point); when it ends, its entries are moved into ``--out`` (a planted symlink there is
replaced, never followed; a directory entry such as ``colmap/`` replaces the old one
whole). A failed run leaves the previous results in ``--out`` as they were and its partial
results in ``--out/partial-<UTC time>/``.

Reading: :func:`regular_file` refuses a missing path, a directory and special files (FIFO,
device, socket) from ``os.stat`` alone, so nothing blocks opening a FIFO;
:func:`read_bounded_text` reads a small text file (config, SPEC) with a size bound, opening
it non-blocking and checking the open file again (no race with a swapped-in FIFO), and
names the file in decode errors; :func:`check_nesting` bounds the nesting depth of a text
before it is parsed (deeply nested JSON/YAML otherwise ends in ``RecursionError``).
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional, Union

__all__ = ["MAX_CONFIG_BYTES", "MAX_NESTING", "StagedFolder", "atomic_output", "check_nesting",
           "check_target",
           "read_bounded_text", "regular_file", "write_bytes", "write_text"]

PathLike = Union[str, os.PathLike]

MAX_CONFIG_BYTES = 1 << 20  # 1 MiB: a config or SPEC is a few kB
MAX_NESTING = 32  # levels of [ / {: options are nested two or three deep

# The mode a plain open() would give (mkstemp makes 0600); the umask is read once because
# reading it means setting it, which is not thread-safe.
_UMASK = os.umask(0)
os.umask(_UMASK)
_FILE_MODE = 0o666 & ~_UMASK

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def check_target(target: Path) -> None:
    """Refuses a target that exists and is not a regular file or a symlink (which is
    replaced, not followed)."""
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        return
    except NotADirectoryError:
        _make_parent(target.parent)  # raises naming the parent that is a file
        raise
    if stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode):
        return
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(f"{target}: is a directory, not a file to write")
    raise ValueError(f"{target}: is {_kind(st.st_mode)}, not a regular file; refusing to "
                     "replace it")


def _make_parent(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        pass
    if not folder.is_dir():
        blocking = next(p for p in (folder, *folder.parents) if os.path.lexists(p))
        raise NotADirectoryError(f"{blocking}: exists and is not a folder" if blocking == folder
                                 else f"cannot create folder {folder}: {blocking} exists and "
                                 "is not a folder")


@contextmanager
def atomic_output(target: PathLike) -> Iterator[Path]:
    """Yields a temporary path beside ``target`` (an empty regular file) to write; renames
    it over ``target`` when the block ends without an exception, removes it otherwise.

    Raises:
        IsADirectoryError: ``target`` is a directory.
        NotADirectoryError: a parent of ``target`` is a file.
        ValueError: ``target`` is a FIFO, device or socket.
    """
    target = Path(target)
    check_target(target)
    _make_parent(target.parent)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    tmp = Path(name)
    try:
        os.fchmod(fd, _FILE_MODE)
        os.close(fd)
        yield tmp
        check_target(target)  # again: it may have changed while the data was written
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(target: PathLike, text: str) -> Path:
    """Writes ``text`` (UTF-8) to ``target`` through :func:`atomic_output`."""
    return write_bytes(target, text.encode("utf-8"))


def write_bytes(target: PathLike, data: bytes) -> Path:
    """Writes ``data`` to ``target`` through :func:`atomic_output`."""
    with atomic_output(target) as tmp:
        tmp.write_bytes(data)
    return Path(target)


class StagedFolder:
    """A run's output folder: ``with StagedFolder(out) as stage:`` write into
    ``stage.path`` (a fresh hidden folder inside ``out``); on success its entries replace those of
    the same name in ``out``; on an exception they go to ``out/partial-<UTC time>/``
    (``stage.partial`` then names it; ``None`` when nothing was written) and the exception
    propagates.

    Raises (on entry) ``NotADirectoryError`` when ``out`` exists and is not a folder.
    """

    def __init__(self, out: PathLike) -> None:
        self.out = Path(out)
        self.path: Optional[Path] = None
        self.partial: Optional[Path] = None
        self._created = False

    def __enter__(self) -> StagedFolder:
        self._created = not os.path.lexists(self.out)
        _make_parent(self.out)  # an unwritable --out fails before the run
        # Inside the folder: the same filesystem as its entries even when --out is a mount
        # point (a volume), so every move is a rename.
        self.path = Path(tempfile.mkdtemp(prefix=".staging-", dir=self.out))
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                try:
                    self._publish()
                except (OSError, ValueError) as err:
                    self.partial = self._keep_partial()
                    raise type(err)(f"{err}; the results are in {self.partial}/") from err
            else:
                self.partial = self._keep_partial()
        finally:
            shutil.rmtree(self.path, ignore_errors=True)  # rmtree never follows links
            if self._created and self.partial is None and exc_type is not None:
                try:
                    self.out.rmdir()  # a run that wrote nothing leaves no new empty folder
                except OSError:
                    pass

    def _publish(self) -> None:
        entries = sorted(self.path.iterdir())
        for src in entries:  # every target checked before any is replaced
            target = self.out / src.name
            if not src.is_dir():
                check_target(target)
            elif os.path.lexists(target) and not (target.is_symlink() or target.is_dir()):
                raise NotADirectoryError(f"{target}: exists and is not a folder")
        trash = self.path / ".replaced"
        trash.mkdir()
        for src in entries:
            target = self.out / src.name
            if src.is_dir() and os.path.lexists(target):
                # a folder (or a link planted in its place) cannot be renamed over: move it
                # into the staging folder, deleted with it
                os.replace(target, trash / src.name)
            os.replace(src, target)

    def _keep_partial(self) -> Optional[Path]:
        if not any(self.path.iterdir()):
            return None  # failed before writing anything: no empty partial folder
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        for n in range(1000):
            partial = self.out / (f"partial-{stamp}" + (f"-{n}" if n else ""))
            try:
                partial.mkdir()
            except FileExistsError:
                continue
            for src in self.path.iterdir():
                os.replace(src, partial / src.name)
            return partial
        raise FileExistsError(f"{self.out}: too many partial-{stamp}* folders")


def regular_file(path: PathLike, what: str = "file") -> Path:
    """``path`` as a ``Path`` after checking (``os.stat``, which never blocks) that it is a
    regular file (a symlink to one is fine).

    Raises:
        FileNotFoundError: nothing at ``path``.
        IsADirectoryError: a directory.
        ValueError: a FIFO, device or socket (reading it could block forever).
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    _require_regular(st.st_mode, path, what)
    return path


def _require_regular(mode: int, path: Path, what: str) -> None:
    if stat.S_ISDIR(mode):
        article = "an" if what[:1] in "aeiou" else "a"
        raise IsADirectoryError(f"{path}: is a directory, expected {article} {what}")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path}: is {_kind(mode)}, expected a regular {what}; refusing to "
                         "read it")


def read_bounded_text(path: PathLike, max_bytes: int = MAX_CONFIG_BYTES,
                      what: str = "file") -> str:
    """The UTF-8 text of the regular file ``path``, at most ``max_bytes`` long.

    Raises what :func:`regular_file` raises, and ``ValueError`` naming the file when it is
    larger than ``max_bytes`` or not UTF-8.
    """
    path = regular_file(path, what)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO swapped in: no wait
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(fd)
        _require_regular(st.st_mode, path, what)
        if st.st_size > max_bytes:
            raise ValueError(f"{path}: {st.st_size} bytes, more than the {max_bytes} a "
                             f"{what} may have")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise ValueError(f"{path}: more than the {max_bytes} bytes a {what} may have")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not UTF-8 text (byte {err.start})") from None


def check_nesting(text: str, source: str, max_depth: int = MAX_NESTING) -> None:
    """Raises ``ValueError`` naming ``source`` when ``[`` / ``{`` nest deeper than
    ``max_depth`` in ``text`` (JSON, or YAML flow style); brackets inside double-quoted
    strings do not count. Checked before parsing: parsers recurse per level."""
    depth = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            if depth > max_depth:
                raise ValueError(f"{source}: nested deeper than {max_depth} levels")
        elif ch in "]}":
            depth -= 1
