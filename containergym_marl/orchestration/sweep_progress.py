"""The sweep's progress in the driver: rows for the sweep and each running run on a terminal, plain
status and event lines otherwise, and the time estimates behind them."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import TextIO

from containergym_marl.progress_bar import Display, format_duration
from containergym_marl.rundir import RunError, measured_rate, run_args

#: Samples per second per CPU assumed for an ETA before any run has reported (PPO, n = 5 or 11, here).
DEFAULT_RATE = 2_000.0


class Progress:
    """The sweep's progress: runs done / running / left, evaluations, ETA, samples/s per running run.

    On a terminal (:class:`containergym_marl.progress_bar.Display`): a row for the sweep (runs done of
    the total, evaluations, the ETA of :meth:`eta_s`) and one per running run (its share of the
    budget, samples/s), redrawn in place, with events (a run finished, resumed, retried, failed)
    printed above them. Otherwise plain lines only: the events, and the status line
    (:meth:`line`) every ``interval_s`` seconds."""

    def __init__(self, budgets: dict[str, int], evaluations: int, cpus: int, stream: TextIO | None = None,
                 interval_s: float = 60.0):
        self.budgets = dict(budgets)  # runs to train in this sweep -> budget
        self.eval_total, self.evals_done = evaluations, 0
        self.cpus = max(cpus, 1)
        self.stream = stream or sys.stdout
        self.interval_s = interval_s
        self.running: dict[str, dict] = {}  # run -> {"samples", "rate", "host"}
        self.done: dict[str, dict] = {}
        self.failed: dict[str, str] = {}
        self.attempts: dict[str, int] = {}
        self.t0 = time.perf_counter()
        self._last_print = -float("inf")
        self.display = Display(self.stream)
        if self.budgets:  # runs a second are meaningless: the sweep's ETA comes from the runs' rates
            self._row = self.display.add("sweep", len(self.budgets), "runs", rate=None, eta_s=None)
        else:
            self._row = self.display.add("sweep", self.eval_total, "evaluations")
        self._run_rows: dict[str, int] = {}  # running run -> its row

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
        if self.display.live:
            self.display.say(f"  {text}")
        else:
            print(f"  {text}", file=self.stream, flush=True)

    def tick(self, force: bool = False) -> None:
        now = time.perf_counter()
        if self.display.live:
            self._draw()
        elif force or now - self._last_print >= self.interval_s:
            print(self.line(), file=self.stream, flush=True)
            self._last_print = now

    def _draw(self) -> None:
        d = self.display
        done, running = len(self.done) + len(self.failed), len(self.running)
        if self.budgets:
            d.update(self._row, done, status=f"evaluations {self.evals_done}/{self.eval_total} · {running} running, "
                                             f"{len(self.budgets) - done - running} queued", eta_s=self.eta_s())
        else:
            d.update(self._row, self.evals_done)
        for name in [n for n in self._run_rows if n not in self.running]:
            d.remove(self._run_rows.pop(name))
        for name, r in sorted(self.running.items()):
            budget = self.budgets.get(name, 0) or 1
            if name in self._run_rows:
                d.update(self._run_rows[name], min(r["samples"], budget), rate=r["rate"])
            else:
                self._run_rows[name] = d.add(name, budget, "samples", r["samples"], status=f"on {r['host']}",
                                             rate=r["rate"])

    def finish(self) -> None:
        if self.display.live:
            self._draw()
        self.display.close()


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
