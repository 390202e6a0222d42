"""The ContainerGym MDP (paper, section 5): one step of the plant, written once, compiled by numba.

Shapes: B simulations, n containers, m processing units (PUs). The action input of :func:`step` is a
``(B, n)`` boolean *request* matrix: ``requests[b, i]`` asks to empty container i of simulation b.
The centralised controller makes at most one request per step; container agents may make many, and
the arbitration grants at most as many as there are free PUs.

One step of one simulation (the body of :func:`step_simulations`' loop, numbered as below):

1. **Arbitration.** PU j is free iff its timer is 0. If the requests outnumber the free PUs, they are
   ranked by the arbitration rule's priority (larger first, ties to the lower index) and the first
   ``f`` (number of free PUs) are *granted*; the rest are *denied*. Otherwise all are granted.
2. **Rewards** per container, from the volumes before this step's inflow: granted → the emptying
   reward of v_i (paper eq. 5; r_pen if v_i = 0, the PU is still used); denied → r_pen (the paper's
   "no free PU"); no request → 0. The plant reward is their sum.
3. **Volumes** at t+1: granted containers are 0; every other container gets
   ``max(0, v + N(μδ, σ²δ))``, one normal draw per container.
4. **Timers** at t+1: the PU taken by granted container i is set to g_i(v_i) = β_i + λ_i⌊v_i / b_i⌋
   (paper eq. 2; the earlier reference code also subtracted δ in the same step); every other timer
   becomes ``max(0, p − δ)``. Granted containers, in index order, take the free PUs in index order
   (PUs are identical, so this choice does not change the dynamics).
5. **End.** If any v_j(t+1) ≥ v_max,j the plant reward is r_min (replacing the step's reward) and the
   episode terminates; otherwise it is truncated when the step count reaches T.

This module is the only definition of the physics, with g in :func:`.params.pu_time_s` (which the
timer bound and the config's validation share). The loop over simulations is compiled with numba
(and threaded for large batches); tests compare it with an independent scalar oracle written from
the paper (``tests/reference_model.py``).
"""

from __future__ import annotations

import functools
import math
import os
import types
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numba
import numpy as np

from containergym_marl.config.pu_time import JIT_OPTIONS, jit, pu_time_s
from containergym_marl.core.params import PlantParams, generated_function, unpack_params

#: From this batch size on, blocks of simulations are stepped in parallel threads.
PARALLEL_MIN_BATCH = 2048
_THREADS = min(os.cpu_count() or 1, 8)


@functools.cache
def _thread_pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(_THREADS, thread_name_prefix="containergym-step")


class PlantState(NamedTuple):
    """State of B simulations: the paper's s_t = (v, p) plus the step counter. A step never writes
    into the state it reads: :func:`step` returns the next one in new arrays (a
    :class:`~containergym_marl.core.simulator.PlantSimulator` in arrays of its own)."""

    volumes: np.ndarray  # (B, n) volume units
    pu_timers_s: np.ndarray  # (B, m) seconds until each PU is free
    step_count: np.ndarray  # (B,) int64, steps taken in the current episode

    @property
    def num_sims(self) -> int:
        return self.volumes.shape[0]

    def select(self, sims: np.ndarray) -> "PlantState":
        return PlantState(self.volumes[sims], self.pu_timers_s[sims], self.step_count[sims])


class StepOutcome(NamedTuple):
    """What happened in one step of B simulations."""

    requested: np.ndarray  # (B, n) bool
    granted: np.ndarray  # (B, n) bool: emptied this step
    denied: np.ndarray  # (B, n) bool: requested but no free PU was left
    pu_index: np.ndarray  # (B, n) int64: PU used by a granted container, -1 otherwise
    emptied_volume: np.ndarray  # (B, n): v_i(t) of granted containers, 0 otherwise
    container_reward: np.ndarray  # (B, n): emptying reward / r_pen / 0, before overflow
    overflowed: np.ndarray  # (B, n) bool: v_i(t+1) >= v_max,i
    individual_reward: np.ndarray  # (B, n): container_reward, r_min for overflowing containers
    plant_reward: np.ndarray  # (B,): sum of container_reward, replaced by r_min on overflow
    free_pus_before: np.ndarray  # (B,) int64: free PUs at time t
    terminated: np.ndarray  # (B,) bool: a container overflowed
    truncated: np.ndarray  # (B,) bool: the time limit T was reached without overflow


