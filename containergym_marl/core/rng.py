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
    """Block-buffered random rows for B simulations with n containers.

    Buffers are laid out ``(B·BLOCK_ROWS, n)``: row ``b·BLOCK_ROWS + k`` is row k of simulation
    b's current block, so one step's rows are a single row gather. A refill writes the
    generator's output straight into the buffer (``out=``), which yields the same numbers as
    drawing a new ``(BLOCK_ROWS, n)`` array.
    """

    def __init__(self, generators: Sequence[np.random.Generator], n_containers: int):
        self.n_containers = int(n_containers)
        self._generators = list(generators)
        b = len(self._generators)
        self._normals = np.empty((b * BLOCK_ROWS, self.n_containers))
        self._uniforms = np.empty((b * BLOCK_ROWS, self.n_containers))
        self._make_block_views()
        self._row_base = np.arange(b, dtype=np.int64) * BLOCK_ROWS
        # A cursor at BLOCK_ROWS means "buffer exhausted": refill before the next draw.
        self._cursor = np.full(b, BLOCK_ROWS, dtype=np.int64)
        # The largest cursor, as a Python int, so that a step that needs no refill (31 in 32)
        # costs no search for exhausted simulations.
        self._max_cursor = BLOCK_ROWS

    def _make_block_views(self) -> None:
        # per-simulation blocks as views, so a refill creates no view objects
        b = len(self._generators)
        self._normal_blocks = [self._normals[i * BLOCK_ROWS:(i + 1) * BLOCK_ROWS] for i in range(b)]
        self._uniform_blocks = [self._uniforms[i * BLOCK_ROWS:(i + 1) * BLOCK_ROWS] for i in range(b)]

    # Copies (deepcopy, pickle: SuperSuit and subprocess vec envs copy environments) must own
    # their buffers' block views, never views of the original's buffers.
    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("_normal_blocks", "_uniform_blocks"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_block_views()

    @property
    def num_sims(self) -> int:
        return len(self._generators)

    def generator(self, index: int) -> np.random.Generator:
        return self._generators[index]

    def set_generator(self, index: int, generator: np.random.Generator) -> None:
        """Replace simulation ``index``'s generator (a reseed); its buffered rows are discarded."""
        self._generators[index] = generator
        self._cursor[index] = BLOCK_ROWS
        self._max_cursor = BLOCK_ROWS

    def _refill(self, sims: np.ndarray) -> None:
        """Draw a new block for each simulation in ``sims`` (each from its own generator)."""
        gens, nb, ub = self._generators, self._normal_blocks, self._uniform_blocks
        for i in sims.tolist():  # each simulation refills once every BLOCK_ROWS events
            gen = gens[i]
            gen.standard_normal(out=nb[i])
            gen.random(out=ub[i])
        self._cursor[sims] = 0

    def next_rows(
        self, sims: np.ndarray | None = None, *, normals: bool = True, uniforms: bool = True
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """One row for each simulation in ``sims`` (all when None): ``(normals, uniforms)``, (k, n).

        The row is consumed whether or not its parts are returned; ``normals=False`` or
        ``uniforms=False`` only skips copying that part out (None is returned in its place). Use the
        rows before the next call: for a single simulation they are views of its block, which a
        later refill overwrites.
        """
        if sims is None:
            cur = self._cursor
            if self._max_cursor >= BLOCK_ROWS:
                self._refill(np.flatnonzero(cur >= BLOCK_ROWS))
                self._max_cursor = int(cur.max())
            if cur.size == 1:  # one simulation: its row is a slice, no index arithmetic nor copy
                r = self._max_cursor
                cur[0] = self._max_cursor = r + 1
                return (self._normals[r:r + 1] if normals else None,
                        self._uniforms[r:r + 1] if uniforms else None)
            rows = self._row_base + cur
            cur += 1
            self._max_cursor += 1
        else:
            idx = np.asarray(sims, dtype=np.int64)
            cur = self._cursor[idx]
            exhausted = idx[cur >= BLOCK_ROWS]
            if exhausted.size:
                self._refill(exhausted)
                cur = self._cursor[idx]
            rows = self._row_base[idx] + cur
            self._cursor[idx] = cur + 1
            self._max_cursor = int(self._cursor.max())
        return (self._normals.take(rows, axis=0) if normals else None,
                self._uniforms.take(rows, axis=0) if uniforms else None)
