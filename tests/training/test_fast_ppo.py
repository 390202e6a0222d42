"""The native PPO trainer (fast_ppo, fast_shared_ppo): the same update and GAE as SB3's PPO,
determinism, resume after kill -9, tensor-only model files, settings checked before anything is
written, the optional action mask."""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from containergym_marl.cli import main as cli_main
from containergym_marl.evaluation import EvalProtocol
from containergym_marl.evaluation.run_policies import evaluate_run, policy_from_run
from containergym_marl.policies.actor_critic import ActorCritic
from containergym_marl.training import TrainArgs, train
from containergym_marl.training.ppo_kernel import FlatAdam
from containergym_marl.training.fast_ppo import PPOArgs, compute_gae, explained_variance, learn, load_checkpoint, update
from containergym_marl.rundir import UPDATE_FIELDS, checkpoints, read_metrics, read_run_summary, run_args
from containergym_marl.training.checkpoints import read_progress
from tests.helpers import train_until_killed

# 2 simulations, rollouts of 16 steps, training episodes of T = 20 steps (they finish)
# the trainer's own defaults for the rest, whatever a method's settings file chooses
TINY = dict(n_envs=2, progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 32, "learning_rate": 3e-4,
                                                       "ent_coef": 0.0},
            overrides={"episode_length_steps": 20})
SHORT = EvalProtocol(episodes=2, episode_length_steps=60)


# ---- the same algorithm as SB3's PPO --------------------------------------------------------------
def _copy_sb3_weights(sb3_policy, model: ActorCritic) -> None:
    """SB3's MlpPolicy (policy_net, action_net, value_net of mlp_extractor) into an ActorCritic."""
    ext = sb3_policy.mlp_extractor
    pairs = [(model.net.actor[0], ext.policy_net[0]), (model.net.actor[2], ext.policy_net[2]),
             (model.net.actor[4], sb3_policy.action_net), (model.net.critic[0], ext.value_net[0]),
             (model.net.critic[2], ext.value_net[2]), (model.net.critic[4], sb3_policy.value_net)]
    with torch.no_grad():
        for ours, theirs in pairs:
            ours.weight.copy_(theirs.weight)
            ours.bias.copy_(theirs.bias)


