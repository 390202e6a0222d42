"""Crash-safe file writes: everything the package writes goes through :func:`atomic_write`, so a
reader (a resumed run, a rerun of ``compare``) sees the old or the new file, never a part of one."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Callable


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The process's umask when the package was imported: new files get 0o666 & ~umask, as open() gives.
_UMASK = _umask()


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Write ``path`` crash-safe: ``write(tmp)`` fills a temporary file in the same directory, which
    is flushed to disk and renamed over ``path``. A reader sees the old or the new file, never a part.
    The file keeps its permissions when it existed; a new one gets what ``open`` would give it
    (0o666 less the umask), not the temporary file's private 0o600."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = path.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = 0o666 & ~_UMASK
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, mode)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)
    return path


def temporary_target(name: str) -> str | None:
    """The file name that a temporary file of :func:`atomic_write` (``.<name>.<random>.tmp``) was
    to become, or None for any other name. A temporary file that outlives its writer (killed
    before the rename) is never read: no reader's name pattern matches it."""
    if not (name.startswith(".") and name.endswith(".tmp")):
        return None
    target, dot, _random = name[1:-len(".tmp")].rpartition(".")
    return target if dot and target else None


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(text))


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):  # not every platform / file system can open directories
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
