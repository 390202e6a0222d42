"""The sweep's progress in the driver: the live line (runs done / running / queued, evaluations,
ETA, samples/s of every running run) and the time estimates behind it."""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path
from typing import TextIO

from containergym_marl.rundir import RunError, measured_rate, run_args

#: Samples per second per CPU assumed for an ETA before any run has reported (PPO, n = 5 or 11, here).
DEFAULT_RATE = 2_000.0


def format_duration(seconds: float | None) -> str:
    if seconds is None or seconds != seconds or seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class Progress:
    """The sweep's live line: runs done / running / left, evaluations, ETA, samples/s per running run.

    On a terminal the line is redrawn in place every second; otherwise it is printed every
    ``interval_s`` seconds. Events (a run finished, resumed, retried, failed) are printed as lines."""

    def __init__(self, budgets: dict[str, int], evaluations: int, cpus: int, stream: TextIO | None = None,
                 interval_s: float = 60.0):
        self.budgets = dict(budgets)  # runs to train in this sweep -> budget
        self.eval_total, self.evals_done = evaluations, 0
        self.cpus = max(cpus, 1)
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval_s = interval_s
        self.running: dict[str, dict] = {}  # run -> {"samples", "rate", "host"}
        self.done: dict[str, dict] = {}
        self.failed: dict[str, str] = {}
        self.attempts: dict[str, int] = {}
        self.t0 = time.perf_counter()
        self._last_print = -float("inf")
        self._width = 0

    # events
    def started(self, name: str, host: str, pid: int, state: str, start: int) -> None:
        self.attempts[name] = self.attempts.get(name, 0) + 1
        if self.attempts[name] > 1:
            self.say(f"retry {name} (attempt {self.attempts[name]}, {state} from {start:,} samples) on {host}")
        elif state == "resume":
            self.say(f"resume {name} from its checkpoint at {start:,} samples")
        self.running[name] = {"samples": start, "rate": None, "host": host, "start": start}

    def sampled(self, name: str, samples: int, rate: float | None) -> None:
        if name in self.running:
            self.running[name].update(samples=samples, rate=rate)

    def run_done(self, name: str, result: dict) -> None:
        self.running.pop(name, None)
        self.done[name] = result
        rate = result.get("samples_per_s")
        how = {"finished": "already finished", "resume": f"resumed from {result['resumed_from']:,}",
               "new": "trained"}[result["state"]]
        self.say(f"done {name}: {how}, {result['samples']:,} samples in {format_duration(result['wall_s'])}"
                 + (f" ({rate:,.0f} samples/s)" if rate else "") + f" on {result['host']}")

    def run_failed(self, name: str, error: str) -> None:
        self.running.pop(name, None)
        self.failed[name] = error
        self.say(f"FAILED {name}: {error}")

    def eval_done(self) -> None:
        self.evals_done += 1

    # rendering
    def rate_per_run(self) -> float | None:
        rates = [r["rate"] for r in self.running.values() if r.get("rate")]
        rates += [d["samples_per_s"] for d in self.done.values() if d.get("samples_per_s")]
        return sum(rates) / len(rates) if rates else None

    def eta_s(self) -> float | None:
        left = [n for n in self.budgets if n not in self.done and n not in self.failed]
        if not left:
            return 0.0
        rate = self.rate_per_run()
        if rate is None:
            return None
        samples = sum(self.budgets[n] - self.running.get(n, {}).get("samples", 0) for n in left)
        return samples / (rate * min(self.cpus, len(left)))

    def line(self) -> str:
        total = len(self.budgets)
        done, running = len(self.done) + len(self.failed), len(self.running)
        parts = [f"[{format_duration(time.perf_counter() - self.t0)}]"]
        if total:
            parts += [f"runs {done}/{total} done, {running} running, {total - done - running} queued"]
        parts += [f"evaluations {self.evals_done}/{self.eval_total}"]
        if total:
            parts += [f"ETA {format_duration(self.eta_s())}"]
        for name, r in sorted(self.running.items()):
            budget = self.budgets.get(name, 0) or 1
            rate = f" {r['rate']:,.0f}/s" if r.get("rate") else ""
            parts.append(f"{name} {100 * r['samples'] / budget:.0f}%{rate}")
        return parts[0] + " " + " · ".join(parts[1:])

    def say(self, text: str) -> None:
        self._clear()
        print(f"  {text}", file=self.stream, flush=True)

    def _clear(self) -> None:
        if self.tty and self._width:
            print("\r" + " " * self._width + "\r", end="", file=self.stream, flush=True)
            self._width = 0

    def tick(self, force: bool = False) -> None:
        now = time.perf_counter()
        if self.tty:
            cols = shutil.get_terminal_size((120, 20)).columns
            text = self.line()[: cols - 1]
            self._clear()
            print(text, end="", file=self.stream, flush=True)
            self._width = len(text)
        elif force or now - self._last_print >= self.interval_s:
            print(self.line(), file=self.stream, flush=True)
            self._last_print = now

    def finish(self) -> None:
        self._clear()
        if not self.tty:
            return
        print(self.line(), file=self.stream, flush=True)



def estimate_rate(runs_root: str | Path) -> float:
    """Samples/s per run measured by earlier SB3 runs under ``runs_root`` (median), else
    :data:`DEFAULT_RATE`. Runs that compare does not train (MAPPO's, which count plant steps at a
    tenth of the rate) share the folder but say nothing about the sweep's runs."""
    from containergym_marl.algorithms import ALGORITHMS

    def sweep_run(run: Path) -> bool:
        try:
            return run_args(run).get("algo") in ALGORITHMS
        except (FileNotFoundError, RunError, AttributeError):
            return False

    rates = sorted(r for p in Path(runs_root).glob("*/metrics.csv")
                   if sweep_run(p.parent) and (r := measured_rate(p.parent)))
    return rates[len(rates) // 2] if rates else DEFAULT_RATE
