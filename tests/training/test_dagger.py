"""Imitation of the rollout planner (dagger_agents, dagger_ppo_agents and their variants): the labels are planner_agents'
decisions in the learner's states, seen through an independent single environment; imitation beats a
random policy clearly within a small budget; the CLI trains, resumes after kill -9 and evaluates; the
fine-tuning phase continues the same run; bad settings are refused before anything is written."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import torch

from containergym_marl.cli import main as cli_main
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.envs.vector import ContainerAgentsVecEnv
from containergym_marl.evaluation import EvalProtocol, evaluate
from containergym_marl.policies.actor_critic import ActorCritic, policy_for
from containergym_marl.policies.planner import PlannerAgents, ShieldedPlannerAgents
from containergym_marl.rundir import checkpoints, read_metrics, read_run_summary
from containergym_marl.training import TrainArgs, train
from containergym_marl.training.checkpoints import TrainingProgress, read_progress
from containergym_marl.training.dagger import (
    DAggerArgs,
    Dataset,
    Episodes,
    Labeller,
    MinibatchDraw,
    collect,
    update,
)
from tests.helpers import train_until_killed

# 2 simulations, iterations of 16 steps, training episodes of T = 20 steps (they finish)
TINY = dict(n_envs=2, progress_bar=False, hyperparams={"n_steps": 16, "minibatch_size": 64},
            overrides={"episode_length_steps": 20})


@pytest.mark.parametrize("labels, config, n_steps, episode_steps", [
    ("planner", "n5_m2_dt120", 30, 20), ("response", "n5_m2_dt120", 30, 20), ("planner", "n11_m2_dt120", 80, 60),
    ("shielded", "n11_m2_dt120", 80, 60)])
def test_labels_are_planner_agents_decisions_in_the_learners_states(labels, config, n_steps, episode_steps):
    """The learner (an untrained policy, so it often disagrees with the planner) acts in 2 simulations,
    across an episode end; replaying its actions in single environments with the simulations' seeds,
    a PlannerAgents evaluated there as in an evaluation decides exactly the labels (``response``: its
    best response to the learner's requests there, ``PlannerAgents.respond``; ``shielded``: the
    reference with its deadline check, ``ShieldedPlannerAgents``, from ``safety_risk`` = 1e-6, which
    decides otherwise than the plain planner in some of these states), every agent's
    observation is the one the learner saw, and its contended flag its simulation's
    ``PlannerAgents.contended`` there. On n11_m2 the learner mostly waits (its output bias), so that
    containers reach their optimum together and some states are contended."""
    seed = 7
    env = ContainerAgentsVecEnv(config, 2, episode_length_steps=episode_steps)
    n = env.n_agents
    hp = DAggerArgs(labels="planner", safety_risk=1e-6) if labels == "shielded" else DAggerArgs(labels=labels)
    shield_differs = 0
    model = ActorCritic("decentralised", env.observation_space.shape[0], 2, generator=torch.Generator().manual_seed(0))
    if config == "n11_m2_dt120":
        with torch.no_grad():  # logits + (2, 0): a request about one step in eight
            [m for m in model.net.actor if isinstance(m, torch.nn.Linear)][-1].bias.copy_(torch.tensor([2.0, 0.0]))
    env.seed(seed)
    obs = torch.from_numpy(env.reset())
    labeller = Labeller(env.num_sims, hp, seed)
    rollout, *_ = collect(model, env, obs, torch.ones(env.num_envs), labeller, n_steps, 0.99,
                          torch.Generator().manual_seed(1), expert_acts=False, greedy=False,
                          episodes=Episodes(env.num_sims, TrainingProgress()), labels=hp.labels)
    assert labeller.planned > 0, "the planner should have planned (a choice between candidates) somewhere"
    assert rollout.contended.any() == (config == "n11_m2_dt120") and not rollout.contended.all()
    assert (rollout.labels == 1).any() and (rollout.actions != rollout.labels).any()
    for b in range(env.num_sims):
        single = parallel_env(config, episode_length_steps=episode_steps)
        planner = ShieldedPlannerAgents() if labels == "shielded" else PlannerAgents()
        planner.reset(seed + b)
        observations, _ = single.reset(seed=seed + b)
        for t in range(n_steps):
            if not single.agents:  # the episode ended: the next one continues the env's stream, as autoreset does
                observations, _ = single.reset()
            agents = single.possible_agents
            np.testing.assert_array_equal(np.stack([observations[a] for a in agents]),
                                          rollout.obs[t, b * n:(b + 1) * n].numpy())
            acted = rollout.actions[t, b * n:(b + 1) * n].numpy().astype(bool)
            if labels != "response":
                if labels == "shielded":  # the same planner, at the same point of its stream, without the check
                    plain = copy.deepcopy(planner)
                    plain.safety_risk = None
                    sim = single.unwrapped.simulator
                    undecided = plain.decide(sim.state, sim.params).astype(int).tolist()
                decided = planner.act(observations, single)
                shield_differs += labels == "shielded" and undecided != [decided[a] for a in agents]
            else:
                sim = single.unwrapped.simulator
                decided = dict(zip(agents, planner.respond(sim.state, sim.params, acted).astype(int).tolist()))
            assert [decided[a] for a in agents] == rollout.labels[t, b * n:(b + 1) * n].tolist(), (b, t)
            sim = single.unwrapped.simulator  # every agent of the simulation carries its state's contention
            assert rollout.contended[t, b * n:(b + 1) * n].tolist() == [bool(planner.contended(sim.state, sim.params)[0])] * n
            observations, *_ = single.step({a: int(rollout.actions[t, b * n + i]) for i, a in enumerate(agents)})
    assert (shield_differs > 0) == (labels == "shielded")


class _RandomAgents:
    """Every agent requests with probability 1/2 (its own seeded generator)."""

    name, view = "random_agents", "decentralised"

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def act(self, observations, env):
        return {a: int(self.rng.integers(2)) for a in observations}


@pytest.mark.slow  # trains to a learning bound, ~25 s
def test_imitation_beats_a_random_policy_clearly_within_a_small_budget(tmp_path):
    """40k samples (about 5 s) of DAgger on n5_m2_dt120; 5 test episodes of the paper's protocol. The
    imitated policy's mean return exceeds the random agents' by more than 5 standard errors of the
    difference, and no episode of it overflows (the planner never lets one)."""
    run = train(TrainArgs(algo="dagger_agents", out=str(tmp_path / "r"), timesteps=40_000, n_envs=8, seed=1,
                          progress_bar=False))
    protocol = EvalProtocol(episodes=5)
    learned = evaluate(policy_for(ActorCritic.load(run / "final_model.pt"), "dagger_agents"), "n5_m2_dt120",
                       protocol, keep_records=False)
    random = evaluate(_RandomAgents(0), "n5_m2_dt120", protocol, keep_records=False)
    a, b = learned.returns, random.returns
    se = np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    assert a.mean() - b.mean() > 5 * se, (a, b)
    assert learned.summary()["overflow_rate"] == 0.0
    record = json.loads((run / "imitation.json").read_text())
    assert record["iterations"][0]["expert_acted"] and not record["iterations"][1]["expert_acted"]
    # on its own states, the learner decides as the planner (over the second half of its iterations: a
    # greedy learner still meets new states late in so small a budget, and one iteration can dip)
    late = [i["agreement"] for i in record["iterations"][len(record["iterations"]) // 2:]]
    assert np.mean(late) > 0.95, late


@pytest.mark.slow  # ~1 min; the native trainer's kill-9 resume is in the default suite
def test_cli_trains_resumes_after_kill_9_and_evaluates(tmp_path):
    """A run killed with SIGKILL after some checkpoints resumes from the newest: every metrics row and
    every iteration of the record once, the labelling cost continuing from the checkpoint's; the
    finished run's models are tensor-only and evaluate through the CLI."""
    run = tmp_path / "r"
    common = ["--algo", "dagger_agents", "--out", str(run), "--timesteps", "60000", "--n-envs", "2",
              "--checkpoint-every", "1000", "--no-progress", "--hp", "n_steps=16", "minibatch_size=64",
              "--override", "episode_length_steps=20"]
    train_until_killed(common, run, checkpoints_wanted=3)
    assert not (run / "final_model.pt").exists()
    steps, _ = checkpoints(run)[0]
    at_checkpoint = read_progress(run, steps)
    assert len(list((run / "checkpoints").glob("ckpt_dataset_*_steps.pt"))) <= 2  # the newest, and one being replaced
    assert cli_main(["train", *common, "--resume"]) == 0

    summary = read_run_summary(run)
    assert summary["resumed_from"] == steps and summary["timesteps"] >= 60000
    assert summary["cpu_time_s"] > at_checkpoint.cpu_time_s > 0  # the resumed run's CPU time continues
    rows = read_metrics(run)
    samples = [int(r["timesteps"]) for r in rows]
    assert samples == sorted(set(samples)) and samples[-1] >= 60000
    after = [r for r in rows if r["timesteps"] > steps]
    assert after[0]["episodes"] >= at_checkpoint.episodes and after[-1]["episodes"] > at_checkpoint.episodes
    iterations = json.loads((run / "imitation.json").read_text())["iterations"]
    assert [r["iteration"] for r in iterations] == list(range(1, len(iterations) + 1))
    assert [r["timesteps"] for r in iterations] == [160 * k for k in range(1, len(iterations) + 1)]
    costs = [r["label_cpu_s"] for r in iterations]
    assert costs == sorted(costs) and summary["imitation"]["label_cpu_s"] == costs[-1] > 0
    assert summary["imitation"]["samples"] == summary["timesteps"]
    assert not list((run / "checkpoints").glob("ckpt_dataset_*"))  # imitation over: no data set left
    for path in (run / "best_model.pt", run / "final_model.pt", *(p for _, p in checkpoints(run))):
        torch.load(path, weights_only=True)
    model = ActorCritic.load(run / "final_model.pt")
    assert (model.view, model.meta["algo"], model.meta["expert"]) == ("decentralised", "dagger_agents", "planner_agents")
    assert cli_main(["evaluate", str(run), "--episodes", "1"]) == 0
    assert json.loads((run / "evaluation_best.json").read_text())["policy"] == "dagger_agents[s1,best]"


