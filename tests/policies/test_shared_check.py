"""The agents' shared check (policies/shared_check.py): one message per agent and step, one rule all apply.

The compiled rule is checked against a plain Python statement of it (the plant's own step for the grants,
DeadlineCheck for the deadlines, the candidates enumerated with itertools) on random states of five plants,
and on hand-built states whose answer is worked out in the docstring; the model carries the setting through
both file formats; the policy adapter binds the plant from the environment, and the batched evaluation and
the per-environment one agree; DAgger's rollouts act with the rule."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core import dynamics
from containergym_marl.core.dynamics import PlantState
from containergym_marl.core.observations import agent_feature_names, agent_observation_size
from containergym_marl.core.params import PlantParams
from containergym_marl.policies.safety import DeadlineCheck
from containergym_marl.policies.shared_check import SHARED_CHECK, SharedCheck, check_shared_check

torch = pytest.importorskip("torch")

from containergym_marl.policies.actor_critic import ActorCritic, policy_for  # noqa: E402


# ---- the rule, stated in Python ------------------------------------------------------------------------
def plant_grants(requests: np.ndarray, volumes: np.ndarray, timers_s: np.ndarray, params: PlantParams) -> np.ndarray:
    """(B, n): what one step of the plant grants (its fill is not used)."""
    b_count, n = requests.shape
    state = PlantState(volumes.astype(np.float64), timers_s.astype(np.float64), np.zeros(b_count, dtype=np.int64))
    _, outcome = dynamics.step(state, requests, params, np.zeros((b_count, n)), np.full((b_count, n), 0.5))
    return outcome.granted.copy()


def safe_emptyings(check: DeadlineCheck, granted: np.ndarray, free: int, log_odds: np.ndarray | None) -> np.ndarray:
    n = granted.size
    pool = np.union1d(check.due[:8], np.flatnonzero(granted))
    sets = [np.flatnonzero(granted), *(check.due[:k] for k in range(1, free + 1)),
            *(np.array(c) for size in (1, 2) for c in itertools.combinations(pool, size))]
    candidates = {tuple(sorted(int(i) for i in s)) for s in sets if 0 < len(s) <= free} | {()}
    rank = {int(i): k for k, i in enumerate(check.due)}
    best, best_key, least, least_risk = None, None, None, np.inf
    for members in sorted(candidates):
        chosen = np.isin(np.arange(n), members)
        risk = check.schedule_risk(chosen)
        key = (int((chosen & granted).sum()), -len(members), tuple(-rank.get(i, n) for i in members))
        if log_odds is not None:
            key = (float(log_odds[list(members)].sum()), *key)
        if risk.max(initial=0.0) <= check.epsilon and (best_key is None or key > best_key):
            best, best_key = chosen, key
        if risk.sum() < least_risk:
            least, least_risk = chosen, risk.sum()
    return best if best is not None else least


def python_rule(volumes, timers, requests, log_odds, params, setting, deadline_check=True) -> np.ndarray:
    granted = plant_grants(requests, volumes, timers, params)
    for b in range(volumes.shape[0]):
        free = int((timers[b] == 0.0).sum())
        if not free or not deadline_check:
            continue
        check = DeadlineCheck(volumes[b], timers[b], params, setting["risk"], setting["window_steps"])
        if check.due.size and not check.safe(granted[b]):
            granted[b] = safe_emptyings(check, granted[b], free,
                                        log_odds[b] if setting["prefer"] == "policy" else None)
    return granted


def observations(params: PlantParams, volumes: np.ndarray, timers_s: np.ndarray) -> np.ndarray:
    """(B·n, F) float32 observations holding what the rule reads: each agent's volume_frac, the PU timers."""
    names = agent_feature_names(params)
    b_count, n = volumes.shape
    obs = np.zeros((b_count, n, len(names)), dtype=np.float32)
    obs[:, :, names.index("volume_frac")] = volumes / np.asarray(params.max_volume)
    for j in range(params.n_pus):
        obs[:, :, names.index(f"pu_timer_frac[{j}]")] = (timers_s[:, j] / params.max_pu_time_s)[:, None]
    return obs.reshape(b_count * n, -1)


def read_back(params, obs):
    """The messages as the rule reads them (float32 observations times v_max and the longest PU time)."""
    names = agent_feature_names(params)
    n = params.n_containers
    o = obs.reshape(-1, n, obs.shape[-1])
    return (o[:, :, names.index("volume_frac")].astype(np.float64) * np.asarray(params.max_volume),
            o[:, 0, [names.index(f"pu_timer_frac[{j}]") for j in range(params.n_pus)]].astype(np.float64)
            * params.max_pu_time_s)