@pytest.mark.parametrize("view", ["centralised", "decentralised"])
def test_gae_and_one_update_equal_sb3_ppo(view, tmp_path):
    """One rollout collected by SB3's PPO (with time-limit cuts in it), then one full-batch epoch:
    our GAE reproduces SB3's advantages and our update SB3's weights, from the same start."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv

    env = (ContainerGymVecEnv("n5_m2_dt120", 4, episode_length_steps=10) if view == "centralised"
           else ContainerAgentsVecEnv("n5_m2_dt120", 2, episode_length_steps=10))
    env.seed(3)
    n_steps = 24
    total = n_steps * env.num_envs
    sb3 = PPO("MlpPolicy", env, n_steps=n_steps, batch_size=total, n_epochs=1, seed=0, device="cpu")
    sb3.set_logger(configure(str(tmp_path / "log"), []))
    ours = ActorCritic(view, env.observation_space.shape[0], int(env.action_space.n))
    _copy_sb3_weights(sb3.policy, ours)
    sb3.learn(total)  # one rollout, one update
    buf = sb3.rollout_buffer
    assert (buf.episode_starts[1:] == 1).any(), "the rollout should hold episode ends"

    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    # SB3's update flattened values, advantages, ... env by env: [n_envs * n_steps, ...]
    per_step = lambda a: a.reshape(env.num_envs, n_steps).swapaxes(0, 1)  # noqa: E731
    with torch.no_grad():
        last_value = ours.value(t(sb3._last_obs))
    advantages = compute_gae(t(buf.rewards), t(per_step(buf.values)), t(buf.episode_starts), last_value,
                             t(sb3._last_episode_starts), 0.99, 0.95)
    np.testing.assert_allclose(advantages.numpy(), per_step(buf.advantages), rtol=1e-5, atol=1e-5)

    hp = PPOArgs(minibatch_size=total, n_epochs=1)
    optimizer = FlatAdam(ours.net.parameters(), lr=3e-4, eps=1e-5)  # torch's Adam rule, as SB3's
    diagnostics = update(ours, optimizer, hp, torch.Generator().manual_seed(0), t(buf.observations).reshape(total, -1),
                         torch.as_tensor(buf.actions.reshape(-1), dtype=torch.long), t(buf.log_probs).reshape(-1),
                         t(buf.advantages).reshape(-1), t(buf.returns).reshape(-1))
    # the update's diagnostics are those SB3 logs for the same update
    logged = sb3.logger.name_to_value
    assert diagnostics["entropy"] == pytest.approx(-logged["train/entropy_loss"], rel=1e-5)
    assert diagnostics["approx_kl"] == pytest.approx(logged["train/approx_kl"], abs=1e-7)
    assert diagnostics["clip_fraction"] == pytest.approx(logged["train/clip_fraction"], abs=1e-7)
    assert explained_variance(t(buf.values).reshape(-1), t(buf.returns).reshape(-1)) == pytest.approx(
        logged["train/explained_variance"], rel=1e-4, abs=1e-6)
    expected = ActorCritic(view, ours.observation_size, ours.n_actions)
    _copy_sb3_weights(sb3.policy, expected)
    changed = False
    for (name, a), b in zip(ours.net.state_dict().items(), expected.net.state_dict().values()):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-4, atol=1e-6, err_msg=name)
    for a, b in zip(ours.net.parameters(), ActorCritic(view, ours.observation_size, ours.n_actions).net.parameters()):
        changed |= not torch.equal(a, b)
    assert changed


def test_gae_by_hand():
    """One slot, three steps, an episode ending after step 1 (the observation of step 2 starts a new one)."""
    rewards = torch.tensor([[1.0], [2.0], [3.0]])
    values = torch.tensor([[0.5], [1.0], [2.0]])
    starts = torch.tensor([[1.0], [0.0], [1.0]])
    gamma, lam = 0.9, 0.8
    last_value, last_start = torch.tensor([4.0]), torch.tensor([0.0])
    adv = compute_gae(rewards, values, starts, last_value, last_start, gamma, lam)[:, 0].tolist()
    d2 = 3.0 + 0.9 * 4.0 - 2.0  # step 2 bootstraps from the value after the rollout
    a2 = d2
    d1 = 2.0 + 0.0 - 1.0  # step 1 ends its episode: no next value, no carried advantage
    a1 = d1
    d0 = 1.0 + 0.9 * 1.0 - 0.5
    a0 = d0 + 0.9 * 0.8 * a1
    assert adv == pytest.approx([a0, a1, a2])


def test_gae_bit_for_bit_the_per_step_recursion():
    """The batched TD errors give, in float32, exactly what the recursion written one step at a time
    gives (SB3's loop: the same products in the same order), so runs train the same numbers."""
    g = torch.Generator().manual_seed(3)
    n_steps, slots, gamma, lam = 64, 33, 0.99, 0.95
    rewards, values = torch.randn(n_steps, slots, generator=g), torch.randn(n_steps, slots, generator=g)
    starts = (torch.rand(n_steps, slots, generator=g) < 0.1).float()
    last_value, last_start = torch.randn(slots, generator=g), (torch.rand(slots, generator=g) < 0.1).float()
    expected, gae = torch.empty(n_steps, slots), torch.zeros(slots)
    for t in reversed(range(n_steps)):
        not_done = 1.0 - (last_start if t == n_steps - 1 else starts[t + 1])
        next_value = last_value if t == n_steps - 1 else values[t + 1]
        delta = rewards[t] + gamma * next_value * not_done - values[t]
        gae = delta + gamma * lam * not_done * gae
        expected[t] = gae
    assert torch.equal(compute_gae(rewards, values, starts, last_value, last_start, gamma, lam), expected)


def test_update_diagnostics_by_hand():
    """Two epochs over one minibatch of a two-action policy: the first pass starts at the policy that
    collected the samples (ratio 1: approx-KL 0, nothing clipped), so the means over both passes are
    half the second pass's; the entropy is that of the softmax, computed here apart."""
    torch.manual_seed(0)
    model = ActorCritic("decentralised", 3, 2, generator=torch.Generator().manual_seed(1))
    obs = torch.randn(8, 3)
    actions = torch.tensor([0, 1, 1, 0, 1, 0, 0, 1])
    with torch.no_grad():
        before = torch.log_softmax(model.logits(obs), -1)
    old_logp = before.gather(-1, actions[:, None]).squeeze(-1)
    advantages = torch.linspace(-1, 1, 8)
    hp = PPOArgs(minibatch_size=8, n_epochs=2, learning_rate=0.05, clip_range=0.01)
    optimizer = FlatAdam(model.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps)
    snapshot = ActorCritic.from_dict(model.to_dict(), "test")
    got = update(model, optimizer, hp, torch.Generator().manual_seed(0), obs, actions, old_logp, advantages,
                 torch.zeros(8))
    # replay: the second pass's policy is the one after the first Adam step, found by stepping a copy
    replay_opt = FlatAdam(snapshot.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps)
    update(snapshot, replay_opt, PPOArgs(minibatch_size=8, n_epochs=1, learning_rate=0.05, clip_range=0.01),
           torch.Generator().manual_seed(0), obs, actions, old_logp, advantages, torch.zeros(8))
    with torch.no_grad():
        mid = torch.log_softmax(snapshot.logits(obs), -1)
    log_ratio = mid.gather(-1, actions[:, None]).squeeze(-1) - old_logp
    kl2 = float(((log_ratio.exp() - 1) - log_ratio).mean())
    clipped2 = float(((log_ratio.exp() - 1).abs() > 0.01).float().mean())
    entropy = lambda lp: float(-(lp.exp() * lp).sum(-1).mean())  # noqa: E731
    assert got["approx_kl"] == pytest.approx(kl2 / 2, rel=1e-5) and kl2 > 0
    assert got["clip_fraction"] == pytest.approx(clipped2 / 2) and clipped2 > 0
    assert got["entropy"] == pytest.approx((entropy(before) + entropy(mid)) / 2, rel=1e-5)


def test_explained_variance_by_hand():
    returns = torch.tensor([1.0, 2.0, 3.0, 4.0])
    assert explained_variance(returns, returns) == 1.0
    assert explained_variance(torch.full((4,), 2.5), returns) == pytest.approx(0.0)
    # residuals [0.5, -0.5, 0.5, -0.5]: variance 1/3 against the returns' 5/3
    assert explained_variance(returns - torch.tensor([0.5, -0.5, 0.5, -0.5]), returns) == pytest.approx(1 - 0.2)
    assert np.isnan(explained_variance(torch.zeros(3), torch.ones(3)))


# ---- the batch shape ---------------------------------------------------------------------------------
@pytest.mark.parametrize("algo, config, sims", [("fast_shared_ppo", "n5_m2_dt120", 13),
                                                ("fast_shared_ppo", "n11_m2_dt120", 6),
                                                ("fast_shared_ppo", "n16_m2_dt120", 4),
                                                ("fast_ppo", "n16_m2_dt120", 64)])
def test_samples_per_update_do_not_grow_with_the_plant(algo, config, sims, tmp_path):
    """A run steps as many simulations as make about ``rollout_samples`` (here 4096) samples per
    64-step rollout: 4096 / (64 x n) for the container agents (n = 5: 12.8 -> 13, n = 11: 5.8 -> 6,
    n = 16: 4), 64 for the controller; the metrics rows are one rollout apart."""
    run = train(TrainArgs(algo=algo, config=config, out=str(tmp_path / "r"), timesteps=1, progress_bar=False,
                          hyperparams={"rollout_samples": 4096, "n_steps": 64},
                          overrides={"episode_length_steps": 20}))
    assert run_args(run)["n_envs"] == sims
    n = int(config.split("_")[0][1:]) if algo == "fast_shared_ppo" else 1
    assert [int(r["timesteps"]) for r in read_metrics(run)] == [64 * sims * n]
    assert abs(64 * sims * n - 4096) <= 64 * n / 2


def test_rollout_samples_and_n_steps_set_the_simulations(tmp_path):
    hp = PPOArgs.from_hyperparams({"rollout_samples": 8192, "n_steps": 128})
    assert hp.num_sims(11) == round(8192 / (128 * 11)) == 6 and hp.num_sims(1) == 64
    assert PPOArgs(rollout_samples=10, n_steps=64).num_sims(16) == 1  # at least one simulation
    run = train(TrainArgs(algo="fast_shared_ppo", config="n5_m2_dt120", out=str(tmp_path / "r"), timesteps=1,
                          n_envs=3, progress_bar=False, overrides={"episode_length_steps": 20}))
    assert run_args(run)["n_envs"] == 3  # --n-envs wins


# ---- diagnostics in metrics.csv ----------------------------------------------------------------------
def test_metrics_rows_carry_the_update_diagnostics(tmp_path):
    """Every row of a native run has the diagnostics, in range: a fresh two-action policy's entropy
    (nearly uniform, then 50 small Adam steps in the first update) is close to ln 2 and never above
    it; KL >= 0; the clip fraction a share; episodes of T = 20 steps all reach the time limit."""
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=4000, seed=2, **TINY))
    rows = read_metrics(run)
    assert rows and all(set(UPDATE_FIELDS) <= set(r) for r in rows)
    assert (run / "metrics.csv").read_text().splitlines()[0].endswith(",".join(UPDATE_FIELDS))
    assert 0.55 < rows[0]["entropy"] <= np.log(2)
    assert all(0 <= r["entropy"] <= np.log(2) + 1e-6 and r["approx_kl"] >= 0 and 0 <= r["clip_fraction"] <= 1
               and r["explained_variance"] <= 1 for r in rows)
    assert all(r["time_limit_share"] == 1.0 for r in rows)


