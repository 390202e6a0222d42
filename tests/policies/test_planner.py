"""What-if simulations in the core and the rollout planner built on them."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from containergym_marl import ContainerGymEnv, load_config
from containergym_marl.core import dynamics, overflow_probabilities, simulate_futures
from containergym_marl.core.whatif import simulate_future_groups
from containergym_marl.core.params import PlantParams
from containergym_marl.core.simulator import PlantSimulator
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies import PlannerAgents, RolloutPlanner, RuleBasedAgents
from containergym_marl.policies.planner import decide_all, fullest_base, index_base, respond_all
from tests.helpers import make_state

SMALL = dict(futures=4, horizon=6)  # a cheap planner for behaviour tests


def _no_requests(state, params):
    return np.zeros(state.volumes.shape, dtype=bool)


# ---- what-if simulations in the core ------------------------------------------------------------
def test_branching_leaves_the_original_trajectory_bit_identical():
    """A simulation that is branched (and whose copies are stepped) at every step follows exactly the
    trajectory of a twin with the same seed and requests that is never branched."""
    cfg = load_config("n5_m2_dt120", episode_length_steps=80)
    requests = np.random.default_rng(5).random((40, 2, cfg.n_containers)) < 0.1
    planned, plain = PlantSimulator(cfg, num_sims=2), PlantSimulator(cfg, num_sims=2)
    planned.reset(generators=[np.random.default_rng(s) for s in (1, 2)])
    plain.reset(generators=[np.random.default_rng(s) for s in (1, 2)])
    for t in range(40):  # crosses a refill of the random blocks (32 rows)
        copies = planned.branch(t % 2, [np.random.default_rng(100 + t + k) for k in range(3)])
        np.testing.assert_array_equal(copies.state.volumes, planned.state.volumes[[t % 2] * 3])
        np.testing.assert_array_equal(copies.state.pu_timers_s, planned.state.pu_timers_s[[t % 2] * 3])
        for _ in range(3):
            copies.step(np.ones((3, cfg.n_containers), bool))
        simulate_futures(planned.state, 0, requests[t, :1], fullest_base_all, planned.params,
                         np.random.default_rng(t).standard_normal((4, 3, cfg.n_containers)))
        a, b = planned.step(requests[t]), plain.step(requests[t])
        np.testing.assert_array_equal(planned.state.volumes, plain.state.volumes)
        np.testing.assert_array_equal(planned.state.pu_timers_s, plain.state.pu_timers_s)
        np.testing.assert_array_equal(a.plant_reward, b.plant_reward)


def fullest_base_all(state, params):
    return fullest_base(state, params, params.n_pus)


def test_branch_copies_fill_with_the_plant_statistics():
    """K copies of one state, stepped once without emptying: every container's volume change has
    mean μδ and standard deviation σ√δ (bounds of 5 standard errors, fixed seeds)."""
    cfg = load_config("n11_m2_dt120")
    sim = PlantSimulator(cfg)
    sim.reset(generators=[np.random.default_rng(0)])
    sim.state = make_state(np.full(cfg.n_containers, 20.0), [0.0, 0.0])  # far from 0 and v_max
    k = 4000
    copies = sim.branch(0, [np.random.default_rng(s) for s in range(k)])
    copies.step(np.zeros((k, cfg.n_containers), bool))
    change = copies.state.volumes - 20.0
    mu, sd = np.asarray(sim.params.fill_mean_per_step), np.asarray(sim.params.fill_std_per_step)
    assert np.all(np.abs(change.mean(axis=0) - mu) < 5 * sd / math.sqrt(k))
    assert np.all(np.abs(change.std(axis=0) - sd) < 5 * sd / math.sqrt(2 * k))
    assert len({row.tobytes() for row in copies.state.volumes}) == k  # every copy has its own stream
    np.testing.assert_array_equal(sim.state.volumes, 20.0)  # the original did not move


def test_futures_match_the_step_and_share_noise_across_candidates():
    cfg = load_config("n5_m2_dt120")
    params = PlantParams.from_config(cfg)
    state = make_state([[5.0, 26.5, 20.0, 30.0, 12.0], [1, 2, 3, 4, 5]], [[0.0, 300.0], [0, 0]], 10)
    candidates = np.zeros((3, 5), bool)
    candidates[1, 1] = candidates[2, 3] = True  # wait; empty C1-30; empty C1-70
    normals = np.random.default_rng(3).standard_normal((5, 7, 5))
    fut = simulate_futures(state, 0, candidates, _no_requests, params, normals)
    assert fut.rewards.shape == fut.overflow_risk.shape == (3, 7, 5)
    # the first step is the core's step from row 0 with the candidate's requests and stream k
    for c in range(3):
        one, out = dynamics.step(state.select(np.zeros(7, int)), np.repeat(candidates[c:c + 1], 7, axis=0),
                                 params, normals[0], np.full((7, 5), 0.5))
        np.testing.assert_array_equal(fut.rewards[c, :, 0], out.plant_reward)
    # common random numbers: containers emptied by no candidate end alike in every candidate
    final = fut.final_state.volumes.reshape(3, 7, 5)
    for i in (0, 2, 4):
        np.testing.assert_array_equal(final[0, :, i], final[1, :, i])
        np.testing.assert_array_equal(final[0, :, i], final[2, :, i])
    assert not np.array_equal(final[0, :, 1], final[1, :, 1])
    assert fut.rewards[1, :, 0] == pytest.approx(dynamics.emptying_reward(1, 26.5, params))
    with pytest.raises(ValueError, match="normals"):
        simulate_futures(state, 0, candidates, _no_requests, params, normals[:, :, :4])


def test_grouped_futures_are_each_groups_futures_alone():
    """Several simulations' futures stepped in one batch are, group by group, the futures each gets
    alone, bit for bit: here one group reaches the time limit after 2 of 6 steps and another
    overflows early, while the third runs on (so the batch steps past the first two's ends)."""
    cfg = load_config("n5_m2_dt120")
    params = PlantParams.from_config(cfg)
    t_end = params.episode_length_steps
    state = make_state([[5.0, 26.5, 20.0, 30.0, 12.0], [1.0, 2.0, 3.0, 4.0, 5.0], [5.0, 5.0, 5.0, 5.0, 39.9]],
                       [[0.0, 300.0], [0.0, 0.0], [100.0, 200.0]])
    state.step_count[:] = [10, t_end - 2, 3]
    rng = np.random.default_rng(8)
    groups = [(b, rng.random((c, 5)) < 0.3, rng.standard_normal((6, k, 5))) for b, c, k in ((0, 3, 4), (1, 2, 5),
                                                                                          (2, 1, 3), (0, 2, 2))]
    together = simulate_future_groups(state, groups, fullest_base_all, params)
    assert together[1].ended.all() and (together[1].end_step == 2).all()  # the time limit
    assert together[2].overflowed.any() and not together[0].ended.all()
    for (sim, first, normals), batched in zip(groups, together):
        alone = simulate_futures(state, sim, first, fullest_base_all, params, normals)
        for field in ("rewards", "overflow_risk", "end_step", "overflowed", "ended"):
            np.testing.assert_array_equal(getattr(batched, field), getattr(alone, field), err_msg=field)
        running = ~alone.ended.reshape(-1)  # the final states of futures still running
        np.testing.assert_array_equal(batched.final_state.volumes[running], alone.final_state.volumes[running])
    with pytest.raises(ValueError, match="same H"):
        simulate_future_groups(state, [groups[0], (1, groups[1][1], groups[1][2][:4])], fullest_base_all, params)


@pytest.mark.parametrize("config, safety_risk", [("n11_m2_dt120", None), ("n16_m2_dt120", 1e-6)])
def test_planners_deciding_together_decide_as_each_alone(config, safety_risk):
    """:func:`decide_all` over B simulations gives each planner's own decision, step after step: the
    same look-ahead on the same random stream, the simulations driven by those decisions (so a
    difference anywhere would change the rest), with the deadline check's replanning included."""
    cfg = load_config(config)
    together, alone = (PlantSimulator(cfg, num_sims=6) for _ in range(2))
    for sim in (together, alone):
        sim.reset(generators=[np.random.default_rng(40 + b) for b in range(6)])
    planners = {side: [PlannerAgents(safety_risk=safety_risk, **SMALL) for _ in range(6)] for side in ("a", "b")}
    for side in planners:
        for b, planner in enumerate(planners[side]):
            planner.reset(70 + b)
    for sim in (together, alone):  # the simulations near the ends of their episodes, each at another step
        sim.state.step_count[:] = cfg.episode_length_steps - 45 + 7 * np.arange(6)  # ends at different steps
    for _ in range(60):
        batched = decide_all(planners["a"], together.state, together.params)
        single = np.stack([p.decide(alone.state.select(slice(b, b + 1)), alone.params)
                           for b, p in enumerate(planners["b"])])
        np.testing.assert_array_equal(batched, single)
        for sim in (together, alone):
            out = sim.step(batched)
            if (done := out.terminated | out.truncated).any():
                sim.reset(np.flatnonzero(done))
    assert [p.planned for p in planners["a"]] == [p.planned for p in planners["b"]]
    assert sum(p.planned for p in planners["a"]) > 30
    if safety_risk is not None:
        assert [p.shielded for p in planners["a"]] == [p.shielded for p in planners["b"]]


def test_best_responses_together_are_each_planners_alone():
    cfg = load_config("n11_m2_dt120")
    sim = PlantSimulator(cfg, num_sims=5)
    sim.reset(generators=[np.random.default_rng(90 + b) for b in range(5)])
    a, b = ([PlannerAgents(**SMALL) for _ in range(5)] for _ in range(2))
    for k in range(5):
        a[k].reset(k)
        b[k].reset(k)
    rng = np.random.default_rng(1)
    responded = 0
    for _ in range(40):
        requests = rng.random((5, 11)) < 0.1
        batched = respond_all(a, sim.state, sim.params, requests)
        single = np.stack([p.respond(sim.state.select(slice(k, k + 1)), sim.params, requests[k])
                           for k, p in enumerate(b)])
        np.testing.assert_array_equal(batched, single)
        responded += int(batched.sum())
        out = sim.step(requests)
        if (done := out.terminated | out.truncated).any():
            sim.reset(np.flatnonzero(done))
    assert responded > 0 and sum(p.planned for p in a) == sum(p.planned for p in b) > 0


def test_planners_deciding_together_must_match_the_batch():
    sim = PlantSimulator(load_config("n5_m2_dt120"), num_sims=2)
    sim.reset(generators=[np.random.default_rng(b) for b in range(2)])
    with pytest.raises(ValueError, match="planners: expected one per simulation"):
        decide_all([PlannerAgents()], sim.state, sim.params)
    with pytest.raises(ValueError, match="requests"):
        respond_all([PlannerAgents(), PlannerAgents()], sim.state, sim.params, np.zeros((2, 4), bool))
    state = make_state([[30.0, 30.0, 30.0, 30.0, 30.0]] * 2, [[0.0, 0.0]] * 2)  # both plan
    with pytest.raises(ValueError, match="same horizon"):
        decide_all([PlannerAgents(horizon=4), PlannerAgents(horizon=8)], state, sim.params)


def test_overflow_probability_matches_the_normal_tail_and_sampling():
    cfg = load_config("n11_m2_dt120")  # C2-10 (index 6): σ√δ ≈ 1.16 per step, v_max = 40
    params = PlantParams.from_config(cfg)
    v = np.full((1, 11), 5.0)
    v[0, 6] = 37.5
    mu, sd = params.fill_mean_per_step[6], params.fill_std_per_step[6]
    expected = 0.5 * math.erfc((40.0 - 37.5 - mu) / (sd * math.sqrt(2)))
    p = overflow_probabilities(v, np.zeros((1, 11), bool), params)
    assert p[0] == pytest.approx(expected, rel=1e-9) and 0.01 < expected < 0.2
    emptied = np.zeros((1, 11), bool)
    emptied[0, 6] = True
    assert overflow_probabilities(v, emptied, params)[0] < 1e-12  # emptied: cannot overflow
    k = 20_000  # sampled: the share of K futures that overflow in their first step
    fut = simulate_futures(make_state(v[0], [0.0, 0.0]), 0, np.zeros((1, 11), bool), _no_requests, params,
                           np.random.default_rng(1).standard_normal((1, k, 11)))
    assert fut.overflow_risk[0, :, 0] == pytest.approx(expected, rel=1e-9)
    assert abs(fut.overflowed.mean() - expected) < 5 * math.sqrt(expected * (1 - expected) / k)


def test_overflow_probability_is_the_product_over_every_container_bit_for_bit():
    """1 − Πᵢ (1 − ½ erfc(zᵢ)) over the containers not emptied, each factor multiplied in as written
    here in Python (containers far below their limit included): the same float64 number."""
    params = PlantParams.from_config(load_config("n16_m2_dt120"))
    rng = np.random.default_rng(3)
    v_max = np.asarray(params.max_volume)
    volumes = v_max * rng.choice([0.2, 0.9, 0.97, 1.0], size=(200, 16)) * rng.uniform(0.9, 1.0, (200, 16))
    volumes[::4] = 0.2 * v_max  # every container far below its limit
    emptied = rng.random((200, 16)) < 0.2
    got = overflow_probabilities(volumes, emptied, params)
    for b in range(200):
        survive = 1.0
        for i in range(16):
            if not emptied[b, i]:
                gap = v_max[i] - volumes[b, i] - params.fill_mean_per_step[i]
                survive *= 1.0 - 0.5 * math.erfc(gap / (params.fill_std_per_step[i] * math.sqrt(2.0)))
        assert got[b] == 1.0 - survive, b
    assert 0 < (got > 0).sum() < 200  # rows with and without a container near its limit


# ---- the planner ----------------------------------------------------------------------------------
def test_base_policies_request_only_what_the_free_pus_grant():
    """Every container at its optimum (all ready): ``fullest`` picks by v / v_max, ``index`` by
    index, as many as free PUs (at most ``max_requests``)."""
    params = PlantParams.from_config(load_config("n5_m2_dt120"))
    target = np.asarray(params.target_volume)  # 27, 25, 25.5, 31.5, 25: v_max 40 for all
    state = make_state([target] * 3, [[0.0, 0.0], [0.0, 60.0], [60.0, 60.0]])
    assert np.flatnonzero(fullest_base(state, params, 2)[0]).tolist() == [0, 3]
    assert fullest_base(state, params, 2).sum(axis=1).tolist() == [2, 1, 0]
    assert np.flatnonzero(fullest_base(state, params, 1)[0]).tolist() == [3]
    assert np.flatnonzero(index_base(state, params, 2)[0]).tolist() == [0, 1]
    assert np.flatnonzero(index_base(state, params, 2)[1]).tolist() == [0]


@pytest.mark.parametrize("config", ["n5_m2_dt120", "n16_m2_dt120"])
def test_base_policies_follow_a_stable_sort_of_the_ready_containers(config):
    """On random states with ties (equal fullness, several containers at the same volume, none or all
    PUs free), each row's requests are the first of its ready containers (v* − v <= margin) sorted by
    (priority descending, index), as many as free PUs and ``max_requests`` allow: written here with
    Python's sort, one row at a time."""
    params = PlantParams.from_config(load_config(config))
    n, m = params.n_containers, params.n_pus
    rng = np.random.default_rng(7)
    volumes = rng.random((300, n)) * np.asarray(params.max_volume) * 1.1
    volumes[::3] = np.round(volumes[::3] / params.max_volume * 4) / 4 * params.max_volume  # equal fullness
    volumes[1::3, 1] = volumes[1::3, 0]  # equal volumes
    timers = np.where(rng.random((300, m)) < 0.5, 0.0, 60.0)
    state = make_state(volumes, timers)
    for margin in (0.0, 1.0, 8.0):
        for max_requests in (1, 2, n):
            for base, priority in ((fullest_base, lambda v, i: v / params.max_volume[i]), (index_base, lambda v, i: -i)):
                got = base(state, params, max_requests, margin)
                for b in range(len(volumes)):
                    ready = [i for i in range(n) if params.target_volume[i] - volumes[b, i] <= margin]
                    ready.sort(key=lambda i: (-priority(volumes[b, i], i), i))
                    limit = min(int((timers[b] == 0.0).sum()), max_requests)
                    assert np.flatnonzero(got[b]).tolist() == sorted(ready[:limit]), (base.__name__, margin, b)


def _decide(planner, cfg, volumes, timers, step=5):
    sim = PlantSimulator(cfg)
    sim.reset(generators=[np.random.default_rng(0)])
    sim.state = make_state(volumes, timers, step)
    planner.reset(seed=1)
    return planner.decide(sim.state, sim.params)


def test_planner_waits_for_the_optimum_but_empties_at_the_end_of_the_episode():
    """C1-20 (v* = 27, w = 2) at 25 earns 0.57 now. Mid-episode waiting is worth more (it reaches
    ~1 two or three steps later); on the last step the volume is worth nothing after the time limit,
    so the planner takes the 0.57. The rule (margin 1) waits in both cases."""
    cfg = load_config("n5_m2_dt120", episode_length_steps=600)
    volumes = [25.0, 5.0, 5.0, 5.0, 5.0]
    planner = RolloutPlanner(**SMALL)
    assert not _decide(planner, cfg, volumes, [0.0, 0.0], step=100).any()
    assert planner.planned == 1  # it did look ahead (C1-20 earns > 0, a candidate)
    assert _decide(planner, cfg, volumes, [0.0, 0.0], step=599).tolist() == [True] + [False] * 4


def test_planner_does_not_plan_without_a_free_pu_or_a_candidate():
    cfg = load_config("n5_m2_dt120")
    planner = RolloutPlanner(**SMALL)
    assert not _decide(planner, cfg, [27.0, 25.0, 22.0, 31.0, 35.0], [100.0, 20.0]).any()
    assert not _decide(planner, cfg, [1.0, 2.0, 3.0, 4.0, 5.0], [0.0, 0.0]).any()
    assert planner.decisions == 2 and planner.planned == 0


def test_planner_agents_never_request_more_than_the_free_pus():
    cfg = load_config("n5_m2_dt120")
    planner = PlannerAgents(**SMALL)
    requests = _decide(planner, cfg, [27.0, 25.0, 22.5, 31.5, 35.0], [0.0, 0.0])  # all at their optimum
    assert requests.sum() == 2
    assert _decide(planner, cfg, [27.0, 25.0, 22.5, 31.5, 35.0], [0.0, 50.0]).sum() == 1


def test_evaluation_with_the_planner_is_reproducible_and_leaves_the_env_stream_alone():
    """Two evaluations give the same episodes; replaying the planner's actions without it gives the
    same trajectory bit for bit (its look-ahead never draws from the environment's generator)."""
    protocol = EvalProtocol(episodes=2, episode_length_steps=60)
    first = evaluate(RolloutPlanner(**SMALL), "n11_m2_dt120", protocol)
    second = evaluate(RolloutPlanner(**SMALL), "n11_m2_dt120", protocol)
    for a, b in zip(first.records, second.records):
        np.testing.assert_array_equal(a.volumes, b.volumes)
        env = ContainerGymEnv("n11_m2_dt120", timestep_s=120, episode_length_steps=60)
        env.reset(seed=a.seed)
        volumes = [env.simulator.state.volumes[0].copy()]
        for row in a.requested:
            env.step(int(row.argmax()) + 1 if row.any() else 0)
            volumes.append(env.simulator.state.volumes[0].copy())
        np.testing.assert_array_equal(np.array(volumes), a.volumes)
    assert any(r.granted.any() for r in first.records)


def test_planner_agents_beat_the_rule_on_a_contended_plant():
    """n11_m2 (11 containers, 2 PUs), two short episodes: the planner through the agents' view earns
    more than the rule-based agents, with no denied request and no overflow."""
    protocol = EvalProtocol(episodes=2, episode_length_steps=150)
    cfg = load_config("n11_m2_dt120")
    planner = evaluate(PlannerAgents(futures=8, horizon=12), cfg, protocol).summary()
    rule = evaluate(RuleBasedAgents(PlantParams.from_config(cfg)), cfg, protocol).summary()
    assert planner["return_mean"] > rule["return_mean"]
    assert planner["denied_requests_mean"] == 0 and planner["overflow_rate"] == 0


def test_planner_runs_through_the_parallel_env_and_the_registries(capsys):
    from containergym_marl.cli import main
    from containergym_marl.methods import METHODS

    env = parallel_env("n5_m2_dt120", episode_length_steps=5)
    observations, _ = env.reset(seed=3)
    planner = PlannerAgents(**SMALL)
    while env.agents:
        actions = planner.act(observations, env)
        assert set(actions) == set(env.possible_agents) and set(actions.values()) <= {0, 1}
        observations, *_ = env.step(actions)
    assert (METHODS["planner"].controller, METHODS["planner_agents"].controller) == (RolloutPlanner, PlannerAgents)
    with pytest.raises(ValueError, match="base"):
        RolloutPlanner(base="nope")
    assert main(["evaluate", "planner", "--config", "n5_m5_dt120", "--episodes", "1"]) == 0
    assert "planner on n5_m5_dt120 (centralised view), 1 episodes" in capsys.readouterr().out


def _script(name: str, monkeypatch):
    """A script of studies/ as a module."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "studies" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_rows_benchmark_smoke_run(tmp_path, monkeypatch):
    """studies/planner_rows.py end to end at a tiny size: every method measured, the table written."""
    script = _script("planner_rows", monkeypatch)
    script.main(script.parse(["--smoke", "--out", str(tmp_path)]))
    data = json.loads((tmp_path / "rows.json").read_text())["evaluations"]
    assert [(e["method"], e["setting"]) for e in data] == [
        ("rule_based", "-"), ("rule_based_agents", "-"), ("planner", "default"), ("planner_agents", "default"),
        ("planner", "strong"), ("planner_agents", "strong")]
    assert all(len(e["returns"]) == 2 and e["decision_ms_mean"] > 0 for e in data)
    table = (tmp_path / "rows.md").read_text()
    assert "| n5_m2_dt120 | planner_agents | strong (K=8, H=8) |" in table and "## Targets" in table


def test_sweep_script_smoke_run(tmp_path, monkeypatch):
    script = _script("planner_sweep", monkeypatch)
    script.main(["--row", "n5_m2_dt120", "--futures", "2", "--horizons", "2", "3", "--episodes", "1",
                 "--episode-length-steps", "15", "--out", str(tmp_path)])
    data = json.loads((tmp_path / "sweep_n5_m2_dt120.json").read_text())
    assert [(e["futures"], e["horizon"]) for e in data["settings"]] == [(2, 2), (2, 3)]
    assert "| 2 | " in (tmp_path / "sweep_n5_m2_dt120.md").read_text()


def test_uncertain_compares_the_paired_gap_with_its_standard_error():
    rng = np.random.default_rng(0)
    common = rng.normal(0.0, 5.0, 16)  # what every candidate's futures share: cancels in the gaps
    clear = np.stack([common + 10.0 + rng.normal(0, 0.1, 16), common + rng.normal(0, 0.1, 16)])
    assert not RolloutPlanner.uncertain(clear, 2.0)  # a gap of 10, its error about 0.04
    close = np.stack([common + 0.05 + rng.normal(0, 1.0, 16), common + rng.normal(0, 1.0, 16)])
    gaps = close[0] - close[1]
    z = abs(gaps.mean()) / (gaps.std(ddof=1) / 4.0)
    assert RolloutPlanner.uncertain(close, z + 0.01) and not RolloutPlanner.uncertain(close, z - 0.01)
    same = np.stack([common, common, common - 1.0])  # equal futures: no sampling error in their gap
    assert not RolloutPlanner.uncertain(same, 2.0)


def test_a_wider_look_ahead_only_on_uncertain_steps():
    """With max_futures the planner plans some steps again on more futures, the others as the default
    does: until its first widened step its decisions are the default planner's, step for step."""
    cfg = load_config("n11_m2_dt120", episode_length_steps=120)
    default, wide = RolloutPlanner(), RolloutPlanner(max_futures=64)
    env = ContainerGymEnv(cfg)
    env.reset(seed=20_000)
    default.reset(seed=20_000)
    wide.reset(seed=20_000)
    sim = env.simulator
    widened_at = None
    for step in range(120):
        a, b = default.decide(sim.state, sim.params), wide.decide(sim.state, sim.params)
        if wide.widened and widened_at is None:
            widened_at = step
        if widened_at is None:
            np.testing.assert_array_equal(a, b)
        elif not np.array_equal(a, b):
            break
        _, _, terminated, truncated, _ = env.step(int(np.flatnonzero(b)[0]) + 1 if b.any() else 0)
        if terminated or truncated:
            break
    assert widened_at is not None and 0 < wide.widened <= wide.planned
    assert default.widened == 0


@pytest.mark.parametrize("kwargs, field", [({"futures": 16, "max_futures": 8}, "max_futures"),
                                           ({"max_futures": 0}, "max_futures"),
                                           ({"confidence": -1.0}, "confidence"),
                                           ({"confidence": float("nan")}, "confidence")])
def test_bad_look_ahead_settings_are_named(kwargs, field):
    with pytest.raises(ValueError, match=field):
        PlannerAgents(**kwargs)
