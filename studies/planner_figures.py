"""What the rollout planner and the learned container agents do on a contended row (m = 2).

    python studies/planner_figures.py                     # n11_m2_dt120, 15 test episodes (~2 min)
    python studies/planner_figures.py --config n16_m2_dt120 --learned
    python studies/planner_figures.py --learned dagger_agents=runs/dagger_agents_n11_m2_dt120_s1/best_model.pt

Evaluates ``rule_based_agents``, ``planner_agents`` (default setting) and the learned shared
container-agent policies of ``--learned`` (NAME=PATH of a tensor-only ``.pt`` model; by default the
published best models of ``fast_shared_ppo``, ``dagger_agents`` and ``dagger_ppo_agents`` for the row, where they exist,
each checked against its folder's MANIFEST.sha256) with the paper's test protocol, keeps the
episode records, and writes to ``--out`` (default docs/figures) the package's figures:
emptying-volume ECDFs and the reward ECDF of all methods, and for the first test episode of each a
rollout (the first ``--window`` steps) and the PU timeline. It prints, and writes to ``--json``, the
numbers behind the explanation: per container, where the emptyings fall relative to the optimum v*
(earlier than the rule's margin, v < v* − 1; later, v > v* + 1), how often a ready container had to
wait because both PUs were busy, and how many requests were denied (no free PU).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from containergym_marl.config import load_config
from containergym_marl.core.params import PlantParams
from containergym_marl.evaluation import PAPER, EpisodeRecord, evaluate
from containergym_marl.evaluation import plots
from containergym_marl.manifest import check, read_manifest
from containergym_marl.policies import PlannerAgents, RuleBasedAgents
from containergym_marl.policies.actor_critic import ActorCritic, policy_for

#: (method, published models folder): the learned policies shown by default, where published
PUBLISHED = tuple((name, Path("results/paper_rows")) for name in ("fast_shared_ppo", "dagger_agents", "dagger_ppo_agents"))


def learned_policies(specs: list[str] | None, config: str) -> list[tuple]:
    """The shared container-agent policies of NAME=PATH specs; None: the published best models of
    :data:`PUBLISHED` for ``config`` that exist. A published file (under a folder with a
    MANIFEST.sha256) must match its hash. Returns (policy, path) pairs."""
    if specs is None:
        specs = [f"{name}={folder / 'models' / config / f'{name}_best.pt'}" for name, folder in PUBLISHED
                 if (folder / "models" / config / f"{name}_best.pt").is_file()]
    policies = []
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path.endswith(".pt"):
            raise SystemExit(f"--learned: expected NAME=PATH of a .pt model, got {spec!r}")
        path = Path(path)
        if not path.is_file():
            raise SystemExit(f"--learned {name}: no model file {path}")
        for folder in path.parents:
            if (folder / "MANIFEST.sha256").is_file():
                check(folder, path.relative_to(folder).as_posix(), path.read_bytes(), read_manifest(folder))
                break
        model = ActorCritic.load(path)
        if model.view != "decentralised":
            raise SystemExit(f"--learned {name}: {path} is a {model.view} model; a container-agent policy is needed")
        policies.append((policy_for(model, name), path))
    return policies


def window(record: EpisodeRecord, steps: int) -> EpisodeRecord:
    """The first ``steps`` steps of an episode, as a record (for a readable rollout figure)."""
    t = min(steps, record.steps)
    per_step = {k: getattr(record, k)[:t] for k in ("requested", "granted", "denied", "pu_index",
                                                     "emptied_volume", "container_reward", "plant_reward")}
    return dataclasses.replace(record, volumes=record.volumes[:t + 1], pu_timers_s=record.pu_timers_s[:t + 1],
                               terminated=record.terminated and t == record.steps, **per_step)


def overflow_causes(records: list[EpisodeRecord], params: PlantParams, margin: float = 1.0,
                    lookback: int = 10) -> dict[str, int]:
    """Why each overflowing episode overflowed, from the overflowing container's last ``lookback``
    steps: ``denied`` (it asked and another request got the free PU: the agents did not coordinate),
    ``not_requested`` (it was ready with a PU free and did not ask), else ``no_free_pu`` (it was
    ready too late, or every PU stayed busy: only an earlier emptying would have helped)."""
    target = np.asarray(params.target_volume)
    causes = {"denied": 0, "not_requested": 0, "no_free_pu": 0}
    for r in records:
        for name in r.overflowed_containers:
            i = r.container_names.index(name)
            last = slice(max(r.steps - lookback, 0), r.steps)
            ready = target[i] - r.volumes[:-1][last, i] <= margin
            free = (r.pu_timers_s[:-1][last] == 0).any(axis=1)
            if r.denied[last, i].any():
                causes["denied"] += 1
            elif (ready & free & ~r.requested[last, i]).any():
                causes["not_requested"] += 1
            else:
                causes["no_free_pu"] += 1
    return causes


def behaviour(records: list[EpisodeRecord], params: PlantParams, names: tuple[str, ...], margin: float = 1.0,
              end_game: int = 20) -> dict:
    """Where emptyings fall relative to v*, and how long ready containers wait for a PU. The
    ``end_game`` last steps of an episode are counted apart: with nothing to gain from volume left at
    the time limit, the planner empties what still earns something there."""
    target = np.asarray(params.target_volume)
    per_container = {}
    for i, name in enumerate(names):
        v = np.concatenate([r.emptying_volumes(i) for r in records])
        per_container[name] = {
            "target": float(target[i]), "emptyings": int(v.size),
            "median_volume": float(np.median(v)) if v.size else None,
            "early_share": float((v < target[i] - margin).mean()) if v.size else None,
            "late_share": float((v > target[i] + margin).mean()) if v.size else None,
            "early_emptyings_before_the_end_game": int(sum(
                ((r.emptied_volume[:, i] < target[i] - margin) & r.granted[:, i])[:r.steps - end_game].sum()
                for r in records)),
        }
    all_v = [(r.emptied_volume[r.granted], np.nonzero(r.granted)[1], np.nonzero(r.granted)[0] >= r.steps - end_game)
             for r in records]
    volumes = np.concatenate([v for v, _, _ in all_v])
    index = np.concatenate([i for _, i, _ in all_v])
    late_in_episode = np.concatenate([e for _, _, e in all_v])
    early = volumes < target[index] - margin
    waits, both_busy, steps = 0, 0, 0
    for r in records:
        state_v, timers = r.volumes[:-1], r.pu_timers_s[:-1]
        ready = target[None, :] - state_v <= margin
        no_pu = (timers == 0).sum(axis=1) == 0
        waits += int((ready & ~r.granted & no_pu[:, None]).sum())
        both_busy += int(no_pu.sum())
        steps += r.steps
    rewards = np.concatenate([r.emptying_rewards() for r in records])  # granted, in the same order as volumes
    return {
        "return_mean": float(np.mean([r.cumulative_reward for r in records])),
        "emptyings_per_episode": volumes.size / len(records),
        "mean_reward_per_emptying": float(rewards.mean()),
        "early_share": float(early.mean()),
        "early_share_before_the_end_game": float(early[~late_in_episode].mean()),
        "end_game_steps": end_game,
        "end_game_emptyings_per_episode": float(late_in_episode.sum() / len(records)),
        "mean_reward_of_early_emptyings_before_the_end_game": (
            float(rewards[early & ~late_in_episode].mean()) if (early & ~late_in_episode).any() else None),
        "late_share": float((volumes > target[index] + margin).mean()),
        "ready_waiting_for_a_pu_per_episode": waits / len(records),
        "all_pus_busy_share_of_steps": both_busy / steps,
        "denied_requests_per_episode": float(np.mean([r.denied.sum() for r in records])),
        "overflowing_episodes": int(sum(r.terminated for r in records)),
        "overflow_causes": overflow_causes(records, params, margin),
        "per_container": per_container,
    }


#: (key of :func:`behaviour`, panel title) of the behaviour summary figure
BEHAVIOUR_PANELS = (("denied_requests_per_episode", "requests denied (no free PU)\nper episode"),
                    ("early_share_before_the_end_game", "share of emptyings early (v < v* − 1),\nbefore the last 20 steps"),
                    ("ready_waiting_for_a_pu_per_episode", "ready containers waiting for a PU\n(container-steps per episode)"),
                    ("return_mean", "test return\n(mean over episodes)"))


def plot_behaviour(summary: dict, path: Path) -> None:
    """One bar per method in each panel of :data:`BEHAVIOUR_PANELS`: how each avoids or meets contention."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = [m for m in summary if m != "meta"]
    fig, axes = plt.subplots(1, len(BEHAVIOUR_PANELS), figsize=(3.2 * len(BEHAVIOUR_PANELS), 3.4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (key, title) in zip(axes, BEHAVIOUR_PANELS):
        values = [summary[m][key] for m in methods]
        ax.bar(range(len(methods)), values, color=colours[:len(methods)])
        for i, v in enumerate(values):
            ax.annotate(f"{v:.3g}", (i, v), ha="center", va="bottom", fontsize=8)
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=8)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"{summary['meta']['config']}: how each method meets contention "
                 f"({summary['meta']['episodes']} test episodes)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default="n11_m2_dt120")
    p.add_argument("--episodes", type=int, default=PAPER.episodes)
    p.add_argument("--window", type=int, default=200, help="steps shown in the rollout figures")
    p.add_argument("--out", default="docs/figures")
    p.add_argument("--json", default=None, help="default: results/planner/behaviour_<config>.json")
    p.add_argument("--learned", nargs="*", default=None, metavar="NAME=PATH",
                   help="learned container-agent policies to show (default: the published best models of "
                        + " and ".join(name for name, _ in PUBLISHED) + "; none: --learned with no value)")
    ns = p.parse_args(argv)
    cfg = load_config(ns.config)
    params = PlantParams.from_config(cfg)
    protocol = dataclasses.replace(PAPER, episodes=ns.episodes)
    learned = learned_policies(ns.learned, cfg.name)
    policies = (RuleBasedAgents(params), PlannerAgents(params), *(policy for policy, _ in learned))
    records = {policy.name: evaluate(policy, cfg, protocol).records for policy in policies}
    plant = protocol.plant(cfg)
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"{cfg.name}_planner"
    plots.plot_emptying_volume_ecdfs(records, f"{stem}_emptying_volume_ecdfs", config=plant, formats=("png",))
    plots.plot_reward_ecdf(records, f"{stem}_reward_ecdf", formats=("png",))
    for method, recs in records.items():
        plots.plot_episode(window(recs[0], ns.window), f"{stem}_episode_{method}", config=plant, formats=("png",))
        plots.plot_pu_timeline(window(recs[0], ns.window), f"{stem}_pu_timeline_{method}", config=plant,
                               formats=("png",))
    summary = {method: behaviour(recs, PlantParams.from_config(plant), plant.container_names)
               for method, recs in records.items()}
    summary["meta"] = {"config": cfg.name, "episodes": ns.episodes, "window_steps": ns.window,
                       "first_seed": protocol.first_seed, "learned": {p.name: str(path) for p, path in learned}}
    path = Path(ns.json or f"results/planner/behaviour_{cfg.name}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary, indent=1) + "\n")
    plot_behaviour(summary, Path(f"{stem}_behaviour.png"))
    for method in records:
        s = summary[method]
        print(f"{method}: return {s['return_mean']:.2f}, {s['emptyings_per_episode']:.1f} emptyings/episode, "
              f"mean reward {s['mean_reward_per_emptying']:.3f}, early {s['early_share']:.3f}, late "
              f"{s['late_share']:.3f} (early before the last {s['end_game_steps']} steps "
              f"{s['early_share_before_the_end_game']:.3f}; {s['end_game_emptyings_per_episode']:.1f} emptyings "
              f"in them per episode; mean reward of those early ones "
              f"{s['mean_reward_of_early_emptyings_before_the_end_game'] or float('nan'):.3f}), ready and waiting for a PU {s['ready_waiting_for_a_pu_per_episode']:.1f} "
              f"container-steps/episode, all PUs busy {s['all_pus_busy_share_of_steps']:.3f} of steps, "
              f"{s['denied_requests_per_episode']:.1f} denied requests/episode, {s['overflowing_episodes']} "
              f"overflowing episode(s): {s['overflow_causes']}")
        for name, c in s["per_container"].items():
            print(f"   {name:6s} v*={c['target']:5.1f}  n={c['emptyings']:4d}  median {c['median_volume']:5.2f}"
                  f"  early {c['early_share']:.2f}  late {c['late_share']:.2f}"
                  f"  early before the end game {c['early_emptyings_before_the_end_game']}")
    print(f"wrote {stem}_*.png and {path}")


if __name__ == "__main__":
    main()
