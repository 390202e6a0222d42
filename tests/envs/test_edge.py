"""The edge module of the views (``containergym_marl.envs.edge``), checked directly against values
written out by hand, and the views that share it: every view refuses the same bad arguments with
the same message (issue 24, step 3)."""

from __future__ import annotations

import numpy as np
import pytest

from containergym_marl import container_agents_v0, container_agents_v1, load_config
from containergym_marl.algorithms import REGISTRY
from containergym_marl.config import MAX_SIMS
from containergym_marl.core import PlantParams
from containergym_marl.core.dynamics import StepOutcome
from containergym_marl.envs import edge
from containergym_marl.envs.centralised import ContainerGymEnv
from containergym_marl.envs.torchrl_env import ContainerAgentsTorchRLEnv
from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv, ContainerGymVectorEnv

from tests.helpers import CFG


def outcome(**fields) -> StepOutcome:
    """A hand-made step of B = 2 simulations with n = 3 containers; nothing happened unless given."""
    b, n = 2, 3
    base = dict(
        requested=np.zeros((b, n), bool), granted=np.zeros((b, n), bool), denied=np.zeros((b, n), bool),
        pu_index=np.full((b, n), -1, np.int64), emptied_volume=np.zeros((b, n)),
        container_reward=np.zeros((b, n)), overflowed=np.zeros((b, n), bool),
        individual_reward=np.zeros((b, n)), plant_reward=np.zeros(b),
        free_pus_before=np.array([2, 0], np.int64), terminated=np.zeros(b, bool), truncated=np.zeros(b, bool))
    base.update({k: np.asarray(v, dtype=base[k].dtype) for k, v in fields.items()})
    return StepOutcome(**base)


# Simulation 0 emptied container 1 (volume 12.5, PU 1, reward 0.75) and container 2 overflowed
# (r_min = -1 for it, the plant reward r_min); simulation 1 asked for container 0 with no free PU.
STEP = outcome(
    requested=[[0, 1, 0], [1, 0, 0]], granted=[[0, 1, 0], [0, 0, 0]], denied=[[0, 0, 0], [1, 0, 0]],
    pu_index=[[-1, 1, -1], [-1, -1, -1]], emptied_volume=[[0, 12.5, 0], [0, 0, 0]],
    container_reward=[[0, 0.75, 0], [-0.1, 0, 0]], overflowed=[[0, 0, 1], [0, 0, 0]],
    individual_reward=[[0, 0.75, -1], [-0.1, 0, 0]], plant_reward=[-1, -0.1], terminated=[1, 0])


# ---- reward modes --------------------------------------------------------------------------------
def test_reward_modes_and_agent_rewards():
    assert edge.REWARD_MODES == ("individual", "team")
    team = edge.agent_rewards(STEP, "team")
    np.testing.assert_array_equal(team, [[-1, -1, -1], [-0.1, -0.1, -0.1]])
    assert team.dtype == np.float64 and team.flags.writeable  # a new array, not a broadcast view
    individual = edge.agent_rewards(STEP, "individual", np.float32)
    np.testing.assert_array_equal(individual, np.float32([[0, 0.75, -1], [-0.1, 0, 0]]))
    assert individual.dtype == np.float32 and individual is not STEP.individual_reward


def test_algorithm_reward_modes_are_the_views_modes():
    for spec in REGISTRY.values():
        assert set(spec.reward_modes) <= set(edge.REWARD_MODES), spec.name
    assert REGISTRY["shared_ppo"].reward_modes == edge.REWARD_MODES


REWARD_MODE_VIEWS = {
    "v0": lambda mode: container_agents_v0.parallel_env(CFG, reward_mode=mode),
    "v1": lambda mode: container_agents_v1.parallel_env(CFG, reward_mode=mode),
    "sb3 agents": lambda mode: ContainerAgentsVecEnv(CFG, 2, reward_mode=mode),
    "torchrl": lambda mode: ContainerAgentsTorchRLEnv(CFG, 2, reward_mode=mode),
}


@pytest.mark.parametrize("view", REWARD_MODE_VIEWS)
@pytest.mark.parametrize("mode", ["shared", "Team", None, 1])
def test_every_view_refuses_an_unknown_reward_mode_alike(view, mode):
    message = f"reward_mode: unknown mode {mode!r}; choose one of ('individual', 'team')"
    with pytest.raises(ValueError) as error:
        REWARD_MODE_VIEWS[view](mode)
    assert str(error.value) == message


