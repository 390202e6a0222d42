"""What the tests share besides fixtures (those are in conftest.py): the repository's root, the
configurations the tests use most, a script imported by path, a plant state from plain lists."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from containergym_marl.core import PlantState

ROOT = Path(__file__).resolve().parents[1]
#: The smallest of the paper's rows (5 containers, 2 PUs, δ = 120 s): the tests' default plant.
CFG = "n5_m2_dt120"


def load_script(relative_path: str):
    """A script of the repository (``baselines/…``, ``benchmarks/…``) imported as a module named after
    its file, registered in sys.modules (dataclasses look their module up there)."""
    path = ROOT / relative_path
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


PAPER_CONFIGS = (
    "n5_m2_dt60",
    "n5_m2_dt120",
    "n5_m5_dt60",
    "n5_m5_dt120",
    "n11_m2_dt60",
    "n11_m2_dt120",
    "n11_m11_dt60",
    "n11_m11_dt120",
)


def make_state(volumes, timers, step_count=0) -> PlantState:
    """A one-simulation state from plain lists."""
    v = np.atleast_2d(np.asarray(volumes, dtype=np.float64))
    p = np.atleast_2d(np.asarray(timers, dtype=np.float64))
    return PlantState(v, p, np.full(v.shape[0], step_count, dtype=np.int64))


def train_until_killed(train_argv: list[str], run: Path, checkpoints_wanted: int, timeout_s: float = 120) -> None:
    """``containergym-marl train ARGV`` in a subprocess, killed with SIGKILL (no clean-up of any
    kind) once ``run`` holds ``checkpoints_wanted`` checkpoints; fails if it ended before."""
    import signal
    import subprocess
    import time

    from containergym_marl.rundir import checkpoints

    proc = subprocess.Popen([sys.executable, "-m", "containergym_marl.cli", "train", *train_argv], cwd=ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + timeout_s
    while time.time() < deadline and len(checkpoints(run)) < checkpoints_wanted and proc.poll() is None:
        time.sleep(0.1)
    assert proc.poll() is None, proc.stderr.read().decode()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stderr.close()


def sigterm_leaves_no_child(argv: list[str], is_child, count: int, timeout_s: float = 120) -> None:
    """Run the script ``argv`` (``python`` + argv), wait until it has ``count`` descendants for which
    ``is_child(cmdline)`` holds, send it SIGTERM, and check that it exits as on Ctrl-C (128 + 15) with
    none of them left running. Whatever fails, no process is left behind."""
    import signal
    import subprocess
    import time

    import psutil

    proc = subprocess.Popen([sys.executable, *argv], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    main, children, deadline = psutil.Process(proc.pid), [], time.monotonic() + timeout_s
    try:
        while len(children) < count and time.monotonic() < deadline and proc.poll() is None:
            children = [c for c in main.children(recursive=True) if is_child(" ".join(c.cmdline()))]
            time.sleep(0.2)
        assert len(children) == count, f"the script did not start its {count} processes"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM
        _, alive = psutil.wait_procs(children, timeout=5)
        assert not alive, f"processes outlived the script: {[p.pid for p in alive]}"
    finally:
        for child in children:
            if child.is_running():
                child.kill()
        proc.kill()
