"""The compiled step is loaded from numba's disk cache by every process after the first.

Each rule's kernel used to be a closure over the rule's priority function; numba's cache key holds
the pickled free variables, and a dispatcher pickles with an identity new in every process, so no
process found the kernels an earlier one had cached: each compiled every rule it used again (about
a second each) and added a cache file. Here a first process fills an empty, private
``NUMBA_CACHE_DIR``; a second one, doing the same, must load every kernel and write nothing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from containergym_marl.config import load_config
from containergym_marl.core import dynamics
from containergym_marl.core.params import PlantParams

ROOT = Path(__file__).resolve().parents[2]
BUILT_IN = ("fullest", "random", "index", "best_reward")

#: Imports the package, steps every built-in rule once, prints {rule: [cache hits, cache misses]}
#: of the rule's kernel.
CHILD = """
import json, sys
import numpy as np
from containergym_marl.config import load_config
from containergym_marl.config import load_config
from containergym_marl.core import dynamics
from containergym_marl.core.params import PlantParams
from containergym_marl.core.params import PlantParams

params = PlantParams.from_config(load_config("n5_m2_dt120"))
rng = np.random.default_rng(0)
state = dynamics.reset_state(params, rng.random((4, 5)))
stats = {}
for rule in sys.argv[1:]:
    dynamics.step(state, rng.random((4, 5)) < 0.5, params, rng.standard_normal((4, 5)), rng.random((4, 5)),
                  arbitration=rule)
    s = dynamics.get_rule(rule).step_batch.stats
    stats[rule] = [sum(s.cache_hits.values()), sum(s.cache_misses.values())]
print(json.dumps(stats))
"""


def cache_files(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_mtime_ns for p in folder.rglob("*") if p.is_file()}


@pytest.mark.skipif(numba.config.DISABLE_JIT, reason="NUMBA_DISABLE_JIT: nothing is compiled or cached")
@pytest.mark.slow  # compiles every rule in a fresh cache, ~20 s
def test_second_process_loads_every_rule_from_the_cache(tmp_path):
    assert set(BUILT_IN) <= set(dynamics.ARBITRATION_RULES)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(ROOT)}

    def run() -> dict[str, list[int]]:
        done = subprocess.run([sys.executable, "-c", CHILD, *BUILT_IN], cwd=ROOT, env=env, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout.splitlines()[-1])

    first = run()
    assert first == {rule: [0, 1] for rule in BUILT_IN}  # an empty cache: each rule compiled once
    written = cache_files(tmp_path)
    assert written
    second = run()
    assert second == {rule: [1, 0] for rule in BUILT_IN}, "a warm process compiled a rule's kernel again"
    assert cache_files(tmp_path) == written, "a warm process wrote to the cache"


def test_rules_of_other_modules_are_compiled_but_not_cached(monkeypatch):
    """A kernel cached for a rule defined outside dynamics.py would outlive changes to the rule (numba
    keys the cache by dynamics.py), so such rules are compiled in each process and never cached."""
    monkeypatch.setattr(dynamics, "ARBITRATION_RULES", dict(dynamics.ARBITRATION_RULES))

    @dynamics.arbitration_rule("test_emptiest")
    def emptiest_first(i, volume, uniform, params):
        """The emptiest container first."""
        return -volume

    rule = dynamics.get_rule("test_emptiest")
    assert rule.description == "The emptiest container first."
    assert rule.step_batch.stats.cache_path is None  # numba's NullCache
    assert all(dynamics.get_rule(name).step_batch.stats.cache_path for name in BUILT_IN)
    params = PlantParams.from_config(load_config("n5_m2_dt120"))
    state = dynamics.PlantState(np.array([[10.0, 5.0, 20.0, 1.0, 3.0]]), np.zeros((1, params.n_pus)),
                                np.zeros(1, dtype=np.int64))
    _, outcome = dynamics.step(state, np.ones((1, 5), bool), params, np.zeros((1, 5)), np.zeros((1, 5)),
                               arbitration="test_emptiest")
    assert outcome.granted[0].tolist() == [False, False, False, True, True]  # the two emptiest, two PUs
