"""The sha256 manifest of a published results folder: what was published, checked before use.

``containergym-marl publish`` writes ``<folder>/MANIFEST.sha256`` (``sha256sum`` format: one
``<hash>  <path>`` line per file, paths relative to the folder) for every file it publishes under
``runs/`` and ``models/``: the models, checkpoints and buffers, and every file that decides what a
run is and how far it got (``args.json``, ``config.toml``, ``run.json``, ``metrics.csv``, a
checkpoint's progress file, a model's ``<method>.json``). A ``# size <bytes>  <path>`` line gives
each file's size (``sha256sum -c`` skips comment lines), so a reader refuses a file of another size
before hashing it. ``compare`` (the shipped policies) and ``containergym-marl publish --restore``
check every such file they read against it and refuse, naming the file, when it is missing from
the manifest, or its size or bytes differ: a file changed after publication is never used
(``sha256sum -c MANIFEST.sha256`` in the folder checks the same hashes). Hidden files (a run's
``.lock``, temporary files of a write cut short) are not published and not listed.

``containergym-marl demonstrations`` writes the same manifest for its output folder, over its
``minari/`` and ``agents/`` folders (:mod:`containergym_marl.demonstrations`).
"""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path
from typing import NamedTuple

from containergym_marl.files import UnsafePathError, atomic_write_text, open_file, refuse_links

MANIFEST = "MANIFEST.sha256"
#: The folders of a results folder whose files the manifest lists (every one, hidden ones aside).
COVERED_FOLDERS = ("runs", "models")
_SIZE = "# size "


class ManifestError(ValueError):
    """A published file is not the one that was published (or was never listed)."""


class Entry(NamedTuple):
    sha256: str
    size: int


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path, within: Path) -> str:
    """The sha256 of a regular file inside ``within`` (no link followed), read in blocks."""
    digest = hashlib.sha256()
    with open_file(path, "rb", within=within) as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return digest.hexdigest()


def is_covered(name: str, folders: tuple[str, ...] = COVERED_FOLDERS) -> bool:
    """Whether the manifest lists the file ``name`` (a path relative to the results folder);
    ``folders``: the folders it covers (a demonstrations folder's are ``minari`` and ``agents``)."""
    parts = Path(name).parts
    return len(parts) > 1 and parts[0] in folders and not parts[-1].startswith(".")


def covered(folder: Path, folders: tuple[str, ...] = COVERED_FOLDERS) -> list[Path]:
    """The files of ``folder`` the manifest lists, walked without following links (a link there is
    an :class:`~containergym_marl.files.UnsafePathError`, anything but a regular file too)."""
    found = []
    for sub in folders:
        for directory, subfolders, files in os.walk(refuse_links(folder / sub, folder)):
            for name in subfolders + files:
                path = Path(directory) / name
                refuse_links(path, directory)  # its folder was checked when the walk entered it
                if name in files and is_covered(path.relative_to(folder).as_posix(), folders):
                    if not stat.S_ISREG(path.lstat().st_mode):
                        raise UnsafePathError(f"{str(path)!r} is not a regular file; refusing to publish it")
                    found.append(path)
    return sorted(found)


def write_manifest(folder: str | Path, folders: tuple[str, ...] = COVERED_FOLDERS) -> Path:
    """``folder/MANIFEST.sha256`` for the files of ``folders`` in it (by default a results folder's)."""
    folder = Path(folder)
    lines = []
    for p in covered(folder, folders):
        name = p.relative_to(folder).as_posix()
        lines += [f"{_SIZE}{p.lstat().st_size}  {name}", f"{sha256_file(p, folder)}  {name}"]
    return atomic_write_text(folder / MANIFEST, "\n".join(lines) + ("\n" if lines else ""))


def read_manifest(folder: str | Path) -> dict[str, Entry]:
    """{relative path: (sha256, size)}; a ManifestError when the folder has none or it is unreadable
    (a hash without its size line included: a manifest from before sizes were listed)."""
    path = Path(folder) / MANIFEST
    try:
        f = open_file(path, "r", encoding="utf-8")  # a link is refused (UnsafePathError), never followed
    except FileNotFoundError:
        raise ManifestError(f"{str(folder)!r} has no {MANIFEST}: its model files cannot be checked "
                            f"(containergym-marl publish writes it)") from None
    digests, sizes = {}, {}
    with f:
        for number, line in enumerate(f, start=1):
            line = line.rstrip("\n")
            if line.startswith(_SIZE):
                size, sep, name = line[len(_SIZE):].partition("  ")
                if not sep or not size.isdigit() or not name:
                    raise ManifestError(f"{path}: line {number} is not '{_SIZE}<bytes>  <path>'")
                sizes[name] = int(size)
                continue
            if line.startswith("#"):
                continue
            digest, sep, name = line.partition("  ")
            if not sep or len(digest) != 64 or not name:
                raise ManifestError(f"{path}: line {number} is not '<sha256>  <path>'")
            digests[name] = digest
    if unsized := sorted(set(digests) ^ set(sizes)):
        raise ManifestError(f"{path}: {unsized[0]} has a hash without a size or a size without a hash (written by "
                            f"an older containergym-marl publish? publish the folder again)")
    return {name: Entry(digest, sizes[name]) for name, digest in digests.items()}


def _expected(folder: Path, name: str, manifest: dict[str, Entry] | None) -> Entry:
    expected = (read_manifest(folder) if manifest is None else manifest).get(name)
    if expected is None:
        raise ManifestError(f"{folder / name}: not listed in {folder / MANIFEST}; refusing to use it")
    return expected


def _differs(folder: Path, name: str, what: str) -> ManifestError:
    return ManifestError(f"{folder / name}: its {what} differs from the one published in {folder / MANIFEST} "
                         f"(the file changed after publication); refusing to use it")


def check(folder: str | Path, name: str, data: bytes, manifest: dict[str, Entry] | None = None) -> None:
    """Raise a ManifestError naming the file unless ``data`` is what the manifest of ``folder``
    lists for ``name`` (a path relative to ``folder``). Files the manifest does not cover (outside
    runs/ and models/, hidden ones) pass."""
    folder = Path(folder)
    if not is_covered(name):
        return
    if sha256_bytes(data) != _expected(folder, name, manifest).sha256:  # already read: no size check first
        raise _differs(folder, name, "sha256")


def check_file(folder: str | Path, name: str, manifest: dict[str, Entry] | None = None) -> None:
    """:func:`check` for the file ``name`` of ``folder`` as it is on disk, in the order that reads
    least: listed, then a regular file (no link followed) of the listed size, then its hash, read
    in blocks. A file of another size is never read."""
    folder = Path(folder)
    expected = _expected(folder, name, manifest)
    path = refuse_links(folder / name, folder)
    if path.lstat().st_size != expected.size:
        raise _differs(folder, name, "size")
    if sha256_file(path, folder) != expected.sha256:
        raise _differs(folder, name, "sha256")
