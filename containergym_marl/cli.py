"""The ``containergym-marl`` command: train and evaluate baselines.

    containergym-marl train --algo ppo --config n5_m2_dt120 --seed 1 --timesteps 2000000
    containergym-marl train --algo shared_ppo --config n5_m2_dt120 --seed 1 --out runs/x --resume
    containergym-marl evaluate runs/ppo_n5_m2_dt120_s1            # the run's best model, paper protocol
    containergym-marl evaluate runs/mappo_n5_m2_dt120_s1          # a MAPPO run (baselines/train_mappo.py)
    containergym-marl evaluate rule_based --config n11_m2_dt120 --episodes 15
    containergym-marl evaluate planner --config n11_m2_dt120      # the rollout planner (planner_agents: per container)
    containergym-marl compare                                   # the main job: the shipped policies, evaluated
    containergym-marl compare --train                           # ... or trained here (--timesteps paper: hours)
    containergym-marl demonstrations --configs n5_m2_dt120 --episodes 10   # datasets of the planner and rules
"""

from __future__ import annotations

import argparse
import sys
import threading
from dataclasses import dataclass

from containergym_marl.config import ConfigError, load_config
from containergym_marl.core.dynamics import ARBITRATION_RULES, DEFAULT_ARBITRATION
from containergym_marl.core.params import PlantParams
from containergym_marl.methods import CONTROLLERS
from containergym_marl.options import add_options, from_namespace, option, positive_int
from containergym_marl.rundir import MODELS


@dataclass
class EvaluateArgs:
    """The options of ``containergym-marl evaluate`` (its ``--episodes`` and ``--json`` also serve
    ``train --evaluate``)."""

    target: str = option(flag="target", help=f"a run directory or one of {', '.join(CONTROLLERS)}")
    config: str | None = option(None, help="plant (default: the run's own, or n5_m2_dt120)")
    episodes: int = option(15, type=positive_int, help="test episodes (default: the paper's 15, seeds 10000 on)")
    model: str = option("best", choices=MODELS,
                        help="a run's model to evaluate: by training return, at the end, or by validation return "
                             "(picked by its sample-efficiency curve)")
    arbitration: str | None = option(None, choices=tuple(ARBITRATION_RULES),
                                     help="how free PUs are shared among a decentralised policy's requests (default: "
                                          "the run's, or fullest)")
    json: str | None = option(None, help="write the evaluation as JSON here")
    no_write: bool = option(False, action="store_true",
                            help="leave the run directory as it is (by default RUN/evaluation_<model>.json is written)")


def _cmd_train(ns: argparse.Namespace) -> int:
    from containergym_marl.training import TrainArgs, train

    args = from_namespace(TrainArgs, ns)
    then = from_namespace(EvaluateArgs, ns, target="")  # checked before training
    run = train(args)
    _print_training_end(run)
    if ns.evaluate:
        return _print_evaluation(_evaluate_target(str(run), args.config, then.episodes, "best"), then.json)
    return 0


def _print_training_end(run) -> None:
    """What the run reached and the command to run next."""
    import shlex

    from containergym_marl.rundir import read_run_summary

    s = read_run_summary(run) or {}
    print(f"run directory: {run}")
    if s.get("train_return_mean100") is not None:
        best = ""
        if s.get("best_model") and s.get("best_train_return") is not None:
            at = f" at {s['best_timesteps']:,} samples" if s.get("best_timesteps") is not None else ""
            best = f"; best {s['best_train_return']:.2f}{at} ({s['best_model']})"
        print(f"training return (mean of the last {min(s['episodes'], 100)} of {s['episodes']} training "
              f"episodes): {s['train_return_mean100']:.2f} after {s['timesteps']:,} samples{best}")
        print(f"next: containergym-marl evaluate {shlex.quote(str(run))}")
    else:
        print(f"note: {s.get('note') or 'no training episode finished'}")
        print(f"next: containergym-marl evaluate {shlex.quote(str(run))} --model final  (or train longer)")


def _episode_bar(total: int):
    """The evaluation's bar on stderr (episodes, episodes/s, ETA, the last episode's return), on a
    terminal only, and the ``on_episode`` that moves it."""
    from containergym_marl.progress_bar import Bar

    bar = Bar("evaluating", total, "episodes")

    def on_episode(done: int, episode) -> None:
        bar.advance_to(done, f"seed {episode.seed}: return {episode.cumulative_reward:.2f}"
                       + (", overflow" if episode.overflow else ""))

    return bar, on_episode


