"""Does the native PPO's compiled update train like autograd's? Seeds trained both ways, side by side,
compared on validation episodes.

    python studies/update_equivalence.py                         # n5_m2_dt60, seeds 101-105, 1M samples
    python studies/update_equivalence.py --row n5_m5_dt60 --hp '{"minibatch_size": 64}'   # other settings
    python studies/update_equivalence.py --smoke                 # seconds; numbers meaningless

The trainer's update (:func:`containergym_marl.training.fast_ppo.update`) is one compiled call
(:mod:`containergym_marl.training.ppo_kernel`): the clipped loss's gradients in closed form, the
networks' backward layer by layer, its own tanh and BLAS; the tests check one update against
autograd's and SB3's to float rounding. Rounding still changes, and over a run a last-bit
difference grows into another trajectory, so the same seed does not give the same model. This
script trains every seed twice, ``compiled``: the trainer as it is, and ``autograd``: the same
trainer with the update taken through autograd and torch's fused Adam (:func:`autograd_update`,
:func:`autograd_optimizer`), at the method's settings file's settings (``--hp``: some replaced),
scores each run's best model on the validation episodes (20000-20029), and reports both methods'
returns and a two-sided Welch t-test and a permutation test of the difference in means. Each run is
trained in its own process, one torch thread; runs already in ``--out`` are reused.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool
from containergym_marl.training import fast_ppo
from containergym_marl.training.ppo_kernel import FlatAdam

#: the trainer's own update and optimiser
COMPILED = (fast_ppo.update, fast_ppo._optimizer)
VARIANTS = ("compiled", "autograd")


class AutogradAdam(FlatAdam):
    """torch's fused Adam over the parameters, which stay views of one flat buffer as the trainer's own
    optimiser leaves them (the rollout's compiled policy step reads them there); its state is torch's."""

    def __init__(self, params, lr: float, eps: float):
        super().__init__(params, lr=lr, eps=eps)
        self.adam = torch.optim.Adam(self.params, lr=lr, eps=eps, fused=True)

    def state_dict(self):
        return self.adam.state_dict()

    def load_state_dict(self, state) -> None:
        self.adam.load_state_dict(state)


def autograd_update(model, optimizer: AutogradAdam, hp, generator, obs, actions, old_logp, advantages, returns,
                    masks=None, bc=None, bc_weight: float = 0.0) -> dict[str, float]:
    """``fast_ppo.update`` through autograd: the loss built from the networks' modules, ``backward``,
    ``clip_grad_norm_`` and torch's Adam at the trainer's step size; the same minibatches and epochs
    from the same generator. PPO alone: the behaviour-cloning term of a DAgger fine-tuning
    (``bc_weight`` > 0) is not part of the comparison."""
    if bc_weight > 0:
        raise ValueError("autograd_update: the reference update has no behaviour-cloning term")
    optimizer.adam.param_groups[0]["lr"] = optimizer.param_groups[0]["lr"]  # the trainer's schedule
    total = obs.shape[0]
    minibatches = max(1, round(total / hp.minibatch_size))
    params = list(model.net.parameters())
    sums, count = torch.zeros(3), 0
    for _ in range(hp.n_epochs):
        order = torch.randperm(total, generator=generator)
        for idx in torch.tensor_split(order, minibatches):
            log_probs = torch.log_softmax(model.logits(obs[idx], None if masks is None else masks[idx]), -1)
            log_ratio = log_probs.gather(-1, actions[idx, None]).squeeze(-1) - old_logp[idx]
            adv = advantages[idx]
            if hp.normalize_advantage and len(idx) > 1:
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
            ratio = torch.exp(log_ratio)
            policy_loss = -torch.min(adv * ratio, adv * torch.clamp(ratio, 1 - hp.clip_range, 1 + hp.clip_range)).mean()
            value_loss = torch.nn.functional.mse_loss(returns[idx], model.value(obs[idx]))
            entropy = -(log_probs.exp() * log_probs.clamp_min(torch.finfo(log_probs.dtype).min)).sum(-1).mean()
            loss = policy_loss + hp.vf_coef * value_loss - hp.ent_coef * entropy
            for p in params:
                p.grad = None
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, hp.max_grad_norm)
            optimizer.adam.step()
            with torch.no_grad():
                sums += torch.stack([entropy, ((ratio - 1) - log_ratio).mean(),
                                     ((ratio - 1).abs() > hp.clip_range).float().mean()])
            count += 1
    entropy, approx_kl, clip_fraction = (sums / count).tolist()
    return {"entropy": entropy, "approx_kl": approx_kl, "clip_fraction": clip_fraction}


def autograd_optimizer(model, hp) -> AutogradAdam:
    """torch's fused Adam over the parameters (:class:`AutogradAdam`)."""
    return AutogradAdam(model.net.parameters(), lr=hp.learning_rate, eps=hp.adam_eps)


def use_update(variant: str):
    """Make ``fast_ppo.learn`` use ``variant``'s update and optimiser in this process (a worker trains
    one run after another: each run sets its own); returns the update."""
    fast_ppo.update, fast_ppo._optimizer = (autograd_update, autograd_optimizer) if variant == "autograd" else COMPILED
    return fast_ppo.update


def train_and_score(job: tuple[str, str, int, int, str, int, dict]) -> dict:
    variant, row, seed, samples, out, episodes, hyperparams = job
    from containergym_marl.evaluation import evaluate
    from containergym_marl.evaluation.protocol import VALIDATION, EvalProtocol
    from containergym_marl.evaluation.run_policies import policy_from_run
    from containergym_marl.rundir import run_name
    from containergym_marl.training import TrainArgs, train

    run = Path(out) / variant / run_name("fast_shared_ppo", row, seed)
    cached = run / "score.json"
    if cached.is_file():
        return json.loads(cached.read_text())
    torch.set_num_threads(1)
    use_update(variant)
    start = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        train(TrainArgs(algo="fast_shared_ppo", config=row, seed=seed, out=str(run), timesteps=samples,
                        progress_bar=False, resume=run.is_dir(), hyperparams=hyperparams))
    cpu = time.process_time() - start
    protocol = EvalProtocol(episodes=episodes, first_seed=VALIDATION.first_seed)
    result = evaluate(policy_from_run(run), row, protocol, keep_records=False)
    entry = {"variant": variant, "row": row, "seed": seed, "samples": samples, "hyperparams": hyperparams,
             "cpu_s": round(cpu, 1),
             "validation_return": float(result.returns.mean()),
             "overflowing_episodes": int(sum(e.overflow for e in result.episodes))}
    atomic_write_text(cached, json.dumps(entry) + "\n")
    return entry


def permutation_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided exact permutation test of the difference in means (every split of the pooled values)."""
    pooled, n = np.concatenate([a, b]), len(a)
    observed = abs(a.mean() - b.mean())
    diffs = [abs(pooled[list(idx)].mean() - np.delete(pooled, list(idx)).mean())
             for idx in itertools.combinations(range(len(pooled)), n)]
    return float(np.mean(np.asarray(diffs) >= observed - 1e-12))


def welch_p(a: np.ndarray, b: np.ndarray) -> float:
    from scipy import stats

    return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--row", default="n5_m2_dt60")
    p.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103, 104, 105])
    p.add_argument("--samples", type=int, default=1_000_000, help="training samples of every run")
    p.add_argument("--episodes", type=int, default=30, help="validation episodes (seeds 20000...)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", default="runs/update_equivalence")
    p.add_argument("--hp", type=json.loads, default={},
                   help="settings replacing the settings file's, as JSON, the same for both variants")
    p.add_argument("--smoke", action="store_true", help="two seeds, 8192 samples, 2 episodes")
    ns = p.parse_args(argv)
    if not isinstance(ns.hp, dict):
        p.error(f"--hp: a JSON object of settings expected, got {ns.hp!r}")
    if ns.smoke:
        ns.seeds, ns.samples, ns.episodes = ns.seeds[:2], 8192, 2
    jobs = [(v, ns.row, s, ns.samples, ns.out, ns.episodes, ns.hp) for s in ns.seeds for v in VARIANTS]
    with worker_pool(ns.workers) as pool:
        entries = list(pool.map(train_and_score, jobs))
    returns = {v: np.array([e["validation_return"] for e in entries if e["variant"] == v]) for v in VARIANTS}
    cpu = {v: sum(e["cpu_s"] for e in entries if e["variant"] == v) for v in VARIANTS}
    report = {"row": ns.row, "seeds": ns.seeds, "samples": ns.samples, "episodes": ns.episodes, "hyperparams": ns.hp,
              "entries": entries,
              "welch_p": welch_p(*returns.values()) if len(ns.seeds) > 1 else math.nan,
              "permutation_p": permutation_p(*returns.values())}
    settings = (f"the settings file's settings with {json.dumps(ns.hp, sort_keys=True)}" if ns.hp
                else "the settings file's settings")
    lines = [f"# The compiled update against autograd's: fast_shared_ppo on {ns.row}", "",
             f"`python studies/update_equivalence.py --row {ns.row}"
             + (f" --hp '{json.dumps(ns.hp, sort_keys=True)}'" if ns.hp else "") + f"`. {len(ns.seeds)} seeds "
             f"({', '.join(map(str, ns.seeds))}) x {ns.samples:,} samples each way at {settings}; each run's best "
             f"model on {ns.episodes} validation episodes (seeds 20000...).", "",
             "| seed | " + " | ".join(VARIANTS) + " |", "|---|" + "---|" * len(VARIANTS)]
    for s in ns.seeds:
        cells = [next(f"{e['validation_return']:.2f} ({e['overflowing_episodes']} overflow)" for e in entries
                      if e["seed"] == s and e["variant"] == v) for v in VARIANTS]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    lines += ["| mean | " + " | ".join(f"{returns[v].mean():.2f}" for v in VARIANTS) + " |",
              "| training CPU-s | " + " | ".join(f"{cpu[v]:.0f}" for v in VARIANTS) + " |", "",
              f"Difference in means {returns['compiled'].mean() - returns['autograd'].mean():+.2f}; Welch's t-test "
              f"p = {report['welch_p']:.2f}, exact permutation test p = {report['permutation_p']:.2f}."]
    print("\n".join(lines))
    out = Path(ns.out)
    atomic_write_text(out / "equivalence.json", json.dumps(report, indent=1) + "\n")
    atomic_write_text(out / "equivalence.md", "\n".join(lines) + "\n")
    return report


if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the study's workers stop with it
    main()
