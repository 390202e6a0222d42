"""Shared test helpers."""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from containergym_marl import load_config
from containergym_marl.core import PlantState

ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    """Ray's session folders (logs, sockets) of every instance the tests start, local or by
    ``ray start``, go to one temporary folder that the run removes at its end (Ray leaves them in
    /tmp/ray otherwise). Short, since Ray's socket paths must stay under 107 characters."""
    if "RAY_TMPDIR" not in os.environ:
        os.environ["RAY_TMPDIR"] = config._containergym_ray_tmp = tempfile.mkdtemp(prefix="cgm-ray-")


def pytest_unconfigure(config):
    folder = getattr(config, "_containergym_ray_tmp", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        del os.environ["RAY_TMPDIR"]


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


@pytest.fixture
def cfg5():
    return load_config("n5_m2_dt120")


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_pytest_folder(tmp_path_factory):
    """Tests that call SB3's ``learn`` directly (not through the package's training loop, which sets
    its own logger) would each leave an empty ``SB3-<date>`` folder in the system temp directory:
    SB3 creates one when no logger is configured, unless $SB3_LOGDIR names a folder."""
    import os

    previous = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3_logs"))
    yield
    if previous is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = previous