# ---- batch sizes and seeds -----------------------------------------------------------------------
@pytest.mark.parametrize("size", [1, 7, np.int32(3), np.uint64(2), MAX_SIMS])
def test_batch_size_accepts_integers_in_range(size):
    checked = edge.check_batch_size(size, "num_envs")
    assert type(checked) is int and checked == int(size)


@pytest.mark.parametrize("size", [0, -1, MAX_SIMS + 1, 3.0, 2.7, True, np.bool_(True), "3", None])
def test_batch_size_refuses_others_naming_the_argument(size):
    with pytest.raises(ValueError) as error:
        edge.check_batch_size(size, "num_sims")
    assert str(error.value) == f"num_sims: expected an integer in [1, 16777216], got {size!r}"


BATCHED_VIEWS = {  # view -> (its batch-size argument, constructor)
    "sb3 centralised": ("num_envs", lambda size: ContainerGymVecEnv(CFG, num_envs=size)),
    "sb3 agents": ("num_sims", lambda size: ContainerAgentsVecEnv(CFG, num_sims=size)),
    "gymnasium vector": ("num_envs", lambda size: ContainerGymVectorEnv(CFG, num_envs=size)),
    "torchrl": ("num_envs", lambda size: ContainerAgentsTorchRLEnv(CFG, num_envs=size)),
}


@pytest.mark.parametrize("view", BATCHED_VIEWS)
@pytest.mark.parametrize("size", [MAX_SIMS + 1, 0, 4.0])
def test_every_batched_view_refuses_a_bad_batch_size_with_the_same_message(view, size):
    """The TorchRL env used to take any B >= 1 (no upper bound, its own message)."""
    name, make = BATCHED_VIEWS[view]
    with pytest.raises(ValueError) as error:
        make(size)
    assert str(error.value) == f"{name}: expected an integer in [1, {MAX_SIMS}], got {size!r}"


@pytest.mark.parametrize("seed", [0, 5, np.int64(5), np.uint8(255)])
def test_seed_accepts_non_negative_integers(seed):
    assert edge.check_seed(seed) == int(seed) and type(edge.check_seed(seed)) is int
    assert edge.check_seed(None) is None


@pytest.mark.parametrize("seed", [-1, 2.7, 5.0, "5", True, np.bool_(False)])
def test_every_view_refuses_a_bad_seed(seed):
    message = f"seed: expected None or a non-negative integer, got {seed!r} ({type(seed).__name__})"
    refusals = [lambda: edge.check_seed(seed),
                lambda: ContainerGymEnv(CFG).reset(seed=seed),
                lambda: container_agents_v1.parallel_env(CFG).reset(seed=seed),
                lambda: ContainerGymVecEnv(CFG, 2).seed(seed),
                lambda: ContainerGymVectorEnv(CFG, 2).reset(seed=seed),
                lambda: ContainerAgentsTorchRLEnv(CFG, 2, seed=seed)]
    for refuse in refusals:
        with pytest.raises(ValueError) as error:
            refuse()
        assert str(error.value) == message


# ---- the container agents' infos -----------------------------------------------------------------
def test_agent_infos_of_a_step_and_a_reset():
    infos = edge.agent_step_infos(STEP, 0, step_count=7)
    shared = {"plant_reward": -1.0, "free_pus": 2, "step": 7}
    assert infos == [
        {"requested": False, "granted": False, "denied": False, "pu_index": -1, "emptied_volume": 0.0,
         "emptying_reward": 0.0, "overflowed": False, **shared},
        {"requested": True, "granted": True, "denied": False, "pu_index": 1, "emptied_volume": 12.5,
         "emptying_reward": 0.75, "overflowed": False, **shared},
        {"requested": False, "granted": False, "denied": False, "pu_index": -1, "emptied_volume": 0.0,
         "emptying_reward": 0.0, "overflowed": True, **shared},
    ]
    assert all(list(info) == list(edge.AGENT_INFO_NEUTRAL) for info in infos)  # the documented order
    assert [type(v) for v in infos[1].values()] == [type(v) for v in edge.agent_reset_info(2).values()]
    assert edge.agent_step_infos(STEP, 1, step_count=3)[0] == {
        "requested": True, "granted": False, "denied": True, "pu_index": -1, "emptied_volume": 0.0,
        "emptying_reward": -0.1, "overflowed": False, "plant_reward": -0.1, "free_pus": 0, "step": 3}
    assert edge.agent_reset_info(2) == {
        "requested": False, "granted": False, "denied": False, "pu_index": -1, "emptied_volume": 0.0,
        "emptying_reward": 0.0, "overflowed": False, "plant_reward": 0.0, "free_pus": 2, "step": 0}


