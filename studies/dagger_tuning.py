"""Choosing the imitation's settings on validation episodes: ``dagger_agents``', the PPO fine-tuning of
``dagger_ppo_agents`` (issue 27), and the learners aimed at the contended rows (issue 38:
``dagger_response_agents``, ``dagger_contended_agents``, ``dagger_dapg_agents``, ``dagger_checked_agents``,
``dagger_messaging_agents``).

    python studies/dagger_tuning.py                       # the variants below, n11_m2 at δ = 60 and 120, seeds 1-2
    python studies/dagger_tuning.py --variants greedy --rows n11_m2_dt60 --seeds 1 --workers 1
    python studies/dagger_tuning.py --smoke               # two variants, one row, 20k samples, 2 episodes

Trains each variant's method once per (variant, row, seed) at the row's own training settings and the
paper's budget (5M agent samples at n = 11), each run in a process of its own on one core (torch one
thread), ``--workers`` at a time, then evaluates every run's best and final model on the
*validation* episodes (δ = 120 s, T = 600, seeds 20000–20029: disjoint from the test seeds
10000–10014 and the fresh seeds 30000+ on which the published results are reported). Writes
``--out``/tuning.json after every evaluation and ``--out``/tuning.md: per variant and row, the mean
validation return over seeds and the overflowing episodes, of the best and of the final model.

Resumable: finished runs and evaluations already in tuning.json are reused, an interrupted run
resumes from its newest checkpoint (``train --resume``). ``--deadline-s`` stops the training
processes at that many seconds after the start (their checkpoints stay); a run stopped before its
budget has no final model, and its best model so far is evaluated, with the samples it trained
recorded (``trained_samples``, from its metrics.csv), so a bounded machine still returns a comparison.
Once such a run has been resumed to its end, that evaluation is dropped and the finished run evaluated.

Each variant (:data:`VARIANTS`) names its method, its ``--hp`` settings of
:class:`containergym_marl.training.dagger.DAggerArgs` (the others stay at their defaults) and, for
``dagger_ppo_agents``, the fine-tuning's ``--reward-mode``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from containergym_marl.files import atomic_write_text
from containergym_marl.orchestration.stopping import exit_on_sigterm, worker_pool
from containergym_marl.rundir import read_metrics, run_name, run_status


@dataclass(frozen=True)
class Variant:
    """What one variant trains: the method, its ``--hp`` settings (KEY=VALUE strings, as the CLI
    takes them) and, for ``dagger_ppo_agents``, the fine-tuning's ``--reward-mode`` (None: the default)."""

    hp: tuple[str, ...]
    method: str = "dagger_agents"
    reward_mode: str | None = None

    def train_args(self) -> list[str]:
        """The variant's part of the ``containergym-marl train`` command."""
        args = ["--algo", self.method]
        if self.reward_mode is not None:
            args += ["--reward-mode", self.reward_mode]
        return args + (["--hp", *self.hp] if self.hp else [])

    def settings(self) -> str:
        """The variant as the table shows it."""
        words = [] if self.method == "dagger_agents" else [self.method]
        words += [f"--reward-mode {self.reward_mode}"] if self.reward_mode else []
        return " ".join(words + list(self.hp)) or "(defaults)"


