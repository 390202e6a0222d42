"""Helpers of the tests that kill a running ``containergym-marl compare`` (test_sweep.py,
test_sweep_slow.py): start it in a process group of its own, find every process it started (Ray's
included), kill them, and check what it left on disk.

Every compare started here carries a marker variable of its own in its environment; the driver and
every Ray process it starts (GCS, raylet, workers: they inherit the environment) hold it, nothing
else on the machine does. Kills target those processes only, never others by name."""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import signal
import subprocess
import sys
import time
import warnings
import zipfile
from pathlib import Path

BIN = Path(sys.executable).parent


def compare_cmd(out: Path, *extra: str) -> list[str]:
    return [str(BIN / "containergym-marl"), "compare", "--train", "--out", str(out), "--episodes", "2", "--n-envs", "1",
            "--bootstrap-reps", "200", *extra]


def wait(predicate, timeout_s: float, what: str, every_s: float = 0.5) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"waited {timeout_s:.0f} s for {what}")
        time.sleep(every_s)


def marked_env(prefix: str = "CONTAINERGYM_KILLS") -> tuple[str, dict]:
    """(marker, environment) for a compare: this process's environment without RAY_ADDRESS (a
    local Ray instance of its own) plus the marker."""
    marker = f"{prefix}_{secrets.token_hex(8)}"
    return marker, {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | {marker: "1"}


def processes_with(marker: str) -> list[int]:
    """Pids of live processes whose environment holds ``marker``."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            with contextlib.suppress(OSError):
                if marker.encode() in (proc / "environ").read_bytes():
                    found.append(int(proc.name))
    return found


def start(out: Path, args: tuple[str, ...], env: dict, log: Path) -> subprocess.Popen:
    """compare in a new session (its own process group, as a command started from a shell)."""
    with log.open("w") as f:
        return subprocess.Popen(compare_cmd(out, *args), stdout=f, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)


def kill_tree(marker: str) -> int:
    """SIGKILL to every process of the compare at once (driver, Ray, workers); returns how many."""
    pids = processes_with(marker)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return len(pids)


def kill_group(proc: subprocess.Popen) -> None:
    """SIGKILL to the compare's process group (``kill -9 -PGID``): the driver and the Ray processes
    it started in its group. Ray's workers run in process groups of their own; they must end by
    themselves once their raylet is gone."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def wait_gone(marker: str, timeout_s: float = 30.0) -> None:
    """Every process of the compare has ended within ``timeout_s`` (no orphaned Ray worker lives on)."""
    wait(lambda: not processes_with(marker), timeout_s,
         f"the compare's processes to end (left: {processes_with(marker)})")


def temporary_files(root: Path) -> list[Path]:
    """Temporary files of writes in progress or cut short under ``root`` (the package writes through
    ``.<name>.<random>.tmp`` files and a rename)."""
    from containergym_marl.files import temporary_target

    return sorted(p for p in root.rglob("*") if p.is_file() and temporary_target(p.name) is not None) \
        if root.is_dir() else []


def check_intact(root: Path) -> None:
    """What a later compare may read under ``root`` (its --out, with the runs) is whole: every JSON
    parses (tables, evaluations, sweep.json, args, run summaries, checkpoint progress), every zip
    (models, checkpoints) is intact, table.csv parses, every row of metrics.csv that read_metrics
    returns is complete, config.toml parses. A file being written exists only as a temporary file
    with a hidden name that no reader takes (asserted: every file is a known kind, or such a
    temporary file). Logs, pid and lock files and TensorBoard event files are not read back."""
    import csv
    import tomllib

    from containergym_marl.files import temporary_target
    from containergym_marl.rundir import METRIC_FIELDS, read_metrics, RunWarning

    for path in root.rglob("*") if root.is_dir() else []:
        if not path.is_file() or "tb" in path.relative_to(root).parts:
            continue
        name = path.name
        if temporary_target(name) is not None:
            assert name.startswith(".") and name.endswith(".tmp"), path  # hidden from every reader's pattern
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".zip":
            with zipfile.ZipFile(path) as z:
                assert z.testzip() is None, path
        elif name == "metrics.csv":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RunWarning)  # a partial last row (a kill mid-append) is skipped
                rows = read_metrics(path.parent)
            assert all(set(METRIC_FIELDS) <= set(r) and r["timesteps"] > 0 for r in rows), path
        elif name == "table.csv":
            with path.open() as f:
                assert list(csv.DictReader(f)), path
        elif name == "config.toml":
            tomllib.loads(path.read_text())
        else:
            # a checkpoint a resume found broken is set aside as *.broken, never read again
            assert name in (".lock", "table.md") or path.suffix in (".log", ".pid", ".broken"), \
                f"unexpected file {path}"
