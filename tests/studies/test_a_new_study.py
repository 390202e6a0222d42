"""A new study is one script: it states its rows, methods and episodes, and the orchestration does
the rest (tasks, caching, evaluation files, table) under the study's own results folder. Nothing in the
package is edited or registered for it: the study, its results folder and its test are the three
places it touches.

The study below is written the way a user would write one (a file of its own, public imports only)
and run as its own process from an empty project folder."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from tests.helpers import ROOT

STUDY = textwrap.dedent('''
    """Does a container decide as well as the central rule? Rule-based agents against the paper's rule,
    on validation episodes (seeds 20000+): a choice, so never on the test seeds."""
    import sys

    from containergym_marl.orchestration import CompareArgs, compare

    compare(CompareArgs(methods=["rule_based", "rule_based_agents"], configs=["n5_m2_dt120"], protocol="validation",
                        episodes=int(sys.argv[1]), out="results/agents_vs_rule", figures="none", num_cpus=1))
''')


@pytest.mark.slow  # a Ray session of its own (20 s idle; about 2 minutes with the other core busy)
def test_a_study_is_one_script_and_writes_only_its_results_folder(tmp_path):
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "agents_vs_rule.py").write_text(STUDY)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "studies/agents_vs_rule.py", "2"], cwd=tmp_path, env=env, check=True,
                   capture_output=True, text=True, timeout=900)

    written = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()}
    outside = {p for p in written if not p.startswith("results/agents_vs_rule/")} - {"studies/agents_vs_rule.py"}
    assert not outside, f"the study wrote outside its results folder: {sorted(outside)}"

    out = tmp_path / "results" / "agents_vs_rule"
    for method in ("rule_based", "rule_based_agents"):
        evaluation = json.loads((out / "evaluations" / "n5_m2_dt120" / f"{method}.json").read_text())
        assert [e["seed"] for e in evaluation["episodes"]] == [20_000, 20_001]  # the validation seeds, not 10000+
    title = (out / "table.md").read_text().splitlines()[0]
    assert title.startswith("Validation cumulative reward (seeds 20000+: δ = 120 s, T = 600, 2 episodes)")
