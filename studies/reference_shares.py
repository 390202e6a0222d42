"""Each decentralised learned method against the reference planner, row by row, on fresh episodes
(issue 38, item 4).

    python studies/reference_shares.py                 # results/paper_rows -> results/planner/reference_shares.md
    python studies/reference_shares.py --results DIR --out DIR

Reads the published ``table.json`` (what ``containergym-marl publish`` wrote) and reports, for every
method of the container agents' view trained on seeds, on every row: the IQM over its seeds of their
mean fresh returns (200 fresh episodes each, seeds 30000+), and the fresh return of its best seed (picked
on validation episodes), each as a share of the reference's (:data:`REFERENCE`, the shielded planner,
on the same fresh episodes), and the share of all its seeds' fresh episodes that overflow. A row meets
the issue's bar (:data:`SHARE`, :data:`OVERFLOW`) when the IQM's share is at least 97 % and the overflow
rate at most 0.5 %; the last line names the methods that meet it on every row. A report, not a gate.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REFERENCE = "planner_agents_shielded"
SHARE, OVERFLOW = 0.97, 0.005


def shares(table: dict) -> dict:
    """Per row, the reference's fresh mean and each decentralised learned method's shares and overflow."""
    rows = table["rows"]
    reference = {r["config"]: r for r in rows if r["method"] == REFERENCE}
    learned = [r for r in rows if r["view"] == "decentralised" and r["seeds"] > 0]
    methods = list(dict.fromkeys(r["method"] for r in learned))
    entries = []
    for config, ref in reference.items():
        base = ref["best_fresh_mean"]
        cells = {}
        for r in learned:
            if r["config"] != config or r.get("fresh_iqm") is None:
                continue
            iqm_share, best_share = r["fresh_iqm"] / base, r["best_fresh_mean"] / base
            cells[r["method"]] = {"seeds": r["seeds"], "fresh_iqm": r["fresh_iqm"], "iqm_share": iqm_share,
                                  "best_fresh_mean": r["best_fresh_mean"], "best_share": best_share,
                                  "fresh_overflow_rate": r["fresh_overflow_rate"],
                                  "meets": iqm_share >= SHARE and r["fresh_overflow_rate"] <= OVERFLOW}
        entries.append({"config": config, "reference_fresh_mean": base,
                        "reference_fresh_overflow_rate": ref["fresh_overflow_rate"], "methods": cells})
    every_row = [m for m in methods if all(m in e["methods"] and e["methods"][m]["meets"] for e in entries)]
    return {"reference": REFERENCE, "share": SHARE, "overflow": OVERFLOW, "methods": methods, "rows": entries,
            "meeting_every_row": every_row}


def markdown(report: dict) -> str:
    methods = report["methods"]
    lines = [f"Fresh episodes (200 per policy, seeds 30000–30199). Per row: `{report['reference']}`'s mean "
             "return; per method, the IQM over its seeds of their mean fresh returns as a share of it, then its "
             "best seed's (picked on validation episodes), then the share of all its seeds' fresh episodes that "
             f"overflow. ✓: an IQM share of at least {report['share']:.0%} and at most {report['overflow']:.1%} of "
             "the episodes overflowing.", "",
             "| row | reference | " + " | ".join(f"`{m}`" for m in methods) + " |",
             "|---|---|" + "---|" * len(methods)]
    for e in report["rows"]:
        cells = []
        for m in methods:
            c = e["methods"].get(m)
            cells.append("–" if c is None else f"{c['iqm_share']:.1%} / {c['best_share']:.1%} · "
                                              f"{c['fresh_overflow_rate']:.1%}{' ✓' if c['meets'] else ''}")
        lines.append(f"| {e['config']} | {e['reference_fresh_mean']:.2f} | " + " | ".join(cells) + " |")
    meeting = report["meeting_every_row"]
    lines += ["", "Methods that meet the bar on every row: "
              + (", ".join(f"`{m}`" for m in meeting) if meeting else "none") + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--results", type=Path, default=REPO / "results" / "paper_rows")
    p.add_argument("--out", type=Path, default=REPO / "results" / "planner")
    ns = p.parse_args(argv)
    table = json.loads((ns.results / "table.json").read_text())
    if not any(r["method"] == REFERENCE for r in table["rows"]):
        raise SystemExit(f"{ns.results / 'table.json'} has no {REFERENCE} rows: publish the reference first")
    report = shares(table)
    from containergym_marl.files import atomic_write_text

    ns.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(ns.out / "reference_shares.json", json.dumps(report, indent=1) + "\n")
    atomic_write_text(ns.out / "reference_shares.md", markdown(report))
    print(markdown(report))
    return report


if __name__ == "__main__":
    main()
