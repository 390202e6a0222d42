"""Crash-safe file writes, and the one rule about symbolic links in the folders the package writes.

Everything the package writes goes through :func:`atomic_write`, so a reader (a resumed run, a rerun
of ``compare``) sees the old or the new file, never a part of one.

Links. A run, results or output folder may come from someone else, and a link in it would make a
writer (or a reader that copies what it reads) reach outside it. So the folder a command is given
(``train --out``, ``--runs``, ``--compare``, ``publish --to``) may itself be reached through links
(a home directory on another disk, say), but no path below it may be a symbolic link: not a file,
not a folder the package finds or creates there (``checkpoints/``, ``tb/``, ``runs/<run>/``,
``evaluations/<config>/``…). :func:`refuse_links` checks one path, :func:`refuse_links_in` a whole
folder (walked without following links), :func:`open_file` opens a file with ``O_NOFOLLOW`` and
requires a regular file (never a fifo that would block), and :func:`atomic_write` refuses a path
that breaks the rule; each raises an :class:`UnsafePathError` naming the path and the rule before
anything is read or written there. Taking a run's lock (:class:`~containergym_marl.rundir.RunLock`,
which every writer of a run does) checks the whole run directory.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from pathlib import Path
from typing import IO, Callable


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The process's umask when the package was imported: new files get 0o666 & ~umask, as open() gives.
_UMASK = _umask()

LINK_RULE = ("nothing inside a run, results or output folder may be a symbolic link (the package never "
             "follows one there; only the folder given may be reached through links)")


class UnsafePathError(ValueError):
    """A path inside a folder the package reads or writes is a symbolic link, lies outside the folder
    or is not a regular file: refused before anything is read or written there."""


def _link_error(path: str | Path) -> UnsafePathError:
    return UnsafePathError(f"{str(path)!r} is a symbolic link; {LINK_RULE}: replace it by the file or folder itself")


def refuse_links(path: str | Path, within: str | Path) -> Path:
    """Raise an :class:`UnsafePathError` unless ``path`` lies inside ``within`` (no ``..``) and no
    component of it below ``within``, the file itself included, is a symbolic link (``within``
    itself may be one). Components that do not exist yet are fine: whoever creates them makes real
    folders. Returns ``path``."""
    path, within = Path(path), Path(within)
    try:
        parts = path.relative_to(within).parts
    except ValueError:
        parts = ("..",)
    if ".." in parts:
        raise UnsafePathError(f"{str(path)!r} is not inside {str(within)!r}; refusing to read or write it")
    current = within
    for part in parts:
        current = current / part
        if current.is_symlink():
            raise _link_error(current)
    return path


def refuse_links_in(folder: str | Path) -> None:
    """Raise an :class:`UnsafePathError` naming the first symbolic link found anywhere below
    ``folder`` (walked without following links; ``folder`` itself may be one, or absent)."""
    for directory, folders, files in os.walk(folder):  # a linked folder is listed, never entered
        for name in sorted(folders + files):
            if os.path.islink(os.path.join(directory, name)):
                raise _link_error(os.path.join(directory, name))


#: open() modes that :func:`open_file` takes (text or binary), as os.open flags.
_FLAGS = {"r": os.O_RDONLY, "a": os.O_WRONLY | os.O_APPEND | os.O_CREAT, "a+": os.O_RDWR | os.O_APPEND | os.O_CREAT}
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # Windows has none: refuse_links's lstat is the check there


def open_file(path: str | Path, mode: str = "rb", within: str | Path | None = None, **kwargs) -> IO:
    """``open(path, mode)`` (``mode`` one of r, a, a+, text or binary) for a regular file that is
    no symbolic link, inside ``within`` by :func:`refuse_links`'s rule (default: the file's folder,
    i.e. only the file itself is checked). The final component is opened with ``O_NOFOLLOW``, so a
    link put there after the check is refused too, and non-blocking, so a fifo is refused rather
    than waited on."""
    path = Path(path)
    refuse_links(path, path.parent if within is None else within)
    try:
        fd = os.open(path, _FLAGS[mode.replace("b", "")] | _NOFOLLOW | _NONBLOCK | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise _link_error(path) from None
        raise
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise UnsafePathError(f"{str(path)!r} is not a regular file; refusing to read or write it")
        if _NONBLOCK:
            os.set_blocking(fd, True)
        return os.fdopen(fd, mode, **kwargs)
    except BaseException:
        os.close(fd)
        raise


def atomic_write(path: str | Path, write: Callable[[Path], None], within: str | Path | None = None,
                 durable: bool = True) -> Path:
    """Write ``path`` crash-safe: ``write(tmp)`` fills a temporary file in the same directory, which
    is flushed to disk and renamed over ``path``. A reader sees the old or the new file, never a part.
    ``durable=False`` leaves out the two flushes to disk (file and folder), for a file that is
    rewritten often and made durable later (:func:`sync_file`): a process killed at any point still
    leaves the old or the new file; only a crash of the machine may lose the newest writes.
    The file keeps its permissions when it existed; a new one gets what ``open`` would give it
    (0o666 less the umask), not the temporary file's private 0o600. ``within`` is the folder the
    caller was given (a run, results or output folder): no component of ``path`` below it may be a
    symbolic link (:func:`refuse_links`; by default only the file itself is checked)."""
    path = Path(path)
    refuse_links(path, path.parent if within is None else within)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = path.lstat().st_mode & 0o7777
    except FileNotFoundError:
        mode = 0o666 & ~_UMASK
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, mode)
        if durable:
            sync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    if durable:
        _fsync_dir(path.parent)
    return path


def sync_file(path: str | Path) -> None:
    """Flush ``path``'s written data to disk (nothing when it does not exist)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def temporary_target(name: str) -> str | None:
    """The file name that a temporary file of :func:`atomic_write` (``.<name>.<random>.tmp``) was
    to become, or None for any other name. A temporary file that outlives its writer (killed
    before the rename) is never read: no reader's name pattern matches it."""
    if not (name.startswith(".") and name.endswith(".tmp")):
        return None
    target, dot, _random = name[1:-len(".tmp")].rpartition(".")
    return target if dot and target else None


def atomic_write_text(path: str | Path, text: str, within: str | Path | None = None) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(text), within)


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):  # not every platform / file system can open directories
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