def test_time_limit_share_counts_overflows_apart():
    from containergym_marl.training.checkpoints import TrainingProgress

    p = TrainingProgress()
    assert np.isnan(p.time_limit_share)
    for k in range(120):
        p.add_episode(1.0, 10, truncated=k % 4 != 0)  # every fourth ends in an overflow
    assert p.time_limit_share == pytest.approx(0.75) and len(p.truncated) == 100
    assert TrainingProgress.from_json(p.to_json()).truncated == p.truncated


def test_annealed_step_size_falls_linearly_to_zero(tmp_path, monkeypatch):
    """With anneal_lr the update after k rollouts of S samples steps with lr x (1 - k S / budget)."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv
    from containergym_marl.training import fast_ppo
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.fast_ppo import new_state

    env = ContainerAgentsVecEnv("n5_m2_dt120", 2, episode_length_steps=20)
    hp = PPOArgs(n_steps=10, minibatch_size=100, learning_rate=1e-3, anneal_lr=True)
    state = new_state(env, hp, "decentralised", 0, {})
    budget = 400  # four rollouts of 100 samples
    seen = []
    run_update = fast_ppo.run_update  # the step size each update's Adam steps take
    monkeypatch.setattr(fast_ppo, "run_update", lambda model, optimizer, *a, **k: (
        seen.append(optimizer.param_groups[0]["lr"]), run_update(model, optimizer, *a, **k))[1])
    learn(tmp_path, state, env, budget, 0.99, hp, TrainingProgress(), interval=10**9)
    assert sorted(set(seen), reverse=True) == pytest.approx([1e-3, 0.75e-3, 0.5e-3, 0.25e-3])


@pytest.mark.parametrize("view, reward_mode", [("centralised", "individual"), ("decentralised", "individual"),
                                               ("decentralised", "team")])
def test_overflow_reward_scale_multiplies_the_learners_reward_at_overflows_only(view, reward_mode, tmp_path,
                                                                               monkeypatch):
    """overflow_reward_scale=10: the rollout's rewards are the plant's except where a container
    overflowed, there 10 x r_min (-10) instead of r_min (-1): the overflowing agent's own reward, every
    agent's team reward, the controller's reward. The training episodes' returns (the best-model
    criterion) stay the plant's. One rollout from the same seed, so both runs act alike."""
    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv
    from containergym_marl.training import fast_ppo
    from containergym_marl.training.checkpoints import TrainingProgress
    from containergym_marl.training.fast_ppo import new_state

    def one_rollout(scale):
        # 11 containers that start nearly full, 2 PUs: random policies let some overflow
        plant = {"initial_volume_min": 30.0, "initial_volume_max": 39.0, "episode_length_steps": 50}
        env = (ContainerAgentsVecEnv("n11_m2_dt120", 4, reward_mode=reward_mode, **plant)
               if view == "decentralised" else ContainerGymVecEnv("n11_m2_dt120", 4, **plant))
        env.seed(7)
        hp = PPOArgs(n_steps=100, minibatch_size=200, overflow_reward_scale=scale)
        state = new_state(env, hp, view, 0, {})
        seen = []
        gae = fast_ppo.compute_gae
        monkeypatch.setattr(fast_ppo, "compute_gae", lambda rewards, *a, **k: (
            seen.append(rewards.clone()), gae(rewards, *a, **k))[1])
        progress = TrainingProgress()
        learn(tmp_path / f"s{scale}", state, env, 1, 0.99, hp, progress, interval=10**9)
        return seen[0], list(progress.returns)

    (tmp_path / "s1").mkdir(), (tmp_path / "s10").mkdir()
    plain, plain_returns = one_rollout(1.0)
    shaped, shaped_returns = one_rollout(10.0)
    overflows = plain == -1.0  # r_min; every other reward is at least r_pen = -0.1
    assert overflows.any() and plain_returns and (plain < 0).any()
    if reward_mode == "team":  # all of a simulation's agents at once
        assert overflows.view(100, 4, 11).all(-1).eq(overflows.view(100, 4, 11).any(-1)).all()
    assert torch.equal(shaped[overflows], torch.full_like(shaped[overflows], -10.0))
    assert torch.equal(shaped[~overflows], plain[~overflows])
    assert shaped_returns == plain_returns