def test_agent_info_arrays_are_the_per_agent_infos_stacked():
    keys = ("granted", "denied", "overflowed", "emptying_reward", "plant_reward", "pu_index")
    arrays = edge.agent_info_arrays(STEP, keys, (2, 3))
    assert {k: a.dtype for k, a in arrays.items()} == {
        "granted": bool, "denied": bool, "overflowed": bool, "emptying_reward": np.float32,
        "plant_reward": np.float32, "pu_index": np.int64}
    for b in range(2):
        for i, info in enumerate(edge.agent_step_infos(STEP, b, step_count=1)):
            assert {k: arrays[k][b, i].item() for k in keys} == {k: arrays[k].dtype.type(info[k]).item() for k in keys}
    reset = edge.agent_info_arrays(None, keys, (4, 3))
    assert all(a.shape == (4, 3) and (a == edge.AGENT_INFO_NEUTRAL[k]).all() for k, a in reset.items())
    for out in (STEP, None):
        with pytest.raises(ValueError, match="keys: 'step' is not a per-agent info key of a step"):
            edge.agent_info_arrays(out, ("granted", "step"), (2, 3))


# ---- the centralised view's info -----------------------------------------------------------------
NEUTRAL = {"step": 0, "emptied_container": "", "emptied_index": -1, "emptied_volume": 0.0,
           "emptying_reward": 0.0, "pu_index": -1, "no_free_pu": False, "overflowed_containers": (),
           "free_pus": 2}


def one(sim: int) -> StepOutcome:
    """Simulation ``sim`` of STEP alone, as the single environment's (B = 1) outcome."""
    return StepOutcome(*(np.asarray(field)[sim:sim + 1] for field in STEP))


def test_centralised_info_of_one_simulation():
    info = edge.CentralisedInfo(("A", "B", "C"))
    assert info.reset(2) == NEUTRAL
    # simulation 0 emptied B (action 2) and overflowed C; simulation 1 found no PU for A (action 1)
    assert info.step(2, one(0), 9) == {
        **NEUTRAL, "step": 9, "emptied_container": "B", "emptied_index": 1, "emptied_volume": 12.5,
        "emptying_reward": 0.75, "pu_index": 1, "overflowed_containers": ("C",)}
    assert info.step(1, one(1), 4) == {**NEUTRAL, "step": 4, "emptying_reward": -0.1, "no_free_pu": True,
                                       "free_pus": 0}
    assert info.step(0, one(1), 4) == {**NEUTRAL, "step": 4, "free_pus": 0}  # a wait: nothing happened


def test_centralised_info_arrays_hold_the_single_infos():
    info = edge.CentralisedInfo(("A", "B", "C"))
    actions = np.array([2, 1])
    arrays = info.step_arrays(actions, STEP, np.array([9, 4]))
    assert list(arrays) == list(edge.CENTRALISED_INFO_NEUTRAL)
    assert {k: a.dtype for k, a in arrays.items()} == dict(edge.CENTRALISED_INFO_DTYPES)
    assert dict(edge.CENTRALISED_INFO_DTYPES) == {
        "step": np.int64, "emptied_container": object, "emptied_index": np.int64, "emptied_volume": np.float64,
        "emptying_reward": np.float64, "pu_index": np.int64, "no_free_pu": bool,
        "overflowed_containers": object, "free_pus": np.int64}
    for b, step_count in enumerate((9, 4)):
        assert {k: a[b] for k, a in arrays.items()} == info.step(int(actions[b]), one(b), step_count)
    reset = info.reset_arrays(np.array([2, 0]))
    assert {k: a.dtype for k, a in reset.items()} == dict(edge.CENTRALISED_INFO_DTYPES)
    assert {k: a[0] for k, a in reset.items()} == NEUTRAL
    assert reset["overflowed_containers"][1] == () and reset["free_pus"].tolist() == [2, 0]


