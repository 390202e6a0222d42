"""Where learned container agents and the reference planner decide differently, on a contended row.

    python studies/decision_differences.py                          # n16_m2_dt120, dagger_agents' published best model
    python studies/decision_differences.py --config n11_m2_dt120 --episodes 30 \\
        --learned dagger_contended_agents=runs/dagger_contended_agents_n11_m2_dt120_s1/validated_model.pt

Runs one learned shared container-agent policy (``--learned NAME=PATH``, a tensor-only ``.pt`` model; by
default the published best ``dagger_agents`` model of the row, checked against its folder's
MANIFEST.sha256) on validation episodes (seeds 20000 + k, the paper's δ and T) of the decentralised view.
At every step it also asks the reference planner (``planner_agents_shielded``, seeded per episode) what
it would request in the same state, without acting on it, and counts the container-steps where the two
differ:

* ``extra``: the learned agent requests where the planner would not; ``denied_extra`` those of them the
  plant denied (no PU left for them);
* ``missing``: the planner would request where the learned agent does not, split by whether a PU was
  free (``missing_with_a_free_pu``).

It writes the counts per episode and in total to ``--json`` (default
``results/planner/decisions_<config>_<name>.json``), and to ``--out`` (default docs/figures) the figure of
one episode, ``<config>_decisions_<name>.png``: the first episode the learned agents overflow in (else
the one with the most differing container-steps), its last ``--window`` steps, with the volumes of the
containers whose decisions differed most there, each one's optimum v* (dashed), and both sides' requests
(learned: filled; planner: open; a denied request: red).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.core.params import PlantParams
from containergym_marl.envs.container_agents_v0 import parallel_env
from containergym_marl.evaluation.protocol import VALIDATION
from containergym_marl.policies.planner import ShieldedPlannerAgents
from planner_figures import learned_policies  # this folder's study: loads a model, checking published hashes

#: the learned policy shown by default (its published best model for the row)
DEFAULT_LEARNED = "dagger_agents"
#: containers drawn in the figure: those whose decisions differed most in its window
SHOWN_CONTAINERS = 6


def run_episode(policy, planner: ShieldedPlannerAgents, config: str, seed: int) -> dict:
    """One episode of ``policy`` acting, ``planner`` asked at every step: (steps, n) arrays of the
    volumes before each step, both sides' requests, the grants and denials, and whether it overflowed."""
    env = parallel_env(config)
    observations, _ = env.reset(seed=seed)
    planner.reset(seed=seed)
    sim = env.simulator
    volumes, learned, planned, granted, denied, free = [], [], [], [], [], []
    overflowed = False
    while env.agents:
        state = sim.state
        volumes.append(state.volumes[0].copy())
        free.append(int((state.pu_timers_s[0] == 0.0).sum()))
        planned.append(planner.decide(state, sim.params).copy())
        actions = policy.act(observations, env)
        learned.append(np.array([actions[a] == 1 for a in env.possible_agents]))
        observations, _, terminations, _, _ = env.step(actions)
        out = sim.last_outcome
        granted.append(out.granted[0].copy())
        denied.append(out.denied[0].copy())
        overflowed = bool(out.terminated[0])
    return {"overflowed_containers": out.overflowed[0].copy(), "seed": seed, "volumes": np.array(volumes), "learned": np.array(learned), "planned": np.array(planned),
            "granted": np.array(granted), "denied": np.array(denied), "free_pus": np.array(free),
            "overflowed": overflowed}


def differences(episode: dict) -> dict[str, int]:
    """Container-steps where the learned agents and the planner decide differently, by kind."""
    learned, planned = episode["learned"], episode["planned"]
    extra, missing = learned & ~planned, planned & ~learned
    with_free = (episode["free_pus"] > 0)[:, None]
    return {"steps": int(len(learned)), "differing_steps": int((extra | missing).any(axis=1).sum()),
            "extra": int(extra.sum()), "denied_extra": int((extra & episode["denied"]).sum()),
            "missing": int(missing.sum()), "missing_with_a_free_pu": int((missing & with_free).sum()),
            "learned_requests": int(learned.sum()), "planned_requests": int(planned.sum()),
            "denied_requests": int(episode["denied"].sum()), "overflowed": episode["overflowed"]}


