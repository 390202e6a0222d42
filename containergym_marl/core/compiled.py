"""Optional compiled backend: :func:`step` of :mod:`.dynamics` as one numba loop per simulation.

The numpy functions in :mod:`.dynamics` define the physics; this module is a faster way to run
them, used when numba is installed (``pip install containergym-marl[fast]``) and selected by
:func:`resolve_backend`. Without numba everything runs on the numpy path.

Why a second formulation at all: a step of one simulation is ~60 small numpy calls, each paying
~1 µs of dispatch for a handful of numbers, so a single environment spends almost all its time in
overhead; and at large B numpy makes ~25 passes over B·n entries where one fused loop reads each
entry once. The loop here follows :func:`.dynamics.step` operation by operation (same IEEE
operations in the same order, no fast-math, numpy's pairwise order for row sums), so:

* states (volumes, timers, step counts), grants, denials, PU choices and episode ends are
  bit-identical to the numpy backend;
* container rewards agree to within 1e-15 (absolute; they are of order 1): numpy evaluates
  ``exp`` with its own SIMD routine, numba with the C library's, and the two differ in the last
  bit for a few per cent of arguments. A plant reward sums up to n of them, so it agrees to within
  1e-15 per unit of the summed |container rewards| (a last-bit difference in one term can move a
  sum of 4 or more by one of the sum's own last bits). Only the ``"best_reward"`` arbitration
  reads rewards to make a decision; it could order two requests differently only if their
  rewards were within ~1e-16 of each other without being equal.

The random streams are unchanged too: :func:`refill_blocks` calls numpy's own C fill functions.
The global-state observation (:func:`global_state`) is the same float32 cast and clip.

``tests/test_compiled_backend.py`` checks these claims on every built-in config and rule.
"""

from __future__ import annotations

import ctypes
import math
import os
from functools import lru_cache

import numpy as np

from containergym_marl.core.dynamics import (
    _EXP_ZERO_BELOW,
    _SEQUENTIAL_SUM_MAX_TERMS,
    ARBITRATION_RULES,
    PlantState,
    StepOutcome,
    check_step_inputs,
)
from containergym_marl.core.observations import global_state_bounds
from containergym_marl.core.params import PlantParams

try:  # numba is optional (the "fast" extra)
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

BACKENDS = ("numpy", "numba")
#: Environment variable that chooses the backend when ``backend="auto"``.
BACKEND_ENV_VAR = "CONTAINERGYM_MARL_BACKEND"
#: From this batch size on, the compiled step runs simulations in parallel threads.
PARALLEL_MIN_BATCH = 512
#: numpy's row sum switches from blocks of 8 to recursive halving above this many terms; the
#: compiled row sum reproduces only the block form, so larger plants use the numpy backend.
_MAX_CONTAINERS = 128
_RULE_CODES = {rule: code for code, rule in enumerate(ARBITRATION_RULES)}


def numba_available() -> bool:
    return numba is not None


def resolve_backend(backend: str = "auto", params: PlantParams | None = None) -> str:
    """The backend to use: ``"numpy"`` or ``"numba"``.

    ``"auto"`` reads :data:`BACKEND_ENV_VAR` if set, else takes numba when it is installed and
    supports the plant (at most 128 containers, at most 7 reward peaks per container), else
    numpy. Asking for ``"numba"`` explicitly when it cannot be used is an error.
    """
    if backend == "auto":
        backend = os.environ.get(BACKEND_ENV_VAR, "auto") or "auto"
        if backend == "auto":
            return "numba" if numba is not None and (params is None or supports(params)) else "numpy"
        where = f"{BACKEND_ENV_VAR}={backend!r}"
    else:
        where = f"backend={backend!r}"
    if backend not in BACKENDS:
        raise ValueError(f"{where}: unknown backend; choose 'auto' or one of {BACKENDS}")
    if backend == "numba":
        if numba is None:
            raise ValueError(f"{where}: numba is not installed (pip install 'containergym-marl[fast]')")
        if params is not None and not supports(params):
            raise ValueError(f"{where}: the compiled step supports at most {_MAX_CONTAINERS} containers "
                             f"and {_SEQUENTIAL_SUM_MAX_TERMS} reward peaks per container; this plant has "
                             f"{params.n_containers} and {params.reward_peaks.shape[1]}")
    return backend


def supports(params: PlantParams) -> bool:
    return (params.n_containers <= _MAX_CONTAINERS
            and params.reward_peaks.shape[1] <= _SEQUENTIAL_SUM_MAX_TERMS)