# ---- the paper's functions of one container ----------------------------------------------------
@jit
def emptying_reward(i: int, volume: float, params: PlantParams) -> float:
    """Reward of emptying container i at ``volume`` with a free PU (paper eq. 5):
    ``r_pen + Σ_k (h_k − r_pen)·exp(−(v − v*_k)² / (2 w_k²))``; r_pen for an empty container."""
    if volume == 0.0:
        return params.penalty_reward
    peaks = 0.0
    for k in range(params.reward_peaks.shape[1]):
        distance = volume - params.reward_peaks[i, k]
        peaks += params.reward_coef[i, k] * math.exp(-(distance * distance) / params.reward_two_width_sq[i, k])
    return params.penalty_reward + peaks


@jit
def pu_busy_time_s(i: int, volume: float, params: PlantParams) -> float:
    """g_i(v) = β_i + λ_i·⌊v / b_i⌋: seconds a PU is busy after emptying container i (paper eq. 2)."""
    return pu_time_s(volume, params.pu_offset_s[i], params.pu_time_per_product_s[i], params.product_size[i])


@jit
def _floor_at_zero(x: float) -> float:
    """max(0, x); -0.0 and NaN become 0.0."""
    return x if x > 0.0 else 0.0


# ---- one step of every simulation ----------------------------------------------------------------
@numba.njit(inline="always", **JIT_OPTIONS)  # inlined: a call per simulation slowed the step by 13 %
def grant_requests(requests, priorities, b, free_pus, granted):
    """Row b of ``granted``: the requests of row b of ``requests``, or where they are more than
    ``free_pus``, the ``free_pus`` of highest priority (``priorities[b, i]``, ties to the lower index)."""
    n_requests = 0
    for i in range(requests.shape[1]):
        granted[b, i] = requests[b, i]
        n_requests += requests[b, i]
    if n_requests > free_pus:
        for i in range(requests.shape[1]):
            granted[b, i] = False
        for _ in range(free_pus):
            best, best_priority = -1, 0.0
            for i in range(requests.shape[1]):
                if requests[b, i] and not granted[b, i]:
                    if best < 0 or priorities[b, i] > best_priority:
                        best, best_priority = i, priorities[b, i]
            granted[b, best] = True


@jit
def step_simulations(state, requests, normals, priorities, params, next_state, out):
    """Step every simulation b of ``state`` into row b of ``next_state`` and ``out`` (a StepOutcome).

    ``priorities[b, i]`` is the arbitration rule's priority of container i's request in simulation
    b (read only for requested containers).

    The loop over simulations is inside this function rather than around a function of one
    simulation: numba increments and decrements the reference count of every array of a named-tuple
    argument at each call (about a hundred atomic operations), which made a batch of centralised
    steps 9× slower (``benchmarks/kernel.py``; ``benchmarks/RESULTS.md``, run 7).
    """
    n, m = params.n_containers, params.n_pus
    volumes, timers = state.volumes, state.pu_timers_s
    next_volumes, next_timers = next_state.volumes, next_state.pu_timers_s
    granted, denied = out.granted, out.denied
    for b in range(requests.shape[0]):
        # 1. Arbitration: grant the `free_pus` requests of highest priority (ties to the lower index).
        free_pus = 0
        for j in range(m):
            if timers[b, j] == 0.0:
                free_pus += 1
        for i in range(n):
            out.requested[b, i] = requests[b, i]
        grant_requests(requests, priorities, b, free_pus, granted)

        # 2. Rewards (volumes before the inflow) and 4. timers: granted containers, in index order,
        # take the free PUs in index order; every other timer counts down by δ.
        for j in range(m):
            next_timers[b, j] = _floor_at_zero(timers[b, j] - params.timestep_s)
        pu = 0
        plant_reward = 0.0
        for i in range(n):
            denied[b, i] = requests[b, i] and not granted[b, i]
            out.pu_index[b, i] = -1
            out.emptied_volume[b, i] = 0.0
            reward = 0.0
            if granted[b, i]:
                while timers[b, pu] != 0.0:
                    pu += 1
                reward = emptying_reward(i, volumes[b, i], params)
                out.emptied_volume[b, i] = volumes[b, i]
                out.pu_index[b, i] = pu
                next_timers[b, pu] = pu_busy_time_s(i, volumes[b, i], params)
                pu += 1
            elif denied[b, i]:
                reward = params.penalty_reward
            out.container_reward[b, i] = reward
            plant_reward += reward

        # 3. Volumes: emptied containers are 0; the others fill by one normal draw, floored at 0.
        for i in range(n):
            if granted[b, i]:
                next_volumes[b, i] = 0.0
            else:
                filled = volumes[b, i] + params.fill_mean_per_step[i] + params.fill_std_per_step[i] * normals[b, i]
                next_volumes[b, i] = _floor_at_zero(filled)

        # 5. End: an overflow replaces the step's reward by r_min and terminates; else the time limit.
        overflow = False
        for i in range(n):
            out.overflowed[b, i] = next_volumes[b, i] >= params.max_volume[i]
            out.individual_reward[b, i] = (params.overflow_reward if out.overflowed[b, i]
                                           else out.container_reward[b, i])
            overflow = overflow or out.overflowed[b, i]
        next_state.step_count[b] = state.step_count[b] + 1
        out.plant_reward[b] = params.overflow_reward if overflow else plant_reward
        out.free_pus_before[b] = free_pus
        out.terminated[b] = overflow
        out.truncated[b] = not overflow and next_state.step_count[b] >= params.episode_length_steps