def test_fine_tuning_continues_the_imitated_policy_in_the_same_run(tmp_path):
    """dagger_ppo_agents: DAgger to imitation_share of the budget, then the native PPO from the
    imitated model (its checkpoints are PPO's), one metrics file and one budget."""
    hp = {"n_steps": 16, "minibatch_size": 64, "imitation_share": 0.5, "ppo_n_steps": 16, "ppo_minibatch_size": 64}
    run = train(TrainArgs(algo="dagger_ppo_agents", out=str(tmp_path / "r"), timesteps=4000, checkpoint_every=400,
                          **{**TINY, "hyperparams": hp}))
    summary = read_run_summary(run)
    assert summary["imitation"]["samples"] == 2080  # 13 iterations of 160 samples reach half of 4000
    assert summary["timesteps"] >= 4000
    formats = {s: torch.load(p, weights_only=True)["format"] for s, p in checkpoints(run)}
    assert {f for s, f in formats.items() if s <= 2080} == {"containergym-marl dagger checkpoint"}
    assert {f for s, f in formats.items() if s > 2080} == {"containergym-marl ppo checkpoint"}
    assert torch.load(checkpoints(run)[0][1], weights_only=True)["hyperparams"]["minibatch_size"] == 64
    assert ActorCritic.load(run / "final_model.pt").meta["algo"] == "dagger_ppo_agents"
    # the plant's reward is its default; the individual reward names the method, as the team reward
    # names fast_shared_ppo's
    assert json.loads((run / "args.json").read_text())["reward_mode"] == "team"
    own = train(TrainArgs(algo="dagger_ppo_agents", reward_mode="individual", out=str(tmp_path / "t"), timesteps=400,
                          **{**TINY, "hyperparams": hp}))
    assert json.loads((own / "args.json").read_text())["reward_mode"] == "individual"
    assert cli_main(["evaluate", str(own), "--episodes", "1"]) == 0
    assert json.loads((own / "evaluation_best.json").read_text())["policy"].startswith("dagger_ppo_agents_individual[s1,")