# ---- runs: determinism, files, resume --------------------------------------------------------------
def _tensors(path) -> dict:
    return {k: v.clone() for k, v in ActorCritic.load(path).net.state_dict().items()}


@pytest.mark.parametrize("algo", ["fast_ppo", "fast_shared_ppo"])
def test_same_seed_same_metrics_and_model(algo, tmp_path):
    runs = [train(TrainArgs(algo=algo, out=str(tmp_path / f"r{k}"), timesteps=2000, seed=4, **TINY)) for k in (0, 1)]
    other = train(TrainArgs(algo=algo, out=str(tmp_path / "other"), timesteps=2000, seed=5, **TINY))
    strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rows]  # noqa: E731
    assert strip(read_metrics(runs[0])) == strip(read_metrics(runs[1]))
    assert read_metrics(runs[0])[-1]["episodes"] > 0
    a, b, c = (_tensors(r / "final_model.pt") for r in (*runs, other))
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_run_directory_holds_tensor_only_models_that_evaluate(tmp_path):
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=2000, checkpoint_every=500,
                          **TINY))
    names = {p.name for p in run.iterdir()}
    assert {"args.json", "config.toml", "metrics.csv", "best_model.pt", "final_model.pt", "run.json"} <= names
    assert not any(n.endswith(".zip") for n in names)
    steps = [s for s, _ in checkpoints(run)]
    assert steps and all(s < 2000 for s in steps)
    for path in [run / "best_model.pt", run / "final_model.pt", *(p for _, p in checkpoints(run))]:
        torch.load(path, weights_only=True)  # plain containers and tensors only
    summary = read_run_summary(run)
    assert summary["best_model"] == "best_model.pt" and summary["timesteps"] >= 2000
    # the training's CPU seconds, at the checkpoint and at the end (both to 0.01 s: the few samples after
    # the checkpoint can take less than that, so the two may be equal)
    assert 0 < read_progress(run, steps[0]).cpu_time_s <= summary["cpu_time_s"]
    model = ActorCritic.load(run / "final_model.pt")
    assert model.view == "decentralised" and model.meta["algo"] == "fast_shared_ppo"
    result = evaluate_run(run, protocol=SHORT, write=False)
    again = evaluate_run(run, protocol=SHORT, write=False)
    np.testing.assert_array_equal(result.returns, again.returns)
    assert policy_from_run(run).name == "fast_shared_ppo[s1,best]"
    # the CLI: --no-write leaves the run directory as it was; without it, the evaluation is kept there
    before = sorted(p.name for p in run.iterdir())
    assert cli_main(["evaluate", str(run), "--episodes", "1", "--no-write"]) == 0
    assert sorted(p.name for p in run.iterdir()) == before
    assert cli_main(["evaluate", str(run), "--episodes", "1"]) == 0
    assert (run / "evaluation_best.json").is_file()


