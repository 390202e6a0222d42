"""Where the native PPO's CPU time goes, at its default shape: CPU microseconds per sample of each
phase of a training run, one torch thread.

    python benchmarks/trainer_profile.py                          # fast_shared_ppo on n11_m2_dt120
    python benchmarks/trainer_profile.py --algo fast_ppo --config n5_m2_dt120
    python benchmarks/trainer_profile.py --smoke                  # seconds; numbers meaningless
    python benchmarks/trainer_profile.py --md benchmarks/profile/fast_shared_ppo_n11_m2_dt120.md  # docs/performance.md's

A whole ``train`` run of ``--samples`` samples is measured first (this process's CPU time). Then the
trainer's own functions are run one by one at the run's shape (the same simulations, rollout length,
minibatches and epochs) and timed apart, each repeated ``--repeats`` times:

* rollout: the vector env's step; the policy's step (:func:`~containergym_marl.training.ppo_kernel.act`:
  the policy's and value's forward, the action sample (Gumbel-max) and its log-probability);
* GAE over one rollout;
* update: ``fast_ppo.update``, one compiled call for every epoch and minibatch
  (:func:`~containergym_marl.training.ppo_kernel.ppo_update`).

"Rest" is the whole run less the sum of the phases: the rollout's bookkeeping (copies into the
buffers, episode returns, the time-limit bootstrap), metrics rows, checkpoints and start-up.
Below the table, the update's arithmetic floor: its matrix products alone, the same BLAS calls on
the same shapes, timed apart (what the update would cost if everything else in it were free).
CPU time is ``time.process_time`` (all threads of this process), which leaves out time spent
waiting for a core; a busy machine still inflates it through shared caches, so compare phases
within one run of this script.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import warnings
from pathlib import Path

import numba
import numpy as np
import torch

from containergym_marl.algorithms import get_algorithm
from containergym_marl.config import load_config
from containergym_marl.config.hyperparams import method_settings
from containergym_marl.training import TrainArgs, train
from containergym_marl.policies.actor_critic import MASKED_LOGIT
from containergym_marl.training.fast_ppo import PPOArgs, compute_gae, new_state, update
from containergym_marl.training.ppo_kernel import act, blas_threads, parameter_layout
from throughput import _cpu_name, _load  # benchmarks/, this script's folder


def _cpu(fn, repeats: int) -> float:
    """CPU seconds of ``fn()`` per call (the median of ``repeats`` calls)."""
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


@numba.njit(cache=True)
def _products(flat, layout, actor_layers, x, steps):
    """The matrix products of ``steps`` minibatch steps of ppo_update on rows ``x``: per network, each
    layer's forward product, its weight gradient's and (but the first) its input gradient's."""
    n_layers = layout.shape[0]
    for _ in range(steps):
        for first, last in ((0, actor_layers), (actor_layers, n_layers)):
            xs = [x]
            for li in range(first, last):
                w_off, n_out, n_in = layout[li, 0], layout[li, 2], layout[li, 3]
                weight = flat[w_off:w_off + n_out * n_in].reshape((n_out, n_in))
                xs.append(np.dot(xs[-1], weight.T))
            g = np.ones_like(xs[-1])
            for li in range(last - 1, first - 1, -1):
                w_off, n_out, n_in = layout[li, 0], layout[li, 2], layout[li, 3]
                weight = flat[w_off:w_off + n_out * n_in].reshape((n_out, n_in))
                np.dot(g.T, xs[li - first])
                if li > first:
                    g = np.dot(g, weight)


def _env(spec, plant, sims):
    from containergym_marl.envs.vector import ContainerAgentsVecEnv, ContainerGymVecEnv

    if spec.view == "decentralised":
        return ContainerAgentsVecEnv(plant, sims)
    return ContainerGymVecEnv(plant, sims)