def test_dapg_fine_tuning_clones_the_imitation_s_data_set_and_resumes_with_it(tmp_path):
    """dagger_dapg_agents: at the switch the imitation's data set is saved for the fine-tuning's
    behaviour-cloning term (the samples DAgger aggregated, as labelled), which changes the fine-tuned
    policy (the same seed without it ends elsewhere); a resumed fine-tuning reloads it, and without
    it continues as PPO alone, saying so."""
    import shutil
    import warnings

    from containergym_marl.rundir import RunWarning
    from containergym_marl.training.dagger import BC_DATASET

    hp = {"n_steps": 16, "minibatch_size": 64, "imitation_share": 0.5, "ppo_n_steps": 16, "ppo_minibatch_size": 64}
    args = dict(timesteps=4000, checkpoint_every=400, **{**TINY, "hyperparams": hp})
    run = train(TrainArgs(algo="dagger_dapg_agents", out=str(tmp_path / "r"), **args))
    saved = torch.load(run / "checkpoints" / BC_DATASET, weights_only=True)
    assert saved["labels"].shape[0] == 2080 and saved["obs"].shape == (2080, 12 + 2 + 5)
    assert 0 < int(saved["labels"].sum()) < 2080  # both actions demonstrated
    plain = train(TrainArgs(algo="dagger_ppo_agents", out=str(tmp_path / "p"), **args))
    assert not (plain / "checkpoints" / BC_DATASET).exists()
    dapg, ppo = (ActorCritic.load(r / "final_model.pt").net.state_dict() for r in (run, plain))
    assert not all(torch.equal(dapg[k], ppo[k]) for k in dapg)
    for keep in (True, False):
        resumed = tmp_path / f"resumed_{keep}"
        shutil.copytree(run, resumed)
        (resumed / "final_model.pt").unlink()
        if not keep:
            (resumed / "checkpoints" / BC_DATASET).unlink()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            train(TrainArgs(algo="dagger_dapg_agents", out=str(resumed), resume=True, **args))
        said = [str(w.message) for w in caught if issubclass(w.category, RunWarning) and "behaviour-cloning" in str(w.message)]
        assert (resumed / "final_model.pt").is_file() and len(said) == (0 if keep else 1), said
        if not keep:
            assert BC_DATASET in said[0] and "continues without its behaviour-cloning term" in said[0]