# ---- the compiled rule against it -----------------------------------------------------------------------
@pytest.mark.parametrize("row", ["n5_m2_dt60", "n5_m5_dt120", "n11_m2_dt120", "n11_m11_dt60", "n16_m2_dt120"])
def test_the_compiled_rule_is_the_python_rule_on_random_states(row):
    params = PlantParams.from_config(load_config(row))
    n, m = params.n_containers, params.n_pus
    rng = np.random.default_rng(7)
    changed = 0
    for setting in ({"risk": 1e-4, "window_steps": 24, "prefer": "policy"},
                    {"risk": 1e-6, "window_steps": 24, "prefer": "nearest"},
                    {"risk": 1e-2, "window_steps": 8, "prefer": "policy"}):
        sims = 300
        volumes = rng.uniform(0, 1, (sims, n)) * rng.choice([0.8, 0.95, 1.0], (sims, 1)) * np.asarray(params.max_volume)
        timers = np.where(rng.random((sims, m)) < 0.6, 0.0, rng.uniform(0, params.max_pu_time_s, (sims, m)))
        requests = rng.random((sims, n)) < rng.choice([0.05, 0.3, 0.8], (sims, 1))
        log_odds = rng.normal(0, 3, (sims, n))
        obs = observations(params, volumes, timers)
        for deadline_check in (True, False):
            rule = SharedCheck(setting, params, "local", deadline_check=deadline_check)
            granted, was_changed = rule(obs, requests.reshape(-1).astype(np.int64), log_odds.reshape(-1))
            expected = python_rule(*read_back(params, obs), requests, log_odds, params, setting, deadline_check)
            np.testing.assert_array_equal(granted, expected)
            grants = plant_grants(requests, *read_back(params, obs), params)
            np.testing.assert_array_equal(was_changed, (granted != grants).any(axis=1))
            changed += int(was_changed.sum())
    assert changed > 50  # the check did replace emptyings: the comparison covered its search


def test_risks_are_summed_as_numpy_sums_them_bit_for_bit():
    """The rule breaks ties of total risk as the Python rule (numpy's sum) does: its sum is numpy's, also past
    the 8-accumulator blocks and the halving above 128 entries."""
    from containergym_marl.policies.shared_check import _pairwise_sum

    rng = np.random.default_rng(3)
    for count in [*range(0, 40), 127, 128, 129, 255, 256, 257, 1000, 4099]:
        x = rng.random(count) ** 8  # many orders of magnitude: the order of the additions shows
        assert _pairwise_sum(x, 0, count) == x.sum()
        assert _pairwise_sum(np.concatenate([[5.0], x]), 1, count) == x.sum()


def test_the_fullest_requests_are_granted_ties_to_the_lower_index_and_none_without_a_free_pu():
    params = PlantParams.from_config(load_config("n5_m5_dt120"))
    volumes = np.array([[0.5, 0.9, 0.9, 0.2, 0.7]]) * np.asarray(params.max_volume)  # C2 and C3 equally full
    requests = np.array([1, 1, 1, 0, 1])
    withdraw = SharedCheck(SHARED_CHECK, params, "local", deadline_check=False)

    def granted(free):
        timers = np.where(np.arange(params.n_pus) < free, 0.0, 500.0)[None]
        return np.flatnonzero(withdraw(observations(params, volumes, timers), requests)[0][0]).tolist()

    assert granted(2) == [1, 2] and granted(1) == [1] and granted(3) == [1, 2, 4] and granted(0) == []


def test_an_emptying_that_breaks_a_deadline_is_replaced_by_the_safe_set_preferred():
    """n5_m2, PU 0 busy 1000 s, PU 1 free; C1-50 (index 3) at its optimum asks, C1-60 (index 4) near v_max
    eight steps from PU 0: giving PU 1 to C1-50 leaves C1-60 to overflow. At 30 units C1-60 can still wait
    (its deadline 2 fills) with PU 1 kept free: the safe set nearest to the request (none of it kept, the
    fewest emptyings) is waiting; at 36 units it cannot (deadline 0), and C1-60 takes the PU. With the
    policy's preference the safe set its agents find most likely: C1-60 emptied where its log-odds are
    positive, waiting where they are negative (waiting being safe at 30 units). A safe request stays."""
    params = PlantParams.from_config(load_config("n5_m2_dt120"))
    timers = np.array([[1000.0, 0.0]])
    asks_c1_50, asks_c1_60 = np.array([0, 0, 0, 1, 0]), np.array([0, 0, 0, 0, 1])

    def granted(volume, requests, prefer="nearest", log_odds=None):
        rule = SharedCheck({"risk": 1e-4, "window_steps": 24, "prefer": prefer}, params, "local")
        obs = observations(params, np.array([[5.0, 5.0, 5.0, 31.5, volume]]), timers)
        return np.flatnonzero(rule(obs, requests, log_odds)[0][0]).tolist()

    assert granted(30.0, asks_c1_50) == [] and granted(36.0, asks_c1_50) == [4]
    assert granted(30.0, asks_c1_60) == [4] and granted(36.0, asks_c1_60) == [4]
    favoured, disfavoured = np.array([-3.0, -3.0, -3.0, 2.0, 0.5]), np.array([-3.0, -3.0, -3.0, 2.0, -0.5])
    assert granted(30.0, asks_c1_50, "policy", favoured) == [4]
    assert granted(30.0, asks_c1_50, "policy", disfavoured) == []


