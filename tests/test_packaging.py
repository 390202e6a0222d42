"""What a wheel of the package ships: every sub-package of the source tree, the built-in configs."""

from __future__ import annotations

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_sub_package_is_listed_for_setuptools():
    """setuptools installs only the packages pyproject.toml lists: a sub-package missing there is
    absent from a non-editable install, though every test of an editable one passes."""
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    source = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "containergym_marl").rglob("__init__.py")
              if "__pycache__" not in p.parts}
    assert source - listed == set(), "sub-packages not listed in pyproject.toml's [tool.setuptools] packages"
    assert "containergym_marl.configs" in listed  # the built-in configs, package data from configs/
