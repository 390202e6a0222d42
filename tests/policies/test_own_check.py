"""A container agent's own deadline check (policies.safety.own_deadline_due): the planner's union bound
computed from the agent's own observation alone, carried by a learned model and applied wherever the model
acts; DAgger trains a student with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from containergym_marl import load_config  # noqa: E402
from containergym_marl.core.dynamics import PlantState  # noqa: E402
from containergym_marl.core.observations import SCALAR_FEATURES, agent_observations  # noqa: E402
from containergym_marl.core.params import PlantParams  # noqa: E402
from containergym_marl.evaluation import EvalProtocol, evaluate  # noqa: E402
from containergym_marl.policies.actor_critic import ActorCritic, policy_for  # noqa: E402
from containergym_marl.policies.safety import (  # noqa: E402
    check_own_check,
    deadlines,
    own_deadline_due,
    waiting_risk,
)
from containergym_marl.training import TrainArgs, train  # noqa: E402

COLUMN = {name: SCALAR_FEATURES.index(name) for name in SCALAR_FEATURES}


def _observation(volume_frac: float, rate: float, noise: float, free: float) -> np.ndarray:
    obs = np.zeros(14, dtype=np.float32)
    obs[[COLUMN["volume_frac"], COLUMN["fill_rate_frac"], COLUMN["fill_noise_frac"], COLUMN["free_pu_frac"]]] = (
        volume_frac, rate, noise, free)
    return obs


def test_the_check_is_the_union_bound_of_the_agents_own_fills_by_hand():
    """v / v_max = 0.9, μδ / v_max = 0.05, σ√δ / v_max = 0.02: one fill leaves a gap of 0.05, P = Φ̄(2.5)
    = 0.0062; two leave 0, P = 0.5. With L = 0 (one fill) it is due at ε = 1e-3, not at ε = 0.01; with L = 1
    due at ε = 0.4. Not due without a free PU, nor at half full; without noise, due where the fills reach
    v_max (0.92 + 2 x 0.05, 0.96 + 0.05), not before."""
    tail = 0.5 * math.erfc(2.5 / math.sqrt(2.0))
    assert 0.006 < tail < 0.0063
    near, half = _observation(0.9, 0.05, 0.02, 0.5), _observation(0.5, 0.05, 0.02, 0.5)
    obs = np.stack([near, half, _observation(0.9, 0.05, 0.02, 0.0), _observation(0.92, 0.05, 0.0, 0.5),
                    _observation(0.96, 0.05, 0.0, 0.5)])
    assert own_deadline_due(obs, 1e-3, 0).tolist() == [True, False, False, False, True]
    assert own_deadline_due(obs, 0.01, 0).tolist() == [False, False, False, False, True]
    assert own_deadline_due(obs, 0.4, 1).tolist() == [True, False, False, True, True]  # 0.0062 + 0.5; 0 + 1
    assert own_deadline_due(obs, 0.51, 1).tolist() == [False, False, False, True, True]


@pytest.mark.parametrize("config", ["n11_m2_dt120", "n16_m2_dt120"])
def test_from_the_agents_observations_it_is_the_planners_deadline_check_per_container(config):
    """On a plant's real observations, an agent is due exactly where the planner's check, from the global
    state and the plant's parameters, gives its container a deadline of at most L fills, and a PU is free."""
    params = PlantParams.from_config(load_config(config))
    rng = np.random.default_rng(0)
    n = params.n_containers
    for trial in range(20):
        volumes = params.max_volume * rng.uniform(0.6, 1.0, n)
        timers = np.where(rng.random(params.n_pus) < 0.5, 0.0, 300.0)
        state = PlantState(volumes[None].astype(float), timers[None].astype(float), np.array([10]))
        obs = agent_observations(state, params, np.zeros((1, n), dtype=bool))[0]
        for risk, lead in ((1e-4, 1), (1e-6, 0), (1e-2, 3)):
            expected = (deadlines(waiting_risk(volumes, params, lead + 1), risk) <= lead) & (timers == 0).any()
            got = own_deadline_due(obs, risk, lead)
            # float32 observations: a container within rounding of ε may differ; none here
            assert got.tolist() == expected.tolist(), (trial, risk, lead)


