"""The evaluation protocol and its metrics against episodes replayed independently."""

from __future__ import annotations

import json

import numpy as np
import pytest

from containergym_marl import ContainerGymEnv, load_config
from containergym_marl.evaluation import PAPER, EvalProtocol, EpisodeRecord, evaluate
from containergym_marl.evaluation.table import markdown_table, method_rows
from containergym_marl.policies import RuleBasedAgents, RuleBasedController
from containergym_marl.core.params import PlantParams


def test_paper_protocol_defaults():
    assert (PAPER.timestep_s, PAPER.episode_length_steps, PAPER.episodes, PAPER.deterministic) == (120.0, 600, 15, True)
    assert PAPER.seeds == list(range(10_000, 10_015))
    plant = PAPER.plant("n5_m2_dt60")
    assert plant.timestep_s == 120.0 and plant.episode_length_steps == 600


def test_metrics_match_a_manual_replay_including_the_final_reward():
    """Replay each evaluation episode by hand with the same seed and actions: cumulative reward
    (final step included), steps, overflow, emptyings and denied requests agree."""
    cfg = load_config("n11_m2_dt120")
    policy = RuleBasedController(PlantParams.from_config(cfg))
    result = evaluate(policy, cfg, EvalProtocol(episodes=4, episode_length_steps=300))
    for metrics, record in zip(result.episodes, result.records):
        env = ContainerGymEnv(cfg, timestep_s=120, episode_length_steps=300)
        obs, _ = env.reset(seed=metrics.seed)
        total, emptied, actions, denied, good, negative, rewards = 0.0, 0, 0, 0, 0, 0, []
        while True:
            action = policy.act(obs)
            obs, r, term, trunc, info = env.step(action)
            total += r
            if action > 0:  # an emptying action, carried out or denied (reward r_pen)
                actions += 1
                good += info["emptying_reward"] >= 0.75
                negative += info["emptying_reward"] < 0
            emptied += info["emptied_index"] >= 0
            denied += info["no_free_pu"]
            rewards.append(r)
            if term or trunc:
                break
        assert metrics.cumulative_reward == pytest.approx(total, abs=1e-9)
        assert metrics.steps == info["step"] and metrics.overflow == term
        assert metrics.emptyings == emptied and metrics.denied_requests == denied
        assert metrics.emptying_actions == actions == emptied + denied
        assert metrics.good_emptying_share == pytest.approx(good / actions)
        assert metrics.negative_emptying_share == pytest.approx(negative / actions)
        np.testing.assert_allclose(record.plant_reward, rewards)


class NeverEmpty:
    name, view = "never_empty", "centralised"

    def act(self, observation, env):
        return 0


def test_final_overflow_reward_is_counted():
    """A controller that never empties overflows; its only non-zero reward is the final r_min, so
    its return is exactly r_min (the paper's script, dropping the last reward, reported 0)."""
    result = evaluate(NeverEmpty(), "n5_m2_dt120", EvalProtocol(episodes=3))
    for metrics, rec in zip(result.episodes, result.records):
        assert metrics.overflow and metrics.steps < 600
        assert metrics.cumulative_reward == -1.0 and rec.plant_reward[-1] == -1.0
        assert metrics.emptyings == 0 and np.isnan(metrics.good_emptying_share)


def test_records_and_the_cli_name_the_containers_whose_overflow_ended_the_episode(capsys, tmp_path):
    """Never emptying, every episode ends in an overflow: the record names exactly the containers at
    or above their v_max in the final state (checked against the config), survives a save and load,
    and the evaluate command prints them with their volume after the reset."""
    from containergym_marl.cli import _print_evaluation

    cfg = load_config("n5_m2_dt120")
    max_volume = np.array([c.max_volume for c in cfg.containers])
    result = evaluate(NeverEmpty(), cfg, EvalProtocol(episodes=3))
    lines = []
    for rec in result.records:
        over = np.flatnonzero(rec.volumes[-1] >= max_volume)
        assert over.size >= 1 and np.all(rec.volumes[-2] < max_volume)
        assert rec.overflowed_containers == tuple(cfg.container_names[i] for i in over)
        lines.append(", ".join(f"{cfg.container_names[i]} ({rec.volumes[0, i]:.1f})" for i in over))
    rec.save_npz(tmp_path / "e.npz")
    assert EpisodeRecord.load_npz(tmp_path / "e.npz").overflowed_containers == rec.overflowed_containers
    _print_evaluation(result, None)
    rows = capsys.readouterr().out.splitlines()[2:5]
    assert [row.split("  ")[-1] for row in rows] == lines

    survivor = evaluate(RuleBasedController(PlantParams.from_config(cfg)), cfg, EvalProtocol(episodes=1))
    assert not survivor.records[0].terminated and survivor.records[0].overflowed_containers == ()


