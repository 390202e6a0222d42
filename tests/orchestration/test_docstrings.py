"""Every public function and class of the orchestration package says what it does (a docstring)."""

from __future__ import annotations

import ast
from pathlib import Path

import containergym_marl.orchestration as orchestration


def test_every_public_function_and_class_of_orchestration_has_a_docstring():
    missing = []
    for path in sorted(Path(orchestration.__file__).parent.glob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if (isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                    and not node.name.startswith("_") and not ast.get_docstring(node)):
                missing.append(f"{path.name}:{node.lineno} {node.name}")
    assert not missing, missing