#: The step's outputs, stacked by type into few arrays (fewer allocations and kernel arguments):
#: (dtype, shape after the batch axis, the fields of the next PlantState (``next_``) and of the
#: StepOutcome that its rows hold; one name: the array itself, unstacked).
OUTPUTS = (
    (np.float64, "n", ("next_volumes", "emptied_volume", "container_reward", "individual_reward")),
    (np.bool_, "n", ("requested", "granted", "denied", "overflowed")),
    (np.int64, "n", "pu_index"),
    (np.float64, "m", "next_pu_timers_s"),
    (np.float64, "", "plant_reward"),
    (np.int64, "", ("next_step_count", "free_pus_before")),
    (np.bool_, "", ("terminated", "truncated")),
)
#: Whether each output array is stacked (its batch axis is then axis 1).
_STACKED = tuple(isinstance(names, tuple) for _, _, names in OUTPUTS)


def _naming_expression() -> str:
    views = {}
    for a, (_, _, names) in enumerate(OUTPUTS):
        views.update({names: f"a{a}"} if isinstance(names, str) else
                     {name: f"a{a}[{k}]" for k, name in enumerate(names)})
    expected = {f"next_{name}" for name in PlantState._fields} | set(StepOutcome._fields)
    if set(views) != expected or len(views) != len(expected):
        raise TypeError(f"OUTPUTS must name every field of the next PlantState and the StepOutcome once, "
                        f"not {sorted(set(views) ^ expected)}")
    state = ", ".join(f"{name}={views['next_' + name]}" for name in PlantState._fields)
    outcome = ", ".join(f"{name}={views[name]}" for name in StepOutcome._fields)
    return f"PlantState({state}), StepOutcome({outcome})"


#: (next PlantState, StepOutcome) as views of the output arrays that :func:`_allocate_outputs`
#: makes: the same views in Python (``.py_func``) and in compiled code.
_named_outputs = generated_function("_named_outputs", tuple(f"a{a}" for a in range(len(OUTPUTS))),
                                    _naming_expression(), {"PlantState": PlantState, "StepOutcome": StepOutcome})


def _rule_priority(i, volume, uniform, params):
    """Stands for the arbitration rule's priority in :func:`_step_batch`; each rule's kernel has its
    own function under this name (:func:`_compile_batch_step`)."""
    raise NotImplementedError("the priority of a rule is bound by _compile_batch_step")


def _step_batch(volumes, pu_timers_s, step_count, requests, normals, uniforms, per_container, reward_table,
                scalars, *outputs):
    """The batched step, with the rule's priority ``_rule_priority`` compiled in.

    Numba unpacks every argument of a call, and a named tuple or a function object several times
    more slowly than an array; with one simulation stepping in a few microseconds that matters. So
    the kernel takes the state, the inputs, the plant's three storage arrays and the outputs stacked
    by type (:func:`_allocate_outputs`), names them again inside, and has the rule compiled in.
    """
    state = PlantState(volumes, pu_timers_s, step_count)
    params = unpack_params(per_container, reward_table, scalars)
    next_state, out = _named_outputs(*outputs)
    priorities = np.empty(requests.shape)  # written and read for requested containers only
    for b in range(requests.shape[0]):
        for i in range(params.n_containers):
            if requests[b, i]:
                priorities[b, i] = _rule_priority(i, volumes[b, i], uniforms[b, i], params)
    step_simulations(state, requests, normals, priorities, params, next_state, out)