def profile(algo: str, config: str, samples: int, repeats: int) -> dict:
    torch.set_num_threads(1)
    spec, plant = get_algorithm(algo), load_config(config)
    # the settings the run trains with (its method's file), so the phases are timed at the run's shape
    hp = PPOArgs.from_hyperparams(method_settings(spec.method_name(None)))
    sims = spec.default_sims(plant.n_containers, settings=hp)
    env = _env(spec, plant, sims)
    slots, steps = env.num_envs, hp.n_steps
    rollout = slots * steps

    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        train(TrainArgs(algo=algo, config=config, timesteps=rollout, out=f"{tmp}/warm", progress_bar=False))
        t = time.process_time()
        run = train(TrainArgs(algo=algo, config=config, timesteps=samples, out=f"{tmp}/run", progress_bar=False))
        whole = time.process_time() - t
        trained = json.loads((Path(run) / "run.json").read_text())["timesteps"]

    state = new_state(env, hp, spec.view, 0, {})
    model, optimizer, generator = state.model, state.optimizer, state.generator
    env.seed(0)
    obs = env.reset()
    rng = np.random.default_rng(0)
    per = {}  # phase -> CPU seconds per sample
    actions = rng.integers(0, model.n_actions, size=slots)
    per["env step"] = _cpu(lambda: [env.step(actions) for _ in range(steps)], repeats) / rollout

    flat = optimizer.flat_param.numpy()
    layout, actor_layers = parameter_layout(model, optimizer.flat_param)
    gumbel = torch.zeros((steps, slots, model.n_actions))
    no_masks = np.zeros((0, model.n_actions), np.bool_)
    out_actions, out_logp, out_values = np.zeros(slots, np.int64), np.zeros(slots, np.float32), np.zeros(slots, np.float32)

    def policy_step():  # the rollout's: the Gumbel noise of the rollout, then one call a step
        with blas_threads(1):
            gumbel.uniform_(generator=generator).log_().neg_().log_()
            g = gumbel.numpy()
            for t in range(steps):
                act(flat, layout, actor_layers, obs, g[t], no_masks, MASKED_LOGIT, out_actions, out_logp, out_values)

    per["policy step (forward, sample, log-probability)"] = _cpu(policy_step, repeats) / rollout

    rewards, values, starts = (torch.randn(steps, slots) for _ in range(3))
    last = torch.zeros(slots)
    per["GAE"] = _cpu(lambda: compute_gae(rewards, values, starts, last, last, 0.99, hp.gae_lambda), repeats) / rollout

    flat_obs = torch.from_numpy(obs).repeat(steps, 1)
    flat_act = torch.from_numpy(rng.integers(0, model.n_actions, size=rollout))
    old_logp, adv, ret = torch.full((rollout,), -0.7), torch.randn(rollout), torch.randn(rollout)
    minibatches = max(1, round(rollout / hp.minibatch_size))
    per["update (one compiled call)"] = _cpu(
        lambda: update(model, optimizer, hp, generator, flat_obs, flat_act, old_logp, adv, ret), repeats) / rollout

    # The update's arithmetic floor: its matrix products alone, the same BLAS calls on the same shapes as
    # ppo_update's forward and backward (dW of every layer, dx of all but the first), nothing else.
    batch = np.ascontiguousarray(flat_obs[: -(-rollout // minibatches)].numpy())

    def products_only():
        with blas_threads(1):
            _products(flat, layout, actor_layers, batch, hp.n_epochs * minibatches)

    floor = _cpu(products_only, repeats) / rollout
    whole_per = whole / trained
    per["rest (bookkeeping, files, start-up)"] = whole_per - sum(per.values())
    return {"algo": algo, "config": config, "simulations": sims, "samples_per_update": rollout,
            "minibatches": minibatches, "epochs": hp.n_epochs, "run_samples": trained, "run_cpu_s": whole,
            "us_per_sample": {k: v * 1e6 for k, v in per.items()}, "whole_us_per_sample": whole_per * 1e6,
            "update_products_us_per_sample": floor * 1e6}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", default="fast_shared_ppo", choices=["fast_ppo", "fast_shared_ppo"])
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--samples", type=int, default=500_000, help="samples of the whole run")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--smoke", action="store_true", help="a run of one rollout, one repeat")
    p.add_argument("--json", default=None)
    p.add_argument("--md", default=None, help="also write the table, with the machine and its load, to this file")
    ns = p.parse_args(argv)
    load_before, started = _load(), time.strftime("%Y-%m-%d %H:%M", time.gmtime())
    result = profile(ns.algo, ns.config, 1 if ns.smoke else ns.samples, 1 if ns.smoke else ns.repeats)
    lines = [f"# {ns.algo} on {ns.config}: CPU µs per sample, one torch thread", "",
             f"`python benchmarks/trainer_profile.py --algo {ns.algo} --config {ns.config} --samples {ns.samples} "
             f"--repeats {ns.repeats}` · {started} UTC · {_cpu_name()} · {os.cpu_count()} CPUs · load average before "
             f"{load_before}, after {_load()} (a busy machine inflates every phase; compare the shares)", "",
             f"{result['simulations']} simulations, {result['samples_per_update']} samples per update, "
             f"{result['minibatches']} minibatches x {result['epochs']} epochs; whole run: {result['run_samples']:,} "
             f"samples in {result['run_cpu_s']:.1f} CPU-s.", "", "| phase | CPU µs per sample | share |", "|---|---|---|"]
    whole = result["whole_us_per_sample"]
    for name, us in result["us_per_sample"].items():
        lines.append(f"| {name} | {us:.2f} | {us / whole:.0%} |")
    lines.append(f"| **whole run** | **{whole:.2f}** | 100% |")
    update_us = sum(us for name, us in result["us_per_sample"].items() if name.startswith("update"))
    floor = result["update_products_us_per_sample"]
    lines += ["", f"The update's matrix products alone (the same products on the same shapes, nothing else): "
              f"{floor:.2f} µs per sample, {floor / update_us:.0%} of the update's {update_us:.2f}; the rest of the "
              f"update is its fused loops (the tanh and its derivative, the loss, the clip and Adam)."]
    print("\n".join(lines))
    if ns.md:
        Path(ns.md).parent.mkdir(parents=True, exist_ok=True)
        Path(ns.md).write_text("\n".join(lines) + "\n")
    if ns.json:
        Path(ns.json).write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
