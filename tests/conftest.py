"""Fixtures shared by every test; plain helpers are in tests/helpers.py."""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest

from containergym_marl import load_config

from tests.helpers import CFG

def pytest_configure(config):
    """Ray's session folders (logs, sockets) of every instance the tests start, local or by
    ``ray start``, go to one temporary folder that the run removes at its end (Ray leaves them in
    /tmp/ray otherwise). Short, since Ray's socket paths must stay under 107 characters."""
    if "RAY_TMPDIR" not in os.environ:
        os.environ["RAY_TMPDIR"] = config._containergym_ray_tmp = tempfile.mkdtemp(prefix="cgm-ray-")
    # One OpenMP thread for torch in this process and the ones it starts (set before torch is imported),
    # as every run and evaluation task of the package uses: the tests' networks are far too small to
    # split, and with the other core busy a second thread made each small SB3 forward wait for it
    # (7 ms instead of 1: an evaluation of 4 episodes took 91 s instead of 12).
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_unconfigure(config):
    folder = getattr(config, "_containergym_ray_tmp", None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
        del os.environ["RAY_TMPDIR"]


@pytest.fixture
def cfg5():
    return load_config(CFG)


@pytest.fixture(autouse=True, scope="session")
def _sb3_logs_in_a_pytest_folder(tmp_path_factory):
    """Tests that call SB3's ``learn`` directly (not through the package's training loop, which sets
    its own logger) would each leave an empty ``SB3-<date>`` folder in the system temp directory:
    SB3 creates one when no logger is configured, unless $SB3_LOGDIR names a folder."""
    previous = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3_logs"))
    yield
    if previous is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = previous