#: the reference's labels, the agents' own check and a request threshold of 0.3: dagger_checked_agents' settings
CHECKED = ("greedy=true", "safety_risk=1e-6", "own_check_risk=1e-4", "own_check_lead_steps=1", "request_threshold=0.3")
CHECKED_LEAD_2 = tuple("own_check_lead_steps=2" if hp.startswith("own_check_lead_steps=") else hp for hp in CHECKED)
#: variant name -> what it trains
VARIANTS: dict[str, Variant] = {
    "sampled": Variant(("greedy=false",)),
    "greedy": Variant(("greedy=true",)),
    "all_data": Variant(("greedy=false", "dataset_size=6000000")),
    "greedy_all_data": Variant(("greedy=true", "dataset_size=6000000")),
    "greedy_all_data_wide": Variant(("greedy=true", "dataset_size=6000000", "hidden=128,128")),
    "greedy_all_data_k32": Variant(("greedy=true", "dataset_size=6000000", "futures=32")),
    "greedy_anneal": Variant(("greedy=true", "anneal_lr=true")),
    "greedy_request_weight_4": Variant(("greedy=true", "request_weight=4")),
    # each agent labelled by its best response to the others' requests as the learner made them (issue 38)
    "greedy_response": Variant(("greedy=true",), "dagger_response_agents"),
    # the reference's labels: the labelling planner with planner_agents_shielded's deadline check
    "greedy_shielded": Variant(("greedy=true", "safety_risk=1e-6")),
    # the student's own deadline check (ε = 1e-4, a lead of one fill), in collection and evaluation, with the
    # planner's labels and with the reference's
    "greedy_own_1": Variant(("greedy=true", "own_check_risk=1e-4", "own_check_lead_steps=1")),
    "greedy_shielded_own_1": Variant(("greedy=true", "safety_risk=1e-6", "own_check_risk=1e-4",
                                      "own_check_lead_steps=1")),
    # a request wherever the student's probability of one is above 0.3 rather than 0.5 (its most likely action), in
    # collection and evaluation (studies/request_threshold.py: the published imitations gain so on the contended rows)
    "greedy_threshold_0.3": Variant(("greedy=true", "request_threshold=0.3")),
    "greedy_shielded_own_1_threshold_0.3": Variant(CHECKED),
    "greedy_own_1_threshold_0.3": Variant(("greedy=true", "own_check_risk=1e-4", "own_check_lead_steps=1",
                                           "request_threshold=0.3")),
    # the contended states (more containers due than free PUs) a quarter or half of every minibatch
    "greedy_contended_0.25": Variant(("greedy=true", "contended_share=0.25"), "dagger_contended_agents"),
    "greedy_contended_0.5": Variant(("greedy=true", "contended_share=0.5"), "dagger_contended_agents"),
    # dagger_checked_agents' settings with the contended states half of every minibatch, or with the labelling
    # planner's futures doubled (n16_m2_dt120, where its agents' requests are still denied before an overflow)
    "checked_contended_0.5": Variant((*CHECKED, "contended_share=0.5")),
    "checked_k32": Variant((*CHECKED, "futures=32")),
    # dagger_checked_agents' settings on n11_m2_dt60 (its own check two steps ahead), and the same with the labelling
    # planner's look-ahead as long in plant time as H = 8 at the evaluation's δ = 120 s: 16 steps of 60 s
    "checked_lead_2": Variant(CHECKED_LEAD_2),
    "checked_lead_2_h16": Variant((*CHECKED_LEAD_2, "horizon=16")),
    # dagger_messaging_agents (the reference's labels, the agents' own check and the shared check), and the same
    # imitating planner_agents (K = 16, H = 8, no deadline check): the shared check alone keeps its students from
    # the overflows the cheap planner's labels allow?
    "messaging": Variant((), "dagger_messaging_agents"),
    "messaging_planner_labels": Variant(("safety_risk=0",), "dagger_messaging_agents"),
    # the same taught by a costlier teacher (64 futures: planner_agents' labels with less noise), and by it with a
    # wider student: can a student that pays none of the labelling at decision time pass the cheap planner?
    "messaging_planner_labels_k64": Variant(("safety_risk=0", "futures=64"), "dagger_messaging_agents"),
    "messaging_planner_labels_k64_wide": Variant(("safety_risk=0", "futures=64", "hidden=128,128"),
                                                 "dagger_messaging_agents"),
    # the wider student of the cheap teacher, at the paper's budget and (--timesteps) at four times it: is the gap
    # to the planner a matter of samples?
    "messaging_planner_labels_wide": Variant(("safety_risk=0", "hidden=128,128"), "dagger_messaging_agents"),
    # the fine-tuning with a decaying behaviour-cloning term (DAPG), at two starting weights
    "dapg_0.5": Variant(("imitation_share=0.5", "bc_coef=0.5", "bc_half_life=0.2"), "dagger_dapg_agents", "team"),
    "dapg_2": Variant(("imitation_share=0.5", "bc_coef=2", "bc_half_life=0.2"), "dagger_dapg_agents", "team"),
    # the PPO fine-tuning of dagger_ppo_agents, every setting named so that a variant keeps its meaning when
    # the defaults change: each agent its own container's reward or the plant's (the planner's objective),
    # a fifth of the budget imitated or half (ppo_team_share_0.5 is dagger_ppo_agents' default), PPO's step size
    "ppo_individual": Variant(("imitation_share=0.2",), "dagger_ppo_agents", "individual"),
    "ppo_team": Variant(("imitation_share=0.2",), "dagger_ppo_agents", "team"),
    "ppo_individual_share_0.5": Variant(("imitation_share=0.5",), "dagger_ppo_agents", "individual"),
    "ppo_team_share_0.5": Variant(("imitation_share=0.5",), "dagger_ppo_agents", "team"),
    # the default with a third of PPO's step size: does a gentler fine-tuning keep more of the imitation?
    "ppo_team_share_0.5_lr_1e-4": Variant(("imitation_share=0.5", "ppo_learning_rate=1e-4"), "dagger_ppo_agents", "team"),
}
ROWS = ("n11_m2_dt60", "n11_m2_dt120")


