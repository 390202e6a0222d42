"""The README's "With your MARL library" snippets run as written, each in a fresh folder.

Each snippet is a ```python block of that section whose first line names its library
(``# TorchRL: …``); the test runs it in a subprocess (its own interpreter, so RLlib's Ray and
torch's thread settings stay there). Needs the ``clients`` extra (``./run test-clients``).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SECTION = README.read_text().split("## With your MARL library", 1)[1].split("\n## ", 1)[0]
SNIPPETS = {m.group(1).split(":")[0].strip(): m.group(0)[len("```python\n"):-len("```")]
            for m in re.finditer(r"```python\n# ([^\n]+)\n.*?```", SECTION, flags=re.S)}
NEEDS = {"TorchRL": "torchrl", "BenchMARL": "benchmarl", "RLlib": "ray.rllib", "Tianshou": "tianshou",
         "SB3": "stable_baselines3"}
SLOW = {"RLlib", "BenchMARL", "SB3"}  # Ray; two MAPPO iterations of 6,000 frames; SB3 (the training extra is in the default venv too)


def test_the_section_has_a_snippet_for_each_library():
    assert set(SNIPPETS) == set(NEEDS)


@pytest.mark.parametrize("library", [pytest.param(lib, marks=pytest.mark.slow) if lib in SLOW else lib
                                     for lib in NEEDS])
def test_readme_snippet_runs(library, tmp_path):
    pytest.importorskip(NEEDS[library])
    script = tmp_path / "snippet.py"
    script.write_text(SNIPPETS[library])
    r = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, f"{library} snippet failed:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