def _compile_batch_step(priority: Callable, cache: bool) -> Callable:
    """:func:`_step_batch` with ``priority`` (a compiled priority function) as its ``_rule_priority``.

    Each rule gets its own copy of the function, with the same code and its own globals, named after
    the priority function. It is not a closure over ``priority``, because numba's disk cache would
    never find a closure's kernel again: its cache key includes the pickled free variables, and a
    dispatcher pickles with an identity (uuid) new in every process, so each process compiled every
    rule it used anew (about a second) and added a cache file. A global is compiled in like a free
    variable but is not part of the key; the copy's name gives each rule a cache file of its own
    (``benchmarks/startup.py``; ``tests/core/test_kernel_cache.py``).

    ``cache``: cache the kernel on disk. Numba keys the cache by this file (dynamics.py) and does
    not look at the priority's own source, so only rules defined in this module are cached; a
    kernel cached for a rule defined elsewhere would outlive changes to it.
    """
    name = f"_step_batch_{priority.py_func.__name__}"
    function = types.FunctionType(_step_batch.__code__, {**globals(), "_rule_priority": priority}, name,
                                  _step_batch.__defaults__)
    function.__qualname__ = name
    function.__doc__ = _step_batch.__doc__
    return numba.njit(nogil=True, **{**JIT_OPTIONS, "cache": cache})(function)


def _allocate_outputs(bsz: int, n: int, m: int) -> tuple[np.ndarray, ...]:
    """Fresh output arrays of one step, as :data:`OUTPUTS` lays them out."""
    sizes = {"n": (n,), "m": (m,), "": ()}
    return tuple(np.empty(((len(names),) if stacked else ()) + (bsz,) + sizes[size], dtype)
                 for (dtype, size, names), stacked in zip(OUTPUTS, _STACKED))


class StepOutputs:
    """Storage for what one step of B simulations writes: the stacked arrays the kernel fills and,
    named once, the next :class:`PlantState` and the :class:`StepOutcome` they hold.

    A :class:`~containergym_marl.core.simulator.PlantSimulator` steps into two of these in turn, so
    a step allocates and names nothing (at B = 1 that was a quarter of the centralised env's step).
    Copies (deepcopy, pickle) hold their own arrays and name them anew.
    """

    __slots__ = ("arrays", "next_state", "outcome")

    def __init__(self, num_sims: int, n_containers: int, n_pus: int):
        self._name(_allocate_outputs(num_sims, n_containers, n_pus))

    def _name(self, arrays: tuple[np.ndarray, ...]) -> None:
        self.arrays = arrays
        self.next_state, self.outcome = _named_outputs.py_func(*arrays)

    def __getstate__(self) -> tuple[np.ndarray, ...]:
        return self.arrays

    def __setstate__(self, arrays: tuple[np.ndarray, ...]) -> None:
        self._name(arrays)  # the copy's own arrays (pickle and deepcopy make new ones)


# ---- 1. arbitration rules: name -> compiled priority ---------------------------------------------
# A rule is a priority function ``priority(i, volume, uniform, params) -> float`` of container i, its
# volume v_i(t) and the step's uniform draw for it; the step grants the requests of highest
# priority, ties to the lower index. Simulators, environments, the CLI and the tests read
# ARBITRATION_RULES. Adding a rule: one function decorated with @arbitration_rule("name") below,
# and the same rule in the test oracle (tests/reference_model.py).

@dataclass(frozen=True)
class ArbitrationRule:
    name: str
    priority: Callable  # compiled: (i, volume, uniform, params) -> float, larger wins
    description: str
    step_batch: Callable  # the batched step with this rule (see _compile_batch_step)
    #: whether the priority reads its uniform draw; a simulator copies the step's uniform rows out of
    #: the random stream only for a rule that does (the rows are consumed either way)
    reads_uniform: bool = True


#: name -> rule, in the order they are documented.
ARBITRATION_RULES: dict[str, ArbitrationRule] = {}
#: The rule every simulator, environment, run and evaluation uses unless told otherwise.
DEFAULT_ARBITRATION = "fullest"


def arbitration_rule(name: str, reads_uniform: bool = True):
    """Register a priority function under ``name`` (compiled with numba); its docstring's first line
    is the rule's description. ``reads_uniform=False`` declares that it never reads its ``uniform``
    argument, which is then 0. The step kernels of the rules defined in this module are cached on
    disk; a rule defined elsewhere has its kernel compiled in each process that uses it (see
    :func:`_compile_batch_step`)."""

    def register(function: Callable) -> Callable:
        priority = jit(function)
        description = (function.__doc__ or "").strip().splitlines()[0]
        step_batch = _compile_batch_step(priority, cache=function.__module__ == __name__)
        ARBITRATION_RULES[name] = ArbitrationRule(name, priority, description, step_batch, reads_uniform)
        return priority

    return register


