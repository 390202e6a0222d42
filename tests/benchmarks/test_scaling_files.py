"""The committed scaling measurements: the table docs/performance.md shows (scaling.md) and the
figure's data (scaling.json) are the same run's numbers."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers import load_script

ROOT = Path(__file__).resolve().parents[2]


def test_the_table_and_the_figures_data_are_one_measurement(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))  # scaling.py imports its neighbour throughput.py
    scaling = load_script("benchmarks/scaling.py")
    rows = json.loads((ROOT / "benchmarks" / "profile" / "scaling.json").read_text())
    table = (ROOT / "benchmarks" / "profile" / "scaling.md").read_text()
    header, first = table.split("\n", 1)[0], table.split("\n", 1)[1]
    command, started = header.split("`")[1], header.split(" · ")[1].removesuffix(" UTC")
    expected = scaling.markdown(rows, command, started)
    # the load average in the first line is read when markdown() runs: compare everything after it
    assert expected.split("\n", 1)[1] == first
    assert [r["n"] for r in rows] == [5, 11, 16, 32, 64, 128]
