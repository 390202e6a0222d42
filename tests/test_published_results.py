"""The published comparison (results/paper_rows/) is consistent with itself and with the README: the
committed table is the table of the committed evaluation files, rebuilt from them alone (what a fresh
clone does), and the README shows that table between its results-table markers."""

from __future__ import annotations

from pathlib import Path

from containergym_marl.evaluation import table as tables
from tests.conftest import load_script

ROOT = Path(__file__).resolve().parents[1]
PUBLISHED = ROOT / "results" / "paper_rows"


def _publish_module():
    return load_script("baselines/publish_results.py")


def test_committed_table_is_the_table_of_the_committed_evaluations(tmp_path):
    rebuilt = tables.build_table(tables.load_evaluations(PUBLISHED / "evaluations"))
    rebuilt.write(tmp_path, {"source": "baselines/publish_results.py"})
    assert (tmp_path / "table.md").read_text() == (PUBLISHED / "table.md").read_text()
    assert (tmp_path / "table.csv").read_text() == (PUBLISHED / "table.csv").read_text()


def test_readme_shows_the_committed_table():
    publish_results = _publish_module()
    readme = (ROOT / "README.md").read_text()
    start = readme.index(publish_results.README_START.format(source="results/paper_rows"))
    end = readme.index(publish_results.README_END)
    shown = readme[start:end].split("\n", 1)[1].strip()
    assert shown == (PUBLISHED / "table.md").read_text().strip()


def test_readme_block_is_replaced_in_place_and_a_missing_marker_is_named(tmp_path):
    publish_results = _publish_module()
    readme = tmp_path / "README.md"
    readme.write_text("# title\n\nbefore\n<!-- results table: old -->\nold table\n<!-- end of results table -->\nafter\n")
    publish_results.show_table_in_readme(readme, "| a |\n|---|\n| 1 |\n", Path("results/x"))
    assert readme.read_text() == (
        "# title\n\nbefore\n"
        "<!-- results table: written by baselines/publish_results.py from results/x; do not edit -->\n\n"
        "| a |\n|---|\n| 1 |\n\n<!-- end of results table -->\nafter\n")
    readme.write_text("no markers\n")
    try:
        publish_results.show_table_in_readme(readme, "| a |\n", Path("results/x"))
    except SystemExit as exc:
        assert "results-table block" in str(exc) and "found 0 start and 0 end" in str(exc)
    else:
        raise AssertionError("a README without markers was accepted")
    assert readme.read_text() == "no markers\n"  # untouched
