"""Per-simulation random streams, drawn in blocks so a batch needs no Python loop per step.

Every simulation owns one ``np.random.Generator``. Each *event* of a simulation (a reset or a step)
consumes exactly one row of its stream: ``n`` standard normals (the fill noise) and ``n`` uniforms
(initial volumes at reset; priorities of the ``"random"`` arbitration at a step). Rows are drawn
from the generator ``BLOCK_ROWS`` at a time. Because the rows a simulation sees depend only on its
own generator and its own event count, B simulations stepped together produce exactly what B
single simulations with the same generators produce.

A refill of many simulations is one compiled call (:func:`_refill_blocks`) that draws from each
generator's own bit generator through NumPy's documented C interface (``bit_generator.ctypes``),
with NumPy's algorithms (its 256-step ziggurat for the normals): the same numbers, and the same
generator states afterwards, as ``standard_normal(out=...)`` then ``random(out=...)`` on each
generator, without a Python call per simulation (``benchmarks/throughput.py``). Generators whose
bit generators do not share one pair of C functions fall back to those Python calls.
"""

from __future__ import annotations

import ctypes
from typing import Sequence

import numba
import numpy as np
from llvmlite import ir
from numba.extending import intrinsic
from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r

from containergym_marl.config.pu_time import JIT_OPTIONS

#: Rows drawn per refill. Part of the definition of the random stream: changing it changes every
#: trajectory for a given seed (and would bump the environments' versions).
BLOCK_ROWS = 32

# NumPy's ziggurat tables (numpy/random/src/distributions/ziggurat_constants.h, as numba ships them)
_WI = np.asarray(wi_double, dtype=np.float64)
_KI = np.asarray(ki_double, dtype=np.uint64)
_FI = np.asarray(fi_double, dtype=np.float64)


def _c_call(return_type: ir.Type, numba_type):
    """An intrinsic ``call(function, state)``: calls the C function at address ``function`` with
    the pointer ``state``, both given as uint64, so compiled code takes a bit generator's functions
    as plain integers (cached on disk like the other kernels; the addresses change with each process)."""

    @intrinsic
    def call(typingctx, function, state):
        def codegen(context, builder, signature, args):
            void_p = ir.IntType(8).as_pointer()
            c_function = builder.inttoptr(args[0], ir.FunctionType(return_type, [void_p]).as_pointer())
            return builder.call(c_function, [builder.inttoptr(args[1], void_p)])

        return numba_type(numba.types.uint64, numba.types.uint64), codegen

    return call


_next_uint64 = _c_call(ir.IntType(64), numba.types.uint64)
_next_double = _c_call(ir.DoubleType(), numba.types.float64)


def _bitgen_functions(generator: np.random.Generator) -> tuple[int, int, int]:
    """(next_uint64, next_double, state) addresses of ``generator``'s bit generator."""
    interface = generator.bit_generator.ctypes
    return (ctypes.cast(interface.next_uint64, ctypes.c_void_p).value,
            ctypes.cast(interface.next_double, ctypes.c_void_p).value, int(interface.state_address))


@numba.njit(inline="always", **JIT_OPTIONS)
def _standard_normal(functions, state):
    """NumPy's ``random_standard_normal`` (numpy/random/src/distributions/distributions.c)."""
    while True:
        r = _next_uint64(functions[0], state)
        idx = r & np.uint64(0xFF)
        r >>= np.uint64(8)
        rabs = (r >> np.uint64(1)) & np.uint64(0x000FFFFFFFFFFFFF)
        x = rabs * _WI[idx]
        if r & np.uint64(1):
            x = -x
        if rabs < _KI[idx]:
            return x  # 99.3 % of draws
        if idx == 0:  # the tail
            while True:
                xx = -ziggurat_nor_inv_r * np.log1p(-_next_double(functions[1], state))
                yy = -np.log1p(-_next_double(functions[1], state))
                if yy + yy > xx * xx:
                    return -(ziggurat_nor_r + xx) if (rabs >> np.uint64(8)) & np.uint64(1) else ziggurat_nor_r + xx
        elif (_FI[idx - 1] - _FI[idx]) * _next_double(functions[1], state) + _FI[idx] < np.exp(-0.5 * x * x):
            return x