@pytest.mark.parametrize("value, match", [
    ({"risk": 0.0, "lead_steps": 1}, "risk"), ({"risk": 1.0, "lead_steps": 1}, "risk"),
    ({"risk": float("nan"), "lead_steps": 1}, "risk"), ({"risk": 1e-4, "lead_steps": -1}, "lead_steps"),
    ({"risk": 1e-4, "lead_steps": 1.5}, "lead_steps"), ({"risk": 1e-4}, "own_check"), ("1e-4", "own_check")])
def test_a_bad_check_is_refused_naming_it(value, match):
    with pytest.raises(ValueError, match=match):
        check_own_check(value)
    with pytest.raises(ValueError, match=match):
        ActorCritic("decentralised", 14 + 0, 2, own_check=value)


def _always_waits(own_check=None, observation_size=25) -> ActorCritic:
    model = ActorCritic("decentralised", observation_size, 2, generator=torch.Generator().manual_seed(0),
                        own_check=own_check)
    with torch.no_grad():  # the action head says "wait" whatever it sees
        model.net.actor[-1].weight.zero_()
        model.net.actor[-1].bias.copy_(torch.tensor([5.0, -5.0]))
    return model


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_the_check_travels_with_the_model_file_and_a_model_without_keeps_its_bytes(tmp_path, suffix):
    checked = _always_waits({"risk": 1e-4, "lead_steps": 1})
    path = tmp_path / f"m{suffix}"
    (checked.save if suffix == ".pt" else checked.save_safetensors)(path)
    assert ActorCritic.load(path).own_check == {"risk": 1e-4, "lead_steps": 1}
    plain = _always_waits()
    assert "own_check" not in plain.to_dict()  # the file of a model without a check is as before
    (plain.save if suffix == ".pt" else plain.save_safetensors)(path)
    assert ActorCritic.load(path).own_check is None
    with pytest.raises(ValueError, match="own_check"):
        ActorCritic("centralised", 7, 6, own_check={"risk": 1e-4, "lead_steps": 1})


def test_a_model_that_always_waits_overflows_and_its_check_empties_in_time():
    """Five 300-step episodes of n5_m2: the network alone never asks and the plant overflows; the same
    network with the check (ε = 1e-4, L = 1) asks only when its own container is due, and none of these
    episodes overflows."""
    protocol = EvalProtocol(episodes=5, episode_length_steps=300, first_seed=20_000)
    plain = evaluate(policy_for(_always_waits(observation_size=19), "waits"), "n5_m2_dt120", protocol)
    checked = evaluate(policy_for(_always_waits({"risk": 1e-4, "lead_steps": 1}, 19), "checked"), "n5_m2_dt120",
                       protocol)
    assert all(m.values["overflow"] for m in plain.episodes)
    assert not any(m.values["overflow"] for m in checked.episodes)
    assert all(m.values["emptyings"] > 0 and m.values["steps"] == 300 for m in checked.episodes)


@pytest.mark.parametrize("algo, hp, match", [
    ("dagger_agents", {"own_check_risk": 1.0}, "own_check_risk"),
    ("dagger_agents", {"own_check_lead_steps": -1}, "own_check_lead_steps"),
    ("dagger_ppo_agents", {"own_check_risk": 1e-4}, "own_check_risk"),  # PPO's fine-tuning: refused
])
def test_bad_own_check_settings_are_refused_before_anything_is_written(tmp_path, algo, hp, match):
    with pytest.raises(ValueError, match=match):
        train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=100, hyperparams=hp, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_a_dagger_student_trains_and_ships_with_its_check(tmp_path):
    run = train(TrainArgs(algo="dagger_agents", config="n5_m2_dt120", out=str(tmp_path / "r"), timesteps=640,
                          n_envs=2, progress_bar=False, overrides={"episode_length_steps": 20},
                          hyperparams={"n_steps": 16, "minibatch_size": 64, "own_check_risk": 1e-4}))
    for name in ("best_model.pt", "final_model.pt"):
        if (run / name).is_file():
            assert ActorCritic.load(run / name).own_check == {"risk": 1e-4, "lead_steps": 1}