def test_bad_settings_and_inputs_are_refused_naming_them():
    params = PlantParams.from_config(load_config("n5_m2_dt120"))
    for bad, field in (({**SHARED_CHECK, "risk": 1.5}, "risk"), ({**SHARED_CHECK, "window_steps": 0}, "window_steps"),
                       ({**SHARED_CHECK, "prefer": "loudest"}, "prefer"), ({"risk": 1e-4}, "shared_check")):
        with pytest.raises(ValueError, match=field):
            check_shared_check(bad)
    with pytest.raises(ValueError, match="arbitration"):
        SharedCheck(SHARED_CHECK, params, "local", arbitration="random")
    with pytest.raises(ValueError, match="portable"):
        SharedCheck(SHARED_CHECK, params, "portable")
    rule = SharedCheck(SHARED_CHECK, params, "local")
    obs = observations(params, np.full((1, 5), 10.0), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="log_odds"):
        rule(obs, np.zeros(5, dtype=np.int64))
    with pytest.raises(ValueError, match="requests"):
        rule(obs, np.zeros(4, dtype=np.int64), np.zeros(4))


# ---- the model and its policy ---------------------------------------------------------------------------
def _model(row="n11_m2_dt120", shared_check=SHARED_CHECK, seed=0):
    params = PlantParams.from_config(load_config(row))
    size = agent_observation_size(params.n_containers, params.n_pus)
    return ActorCritic("decentralised", size, 2, (16,), generator=torch.Generator().manual_seed(seed),
                       shared_check=shared_check)


@pytest.mark.parametrize("suffix", [".pt", ".safetensors"])
def test_the_model_carries_its_shared_check_through_its_file(tmp_path, suffix):
    model = _model(shared_check={"risk": 1e-3, "window_steps": 12, "prefer": "nearest"})
    path = tmp_path / f"model{suffix}"
    model.save(path) if suffix == ".pt" else model.save_safetensors(path)
    assert ActorCritic.load(path).shared_check == {"risk": 1e-3, "window_steps": 12, "prefer": "nearest"}
    plain = tmp_path / f"plain{suffix}"
    _model(shared_check=None).save(plain) if suffix == ".pt" else _model(shared_check=None).save_safetensors(plain)
    assert ActorCritic.load(plain).shared_check is None


def test_a_broken_or_centralised_shared_check_is_refused_naming_the_file(tmp_path):
    data = _model().to_dict()
    data["shared_check"] = {**SHARED_CHECK, "window_steps": -1}
    with pytest.raises(ValueError, match="window_steps"):
        ActorCritic.from_dict(data, "model file 'x.pt'")
    with pytest.raises(ValueError, match="centralised model has no container agents"):
        ActorCritic("centralised", 13, 12, (8,), shared_check=SHARED_CHECK)


def test_the_policy_binds_the_plant_from_its_environment_and_asks_for_it_otherwise():
    """Through the PettingZoo env (per-agent dicts) the policy applies the rule to the network's requests:
    the same actions as the rule on the same observations, and no request is denied although the network
    asks for far more PUs than are free; act_batch without a bound plant is refused."""
    from containergym_marl.envs.container_agents_v0 import parallel_env

    cfg = load_config("n11_m2_dt120")
    model = _model()
    with torch.no_grad():
        model.net.actor[-1].bias[:] = torch.tensor([0.0, 3.0])  # every agent asks: many would be denied
    policy = policy_for(model, name="messaging")
    with pytest.raises(ValueError, match="bind"):
        policy.act_batch(np.zeros((11, model.observation_size), dtype=np.float32), None)
    env = parallel_env(cfg, action_masking=True)
    obs, _ = env.reset(seed=20_000)
    rule = SharedCheck(SHARED_CHECK, PlantParams.from_config(cfg), "local")
    asked = denied = 0
    for _ in range(60):
        actions = policy.act(obs, env)
        stacked = np.stack([obs[a]["observation"] if isinstance(obs[a], dict) else obs[a] for a in env.agents])
        logits = model.decision_logits(torch.as_tensor(stacked))
        network = logits.argmax(-1).numpy()
        expected, _ = rule(stacked, network, (logits[:, 1] - logits[:, 0]).double().numpy())
        assert [actions[a] for a in env.agents] == expected[0].astype(int).tolist()
        asked += int(network.sum())
        obs, _, _, _, infos = env.step(actions)
        denied += sum(int(info["denied"]) for info in infos.values())
        if not env.agents:
            break
    assert asked > 300 and denied == 0