def test_the_reward_mode_defaults_to_the_algorithms_first():
    """Without --reward-mode, dagger_ppo_agents fine-tunes on the plant's reward and the other
    decentralised algorithms on each container's own; an explicit mode is kept."""
    from containergym_marl.options import parse

    assert parse(TrainArgs, ["--algo", "dagger_ppo_agents"]).reward_mode == "team"
    assert parse(TrainArgs, ["--algo", "fast_shared_ppo"]).reward_mode == "individual"
    assert parse(TrainArgs, ["--algo", "fast_shared_ppo", "--reward-mode", "team"]).reward_mode == "team"
    assert TrainArgs(algo="dagger_ppo_agents", reward_mode="individual").reward_mode == "individual"
    assert TrainArgs(algo="shared_ppo").reward_mode == "individual"


def test_same_seed_same_run(tmp_path):
    runs = [train(TrainArgs(algo="dagger_agents", out=str(tmp_path / f"r{k}"), timesteps=1600, seed=seed, **TINY))
            for k, seed in ((0, 4), (1, 4), (2, 5))]
    strip = lambda rows: [{k: v for k, v in r.items() if "wall" not in k and "cpu" not in k} for r in rows]  # noqa: E731
    records = [json.loads((r / "imitation.json").read_text())["iterations"] for r in runs]
    assert strip(records[0]) == strip(records[1]) != strip(records[2])
    a, b, c = (ActorCritic.load(r / "final_model.pt").net.state_dict() for r in runs)
    assert all(torch.equal(a[k], b[k]) for k in a) and not all(torch.equal(a[k], c[k]) for k in a)