def test_the_student_acts_with_its_check_while_dagger_collects():
    """DAgger's learner acts as it is deployed: a network that always waits, with the check, asks in
    the collected steps exactly where its own observation is due."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.dagger import DAggerArgs, Episodes, Labeller, collect

    env = ContainerAgentsVecEnv("n5_m2_dt120", 2, episode_length_steps=60)
    env.seed(3)
    obs = torch.from_numpy(env.reset())
    model = _always_waits({"risk": 1e-4, "lead_steps": 1}, env.observation_space.shape[0])
    labeller = Labeller(env.num_sims, DAggerArgs(), 3)
    rollout, *_ = collect(model, env, obs, torch.ones(env.num_envs), labeller, 50, 0.99, torch.Generator().manual_seed(1),
                          expert_acts=False, greedy=True, episodes=Episodes(env.num_sims, TrainingProgress()),
                          labels="planner")
    due = own_deadline_due(rollout.obs.reshape(-1, rollout.obs.shape[-1]).numpy(), 1e-4, 1)
    assert due.any() and rollout.actions.reshape(-1).numpy().astype(bool).tolist() == due.tolist()


def test_ppo_learns_in_the_environment_its_check_makes_and_ships_with_it(tmp_path):
    """fast_shared_ppo with the check: every step the environment executes the sampled actions with a
    request wherever the agents' own observations are due (PPO keeps the sampled actions); the model
    file carries the check. A centralised controller, and a DAgger fine-tuning's PPO, refuse it."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.fast_ppo import PPOArgs, learn, new_state

    env = ContainerAgentsVecEnv("n5_m2_dt120", 2, episode_length_steps=40)
    hp = PPOArgs(n_steps=20, minibatch_size=100, own_check_risk=1e-4, own_check_lead_steps=1)
    state = new_state(env, hp, "decentralised", 0, {})
    assert state.model.own_check == {"risk": 1e-4, "lead_steps": 1}
    with torch.no_grad():  # a policy that mostly waits, so that containers fill up and fall due
        state.model.net.actor[-1].bias.copy_(torch.tensor([5.0, -5.0]))
    seen, step, reset, last = [], env.step, env.reset, {}

    def recording_reset(*args, **kwargs):  # what the policy sees first
        last["obs"] = reset(*args, **kwargs).copy()
        return last["obs"]

    def recording_step(actions):  # the actions executed, and the observations they were chosen on
        seen.append((np.array(actions), last["obs"]))
        out = step(actions)
        last["obs"] = out[0].copy()
        return out

    env.step, env.reset = recording_step, recording_reset
    learn(tmp_path, state, env, 400, 0.99, hp, TrainingProgress(), interval=10**9)
    executed = np.concatenate([a for a, _ in seen])
    due = np.concatenate([own_deadline_due(o, 1e-4, 1) for _, o in seen])
    assert due.any() and executed[due].all()  # every due agent asked
    with pytest.raises(ValueError, match="own_check_risk"):
        train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "c"), timesteps=100,
                        hyperparams={"own_check_risk": 1e-4}, progress_bar=False))
    with pytest.raises(ValueError, match="ppo_own_check_risk"):
        train(TrainArgs(algo="dagger_ppo_agents", out=str(tmp_path / "d"), timesteps=100,
                        hyperparams={"ppo_own_check_risk": 1e-4}, progress_bar=False))
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()


def test_the_checked_method_trains_with_the_check_its_name_promises(tmp_path):
    """fast_shared_ppo_checked: fast_shared_ppo with the check of OWN_CHECK_SETTINGS in every model it
    writes, whatever its settings file says of PPO; ``--hp`` can still change the check; the plain
    method's models carry none."""
    from containergym_marl.training.fast_ppo import OWN_CHECK_SETTINGS

    tiny = dict(config="n5_m2_dt120", n_envs=2, progress_bar=False, overrides={"episode_length_steps": 20},
                timesteps=320)
    expected = {"risk": OWN_CHECK_SETTINGS["own_check_risk"], "lead_steps": OWN_CHECK_SETTINGS["own_check_lead_steps"]}
    runs = {"checked": train(TrainArgs(algo="fast_shared_ppo_checked", out=str(tmp_path / "a"),
                                       hyperparams={"n_steps": 16, "minibatch_size": 80}, **tiny)),
            "lead 0": train(TrainArgs(algo="fast_shared_ppo_checked", out=str(tmp_path / "b"),
                                      hyperparams={"n_steps": 16, "minibatch_size": 80, "own_check_lead_steps": 0},
                                      **tiny)),
            "plain": train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "c"),
                                     hyperparams={"n_steps": 16, "minibatch_size": 80}, **tiny))}
    checks = {name: ActorCritic.load(run / "final_model.pt").own_check for name, run in runs.items()}
    assert checks == {"checked": expected, "lead 0": {**expected, "lead_steps": 0}, "plain": None}
    assert expected == {"risk": 1e-4, "lead_steps": 1}  # the screened setting (results/own_check/screen.md)