def test_the_batched_evaluation_and_the_environments_agree_with_the_rule():
    """Three validation episodes of a fresh network that asks too often: evaluate() (through the env) and
    evaluate_batched() give the same returns with the rule, no denied request, and other returns without."""
    from containergym_marl.evaluation import EvalProtocol, evaluate
    from containergym_marl.evaluation.batched import evaluate_batched

    model, plain = _model(seed=3), _model(seed=3, shared_check=None)
    for m in (model, plain):
        with torch.no_grad():
            m.net.actor[-1].bias[:] = torch.tensor([0.0, 1.0])
    protocol = EvalProtocol(episodes=3, first_seed=20_000)
    one = evaluate(policy_for(model, name="m"), "n11_m2_dt120", protocol, keep_records=False)
    batched = evaluate_batched(policy_for(model, name="m"), "n11_m2_dt120", protocol)
    # the same decisions: the same steps and emptyings; the returns summed in another order (ulps apart)
    for a, b in zip(one.episodes, batched.episodes):
        assert (a.values["steps"], a.values["emptyings"]) == (b.values["steps"], b.values["emptyings"])
        assert a.cumulative_reward == pytest.approx(b.cumulative_reward, rel=1e-12)
    assert all(e.values["denied_requests"] == 0 for e in batched.episodes)
    without = evaluate_batched(policy_for(plain, name="m"), "n11_m2_dt120", protocol)
    assert all(e.values["denied_requests"] > 0 for e in without.episodes)


def test_the_imitations_rollouts_act_with_the_rule():
    """DAgger's learner, with the model's shared check, takes in every step of a rollout the rule's actions
    on its network's greedy requests (here a network that asks too often), so the data set holds the states
    the deployed policy meets."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.dagger import DAggerArgs, Episodes, Labeller, collect

    env = ContainerAgentsVecEnv("n11_m2_dt120", 2, episode_length_steps=40)
    model = ActorCritic("decentralised", env.observation_space.shape[0], 2, (16,),
                        generator=torch.Generator().manual_seed(0), shared_check=SHARED_CHECK)
    with torch.no_grad():
        model.net.actor[-1].bias[:] = torch.tensor([0.0, 2.0])
    obs = torch.from_numpy(env.reset())
    rollout, _, _ = collect(model, env, obs, torch.ones(env.num_envs), Labeller(2, DAggerArgs(futures=2, horizon=2), 0),
                            30, 0.99, torch.Generator().manual_seed(0), False, True,
                            Episodes(2, TrainingProgress(0)))
    rule = SharedCheck(SHARED_CHECK, PlantParams.from_config(load_config("n11_m2_dt120")), "local")
    withdrawn = 0
    for t in range(30):
        with torch.no_grad():
            logits = model.logits(rollout.obs[t])
        network = logits.argmax(-1).numpy()
        expected, _ = rule(rollout.obs[t].numpy(), network, (logits[:, 1] - logits[:, 0]).double().numpy())
        np.testing.assert_array_equal(rollout.actions[t].numpy(), expected.reshape(-1))
        withdrawn += int((network.astype(bool) & ~expected.reshape(-1)).sum())
    assert withdrawn > 30


def test_the_messaging_imitation_trains_and_saves_the_chosen_rule(tmp_path):
    from containergym_marl.algorithms import get_algorithm
    from containergym_marl.training import TrainArgs, train

    trainer = get_algorithm("dagger_messaging_agents").trainer()
    assert trainer.settings({}).shared_check() == SHARED_CHECK
    for bad in ({"shared_check_prefer": "loudest"}, {"shared_check_window_steps": 0}, {"shared_check_risk": 1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            trainer.settings(bad)
    run = train(TrainArgs(algo="dagger_messaging_agents", out=str(tmp_path / "r"), timesteps=1600, seed=1, n_envs=2,
                          progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 64, "futures": 2,
                                                           "horizon": 2}, overrides={"episode_length_steps": 20}))
    assert ActorCritic.load(run / "final_model.pt").shared_check == SHARED_CHECK