@numba.njit(**JIT_OPTIONS)
def _refill_blocks(functions, states, sims, normals, uniforms):
    """For each simulation b in ``sims``: its block of normals, then its block of uniforms, drawn
    from its bit generator (state address ``states[b]``; C functions ``functions``: next_uint64,
    next_double) into rows b·BLOCK_ROWS.. of the buffers.
    Holds the GIL: no other Python thread draws from these generators meanwhile."""
    n = normals.shape[1]
    for k in range(sims.shape[0]):
        b = sims[k]
        state = states[b]
        for r in range(b * BLOCK_ROWS, (b + 1) * BLOCK_ROWS):
            for i in range(n):
                normals[r, i] = _standard_normal(functions, state)
        for r in range(b * BLOCK_ROWS, (b + 1) * BLOCK_ROWS):
            for i in range(n):
                uniforms[r, i] = _next_double(functions[1], state)


class NoiseStreams:
    """Block-buffered random rows for B simulations with n containers.

    Buffers are laid out ``(B·BLOCK_ROWS, n)``: row ``b·BLOCK_ROWS + k`` is row k of simulation
    b's current block, so one step's rows are a single row gather. A refill writes each
    generator's output straight into the buffer, the same numbers as drawing a new
    ``(BLOCK_ROWS, n)`` array of normals, then one of uniforms.
    """

    def __init__(self, generators: Sequence[np.random.Generator], n_containers: int):
        self.n_containers = int(n_containers)
        self._generators = list(generators)
        b = len(self._generators)
        self._normals = np.empty((b * BLOCK_ROWS, self.n_containers))
        self._uniforms = np.empty((b * BLOCK_ROWS, self.n_containers))
        self._make_block_views()
        self._find_bitgen_functions()
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

    def _find_bitgen_functions(self) -> None:
        """The generators' state addresses and, when all their bit generators share one pair of C
        functions (e.g. all PCG64), that pair for :func:`_refill_blocks`; else None."""
        found = [_bitgen_functions(g) for g in self._generators]
        self._states = np.array([state for _, _, state in found], dtype=np.uint64)
        self._functions = [(u64, dbl) for u64, dbl, _ in found]
        self._set_bitgen(set(self._functions))

    def _set_bitgen(self, pairs: set) -> None:
        if len(pairs) != 1:
            self._bitgen = None
            return
        ((u64, dbl),) = pairs
        self._bitgen = np.array([u64, dbl], dtype=np.uint64)

    # Copies (deepcopy, pickle: SuperSuit and subprocess vec envs copy environments) must own
    # their buffers' block views, never views of the original's buffers, and the addresses of
    # their own generators (another process has other addresses).
    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("_normal_blocks", "_uniform_blocks", "_states", "_functions", "_bitgen"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._make_block_views()
        self._find_bitgen_functions()

    @property
    def num_sims(self) -> int:
        return len(self._generators)

    def generator(self, index: int) -> np.random.Generator:
        return self._generators[index]

    def set_generator(self, index: int, generator: np.random.Generator) -> None:
        """Replace simulation ``index``'s generator (a reseed); its buffered rows are discarded."""
        self._generators[index] = generator
        u64, dbl, self._states[index] = _bitgen_functions(generator)
        if self._functions[index] != (u64, dbl):  # another kind of bit generator: look at them all again
            self._functions[index] = (u64, dbl)
            self._set_bitgen(set(self._functions))
        self._cursor[index] = BLOCK_ROWS
        self._max_cursor = BLOCK_ROWS

    def _refill(self, sims: np.ndarray) -> None:
        """Draw a new block for each simulation in ``sims`` (each from its own generator)."""
        if self._bitgen is not None:
            _refill_blocks(self._bitgen, self._states, sims, self._normals, self._uniforms)
            self._cursor[sims] = 0
            return
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