@lru_cache(maxsize=64)  # params are immutable and hashed by identity
def _packed(params: PlantParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-container columns (n, 6), reward peaks (3, n, K) and plant scalars (4,) for the kernel."""
    columns = np.stack([params.fill_mean_per_step, params.fill_std_per_step, params.max_volume,
                        params.pu_offset_s, params.pu_time_per_product_s, params.product_size], axis=1)
    peaks = np.stack([params.reward_peaks, params.reward_two_width_sq, params.reward_coef])
    scalars = np.array([params.penalty_reward, params.overflow_reward, params.timestep_s,
                        params.episode_length_steps], dtype=np.float64)
    no_uniforms = np.zeros((0, params.n_containers))
    return np.ascontiguousarray(columns), np.ascontiguousarray(peaks), scalars, no_uniforms


# ---- the kernel: plain Python, compiled lazily (on first call, cached on disk) when numba exists --

if numba is not None:
    _jit = numba.njit(cache=True)
    _jit_parallel = numba.njit(cache=True, parallel=True)
    _prange = numba.prange
else:  # pragma: no cover - the plain functions stay usable (slowly) for tests
    _jit = _jit_parallel = lambda f: f  # noqa: E731
    _prange = range


@_jit
def _reward(x, i, peaks, r_pen):
    """Emptying reward of container i at volume x: dynamics.emptying_reward, term by term."""
    if x == 0.0:
        return r_pen
    acc = 0.0
    for k in range(peaks.shape[2]):
        d = x - peaks[0, i, k]
        t = -(d * d) / peaks[1, i, k]
        e = math.exp(t) if t >= _EXP_ZERO_BELOW else 0.0
        term = peaks[2, i, k] * e
        acc = term if k == 0 else acc + term
    return r_pen + acc


@_jit
def _row_sum(row):
    """numpy's ``np.sum`` of a contiguous float64 row of at most 128 entries, same bits."""
    n = row.shape[0]
    if n < 8:
        res = 0.0
        for i in range(n):
            res += row[i]
        return res
    r0, r1, r2, r3 = row[0], row[1], row[2], row[3]
    r4, r5, r6, r7 = row[4], row[5], row[6], row[7]
    i = 8
    stop = n - n % 8
    while i < stop:
        r0 += row[i]
        r1 += row[i + 1]
        r2 += row[i + 2]
        r3 += row[i + 3]
        r4 += row[i + 4]
        r5 += row[i + 5]
        r6 += row[i + 6]
        r7 += row[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += row[i]
        i += 1
    return res


@_jit
def _step_sims(lo, hi, v, p, steps, requests, normals, uniforms, rule, cols, peaks, scalars,
               values, p_next, counts, flags, pu_index, plant_reward, ends):
    """Step simulations lo..hi-1 into the outputs (see :func:`_allocate_outputs`); the numbered
    comments follow dynamics.step's docstring. (The loop over simulations is in here rather than
    in the callers: a call passing ~20 arrays costs more than one simulation's arithmetic.)"""
    n = v.shape[1]
    m = p.shape[1]
    r_pen, r_min, dt, horizon = scalars[0], scalars[1], scalars[2], scalars[3]
    for b in range(lo, hi):
        free = 0
        for j in range(m):
            if p[b, j] == 0.0:
                free += 1
        counts[1, b] = free
        # 3. inflow for every container (emptied ones are overwritten below)
        n_req = 0
        for i in range(n):
            x = v[b, i] + cols[i, 0]
            x = x + cols[i, 1] * normals[b, i]
            values[0, b, i] = x if x > 0.0 else 0.0
            pu_index[b, i] = -1
            values[1, b, i] = 0.0
            values[2, b, i] = 0.0
            flags[1, b, i] = False
            flags[0, b, i] = requests[b, i]
            if requests[b, i]:
                n_req += 1
        for j in range(m):
            t = p[b, j] - dt
            p_next[b, j] = t if t > 0.0 else 0.0
        # 1. arbitration, only where requests outnumber free PUs: `free` rounds of "the remaining
        # request with the largest key, ties to the lower index" (dynamics.arbitrate)
        if n_req > free:
            for i in range(n):
                flags[0, b, i] = False
            for _ in range(free):
                best = -1
                best_key = 0.0
                for i in range(n):
                    if requests[b, i] and not flags[0, b, i]:
                        if rule == 0:  # fullest
                            key = v[b, i] / cols[i, 2]
                        elif rule == 1:  # random
                            key = uniforms[b, i]
                        elif rule == 2:  # index
                            key = -float(i)
                        else:  # best_reward
                            key = _reward(v[b, i], i, peaks, r_pen)
                        if best < 0 or key > best_key:
                            best = i
                            best_key = key
                flags[0, b, best] = True
            for i in range(n):
                flags[1, b, i] = requests[b, i] and not flags[0, b, i]
        # 2. and 4. rewards, emptying and PUs: granted containers in index order take the free PUs
        # in index order
        pu = 0
        for i in range(n):
            if flags[0, b, i]:
                while p[b, pu] != 0.0:
                    pu += 1
                vol = v[b, i]
                values[2, b, i] = _reward(vol, i, peaks, r_pen)
                values[1, b, i] = vol
                values[0, b, i] = 0.0
                pu_index[b, i] = pu
                p_next[b, pu] = cols[i, 3] + cols[i, 4] * np.floor(vol / cols[i, 5])
                pu += 1
            elif flags[1, b, i]:
                values[2, b, i] = r_pen
        # the plant reward is the row sum (a lone request's entry is its own sum)
        total = 0.0
        if n_req == 1:
            for i in range(n):
                if requests[b, i]:
                    total = values[2, b, i]
        elif n_req > 1:
            total = _row_sum(values[2, b])
        # 5. overflow and time limit
        over = False
        for i in range(n):
            o = values[0, b, i] >= cols[i, 2]
            flags[2, b, i] = o
            values[3, b, i] = r_min if o else values[2, b, i]
            over = over or o
        counts[0, b] = steps[b] + 1
        plant_reward[b] = r_min if over else total
        ends[0, b] = over
        ends[1, b] = (not over) and counts[0, b] >= horizon


@_jit_parallel
def _step_parallel(chunks, v, p, steps, requests, normals, uniforms, rule, cols, peaks, scalars,
                   values, p_next, counts, flags, pu_index, plant_reward, ends):
    """:func:`_step_sims` over all simulations, in ``chunks`` shared among numba's threads."""
    bsz = v.shape[0]
    size = (bsz + chunks - 1) // chunks
    for c in _prange(chunks):  # simulations are independent
        _step_sims(min(c * size, bsz), min((c + 1) * size, bsz), v, p, steps, requests, normals, uniforms,
                   rule, cols, peaks, scalars, values, p_next, counts, flags, pu_index, plant_reward, ends)


def _allocate_outputs(bsz: int, n: int, m: int) -> tuple[np.ndarray, ...]:
    """Fresh outputs of one step, allocated here (numba takes arrays faster than it returns
    them) and stacked by type (fewer allocations): (v(t+1), emptied volume, container reward,
    individual reward), p(t+1), (step count, free PUs before), (granted, denied, overflowed),
    PU index, plant reward, (terminated, truncated)."""
    return (np.empty((4, bsz, n)), np.empty((bsz, m)), np.empty((2, bsz), np.int64),
            np.empty((3, bsz, n), bool), np.empty((bsz, n), np.int64), np.empty(bsz),
            np.empty((2, bsz), bool))


_BOOL, _FLOAT = np.dtype(bool), np.dtype(np.float64)


def _c_array(a, dtype: np.dtype) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype``; itself when it already is one (the usual case,
    checked more cheaply than np.ascontiguousarray does)."""
    if type(a) is np.ndarray and a.dtype == dtype and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=dtype)


def step(
    state: PlantState,
    requests: np.ndarray,
    params: PlantParams,
    normals: np.ndarray,
    uniforms: np.ndarray | None,
    arbitration: str = "fullest",
) -> tuple[PlantState, StepOutcome]:
    """:func:`.dynamics.step`, compiled; same arguments, same results (see the module docstring)."""
    v, p = state.volumes, state.pu_timers_s
    bsz, n = v.shape
    requests = _c_array(requests, _BOOL)
    normals = _c_array(normals, _FLOAT)
    # the kernel does not check bounds: every shape is checked here
    check_step_inputs(bsz, n, requests, normals, uniforms, arbitration)
    cols, peaks, scalars, no_uniforms = _packed(params)
    if uniforms is None:
        uniforms = no_uniforms
    out = _allocate_outputs(bsz, n, p.shape[1])
    inputs = (v, p, state.step_count, requests, normals, uniforms, _RULE_CODES[arbitration], cols, peaks, scalars)
    if bsz >= PARALLEL_MIN_BATCH:
        _step_parallel(4 * numba.get_num_threads(), *inputs, *out)
    else:
        _step_sims(0, bsz, *inputs, *out)
    values, p_next, counts, flags, pu_index, plant_reward, ends = out
    # tuple.__new__: the named tuples' fields in order, without the keyword-argument overhead
    outcome = tuple.__new__(StepOutcome, (
        requests, flags[0], flags[1], pu_index, values[1], values[2], flags[2], values[3], plant_reward,
        counts[1], ends[0], ends[1]))
    return tuple.__new__(PlantState, (values[0], p_next, counts[0])), outcome


@_jit
def _global_state_into(v, p, low, high, out):
    n = v.shape[1]
    for b in range(v.shape[0]):
        for i in range(n):
            out[b, i] = min(max(np.float32(v[b, i]), low[i]), high[i])
        for j in range(p.shape[1]):
            out[b, n + j] = min(max(np.float32(p[b, j]), low[n + j]), high[n + j])


def global_state(state: PlantState, params: PlantParams) -> np.ndarray:
    """:func:`.observations.global_state`, compiled (the same float32 values: cast, then clip)."""
    low, high = global_state_bounds(params)
    v = state.volumes
    out = np.empty((v.shape[0], v.shape[1] + params.n_pus), np.float32)
    _global_state_into(v, state.pu_timers_s, low, high, out)
    return out


# ---- refilling the random streams without the GIL ------------------------------------------------
# NoiseStreams (rng.py) refills a simulation's block with ``gen.standard_normal(out=...)`` and
# ``gen.random(out=...)``. Those methods run numpy's C functions random_standard_normal_fill and
# random_standard_uniform_fill (numpy's documented random C API, exported by
# numpy.random._generator) on the generator's bitgen_t. Calling the same two functions on the same
# bitgen_t from compiled code gives the same numbers, without a Python call per simulation and in
# parallel threads (each generator is touched by one thread only). The functions are linked by
# symbol name (so the compiled kernels can be cached on disk); pointers are passed as integers,
# the same calling convention on 64-bit platforms.

def _numpy_fill_functions():
    try:
        import llvmlite.binding as llvm
        import numpy.random._generator as generator_module

        llvm.load_library_permanently(generator_module.__file__)
        for name in ("random_standard_normal_fill", "random_standard_uniform_fill"):
            ctypes.CDLL(generator_module.__file__)[name]  # raises AttributeError if not exported
    except (ImportError, OSError, AttributeError, RuntimeError):  # pragma: no cover
        return None
    signature = numba.types.void(numba.types.uintp, numba.types.intp, numba.types.uintp)
    return (numba.types.ExternalFunction("random_standard_normal_fill", signature),
            numba.types.ExternalFunction("random_standard_uniform_fill", signature))


_FILLS = _numpy_fill_functions() if numba is not None else None


def bitgen_address(generator: np.random.Generator) -> int:
    """Address of the generator's C ``bitgen_t`` (numpy's ctypes interface)."""
    return generator.bit_generator.ctypes.bit_generator.value


if _FILLS is not None:
    _normal_fill, _uniform_fill = _FILLS

    @_jit
    def _refill_range(lo, hi, addresses, sims, normals, uniforms, rows):
        count = rows * normals.shape[1]
        # all address arithmetic in uint64 (mixing signed and unsigned would give float64)
        block_bytes = np.uint64(count * 8)
        normals_base = np.uint64(normals.ctypes.data)
        uniforms_base = np.uint64(uniforms.ctypes.data)
        for k in range(lo, hi):
            i = np.uint64(sims[k])
            _normal_fill(addresses[i], count, normals_base + i * block_bytes)
            _uniform_fill(addresses[i], count, uniforms_base + i * block_bytes)

    @_jit_parallel
    def _refill_parallel(chunks, addresses, sims, normals, uniforms, rows):
        total = sims.shape[0]
        size = (total + chunks - 1) // chunks
        for c in _prange(chunks):
            _refill_range(min(c * size, total), min((c + 1) * size, total), addresses, sims, normals,
                          uniforms, rows)


def refill_available() -> bool:
    return _FILLS is not None


def refill_blocks(addresses: np.ndarray, sims: np.ndarray, normals: np.ndarray, uniforms: np.ndarray,
                  rows: int) -> None:
    """For each simulation i in ``sims``: ``rows`` rows of normals, then of uniforms, from the
    generator whose bitgen_t is at ``addresses[i]``, into rows ``i·rows …`` of the two
    contiguous (B·rows, n) float64 buffers; exactly what ``gen.standard_normal(out=block)`` then
    ``gen.random(out=block)`` write."""
    if sims.size >= PARALLEL_MIN_BATCH // 8:
        _refill_parallel(4 * numba.get_num_threads(), addresses, sims, normals, uniforms, rows)
    else:
        _refill_range(0, sims.size, addresses, sims, normals, uniforms, rows)