def run_dir(runs: Path, variant: str, row: str, seed: int) -> Path:
    return runs / variant / run_name(VARIANTS[variant].method, row, seed)


def train_all(jobs, workers: int):
    """``containergym-marl train`` of each job (variant, row, seed, runs, timesteps, deadline) in a child
    process, ``workers`` at a time, killed at the deadline; yields (variant, row, seed, exit code) as each
    ends. However this ends (run as a script, a SIGTERM exits as Ctrl-C does), the children still running
    are stopped first (SIGTERM: their checkpoints stay, ``--resume`` continues them): none outlives the
    study to hold its run folder's lock when the study runs again."""
    pending, running = list(jobs), {}
    try:
        while pending or running:
            while pending and len(running) < max(workers, 1):
                variant, row, seed, runs, timesteps, deadline = job = pending.pop(0)
                out = run_dir(Path(runs), variant, row, seed)
                cmd = [sys.executable, "-m", "containergym_marl.cli", "train", *VARIANTS[variant].train_args(),
                       "--config", row, "--seed", str(seed), "--out", str(out), "--no-progress", "--torch-threads", "1"]
                if timesteps is not None:
                    cmd += ["--timesteps", str(timesteps)]
                if out.exists():
                    cmd.append("--resume")
                out.parent.mkdir(parents=True, exist_ok=True)
                log = open(out.parent / f"{out.name}.log", "a")
                running[job] = (subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), log, deadline)
            time.sleep(0.2)
            for job, (proc, log, deadline) in list(running.items()):
                code = proc.poll()
                if code is None and deadline is not None and time.time() > deadline:
                    proc.kill()
                    proc.wait()
                    code = -9
                if code is not None:
                    log.close()
                    del running[job]
                    yield (*job[:3], code)
    finally:
        for proc, _, _ in running.values():
            proc.terminate()
        for proc, log, _ in running.values():
            proc.wait()
            log.close()


def evaluate_one(job: tuple[str, str, int, str, str, int]) -> dict:
    """A run's model on the validation episodes."""
    import torch

    from containergym_marl.evaluation.protocol import VALIDATION, EvalProtocol
    from containergym_marl.evaluation.run_policies import evaluate_run

    torch.set_num_threads(1)
    variant, row, seed, runs, which, episodes = job
    protocol = EvalProtocol(episodes=episodes, first_seed=VALIDATION.first_seed)
    result = evaluate_run(run_dir(Path(runs), variant, row, seed), which=which, protocol=protocol, write=False)
    returns = result.returns
    run = run_dir(Path(runs), variant, row, seed)
    return {"variant": variant, "row": row, "seed": seed, "model": which, "finished": finished(run),
            "trained_samples": trained_samples(run), "episodes": len(returns),
            "first_seed": protocol.first_seed, "return_mean": float(returns.mean()), "return_std": float(returns.std()),
            "overflowing_episodes": int(sum(e.overflow for e in result.episodes)), "returns": returns.tolist()}


def without_stale(entries: list[dict], runs: Path) -> list[dict]:
    """The evaluations still standing: one made before its run finished (its best model so far, after a
    deadline or a kill) is dropped once the run has finished, so that the finished run is evaluated."""
    return [e for e in entries if e.get("finished", True) or not finished(run_dir(runs, e["variant"], e["row"], e["seed"]))]


def finished(run: Path) -> bool:
    return run_status(run) == "finished"


def evaluable(run: Path, which: str) -> bool:
    """A finished run's models; an unfinished run's best model so far."""
    return finished(run) or (which == "best" and (run / "best_model.pt").is_file())


def trained_samples(run: Path) -> int:
    """A finished run's samples (run.json); an unfinished run's newest metrics row (its training so far)."""
    if finished(run):
        return int(json.loads((run / "run.json").read_text())["timesteps"])
    rows = read_metrics(run, quiet=True)
    return int(rows[-1]["timesteps"]) if rows else 0