def test_a_shared_policy_on_the_portable_observation_acts_on_a_plant_it_was_not_trained_on(tmp_path):
    """--hp observation=portable: 14 entries whatever n and m, recorded in the model, so a policy
    trained on 5 containers and 2 PUs runs on 32 containers and 4 PUs (zero-shot); on the default
    observation the sizes differ and the model is refused, naming them."""
    hp = {**TINY["hyperparams"], "observation": "portable"}
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "p"), timesteps=600,
                          **{**TINY, "hyperparams": hp}))
    model = ActorCritic.load(run / "final_model.pt")
    assert (model.observation, model.observation_size) == ("portable", 14)
    result = evaluate_run(run, config="n32_m4_dt120", protocol=SHORT, write=False)
    assert len(result.episodes) == 2 and result.episodes[0].steps > 0
    local = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "l"), timesteps=300, **TINY))
    with pytest.raises(ValueError, match="observation"):
        evaluate_run(local, config="n32_m4_dt120", protocol=SHORT, write=False)


def test_team_reward_run_is_named_as_its_method(tmp_path):
    run = train(TrainArgs(algo="fast_shared_ppo", reward_mode="team", out=str(tmp_path / "r"), timesteps=500, **TINY))
    assert policy_from_run(run).name.startswith("fast_shared_ppo_team[")