def test_contended_share_draws_that_share_of_each_minibatch_from_the_contended_samples():
    """A data set of 1,000 samples, 50 of them contended (5 %). At contended_share 0.5, minibatches of
    64 hold 32 contended samples plus the uniform half's ~5 %: over 200 draws the contended share is
    0.5 + 0.5 × 0.05 = 0.525 within 4 binomial standard errors of the uniform half, and the contended
    part covers the contended samples uniformly. At 0 a draw is DAgger's own uniform draw, number for
    number; a data set with no contended sample is drawn uniformly whatever the share."""
    dataset = Dataset(1000, 2)
    flags = torch.zeros(1000, dtype=torch.bool)
    flags[torch.arange(0, 1000, 20)] = True
    dataset.add(torch.zeros(1000, 2), torch.zeros(1000, dtype=torch.uint8), flags)
    draw, generator = MinibatchDraw(dataset, 64, 0.5), torch.Generator().manual_seed(3)
    drawn = torch.stack([draw(generator) for _ in range(200)])
    share = float(flags[drawn].float().mean())
    uniform_half = 200 * 32
    assert abs(share - 0.525) <= 4 * 0.5 * (0.05 * 0.95 / uniform_half) ** 0.5
    assert flags[drawn[:, :32]].all()  # the contended part
    counts = torch.bincount(drawn[:, :32].reshape(-1), minlength=1000)[flags]
    assert counts.min() > 0.5 * 128 and counts.max() < 1.5 * 128  # 6,400 over 50: 128 each on average
    plain = MinibatchDraw(dataset, 64, 0.0)
    assert torch.equal(plain(torch.Generator().manual_seed(5)),
                       torch.randint(1000, (64,), generator=torch.Generator().manual_seed(5)))
    none = Dataset(1000, 2)
    none.add(torch.zeros(1000, 2), torch.zeros(1000, dtype=torch.uint8))
    assert torch.equal(MinibatchDraw(none, 64, 0.5)(torch.Generator().manual_seed(5)),
                       torch.randint(1000, (64,), generator=torch.Generator().manual_seed(5)))


def test_a_saved_data_set_keeps_its_contended_flags_and_an_older_one_loads_with_none():
    dataset = Dataset(10, 2)
    dataset.add(torch.ones(6, 2), torch.tensor([0, 1, 0, 1, 0, 1]), torch.tensor([True, False] * 3))
    copy = Dataset(10, 2)
    copy.load(dataset.to_dict(), "data set")
    assert copy.contended[:6].tolist() == [True, False] * 3 and copy.size == 6
    older = {k: v for k, v in dataset.to_dict().items() if k != "contended"}
    copy.load(older, "data set")
    assert copy.size == 6 and not copy.contended[:6].any()
    with pytest.raises(ValueError, match=r"^data set: its contended flags are \(torch\.uint8, \(6,\)\)"):
        Dataset(10, 2).load({**dataset.to_dict(), "contended": torch.zeros(6, dtype=torch.uint8)}, "data set")


@pytest.mark.parametrize("algo, hp, field", [
    ("dagger_agents", {"bogus": 1}, "bogus"),
    ("dagger_agents", {"n_steps": 0}, "n_steps"),
    ("dagger_agents", {"learning_rate": "nan"}, "learning_rate"),
    ("dagger_agents", {"expert_iterations": -1}, "expert_iterations"),
    ("dagger_agents", {"imitation_share": 0.5}, "imitation_share"),  # no PPO phase to share with
    ("dagger_agents", {"ppo_learning_rate": 1e-4}, "ppo_learning_rate"),
    ("dagger_ppo_agents", {"imitation_share": 1.0}, "imitation_share"),
    ("dagger_response_agents", {"labels": "oracle"}, "labels"),
    ("dagger_contended_agents", {"contended_share": 1.0}, "contended_share"),  # none drawn uniformly: no DAgger
    ("dagger_agents", {"bc_coef": 0.5}, "bc_coef"),  # no fine-tuning to clone in
    ("dagger_dapg_agents", {"bc_coef": -1}, "bc_coef"),
    ("dagger_dapg_agents", {"bc_half_life": 0}, "bc_half_life"),
    ("dagger_agents", {"contended_share": -0.1}, "contended_share"),
    ("dagger_ppo_agents", {"ppo_clip_range": 0}, "ppo_clip_range"),
    ("dagger_ppo_agents", {"ppo_hidden": "32,32"}, "ppo_hidden"),
    ("dagger_ppo_agents", {"ppo_bogus": 1}, "ppo_bogus"),
    ("dagger_agents", {"request_weight": "0"}, "request_weight"),
    ("dagger_agents", {"anneal_lr": "sometimes"}, "anneal_lr"),
    ("dagger_agents", {"safety_risk": 1.0}, "safety_risk"),
    ("dagger_agents", {"safety_risk": -1e-6}, "safety_risk"),
    ("dagger_response_agents", {"safety_risk": 1e-6}, "safety_risk"),  # the best responses are not shielded
])
def test_bad_settings_are_refused_before_anything_is_written(algo, hp, field, tmp_path):
    with pytest.raises(ValueError, match=field):
        train(TrainArgs(algo=algo, out=str(tmp_path / "r"), timesteps=100, hyperparams=hp, progress_bar=False))
    assert not (tmp_path / "r").exists()