def test_centralised_info_arrays_name_every_overflowed_container():
    """Overflows of one, two and three containers in one step, and an episode's end without one,
    beside steps without an end: each simulation's names as its single info holds them."""
    over = [[0, 0, 1], [1, 1, 0], [0, 0, 0], [1, 1, 1], [0, 1, 0], [0, 0, 0]]
    step = outcome(
        requested=np.zeros((6, 3)), granted=np.zeros((6, 3)), denied=np.zeros((6, 3)), pu_index=np.full((6, 3), -1),
        emptied_volume=np.zeros((6, 3)), container_reward=np.zeros((6, 3)), overflowed=over,
        individual_reward=np.zeros((6, 3)), plant_reward=np.zeros(6), free_pus_before=np.full(6, 2),
        terminated=[1, 1, 1, 1, 1, 0], truncated=np.zeros(6))
    info = edge.CentralisedInfo(("A", "B", "C"))
    arrays = info.step_arrays(np.zeros(6, dtype=np.int64), step, np.arange(6))
    assert arrays["overflowed_containers"].tolist() == [("C",), ("A", "B"), (), ("A", "B", "C"), ("B",), ()]
    for b in range(6):
        single = StepOutcome(*(np.asarray(field)[b:b + 1] for field in step))
        assert arrays["overflowed_containers"][b] == info.step(0, single, b)["overflowed_containers"]


def test_the_centralised_envs_report_the_edge_schema():
    _, single = ContainerGymEnv(CFG).reset(seed=0)
    _, batched = ContainerGymVectorEnv(CFG, 3).reset(seed=0)
    assert single == {**NEUTRAL}
    assert [k for k in batched if not k.startswith("_")] == list(edge.CENTRALISED_INFO_NEUTRAL)


# ---- the normalised state ------------------------------------------------------------------------
def test_normalised_state_divides_by_v_max_and_the_longest_pu_time():
    params = PlantParams.from_config(load_config(CFG))
    normalise = edge.NormalisedState(params)
    v_max, pu_time_s = np.asarray(params.max_volume, dtype=float), float(params.max_pu_time_s)
    n, m = params.n_containers, params.n_pus
    np.testing.assert_array_equal(normalise.low, np.zeros(n + m))
    np.testing.assert_array_equal(normalise.high, [2.0] * n + [1.0] * m)
    # half full, at v_max and beyond the bound of 2 v_max; timers at half and beyond the longest time
    state = np.stack([np.concatenate([0.5 * v_max, [0.5 * pu_time_s] * m]),
                      np.concatenate([v_max, [0.0] * m]),
                      np.concatenate([3 * v_max, [2 * pu_time_s] * m])]).astype(np.float32)
    out = normalise(state)
    assert out.dtype == np.float32 and out.shape == state.shape
    np.testing.assert_allclose(out, [[0.5] * n + [0.5] * m, [1.0] * n + [0.0] * m, [2.0] * n + [1.0] * m],
                               rtol=1e-6)
    # the PettingZoo view's normalised state is this one
    env = container_agents_v1.parallel_env(CFG, state_mode="normalised")
    env.reset(seed=3)
    for _ in range(5):
        env.step({a: 1 for a in env.agents})
    np.testing.assert_array_equal(env.state(), normalise(env.simulator.global_state()[0]))


def test_torchrl_set_seed_refuses_what_the_other_views_refuse():
    """TorchRL's ``set_seed`` used to cast any number (``2.7`` seeded like 2)."""
    pytest.importorskip("torchrl")
    env = ContainerAgentsTorchRLEnv(CFG, 2)
    for seed in (2.7, -1, True):
        with pytest.raises(ValueError, match=r"^seed: expected None or a non-negative integer"):
            env.set_seed(seed)
    env.set_seed(np.int64(4))  # numpy integers, as everywhere
    first = env.reset()["state"]
    single = container_agents_v1.parallel_env(CFG, state_mode="normalised")
    single.reset(seed=5)  # simulation 1 of seed 4
    np.testing.assert_array_equal(first[1].numpy(), single.state())