class _Payload:
    """Unpickling this runs code: it writes a marker file."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "code ran"))


def _plant_payload(path: Path, marker: Path) -> None:
    """Replace a torch file with one whose pickle carries the payload (a valid torch archive)."""
    torch.save({"format": "containergym-marl actor-critic", "payload": _Payload(marker)}, path)


def test_a_crafted_model_file_never_runs_its_code(tmp_path, capsys):
    run = train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "r"), timesteps=1000, checkpoint_every=200, **TINY))
    marker = tmp_path / "ran.txt"
    _plant_payload(run / "best_model.pt", marker)
    assert cli_main(["evaluate", str(run), "--episodes", "1"]) == 2
    assert "holds more than tensors" in capsys.readouterr().err
    # resuming from a crafted checkpoint: set aside as broken, the previous one used
    newest = checkpoints(run)[0][1]
    _plant_payload(newest, marker)
    (run / "final_model.pt").unlink()
    with pytest.warns(UserWarning, match="set aside"):
        train(TrainArgs(algo="fast_ppo", out=str(run), timesteps=1000, checkpoint_every=200, resume=True, **TINY))
    assert not marker.exists()
    assert (run / "final_model.pt").is_file()


def test_kill_9_then_resume_keeps_metrics_and_episode_window(tmp_path):
    """A run killed with SIGKILL after some checkpoints resumes: every metrics row once, the episode
    counter continuing from the checkpoint's, the final model at the budget."""
    run = tmp_path / "r"
    train_until_killed(["--algo", "fast_shared_ppo", "--out", str(run), "--timesteps", "60000", "--n-envs", "2",
                        "--checkpoint-every", "6000", "--no-progress", "--hp", "n_steps=16", "minibatch_size=160",
                        "--override", "episode_length_steps=20"], run, checkpoints_wanted=2)
    assert not (run / "final_model.pt").exists()
    steps, _ = checkpoints(run)[0]
    at_checkpoint = read_progress(run, steps)
    # rows written between the newest checkpoint and the kill (as many as the kill's timing allowed) are
    # dropped, and the resume says so; the run then writes them again
    later = sum(r["timesteps"] > steps for r in read_metrics(run, quiet=True))
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        train(TrainArgs(algo="fast_shared_ppo", out=str(run), timesteps=60000, resume=True, checkpoint_every=6000,
                        n_envs=2, progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 160},
                        overrides={"episode_length_steps": 20}))
    dropped = [str(w.message) for w in seen if "dropped" in str(w.message)]
    assert dropped == ([f"{run}/metrics.csv: dropped {later} row(s) after the checkpoint at {steps} samples "
                        f"(training continues from there)"] if later else [])
    rows = read_metrics(run)
    samples = [int(r["timesteps"]) for r in rows]
    assert samples == sorted(set(samples)) and samples[-1] >= 60000
    after = [r for r in rows if r["timesteps"] > steps]
    assert after[0]["episodes"] >= at_checkpoint.episodes and after[-1]["episodes"] > at_checkpoint.episodes
    assert read_run_summary(run)["resumed_from"] == steps
    state = load_checkpoint(checkpoints(run)[0][1], PPOArgs(n_steps=16, minibatch_size=160))
    assert state.num_timesteps == checkpoints(run)[0][0]


# ---- settings, masks --------------------------------------------------------------------------------
@pytest.mark.parametrize("hp, field", [({"bogus": 1}, "bogus"), ({"n_steps": 0}, "n_steps"),
                                       ({"learning_rate": "nan"}, "learning_rate"),
                                       ({"action_mask": "maybe"}, "action_mask"),
                                       ({"minibatch_size": 2.5}, "minibatch_size"),
                                       ({"observation": "oracle"}, "observation"),
                                       ({"observation": "portable"}, "observation"),  # not the controller's
                                       ({"overflow_reward_scale": 0}, "overflow_reward_scale"),
                                       ({"overflow_reward_scale": "inf"}, "overflow_reward_scale")])
