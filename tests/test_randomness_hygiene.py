"""All randomness flows from reset(seed=...): no global numpy or stdlib random state in the package."""

from __future__ import annotations

import ast
from pathlib import Path

import containergym_marl

PACKAGE_DIR = Path(containergym_marl.__file__).resolve().parent
# Constructors of explicit generators are fine; everything else on np.random uses global state.
ALLOWED_NP_RANDOM = {"Generator", "default_rng", "SeedSequence", "PCG64", "BitGenerator"}


def _violations(source: str) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [f"import {a.name}" for a in node.names if a.name == "random"]
        elif isinstance(node, ast.ImportFrom):
            if node.module == "random" or (node.module == "numpy" and any(a.name == "random" for a in node.names)):
                found.append(f"from {node.module} import ...")
            if node.module == "numpy.random":
                found += [f"from numpy.random import {a.name}" for a in node.names if a.name not in ALLOWED_NP_RANDOM]
        elif isinstance(node, ast.Attribute) and node.attr not in ALLOWED_NP_RANDOM:
            inner = node.value
            if (isinstance(inner, ast.Attribute) and inner.attr == "random"
                    and isinstance(inner.value, ast.Name) and inner.value.id in {"np", "numpy"}):
                found.append(f"np.random.{node.attr}")
    return found


def test_the_checker_catches_global_random_use():
    assert _violations("import numpy as np\nnp.random.normal(0, 1)") == ["np.random.normal"]
    assert _violations("import random\nrandom.random()") == ["import random"]
    assert _violations("from numpy.random import rand") == ["from numpy.random import rand"]
    assert _violations("import numpy as np\nnp.random.default_rng(0)") == []


def test_package_uses_no_global_random_state():
    files = sorted(PACKAGE_DIR.rglob("*.py"))
    assert len(files) > 5
    bad = {str(f.relative_to(PACKAGE_DIR)): v for f in files if (v := _violations(f.read_text()))}
    assert bad == {}
