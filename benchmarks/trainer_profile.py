"""Where the native PPO's CPU time goes, at its default shape: CPU microseconds per sample of each
phase of a training run, one torch thread.

    python benchmarks/trainer_profile.py                          # fast_shared_ppo on n11_m2_dt120
    python benchmarks/trainer_profile.py --algo fast_ppo --config n5_m2_dt120
    python benchmarks/trainer_profile.py --smoke                  # seconds; numbers meaningless
    python benchmarks/trainer_profile.py --md benchmarks/profile/fast_shared_ppo_n11_m2_dt120.md  # docs/performance.md's

A whole ``train`` run of ``--samples`` samples is measured first (this process's CPU time). Then the
trainer's own functions are run one by one at the run's shape (the same simulations, rollout length,
minibatches and epochs) and timed apart, each repeated ``--repeats`` times:

* rollout: the vector env's step; the policy's and value's forward with the action sample
  (Gumbel-max) and the log-probability;
* GAE over one rollout;
* update (``fast_ppo.update``'s loop, replayed step by step): the minibatch's rows and the networks'
  forward, the loss's gradients (:mod:`~containergym_marl.training.ppo_gradients`), the networks'
  backward, gradient clip, Adam.

"Rest" is the whole run less the sum of the phases: the rollout's bookkeeping (copies into the
buffers, episode returns, the time-limit bootstrap), metrics rows, checkpoints and start-up.
Below the table, the update's arithmetic floor: its matrix products alone, the same calls on the
same shapes, timed apart (what the update would cost if everything else in it were free).
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

import numpy as np
import torch

from containergym_marl.algorithms import get_algorithm
from containergym_marl.config import load_config
from containergym_marl.config.hyperparams import method_settings
from containergym_marl.training import TrainArgs, train
from containergym_marl.training.fast_ppo import PPOArgs, compute_gae, new_state
from containergym_marl.training.ppo_gradients import MLPGradients, ppo_loss_gradients
from throughput import _cpu_name, _load  # benchmarks/, this script's folder


def _cpu(fn, repeats: int) -> float:
    """CPU seconds of ``fn()`` per call (the median of ``repeats`` calls)."""
    times = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


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
    obs = torch.from_numpy(env.reset())
    rng = np.random.default_rng(0)
    per = {}  # phase -> CPU seconds per sample
    actions = rng.integers(0, model.n_actions, size=slots)
    per["env step"] = _cpu(lambda: [env.step(actions) for _ in range(steps)], repeats) / rollout

    nets = MLPGradients(model, optimizer)
    gumbel = torch.zeros((steps, slots, model.n_actions))

    def policy_forward():  # the rollout's: logits and values in one call, the Gumbel-max sample
        with torch.inference_mode(), nets.fixed_parameters():
            gumbel.uniform_(generator=generator).log_().neg_().log_()
            for t in range(steps):
                logits, _ = nets.forward(obs, keep=False)
                a = torch.sub(logits, gumbel[t]).argmax(-1)
                torch.log_softmax(logits, -1).gather(-1, a[:, None])

    per["policy and value forward + sample"] = _cpu(policy_forward, repeats) / rollout

    rewards, values, starts = (torch.randn(steps, slots) for _ in range(3))
    last = torch.zeros(slots)
    per["GAE"] = _cpu(lambda: compute_gae(rewards, values, starts, last, last, 0.99, hp.gae_lambda), repeats) / rollout

    flat_obs = obs.repeat(steps, 1)
    flat_act = torch.from_numpy(rng.integers(0, model.n_actions, size=rollout))
    old_logp, adv, ret = torch.full((rollout,), -0.7), torch.randn(rollout), torch.randn(rollout)
    minibatches = max(1, round(rollout / hp.minibatch_size))
    parts = {"update: minibatch and forward": 0.0, "update: loss gradients": 0.0, "update: backward": 0.0,
             "update: gradient clip": 0.0, "update: Adam": 0.0}

    def one_update():  # fast_ppo.update's loop, phase by phase
        for _ in range(hp.n_epochs):
            for idx in torch.tensor_split(torch.randperm(rollout, generator=generator), minibatches):
                t0 = time.process_time()
                logits, values = nets.forward(flat_obs.index_select(0, idx))
                a = adv.index_select(0, idx)
                t1 = time.process_time()
                g_logits, g_values, _ = ppo_loss_gradients(
                    logits, values, flat_act.index_select(0, idx), old_logp.index_select(0, idx),
                    (a - a.mean()) / (a.std() + 1e-8), ret.index_select(0, idx), hp.clip_range, hp.vf_coef, hp.ent_coef)
                t2 = time.process_time()
                nets.backward(g_logits, g_values)
                t3 = time.process_time()
                nets.clip_grad_norm_(hp.max_grad_norm)
                t4 = time.process_time()
                optimizer.step()
                t5 = time.process_time()
                for name, dt in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4)):
                    parts[name] += dt

    for _ in range(repeats):
        one_update()
    per.update({name: total / repeats / rollout for name, total in parts.items()})

    # The update's arithmetic floor: its matrix products alone, the same calls on the same shapes as
    # MLPGradients' forward and backward (dW of every layer, dx of all but the first), nothing else.
    layers = [[(m.weight.detach(), m.bias.detach()) for m in net if isinstance(m, torch.nn.Linear)]
              for net in (model.net.actor, model.net.critic)]
    batch = flat_obs[: -(-rollout // minibatches)]

    def products_only():
        for _ in range(hp.n_epochs * minibatches):
            for net in layers:
                xs = [batch]
                for weight, bias in net:
                    xs.append(torch.addmm(bias, xs[-1], weight.t()))
                g = torch.ones_like(xs[-1])
                for i in reversed(range(len(net))):
                    weight, x = net[i][0], xs[i]
                    x.t().mm(g) if x.shape[1] < g.shape[1] else g.t().mm(x)
                    if i > 0:
                        g = g.mm(weight)

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
    update = sum(us for name, us in result["us_per_sample"].items() if name.startswith("update"))
    floor = result["update_products_us_per_sample"]
    lines += ["", f"The update's matrix products alone (the same products on the same shapes, nothing else): "
              f"{floor:.2f} µs per sample, {floor / update:.0%} of the update's {update:.2f}; the rest of the "
              f"update is elementwise passes (the tanh and its derivative, the loss) and per-call overhead."]
    print("\n".join(lines))
    if ns.md:
        Path(ns.md).parent.mkdir(parents=True, exist_ok=True)
        Path(ns.md).write_text("\n".join(lines) + "\n")
    if ns.json:
        Path(ns.json).write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