def get_rule(name: str) -> ArbitrationRule:
    """The rule called ``name``; a ValueError naming the valid choices otherwise."""
    rule = ARBITRATION_RULES.get(name) if isinstance(name, str) else None
    if rule is None:
        raise ValueError(f"arbitration: unknown rule {name!r}; choose one of {tuple(ARBITRATION_RULES)}")
    return rule


@arbitration_rule(DEFAULT_ARBITRATION, reads_uniform=False)
def fullest_first(i, volume, uniform, params):
    """The fullest container first (highest v / v_max); the default."""
    return volume / params.max_volume[i]


@arbitration_rule("random")
def random_order(i, volume, uniform, params):
    """A uniformly random order, from the simulation's own random stream."""
    return uniform


@arbitration_rule("index", reads_uniform=False)
def lowest_index_first(i, volume, uniform, params):
    """A fixed priority: the lower container index first."""
    return -float(i)


@arbitration_rule("best_reward", reads_uniform=False)
def best_reward_first(i, volume, uniform, params):
    """The request whose emptying would earn the most now first."""
    return emptying_reward(i, volume, params)



# ---- the batched step: Python entry point -------------------------------------------------------
def _float_rows(name: str, x, shape: tuple[int, int]) -> np.ndarray:
    """``x`` as a C-contiguous float64 array of ``shape``: the kernel checks no bounds, so every
    shape is checked here (one random row per simulation, never broadcast)."""
    if not (type(x) is np.ndarray and x.dtype == np.float64 and x.flags.c_contiguous):
        x = np.ascontiguousarray(x, dtype=np.float64)
    if x.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {x.shape}")
    return x


def check_requests(requests, shape: tuple[int, int]) -> np.ndarray:
    """``requests`` as a C-contiguous (B, n) bool array: booleans, or integers 0/1; floats (NaN too),
    other integers and objects are refused rather than cast (``bool(nan)`` is True)."""
    if not (type(requests) is np.ndarray and requests.dtype == np.bool_ and requests.flags.c_contiguous):
        a = np.asarray(requests)
        if a.dtype != np.bool_:
            if not np.issubdtype(a.dtype, np.integer):
                raise ValueError(f"requests: expected booleans (or integers 0/1), got dtype {a.dtype}: {a!r}")
            if ((a != 0) & (a != 1)).any():
                raise ValueError(f"requests: integer requests must be 0 or 1, got {a!r}")
        requests = np.ascontiguousarray(a, dtype=bool)
    if requests.shape != shape:
        raise ValueError(f"requests: expected shape {shape}, got {requests.shape}")
    return requests


def step(
    state: PlantState,
    requests: np.ndarray,
    params: PlantParams,
    normals: np.ndarray,
    uniforms: np.ndarray,
    arbitration: str = DEFAULT_ARBITRATION,
) -> tuple[PlantState, StepOutcome]:
    """Advance B simulations by one step of δ seconds. Pure: ``state`` is not modified.

    Args:
        state: the current state (B simulations).
        requests: (B, n) bool (or integers 0/1), which containers ask to be emptied; floats
            are refused.
        params: the plant.
        normals, uniforms: (B, n), one random row per simulation (see :mod:`.rng`); the uniforms
            are read only by the ``"random"`` arbitration.
        arbitration: the rule ranking competing requests, a name of :data:`ARBITRATION_RULES`.
    """
    rule = get_rule(arbitration)
    bsz, n = state.volumes.shape
    requests = check_requests(requests, (bsz, n))
    normals = _float_rows("normals", normals, (bsz, n))
    uniforms = _float_rows("uniforms", uniforms, (bsz, n))
    return step_checked(state, requests, params, normals, uniforms, rule)