def test_settings_parse_from_strings():
    hp = DAggerArgs.from_hyperparams({"n_steps": "32", "greedy": "false", "hidden": "32,16", "ppo_clip_range": "0.1"},
                                     fine_tune=True)
    assert (hp.n_steps, hp.greedy, hp.hidden, hp.ppo.clip_range, hp.imitation_share) == (32, False, (32, 16), 0.1, 0.5)
    assert hp.imitation_budget(1000) == 500 and DAggerArgs().imitation_budget(1000) == 1000


def test_annealed_step_size_falls_linearly_to_zero_over_the_imitation_budget(tmp_path):
    """The record's step size per iteration: learning_rate × (1 − samples before the iteration / budget),
    the imitation budget of a fine-tuning run (here a fifth of its budget), and constant by default."""
    assert DAggerArgs(anneal_lr=True).learning_rate_at(250, 1000) == pytest.approx(0.75e-3)
    assert DAggerArgs().learning_rate_at(250, 1000) == 1e-3
    run = train(TrainArgs(algo="dagger_ppo_agents", out=str(tmp_path / "r"), timesteps=50_000, n_envs=2, seed=1,
                          progress_bar=False, hyperparams={"anneal_lr": "true", "n_steps": "50", "imitation_share": "0.2"}))
    rows = json.loads((run / "imitation.json").read_text())["iterations"]
    imitation = 10_000  # a fifth of 50k: 20 iterations of 2 simulations x 5 agents x 50 steps
    assert [r["learning_rate"] for r in rows] == pytest.approx(
        [1e-3 * (1 - (r["timesteps"] - 500) / imitation) for r in rows])
    assert len(rows) == 20 and rows[-1]["learning_rate"] == pytest.approx(1e-3 * 500 / imitation)


def test_request_weight_scales_the_cross_entropy_of_requests():
    """One update's reported cross-entropy is the class-weighted mean over its minibatch (torch's
    ``weight`` rule: the sum of w_y × loss over the sum of w_y), computed here by hand from the same
    logits and the same draw (with replacement, from the update's generator)."""
    generator = torch.Generator().manual_seed(0)
    model = ActorCritic("decentralised", 3, 2, generator=generator)
    obs = torch.randn(8, 3, generator=generator)
    labels = torch.tensor([1, 0, 0, 0, 1, 0, 0, 0], dtype=torch.uint8)
    dataset = Dataset(8, 3)
    dataset.add(obs, labels)
    with torch.no_grad():
        nll = -torch.log_softmax(model.logits(obs), -1)[torch.arange(8), labels.long()]
    idx = torch.randint(8, (8,), generator=torch.Generator().manual_seed(1))
    w = torch.where(labels[idx] == 1, 4.0, 1.0)
    hp = DAggerArgs(request_weight=4.0, minibatch_size=8, n_epochs=1)
    frozen = torch.optim.SGD(model.net.parameters(), lr=0.0)
    got = update(model, frozen, hp, torch.Generator().manual_seed(1), dataset, obs, torch.zeros(8))
    assert labels[idx].any() and got == pytest.approx(float((w * nll[idx]).sum() / w.sum()), rel=1e-5)
    plain = update(model, frozen, DAggerArgs(minibatch_size=8, n_epochs=1), torch.Generator().manual_seed(1),
                   dataset, obs, torch.zeros(8))
    assert plain == pytest.approx(float(nll[idx].mean()), rel=1e-5) and plain != pytest.approx(got)