def test_bad_settings_are_refused_before_anything_is_written(hp, field, tmp_path):
    with pytest.raises(ValueError, match=field):
        train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "r"), timesteps=100, hyperparams=hp, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_cli_settings_parse_from_strings():
    hp = PPOArgs.from_hyperparams({"n_steps": "32", "action_mask": "true", "hidden": "32,16", "clip_range": "0.1"})
    assert (hp.n_steps, hp.action_mask, hp.hidden, hp.clip_range) == (32, True, (32, 16), 0.1)


def test_gamma_out_of_range_is_refused(tmp_path):
    for gamma in (float("nan"), 2.5, 0.0):
        with pytest.raises(ValueError, match="gamma"):
            train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "r"), timesteps=100, gamma=gamma, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_masked_controller_never_empties_without_a_free_pu(tmp_path):
    run = train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "r"), timesteps=1000,
                          **{**TINY, "hyperparams": {**TINY["hyperparams"], "action_mask": True}}))
    assert ActorCritic.load(run / "final_model.pt").action_mask
    result = evaluate_run(run, protocol=EvalProtocol(episodes=3), write=False)
    assert sum(e.denied_requests for e in result.episodes) == 0
    unmasked = train(TrainArgs(algo="fast_ppo", out=str(tmp_path / "u"), timesteps=1000, **TINY))
    assert sum(e.denied_requests for e in evaluate_run(unmasked, protocol=EvalProtocol(episodes=3), write=False).episodes) > 0


def test_the_sigmoid_form_of_tanh_equals_torch_tanh_and_its_gradient():
    from containergym_marl.policies._fast_tanh import Tanh

    x = torch.linspace(-12, 12, 20001, dtype=torch.float32, requires_grad=True)
    y = Tanh()(x)
    assert (y - torch.tanh(x)).abs().max().item() < 3e-7
    (grad,) = torch.autograd.grad(y.sum(), x)
    np.testing.assert_allclose(grad.numpy(), (1 - torch.tanh(x) ** 2).detach().numpy(), atol=1e-6)


@pytest.mark.parametrize("view, size, hidden", [("decentralised", 25, (64, 64)), ("centralised", 37, (32, 48, 16))])
def test_the_decisions_forward_is_the_actors_modules_bit_for_bit(view, size, hidden):
    """decision_logits (the evaluation policies' forward, without module calls) against the actor's
    own modules, on observations of every scale, after the weights change in place as training changes
    them; a masked policy's decisions with it are the masked logits' argmax."""
    from containergym_marl.policies.actor_critic import policy_for

    model = ActorCritic(view, size, 2 if view == "decentralised" else 6, hidden=hidden,
                        generator=torch.Generator().manual_seed(3))
    obs = torch.randn(500, size, generator=torch.Generator().manual_seed(4)) * torch.logspace(-3, 2, 500)[:, None]
    for _ in range(2):
        with torch.no_grad():
            assert torch.equal(model.decision_logits(obs), model.net.actor(obs))
            for p in model.net.actor.parameters():  # an optimiser's in-place step
                p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())) * 0.3)
    masks = torch.rand(500, model.n_actions, generator=torch.Generator().manual_seed(5)) > 0.3
    masks[:, 0] = True
    with torch.no_grad():
        expected = model.logits(obs, masks).argmax(-1).tolist()
    assert policy_for(model)._actions(obs.numpy(), masks.numpy()) == expected


def test_the_same_model_makes_the_same_safetensors_bytes(tmp_path):
    """The library writes the header's keys in a hash map's order, seeded anew each time: the same
    model gave different bytes at every write, and every publish rewrote every published file."""
    from safetensors.torch import load_file

    model = ActorCritic("decentralised", 25, 2, generator=torch.Generator().manual_seed(0),
                        meta={"algo": "fast_shared_ppo", "seed": 3, "config": "n11_m2_dt120"},
                        own_check={"risk": 1e-4, "lead_steps": 1})
    files = [model.save_safetensors(tmp_path / f"m{k}.safetensors") for k in range(5)]
    assert len({f.read_bytes() for f in files}) == 1
    assert int.from_bytes(files[0].read_bytes()[:8], "little") % 8 == 0  # the header padded as the format pads it
    again = ActorCritic.load(files[0])
    assert again.own_check == model.own_check and again.meta == model.meta
    plain = load_file(files[0])  # the format's own reader
    assert all(torch.equal(plain[k], v) for k, v in model.net.state_dict().items())


