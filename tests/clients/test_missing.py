"""Without the ``clients`` extra the package still imports, and each entry point for the MARL
libraries raises an ImportError that names the extra to install (run in a subprocess with the
libraries blocked, so this runs in every environment)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HINT = "pip install 'containergym-marl[clients]'"


def test_missing_clients_extra_is_named():
    code = textwrap.dedent("""
        import sys
        for name in ("torch", "torchrl", "tensordict", "benchmarl"):
            sys.modules[name] = None  # makes `import name...` fail
        import containergym_marl
        from containergym_marl.envs import torchrl_env
        from containergym_marl.policies import torchrl_policy
        for make in (lambda: torchrl_env.ContainerAgentsTorchRLEnv("n5_m2_dt120"),
                     lambda: torchrl_policy.TorchRLAgentsPolicy(None),
                     lambda: __import__("containergym_marl.training.benchmarl_task")):
            try:
                make()
            except ImportError as e:
                print(e)
            else:
                print("no error")
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 3
    for line, what in zip(lines, ("ContainerAgentsTorchRLEnv", "TorchRLAgentsPolicy", "benchmarl_task")):
        assert HINT in line and what in line, line