def test_overflow_risk_is_each_step_s_normal_tail_summed_over_the_episode():
    """Each step's probability of an overflow, computed by hand from the config (fill rate and noise
    per second, δ, v_max) with scipy's normal tail over the containers the step did not empty, and
    the episode's ``overflow_risk`` as their sum."""
    from scipy.stats import norm

    cfg = load_config("n11_m2_dt120")
    dt = 120.0
    rate = np.array([c.fill_rate_per_s for c in cfg.containers]) * dt
    noise = np.array([c.fill_noise_per_sqrt_s for c in cfg.containers]) * np.sqrt(dt)
    v_max = np.array([c.max_volume for c in cfg.containers])
    result = evaluate(RuleBasedAgents(PlantParams.from_config(cfg)), cfg, EvalProtocol(episodes=2, episode_length_steps=300))
    for metrics, rec in zip(result.episodes, result.records):
        tails = norm.sf(v_max, loc=rec.volumes[:-1] + rate, scale=noise)  # (T, n): P(v + fill >= v_max)
        expected = 1.0 - np.prod(np.where(rec.granted, 1.0, 1.0 - tails), axis=1)
        np.testing.assert_allclose(rec.overflow_probability, expected, rtol=1e-9, atol=1e-15)
        assert expected.max() > 1e-9  # the rule runs containers close enough to v_max to test the sum
        assert metrics.overflow_risk == pytest.approx(expected.sum(), rel=1e-9)


def test_the_mean_overflow_risk_estimates_the_overflow_rate():
    """Never emptying on episodes of 20 steps, about half the episodes overflow: the mean overflow
    risk and the share of overflowing episodes agree within four standard errors of their paired
    difference (both are unbiased for the overflow rate)."""
    result = evaluate(NeverEmpty(), "n5_m2_dt120", EvalProtocol(episodes=400, episode_length_steps=20,
                                                                  first_seed=20_000), keep_records=False)
    overflow = np.array([e.overflow for e in result.episodes], dtype=float)
    risk = np.array([e.overflow_risk for e in result.episodes])
    assert 0.3 < overflow.mean() < 0.7
    difference = overflow - risk
    assert abs(difference.mean()) < 4 * difference.std(ddof=1) / np.sqrt(len(difference))


def test_pu_utilisation_counts_busy_pu_steps():
    result = evaluate(RuleBasedController(PlantParams.from_config(load_config("n5_m2_dt120"))), "n5_m2_dt120", EvalProtocol(episodes=1))
    rec = result.records[0]
    busy = sum(int((timers > 0).sum()) for timers in rec.pu_timers_s[1:])
    assert result.episodes[0].pu_utilisation == pytest.approx(busy / (rec.steps * 2))


def test_decentralised_evaluation_counts_denials_and_records_round_trip(tmp_path):
    cfg = load_config("n11_m2_dt120")
    result = evaluate(RuleBasedAgents(PlantParams.from_config(cfg)), cfg, EvalProtocol(episodes=2, episode_length_steps=200),
                      arbitration="index")
    rec = result.records[0]
    assert result.episodes[0].denied_requests == int(rec.denied.sum())
    assert np.all(rec.granted.sum(axis=1) <= 2)  # never more emptyings than PUs
    rec.save_npz(tmp_path / "e.npz")
    back = EpisodeRecord.load_npz(tmp_path / "e.npz")
    np.testing.assert_array_equal(back.volumes, rec.volumes)
    np.testing.assert_array_equal(back.overflow_probability, rec.overflow_probability)
    assert back.cumulative_reward == rec.cumulative_reward and back.view == "decentralised"