def _evaluate_target(target: str, config: str | None, episodes: int, which: str, arbitration: str | None = None,
                     write: bool = True):
    import warnings
    from pathlib import Path

    from containergym_marl.evaluation import PAPER, EvalProtocol, evaluate

    protocol = EvalProtocol(episodes=episodes) if episodes != PAPER.episodes else PAPER
    if target in CONTROLLERS:
        plant = load_config(config or "n5_m2_dt120")
        policy = CONTROLLERS[target](PlantParams.from_config(plant))
        bar, on_episode = _episode_bar(protocol.episodes)
        with bar:
            return evaluate(policy, plant, protocol, arbitration=arbitration or DEFAULT_ARBITRATION,
                            on_episode=on_episode)
    if Path(target).is_dir():
        from containergym_marl.evaluation.run_policies import evaluate_run
        from containergym_marl.rundir import RunWarning

        try:  # one thread, as training and the sweep's evaluations: a learned policy's networks are too
            import torch  # small to split, and on a busy machine a second thread made each step wait for it

            torch.set_num_threads(1)
        except ImportError:
            pass  # loading the run's model names the extra to install

        bar, on_episode = _episode_bar(protocol.episodes)
        with warnings.catch_warnings(record=True) as caught, bar:
            warnings.simplefilter("always", RunWarning)
            result = evaluate_run(target, config=config, which=which, protocol=protocol, arbitration=arbitration,
                                  write=write, on_episode=on_episode)
        for w in caught:
            if issubclass(w.category, RunWarning):
                print(f"note: {w.message}", file=sys.stderr)
            else:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        return result
    raise SystemExit(
        f"evaluate: {target!r} is neither a run directory nor a built-in policy ({', '.join(CONTROLLERS)})"
    )


def _overflowed(record) -> str:
    """The containers whose overflow ended the episode, each with its volume after the reset."""
    if record is None:
        return ""
    index = {name: i for i, name in enumerate(record.container_names)}
    return ", ".join(f"{name} ({record.volumes[0, index[name]]:.1f})" for name in record.overflowed_containers)


def _print_evaluation(result, json_path: str | None) -> int:
    from containergym_marl.evaluation import metrics
    from containergym_marl.evaluation import table as tables

    s = result.summary()
    shown = metrics.shown_in("cli")
    widths = [max(len(m.short), 6) for m in shown]
    print(f"{result.policy} on {result.config} ({result.view} view), {s['episodes']} episodes, "
          f"delta={result.protocol.timestep_s:g} s, T={result.protocol.episode_length_steps}")
    print(f"{'seed':>6} {'return':>9} " + " ".join(f"{m.short:>{w}}" for m, w in zip(shown, widths))
          + "  overflowed (volume at the start)")
    records = result.records if len(result.records) == len(result.episodes) else [None] * len(result.episodes)
    for e, record in zip(result.episodes, records):
        print(f"{e.seed:>6} {e.cumulative_reward:>9.2f} "
              + " ".join(f"{m.episode_text(e.values[m.name]):>{w}}" for m, w in zip(shown, widths))
              + f"  {_overflowed(record)}".rstrip())
    print(f"cumulative reward {s['return_mean']:.2f} ± {s['return_std']:.2f}; mean over episodes: "
          + ", ".join(f"{m.label} {tables.format_value(s[m.summary], m.fmt)}" for m in shown))
    if json_path:
        from containergym_marl.files import atomic_write_text

        atomic_write_text(json_path, result.to_json())
    return 0


def _cmd_evaluate(ns: argparse.Namespace) -> int:
    a = from_namespace(EvaluateArgs, ns)
    return _print_evaluation(_evaluate_target(a.target, a.config, a.episodes, a.model, a.arbitration,
                                              write=not a.no_write), a.json)


_terminated = threading.Event()


def _raise_terminated(signum, frame):
    """SIGTERM, taken as Ctrl-C: the same orderly stop (runs kept resumable, Ray shut down). The
    signal is remembered in a flag, since libraries on the way up (Ray's waits) re-raise their own
    KeyboardInterrupt."""
    _terminated.set()
    raise KeyboardInterrupt


