"""The repository passes ``ruff check`` under the configuration in pyproject.toml ([tool.ruff]).

ruff comes from the ``dev`` extra (pinned there); the test is skipped where it is not installed.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def ruff_command() -> list[str] | None:
    """ruff beside this Python (a virtual environment's bin/), else on PATH."""
    beside = Path(sys.executable).with_name("ruff")
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("ruff")
    return [found] if found else None


def test_ruff_check_is_clean():
    command = ruff_command()
    if command is None:
        pytest.skip("ruff is not installed (the dev extra installs it)")
    result = subprocess.run([*command, "check", "--no-cache", "--output-format", "concise", str(ROOT)],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, f"ruff check found problems:\n{result.stdout}{result.stderr}"


def test_package_is_marked_typed():
    """PEP 561: the marker ships inside the package (pyproject's package-data)."""
    assert (ROOT / "containergym_marl" / "py.typed").is_file()
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert '"containergym_marl" = ["py.typed"]' in text
