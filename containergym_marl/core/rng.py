"""Per-simulation random streams, drawn in blocks so a batch needs no Python loop per step.

Every simulation owns one ``np.random.Generator``. Each *event* of a simulation (a reset or a step)
consumes exactly one row of its stream: ``n`` standard normals (the fill noise) and ``n`` uniforms
(initial volumes at reset; priorities of the ``"random"`` arbitration at a step). Rows are drawn
from the generator ``BLOCK_ROWS`` at a time. Because the rows a simulation sees depend only on its
own generator and its own event count, B simulations stepped together produce exactly what B
single simulations with the same generators produce.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

#: Rows drawn per refill. Part of the definition of the random stream: changing it changes every
#: trajectory for a given seed (and would bump the environments' versions).
BLOCK_ROWS = 32


class NoiseStreams:
    """Block-buffered random rows for B simulations with n containers."""

    def __init__(self, generators: Sequence[np.random.Generator], n_containers: int):
        self.n_containers = int(n_containers)
        self._generators = list(generators)
        b = len(self._generators)
        self._normals = np.empty((b, BLOCK_ROWS, self.n_containers))
        self._uniforms = np.empty((b, BLOCK_ROWS, self.n_containers))
        # A cursor at BLOCK_ROWS means "buffer exhausted": refill before the next draw.
        self._cursor = np.full(b, BLOCK_ROWS, dtype=np.int64)

    @property
    def batch_size(self) -> int:
        return len(self._generators)

    def generator(self, index: int) -> np.random.Generator:
        return self._generators[index]

    def set_generator(self, index: int, generator: np.random.Generator) -> None:
        """Replace simulation ``index``'s generator (a reseed); its buffered rows are discarded."""
        self._generators[index] = generator
        self._cursor[index] = BLOCK_ROWS

    def _refill(self, index: int) -> None:
        gen = self._generators[index]
        self._normals[index] = gen.standard_normal((BLOCK_ROWS, self.n_containers))
        self._uniforms[index] = gen.random((BLOCK_ROWS, self.n_containers))
        self._cursor[index] = 0

    def next_rows(self, sims: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One row for each simulation in ``sims`` (all when None): ``(normals, uniforms)``, (k, n)."""
        idx = np.arange(self.batch_size) if sims is None else np.asarray(sims, dtype=np.int64)
        cur = self._cursor[idx]
        exhausted = idx[cur >= BLOCK_ROWS]
        for i in exhausted:  # each simulation refills once every BLOCK_ROWS events
            self._refill(int(i))
        cur = self._cursor[idx]
        normals = self._normals[idx, cur]
        uniforms = self._uniforms[idx, cur]
        self._cursor[idx] = cur + 1
        return normals, uniforms
