"""What-if simulations: many futures of one simulation's state, for look-ahead planning.

:func:`simulate_futures` copies one state into a batch of C × K simulations: C candidate first
decisions, each followed by K noise streams over H steps, with the same K streams for every
candidate (common random numbers: two candidates are compared on the same futures, so the noise of
their difference is far smaller than that of either return). After the first step a policy of the
state, ``(B, n) requests = policy(state, params)``, decides. The noise comes from arrays the caller
draws (from the planner's own generator), so the simulation whose state is copied, and its random
stream, are never touched. All C·K simulations advance together, one call of the compiled step per
look-ahead step.

:meth:`PlantSimulator.branch <containergym_marl.core.simulator.PlantSimulator.branch>` is the same
idea as a full simulator object (one generator per copy, episode control), for interactive use.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np

from containergym_marl.config.pu_time import jit
from containergym_marl.core import dynamics
from containergym_marl.core.dynamics import DEFAULT_ARBITRATION, PlantState
from containergym_marl.core.params import PlantParams

#: ``policy(state, params) -> (B, n) bool requests``: who decides after the first step.
RequestPolicy = Callable[[PlantState, PlantParams], np.ndarray]


class Futures(NamedTuple):
    """C candidates × K futures of one state (arrays indexed ``[c, k]``).

    ``rewards[c, k, t]`` is the plant reward of look-ahead step t (r_min on the step that
    overflows), 0 after the future's episode ended. ``end_step[c, k]`` is the number of steps the
    future ran (H if its episode did not end), ``overflowed[c, k]`` whether it ended in an overflow.
    ``overflow_risk[c, k, t]`` is the probability that step t overflows given the state before it
    and its emptyings (:func:`~containergym_marl.core.dynamics.overflow_probabilities`), 0 after the
    end: ``Σₜ overflow_risk`` has the expectation of ``overflowed`` with far less variance.
    ``final_state`` holds the C·K states after the last step (candidate-major: row c·K + k); rows of
    futures that ended early are not meaningful.
    """

    rewards: np.ndarray  # (C, K, H)
    overflow_risk: np.ndarray  # (C, K, H)
    end_step: np.ndarray  # (C, K) int64
    overflowed: np.ndarray  # (C, K) bool
    final_state: PlantState  # C·K rows
    ended: np.ndarray  # (C, K) bool: the episode ended (overflow or time limit) within H steps


@jit
def _record_step(t, alive, plant_reward, step_risk, terminated, truncated, rewards, risk, end_step, overflowed):
    """Step ``t``'s reward and overflow risk of the futures still alive (the others keep their 0), and
    the ends of those whose episode ended in it; whether any future is still alive."""
    any_alive = False
    for b in range(alive.shape[0]):
        if not alive[b]:
            continue
        rewards[b, t] = plant_reward[b]
        risk[b, t] = step_risk[b]
        if terminated[b] or truncated[b]:
            end_step[b] = t + 1
            overflowed[b] = terminated[b]
            alive[b] = False
        else:
            any_alive = True
    return any_alive


def simulate_futures(
    state: PlantState,
    sim: int,
    first_requests: np.ndarray,
    policy: RequestPolicy,
    params: PlantParams,
    normals: np.ndarray,
    arbitration: str = DEFAULT_ARBITRATION,
) -> Futures:
    """Simulate K futures of each of C first decisions from simulation ``sim`` of ``state``.

    Args:
        state: any batch of states; only row ``sim`` is read (and not modified).
        sim: the simulation to copy.
        first_requests: (C, n) bool, the candidates' requests of the first step.
        policy: the requests of every later step, from the state (e.g. a rule-based base policy).
        params: the plant.
        normals: (H, K, n) standard normals, the K noise streams of the H steps; the same for every
            candidate. The uniforms of the step (read only by the ``"random"`` arbitration) are
            0.5, so a random arbitration breaks ties by index here.
        arbitration: the arbitration rule of the simulated plant.

    Cost: H compiled steps of C·K simulations (and their overflow probabilities) plus H calls of
    ``policy`` on them.
    """
    return simulate_future_groups(state, [(sim, first_requests, normals)], policy, params, arbitration)[0]


def simulate_future_groups(
    state: PlantState,
    groups: Sequence[tuple[int, np.ndarray, np.ndarray]],
    policy: RequestPolicy,
    params: PlantParams,
    arbitration: str = DEFAULT_ARBITRATION,
) -> list[Futures]:
    """:func:`simulate_futures` of several simulations of ``state`` at once: one
    ``(sim, first_requests, normals)`` per group, every group's C·K futures stepped together (one call
    of the compiled step per look-ahead step for all of them). Each group's :class:`Futures` are
    those :func:`simulate_futures` gives it alone: every simulation steps on its own row and noise,
    and the batch runs while any future of any group is alive (a future that ended records nothing
    more). The groups must share H."""
    if not groups:
        return []
    rows, requests, noises, shapes = [], [], [], []
    horizon = None
    for sim, first_requests, normals in groups:
        first_requests = np.asarray(first_requests, dtype=bool)
        normals = np.asarray(normals, dtype=np.float64)
        n_candidates, n = first_requests.shape
        h, copies = normals.shape[:2]
        if normals.shape != (h, copies, n) or n != params.n_containers or h < 1 or h != (horizon or h):
            raise ValueError(f"normals: expected shape (H >= 1, K, {params.n_containers}) with the same H in "
                             f"every group, got {normals.shape}")
        horizon = h
        rows.append(np.full(n_candidates * copies, int(sim)))
        requests.append(np.repeat(first_requests, copies, axis=0))
        noises.append(np.tile(normals, (1, n_candidates, 1)))  # [t] candidate-major: row c·K + k uses stream k
        shapes.append((n_candidates, copies))
    n = params.n_containers
    current = state.select(np.concatenate(rows))
    batch = current.volumes.shape[0]
    rule = dynamics.get_rule(arbitration)
    uniforms = np.full((batch, n), 0.5)
    step_requests = np.concatenate(requests)
    noise = np.concatenate(noises, axis=1)
    # two sets of step outputs, taken in turn (a step must not write over the state it reads), so the
    # look-ahead's steps allocate nothing; its other inputs are right by construction (no checks)
    outputs = [dynamics.StepOutputs(batch, n, current.pu_timers_s.shape[1]) for _ in range(2)]
    rewards = np.zeros((batch, horizon))
    risk = np.zeros((batch, horizon))
    end_step = np.full(batch, horizon, dtype=np.int64)
    overflowed = np.zeros(batch, dtype=bool)
    alive = np.ones(batch, dtype=bool)
    for t in range(horizon):
        if t > 0:
            step_requests = dynamics.check_requests(policy(current, params), (batch, n))
        before = current.volumes
        # one thread: a planner decides within one core (a training run's, an evaluation worker's)
        current, out = dynamics.step_checked(current, step_requests, params, noise[t], uniforms, rule,
                                             outputs[t % 2], threaded=False)
        step_risk = dynamics.overflow_probabilities(before, out.granted, params)
        if not _record_step(t, alive, out.plant_reward, step_risk, out.terminated, out.truncated, rewards, risk,
                            end_step, overflowed):
            break
    futures, start = [], 0
    for shape in shapes:
        stop = start + shape[0] * shape[1]
        futures.append(Futures(rewards[start:stop].reshape(*shape, horizon), risk[start:stop].reshape(*shape, horizon),
                               end_step[start:stop].reshape(shape), overflowed[start:stop].reshape(shape),
                               current.select(slice(start, stop)), (~alive[start:stop]).reshape(shape)))
        start = stop
    return futures