def table(entries: list[dict], variants: list[str], rows: list[str], note: str = "") -> str:
    lines = ["# The imitation's settings on validation episodes", "",
             "Mean validation return over training seeds (each seed: the mean of its episodes, δ = 120 s, "
             "T = 600, seeds 20000+), and overflowing episodes over all seeds' episodes, of each run's best "
             "and final model; samples: the training of the runs (fewer than the budget where a run was "
             "stopped before it: then only its best model so far exists). Settings: the method "
             "(`dagger_agents` unless named), `--reward-mode` and `--hp` of "
             "`containergym_marl.training.dagger.DAggerArgs`.", "",
             "| variant | settings | row | seeds | samples | best: return | best: overflows | final: return | final: overflows |",
             "|---|---|---|---|---|---|---|---|---|"]
    if note:
        lines[3:3] = ["Where the runs were trained: " + note, ""]
    for variant in variants:
        for row in rows:
            cells = []
            seeds, samples = 0, []
            for which in ("best", "final"):
                found = [e for e in entries if (e["variant"], e["row"], e["model"]) == (variant, row, which)]
                seeds = max(seeds, len(found))
                samples += [e["trained_samples"] for e in found]
                if found:
                    means = np.array([e["return_mean"] for e in found])
                    cells += [f"{means.mean():.2f} (min {means.min():.2f})",
                              f"{sum(e['overflowing_episodes'] for e in found)}/{sum(e['episodes'] for e in found)}"]
                else:
                    cells += ["–", "–"]
            if not seeds:  # a variant not run on this row
                continue
            settings = VARIANTS[variant].settings()
            span = f"{min(samples) / 1e6:.1f}–{max(samples) / 1e6:.1f}M" if samples else "–"
            lines.append(f"| {variant} | {settings} | {row} | {seeds} | {span} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--rows", nargs="+", default=list(ROWS))
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    p.add_argument("--timesteps", type=int, default=None, help="training budget (default: the paper's of each row)")
    p.add_argument("--episodes", type=int, default=30, help="validation episodes (seeds 20000 on)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    p.add_argument("--deadline-s", type=float, default=None, help="stop training this many seconds after the start")
    p.add_argument("--runs", default="runs/dagger_tuning")
    p.add_argument("--out", default="results/dagger_tuning")
    p.add_argument("--no-train", action="store_true", help="only evaluate the runs there are")
    p.add_argument("--note", default=None, help="where and how the runs were trained (kept in tuning.json, shown in tuning.md)")
    p.add_argument("--smoke", action="store_true", help="two variants, one row, one seed, 20k samples, 2 episodes")
    ns = p.parse_args(argv)
    if ns.smoke:
        ns.variants, ns.rows, ns.seeds, ns.timesteps, ns.episodes = ["sampled", "greedy"], ["n5_m2_dt120"], [1], 20_000, 2
        ns.runs = ns.runs if ns.runs != p.get_default("runs") else "runs/dagger_tuning_smoke/runs"
        ns.out = ns.out if ns.out != p.get_default("out") else "runs/dagger_tuning_smoke/results"
    runs, out = Path(ns.runs), Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    deadline = None if ns.deadline_s is None else time.time() + ns.deadline_s
    jobs = [(v, r, s, str(runs), ns.timesteps, deadline) for v in ns.variants for r in ns.rows for s in ns.seeds
            if not ns.no_train and not finished(run_dir(runs, v, r, s))]
    for variant, row, seed, code in train_all(jobs, ns.workers):
        print(f"train {variant} {row} s{seed}: exit {code}", flush=True)
    path = out / "tuning.json"
    saved = json.loads(path.read_text()) if path.is_file() else {}
    entries = without_stale(saved.get("evaluations", []), runs)
    note = ns.note if ns.note is not None else saved.get("note", "")
    done = {(e["variant"], e["row"], e["seed"], e["model"], e["episodes"]) for e in entries}
    evals = [(v, r, s, str(runs), w, ns.episodes) for v in ns.variants for r in ns.rows for s in ns.seeds
             for w in ("best", "final") if evaluable(run_dir(runs, v, r, s), w) and (v, r, s, w, ns.episodes) not in done]
    with worker_pool(ns.workers) as pool:
        for entry in pool.map(evaluate_one, evals):
            entries.append(entry)
            print(f"{entry['variant']:22s} {entry['row']:13s} s{entry['seed']} {entry['model']:5s} "
                  f"{entry['return_mean']:7.2f} ± {entry['return_std']:5.2f}  overflows {entry['overflowing_episodes']}",
                  flush=True)
            save(path, ns.variants, entries, note)
    save(path, ns.variants, entries, note)
    # the table shows every evaluation on record, also of variants, rows and seeds not asked for this time
    variants = [v for v in VARIANTS if any(e["variant"] == v for e in entries)]
    rows = list(dict.fromkeys([*ns.rows, *(e["row"] for e in entries)]))
    atomic_write_text(out / "tuning.md", table(entries, variants, rows, note))
    print(table(entries, variants, rows, note))


def save(path: Path, variants: list[str], entries: list[dict], note: str) -> None:
    variants = [v for v in VARIANTS if v in variants or any(e["variant"] == v for e in entries)]
    atomic_write_text(path, json.dumps({"variants": {v: dataclasses.asdict(VARIANTS[v]) for v in variants}, "note": note,
                                        "evaluations": entries}, indent=1) + "\n")



if __name__ == "__main__":
    exit_on_sigterm()  # stopped by SIGTERM, the finally clauses stop the child processes first
    main()