def test_a_rollout_is_split_into_equal_minibatches():
    """4160 samples with minibatches of about 1024: four Adam steps on 1040 samples each per epoch
    (SB3's slicing would take four of 1024 and a fifth of 64); the cuts are torch.tensor_split's."""
    from containergym_marl.training.ppo_kernel import split_bounds

    assert split_bounds(4160, 4).tolist() == [0, 1040, 2080, 3120, 4160]
    for total, parts in ((4160, 4), (2112, 2), (6144, 96), (37, 5), (5, 5)):
        sizes = [len(part) for part in torch.tensor_split(torch.arange(total), parts)]
        assert np.diff(split_bounds(total, parts)).tolist() == sizes
    model = ActorCritic("decentralised", 3, 2, generator=torch.Generator().manual_seed(1))
    optimizer = FlatAdam(model.net.parameters(), lr=1e-4, eps=1e-5)
    total = 4160
    update(model, optimizer, PPOArgs(minibatch_size=1024, n_epochs=2), torch.Generator().manual_seed(0),
           torch.randn(total, 3), torch.randint(0, 2, (total,)), torch.full((total,), -0.69), torch.randn(total),
           torch.zeros(total))
    assert optimizer.steps == 8


def test_a_version_1_checkpoint_resumes_its_torch_adam_state_on_the_flat_adam(tmp_path):
    """Checkpoints written before the flat Adam hold torch.optim.Adam's state: they load, with the
    moments and the step count carried over (a resumed run of before continues its optimiser)."""
    from containergym_marl.training.fast_ppo import CHECKPOINT_FORMAT

    model = ActorCritic("decentralised", 7, 2, generator=torch.Generator().manual_seed(0))
    adam = torch.optim.Adam(model.net.parameters(), lr=3e-4, eps=1e-5)
    for p in model.net.parameters():
        p.grad = torch.full_like(p, 0.5)
    adam.step()
    adam.step()
    path = tmp_path / "ckpt_100_steps.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "version": 1, "model": model.to_dict(), "optimizer": adam.state_dict(),
                "generator": torch.Generator().manual_seed(1).get_state(), "num_timesteps": 100, "hyperparams": {}}, path)
    state = load_checkpoint(path, PPOArgs())
    assert state.optimizer.steps == 2 and state.num_timesteps == 100
    moments = torch.cat([adam.state[p]["exp_avg"].reshape(-1) for p in model.net.parameters()])
    assert torch.equal(state.optimizer.exp_avg, moments)
    for ours, theirs in zip(state.model.net.parameters(), model.net.parameters()):
        assert torch.equal(ours, theirs)


def test_the_rows_and_best_model_reach_the_disk_with_each_checkpoint_not_at_every_update(tmp_path, monkeypatch):
    """The native trainer writes a metrics row (and often a best model) every update; flushing each to
    disk cost about as much wall time as an update of a small plant. They are flushed before each
    checkpoint is written (the checkpoint vouches for them: --resume keeps the rows up to it) and
    before run.json marks the run finished."""
    synced: list[str] = []
    real_fsync = os.fsync

    def recording_fsync(fd):
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    run = train(TrainArgs(algo="fast_shared_ppo", out=str(tmp_path / "r"), timesteps=3000, checkpoint_every=1000,
                          **TINY))
    rows, names = len(read_metrics(run)), [Path(p).name for p in synced]
    written = [i for i, name in enumerate(names) if re.fullmatch(r"\.?ckpt_\d+_steps\.pt\..*tmp", name)]
    assert rows > 10 and len(written) == len(checkpoints(run)) >= 2
    # metrics.csv: once before each checkpoint and once before run.json, not once a row
    assert names.count("metrics.csv") == len(written) + 1
    before = [i for i, name in enumerate(names) if name == "metrics.csv"]
    assert all(any(prev < w and not any(prev < o < w for o in written) for prev in before) for w in written)
    assert names.index("metrics.csv", before[-1]) < next(i for i, n in enumerate(names) if n.startswith(".run.json"))
    # the best model: flushed with the checkpoints and at the end, never at its own (frequent) saves
    assert names.count("best_model.pt") <= len(written) + 1
    assert not any(n.startswith(".best_model.pt.") for n in names)
