"""The sha256 manifest of a published results folder: what was published, checked before use.

``containergym-marl publish`` writes ``<folder>/MANIFEST.sha256`` (``sha256sum`` format: one
``<hash>  <path>`` line per file, paths relative to the folder) for every model and checkpoint file
it publishes (``runs/**``, ``models/**``: ``.zip``, ``.pt``, ``.npz``). ``compare`` (the shipped
policies) and ``containergym-marl publish --restore`` check every such file they read against it and refuse,
naming the file, when it is missing from the manifest or its bytes differ: a model file changed
after publication is never loaded (``sha256sum -c MANIFEST.sha256`` in the folder checks the same).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from containergym_marl.files import atomic_write_text

MANIFEST = "MANIFEST.sha256"
#: The files the manifest covers: what a loader reads as a model, a checkpoint or a buffer.
COVERED_SUFFIXES = (".zip", ".pt", ".npz")


class ManifestError(ValueError):
    """A published file is not the one that was published (or was never listed)."""


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def covered(folder: Path) -> list[Path]:
    """The files of ``folder`` the manifest lists: models, checkpoints and buffers under runs/ and models/."""
    return sorted(p for sub in ("runs", "models") for p in (folder / sub).rglob("*")
                  if p.is_file() and p.suffix in COVERED_SUFFIXES and not p.name.startswith("."))


def write_manifest(folder: str | Path) -> Path:
    folder = Path(folder)
    lines = [f"{sha256_bytes(p.read_bytes())}  {p.relative_to(folder).as_posix()}" for p in covered(folder)]
    return atomic_write_text(folder / MANIFEST, "\n".join(lines) + ("\n" if lines else ""))


def read_manifest(folder: str | Path) -> dict[str, str]:
    """{relative path: sha256}; a ManifestError when the folder has none or it is unreadable."""
    path = Path(folder) / MANIFEST
    if not path.is_file():
        raise ManifestError(f"{str(folder)!r} has no {MANIFEST}: its model files cannot be checked "
                            f"(containergym-marl publish writes it)")
    entries = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        digest, sep, name = line.partition("  ")
        if not sep or len(digest) != 64 or not name:
            raise ManifestError(f"{path}: line {number} is not '<sha256>  <path>'")
        entries[name] = digest
    return entries


def check(folder: str | Path, name: str, data: bytes, manifest: dict[str, str] | None = None) -> None:
    """Raise a ManifestError naming the file unless ``data`` is what the manifest of ``folder``
    lists for ``name`` (a path relative to ``folder``). Files the manifest does not cover (JSON,
    CSV) pass."""
    folder = Path(folder)
    if Path(name).suffix not in COVERED_SUFFIXES:
        return
    expected = (read_manifest(folder) if manifest is None else manifest).get(name)
    if expected is None:
        raise ManifestError(f"{folder / name}: not listed in {folder / MANIFEST}; refusing to load it")
    if sha256_bytes(data) != expected:
        raise ManifestError(f"{folder / name}: its sha256 differs from the one published in {folder / MANIFEST} "
                            f"(the file changed after publication); refusing to load it")