def step_checked(state: PlantState, requests: np.ndarray, params: PlantParams, normals: np.ndarray,
                 uniforms: np.ndarray, rule: ArbitrationRule,
                 outputs: StepOutputs | None = None, threaded: bool = True) -> tuple[PlantState, StepOutcome]:
    """:func:`step` for inputs already checked: C-contiguous (B, n) bool requests and float64 random
    rows, and a rule from :func:`get_rule`. The kernel checks no bounds; the simulator, whose inputs
    are right by construction, calls this to skip the checks (a fifth of a one-simulation step).

    ``outputs``: where to write the step (fresh arrays when None); they must not hold ``state``.
    ``threaded``: False steps a large batch in the calling thread too (a caller that works within
    one core, as the planner's look-ahead inside a training run).
    """
    bsz, n = state.volumes.shape
    if outputs is None:
        outputs = StepOutputs(bsz, n, state.pu_timers_s.shape[1])
    arrays = outputs.arrays
    inputs = (*state, requests, normals, uniforms)
    if not threaded or bsz < PARALLEL_MIN_BATCH or _THREADS == 1:
        rule.step_batch(*inputs, *params.kernel_arrays(), *arrays)
    else:  # row blocks in threads: the kernel releases the GIL, and simulations are independent
        bounds = np.linspace(0, bsz, _THREADS + 1).astype(int)

        def block(lo: int, hi: int) -> None:
            rule.step_batch(*(a[lo:hi] for a in inputs), *params.kernel_arrays(),
                            *(a[:, lo:hi] if stacked else a[lo:hi] for a, stacked in zip(arrays, _STACKED)))

        list(_thread_pool().map(block, bounds[:-1], bounds[1:]))
    return outputs.next_state, outputs.outcome


def reset_state(params: PlantParams, uniforms: np.ndarray) -> PlantState:
    """Initial state from one row of uniforms per simulation: v ~ U[v0_min, v0_max], p = 0."""
    b = uniforms.shape[0]
    lo, hi = params.initial_volume_min, params.initial_volume_max
    return PlantState(
        volumes=lo + (hi - lo) * uniforms,
        pu_timers_s=np.zeros((b, params.n_pus)),
        step_count=np.zeros(b, dtype=np.int64),
    )


@jit
def _emptying_rewards_into(volumes, out, per_container, reward_table, scalars):
    params = unpack_params(per_container, reward_table, scalars)
    for b in range(volumes.shape[0]):
        for i in range(volumes.shape[1]):
            out[b, i] = emptying_reward(i, volumes[b, i], params)


def emptying_rewards(volumes: np.ndarray, params: PlantParams) -> np.ndarray:
    """(B, n) reward of emptying each container at ``volumes`` (B, n) now (for figures and
    analysis; the step calls :func:`emptying_reward`)."""
    volumes = np.ascontiguousarray(volumes, dtype=np.float64)
    if volumes.ndim != 2 or volumes.shape[1] != params.n_containers:
        raise ValueError(f"volumes: expected shape (B, {params.n_containers}), got {volumes.shape}")
    out = np.empty(volumes.shape)
    _emptying_rewards_into(volumes, out, *params.kernel_arrays())
    return out


@jit
def _overflow_probabilities_into(volumes, emptied, out, per_container, reward_table, scalars):
    params = unpack_params(per_container, reward_table, scalars)
    for b in range(volumes.shape[0]):
        survive = 1.0
        for i in range(volumes.shape[1]):
            if not emptied[b, i]:
                std = params.fill_std_per_step[i]
                gap = params.max_volume[i] - volumes[b, i] - params.fill_mean_per_step[i]
                if std > 0.0:
                    z = gap / (std * math.sqrt(2.0))
                    if z < 6.5:  # beyond, 0.5·erfc(z) < 2e-20 and the factor rounds to 1.0: nothing to multiply
                        survive *= 1.0 - 0.5 * math.erfc(z)
                elif gap <= 0.0:
                    survive = 0.0
        out[b] = 1.0 - survive


def overflow_probabilities(volumes: np.ndarray, emptied: np.ndarray, params: PlantParams) -> np.ndarray:
    """(B,) probability that a step from ``volumes`` (B, n), emptying the containers ``emptied``
    (B, n) bool, overflows: 1 − Πᵢ P(vᵢ + N(μᵢδ, σᵢ²δ) < v_max,i) over the containers not emptied
    (the step's fill draws are independent). A planner uses it as the conditional probability of an
    overflow given the state, far less noisy than the sampled event."""
    volumes = np.ascontiguousarray(volumes, dtype=np.float64)
    emptied = np.ascontiguousarray(emptied, dtype=bool)
    if volumes.ndim != 2 or volumes.shape[1] != params.n_containers or emptied.shape != volumes.shape:
        raise ValueError(f"volumes, emptied: expected shape (B, {params.n_containers}), got "
                         f"{volumes.shape} and {emptied.shape}")
    out = np.empty(volumes.shape[0])
    _overflow_probabilities_into(volumes, emptied, out, *params.kernel_arrays())
    return out