def _cmd_compare(ns: argparse.Namespace) -> int:
    import signal

    from containergym_marl.orchestration.cluster import SweepError
    from containergym_marl.orchestration.compare import compare
    from containergym_marl.orchestration.compare_args import args_from_namespace

    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        compare(args_from_namespace(ns))
    except SweepError as exc:
        print(f"containergym-marl compare: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 143 if _terminated.is_set() else 130  # 128 + the signal, as a shell reports it
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def _cmd_publish(ns: argparse.Namespace) -> int:
    from containergym_marl.orchestration.publish import PublishArgs, run

    return run(from_namespace(PublishArgs, ns))


def _cmd_demonstrations(ns: argparse.Namespace) -> int:
    from containergym_marl.demonstrations import DemonstrationsArgs, build

    try:  # bad values, a dataset of other episodes, a changed file: ValueErrors, reported by main()
        build(from_namespace(DemonstrationsArgs, ns))
    except KeyboardInterrupt:
        print("containergym-marl demonstrations: interrupted; the finished datasets are kept, and the same command "
              "builds the others", file=sys.stderr)
        return 130
    return 0


def _version() -> str:
    """The installed package's version (its metadata), else the source tree's."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("containergym-marl")
    except PackageNotFoundError:
        from containergym_marl import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    from containergym_marl.training.train_args import TrainArgs

    parser = argparse.ArgumentParser(prog="containergym-marl", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="train a baseline; writes a run directory")
    add_options(t, TrainArgs)
    t.add_argument("--evaluate", action="store_true", help="evaluate the best model when training ends")
    add_options(t, EvaluateArgs, exclude=("target", "config", "model", "arbitration", "no_write"))
    t.set_defaults(func=_cmd_train)

    e = sub.add_parser("evaluate", help="evaluate a run directory or a built-in policy (paper protocol)")
    add_options(e, EvaluateArgs)
    e.set_defaults(func=_cmd_evaluate)

    from containergym_marl.orchestration.compare_args import add_arguments

    c = sub.add_parser("compare", help="evaluate the shipped policies (or train, --train) and compare methods; "
                                       "tables and figures", formatter_class=argparse.RawDescriptionHelpFormatter,
                       description="The benchmark's main job; evaluation and training run on Ray (a local\n"
                                   "instance, or a cluster with --address). With no arguments it trains nothing: it\n"
                                   "evaluates the shipped policies (the best seed of each learned method on each\n"
                                   "paper row with finished runs in results/paper_rows/runs) and the rule-based\n"
                                   "controllers on every paper row with the paper's test protocol, checks them\n"
                                   "against their published evaluations, says how long it took and draws\n"
                                   "the headline figures (--figures all for every figure of every row).\n"
                                   "--train trains instead: 30k samples per run, a quick look far below the\n"
                                   "paper's budget (--timesteps paper for that, hours). Cluster recipe and\n"
                                   "storage: see containergym_marl/orchestration/compare.py.")
    add_arguments(c)
    c.set_defaults(func=_cmd_compare)

    from containergym_marl.orchestration.publish import PublishArgs

    p = sub.add_parser("publish", help="copy a comparison's runs, evaluations, models and table into the repository "
                                       "(or back, --restore)")
    add_options(p, PublishArgs)
    p.set_defaults(func=_cmd_publish)

    from containergym_marl.demonstrations import DemonstrationsArgs

    d = sub.add_parser("demonstrations", help="datasets of the planner's and the rule-based controllers' episodes: "
                                              "Minari (centralised) and NumPy (container agents)",
                       description="Episodes of the rollout planner and the rule-based controllers on the built-in "
                                   "rows (the paper's test plant, seeds 40000 on): a Minari dataset per (row, "
                                   "policy) for the centralised view and a NumPy file for the container agents, "
                                   "labelled with planner_agents' decisions. Finished datasets are reused; an "
                                   "interrupted build resumes. Needs the offline extra.")
    add_options(d, DemonstrationsArgs)
    d.set_defaults(func=_cmd_demonstrations)
    return parser


def main(argv: list[str] | None = None) -> int:
    from containergym_marl.extras import MissingExtraError
    from containergym_marl.rundir import RunError

    ns = build_parser().parse_args(argv)
    try:
        return ns.func(ns)
    except (ConfigError, RunError, MissingExtraError, FileNotFoundError, ValueError) as exc:
        print(f"containergym-marl {ns.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