def plot_episode(episode: dict, params: PlantParams, names: tuple[str, ...], title: str, path: Path,
                 window: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = len(episode["learned"])
    start = max(0, steps - window)
    span = slice(start, steps)
    differ = (episode["learned"][span] != episode["planned"][span]).sum(axis=0)
    overflowing = [int(i) for i in np.flatnonzero(episode["overflowed_containers"])]  # first, then the most differing
    ranked = [int(i) for i in np.argsort(-differ, kind="stable") if differ[i] > 0 and i not in overflowing]
    shown = (overflowing + ranked)[:SHOWN_CONTAINERS] or [0]
    t = np.arange(start, steps)
    fig, axes = plt.subplots(len(shown) + 1, 1, figsize=(9, 1.8 * len(shown) + 1.6), sharex=True, squeeze=False,
                             gridspec_kw={"height_ratios": [3] * len(shown) + [1]})
    for ax, i in zip(axes[:-1, 0], shown):
        ax.plot(t, episode["volumes"][span, i], color="0.3", lw=1.2, label="volume (before the step)")
        ax.axhline(params.target_volume[i], color="tab:green", ls="--", lw=1, label="optimum v*")
        ax.axhline(params.max_volume[i], color="tab:red", ls=":", lw=1, label="limit")
        top = params.max_volume[i] * 1.04
        learned, planned, denied = (episode[k][span, i] for k in ("learned", "planned", "denied"))
        ax.scatter(t[learned & ~denied], np.full((learned & ~denied).sum(), top), marker="v", color="tab:blue",
                   s=22, label="learned agent requests")
        ax.scatter(t[learned & denied], np.full((learned & denied).sum(), top), marker="v", color="tab:red",
                   s=22, label="learned request denied")
        ax.scatter(t[planned], np.full(planned.sum(), top * 1.05), marker="v", facecolors="none",
                   edgecolors="tab:orange", s=22, label="planner would request")
        ax.set_ylabel(f"{names[i]}\nvolume", fontsize=8)
        ax.set_ylim(0, top * 1.1)
        ax.grid(alpha=0.3)
    free_ax = axes[-1, 0]
    free_ax.step(t, episode["free_pus"][span], where="post", color="0.3", lw=1.2)
    free_ax.set_ylabel("free PUs", fontsize=8)
    free_ax.set_ylim(-0.2, params.n_pus + 0.2)
    free_ax.set_yticks(range(params.n_pus + 1))
    free_ax.grid(alpha=0.3)
    free_ax.set_xlabel("step")
    axes[0, 0].legend(fontsize=7, ncol=3, loc="lower left", bbox_to_anchor=(0, 1.02))
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="n16_m2_dt120")
    p.add_argument("--learned", default=None, metavar="NAME=PATH",
                   help=f"the learned policy (default: the published best {DEFAULT_LEARNED} model of the row)")
    p.add_argument("--episodes", type=int, default=VALIDATION.episodes, help="validation episodes (seeds 20000 + k)")
    p.add_argument("--window", type=int, default=60, help="steps shown, up to the episode's end")
    p.add_argument("--out", default="docs/figures")
    p.add_argument("--json", default=None, help="default: results/planner/decisions_<config>_<name>.json")
    ns = p.parse_args(argv)
    if ns.episodes < 1 or ns.window < 1:
        raise SystemExit("--episodes and --window: at least 1")
    cfg = VALIDATION.plant(load_config(ns.config))
    params = PlantParams.from_config(cfg)
    spec = ns.learned or (f"{DEFAULT_LEARNED}=results/paper_rows/models/{load_config(ns.config).name}/"
                          f"{DEFAULT_LEARNED}_best.pt")
    ((policy, model_path),) = learned_policies([spec], cfg.name)
    probe = parallel_env(cfg)
    expected = probe.observation_space(probe.possible_agents[0]).shape
    if policy.observation_space.shape != expected:
        raise SystemExit(f"--learned {policy.name}: {model_path} takes observations of shape "
                         f"{policy.observation_space.shape}; the container agents of {cfg.name} observe {expected}")
    planner = ShieldedPlannerAgents(params)
    episodes, per_episode = [], []
    for seed in VALIDATION.seeds[:ns.episodes]:
        episodes.append(run_episode(policy, planner, cfg, seed))
        per_episode.append({"seed": seed, **differences(episodes[-1])})
    totals = {key: sum(e[key] for e in per_episode) for key in per_episode[0] if key not in ("seed", "overflowed")}
    totals["overflowing_episodes"] = sum(e["overflowed"] for e in per_episode)
    shown = next((e for e in episodes if e["overflowed"]),
                 max(episodes, key=lambda e: differences(e)["differing_steps"]))
    stem = f"{cfg.name}_decisions_{policy.name}"
    figure = Path(ns.out) / f"{stem}.png"
    ending = "overflows" if shown["overflowed"] else "ends"
    plot_episode(shown, params, cfg.container_names,
                 f"{cfg.name}, validation episode {shown['seed']} ({ending} at step {len(shown['learned'])}):\n"
                 f"{policy.name} acting, {ShieldedPlannerAgents.name} asked in the same states", figure, ns.window)
    result = {"config": cfg.name, "learned": policy.name, "model": str(model_path), "reference": ShieldedPlannerAgents.name,
              "episodes": ns.episodes, "first_seed": VALIDATION.first_seed, "totals": totals,
              "per_episode": per_episode, "figure": {"path": str(figure), "seed": shown["seed"], "window": ns.window}}
    path = Path(ns.json or f"results/planner/decisions_{cfg.name}_{policy.name}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{policy.name} on {cfg.name}, {ns.episodes} validation episodes: {totals}")
    print(f"wrote {figure} and {path}")
    return result


if __name__ == "__main__":
    main()