def test_results_table_best_and_median_over_seeds(tmp_path):
    """Synthetic evaluation files: best = highest mean, median = middle seed by mean."""
    results = tmp_path / "n5_m2_dt120"
    results.mkdir()
    means = {1: 10.0, 2: 30.0, 3: 20.0}
    for seed, mean in means.items():
        episodes = [{"cumulative_reward": mean - 1}, {"cumulative_reward": mean + 1}]
        (results / f"ppo_s{seed}.json").write_text(json.dumps({"episodes": episodes, "summary": {"overflow_rate": 0.0}}))
    (results / "rule_based.json").write_text(json.dumps(
        {"episodes": [{"cumulative_reward": 50.0}], "summary": {"overflow_rate": 0.0}}))
    rows = {r.method: r for r in method_rows(results)}
    assert rows["ppo"].best == (30.0, 1.0, 2) and rows["ppo"].median == (20.0, 1.0, 3)
    assert rows["rule_based"].seeds == [-1]
    table = markdown_table(results)
    assert "| ppo | centralised | 3 | 30.00 ± 1.00 | – | 20.00 ± 1.00 | – |" in table  # no fresh episodes here
    assert "| rule_based | centralised | – | 50.00 ± 0.00 |" in table
    assert "paper PPO (15 seeds)" in table and "51.43 ± 3.00" in table


def test_cli_prints_a_dash_where_no_emptying_makes_a_share_undefined(capsys):
    """An episode without an emptying action has no share of good emptyings: the CLI prints "–"
    there, as the table does, never "nan"."""
    from containergym_marl.cli import _print_evaluation

    cfg = load_config("n5_m2_dt120")
    never = RuleBasedController(PlantParams.from_config(cfg), margin=-100.0)  # never within the margin
    result = evaluate(never, cfg, EvalProtocol(episodes=1))
    assert result.episodes[0].emptyings == 0
    _print_evaluation(result, None)
    out = capsys.readouterr().out
    assert "nan" not in out and "–" in out


def test_evaluation_reports_every_episode_as_it_ends():
    """evaluate(on_episode=...) is called after each episode with the count and its metrics (the
    evaluate command's bar: tests/test_progress.py)."""
    cfg = load_config("n5_m2_dt120")
    seen = []
    result = evaluate(RuleBasedController(PlantParams.from_config(cfg)), cfg, EvalProtocol(episodes=3),
                      on_episode=lambda done, metrics: seen.append((done, metrics.seed, metrics.cumulative_reward)))
    assert seen == [(i + 1, e.seed, e.cumulative_reward) for i, e in enumerate(result.episodes)]



@pytest.mark.parametrize("first_seed,kind,protocol", [(10_000, "Test", "paper protocol"), (20_000, "Validation", "seeds 20000+"),
                                                      (30_000, "Fresh", "seeds 30000+")])
def test_a_table_says_which_episodes_it_reports(tmp_path, first_seed, kind, protocol):
    """A comparison on validation or fresh episodes (a study) is not titled as the paper's test protocol."""
    protocol_record = {"timestep_s": 120.0, "episode_length_steps": 600, "episodes": 2, "first_seed": first_seed}
    results = tmp_path / "n5_m2_dt120"
    results.mkdir()
    for name, reward in (("rule_based", 50.0), ("rule_based_agents", 40.0)):
        episodes = [{"cumulative_reward": reward, "seed": first_seed + k} for k in range(2)]
        (results / f"{name}.json").write_text(json.dumps(
            {"episodes": episodes, "protocol": protocol_record, "summary": {"overflow_rate": 0.0}}))
    table = markdown_table(results)
    title = table.splitlines()[0]
    assert title.startswith(f"{kind} cumulative reward ({protocol}: δ = 120 s, T = 600, 2 episodes)")
    assert f"mean ± std over {kind.lower()} episodes" in title
    assert f"(over {kind.lower()} episodes)" in table  # the probability of improvement of two controllers
