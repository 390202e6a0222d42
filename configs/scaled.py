"""Plants beyond the paper: 32, 64 and 128 containers, built from the 16-container plant by one rule.

    python -m containergym_marl.configs.scaled          # rewrite the n32/n64/n128 TOML files beside this one
    python -m containergym_marl.configs.scaled --check  # exit 1 if a file differs from what the rule gives

**The rule.** A plant of ``n = 16·k`` containers is ``k`` copies of ``n16_m2_dt120``'s 16 containers,
every parameter unchanged (fill rate and noise, v_max, product size, PU offset and time per product,
reward peaks), copy ``j`` of container ``C`` named ``C.j`` (j = 1..k; each copy fills with its own
noise). Everything plant-wide is the 16-container plant's too: δ = 120 s, T = 1500 training steps,
v(0) ~ U[0, 30], r_min = −1, r_pen = −0.1. Only the PUs change:

* ``n<N>_m<N/8>_dt120`` (m = 4, 8, 16): PUs in proportion, one per 8 containers as in
  ``n16_m2_dt120``, so the average PU load at the target volumes is that plant's (0.45 of each PU's
  time: Σ_i g_i(v*_i)·μ_i / v*_i / m);
* ``n<N>_m<3N/32>_dt120`` (m = 3, 6, 12): the scarce variant, a quarter fewer PUs: load 0.59, where
  waiting for a PU decides most episodes (on validation episodes the rule-based agents collect about
  half of the planner's return on ``n32_m3_dt120``, against 0.92 of it on ``n32_m4_dt120``).
  One PU per 16 containers (load 0.89) was tried first and is infeasible: the rules and the planner
  overflowed within 100 steps in every validation episode, the initial volumes (up to 30 of 40)
  asking more of the PUs at once than they can give.

None of these plants is in the paper or its reference data: they test what the paper's plant cannot,
how a method scales with n and whether a policy shared by the container agents transfers from a
smaller plant. Their PU parameters inherit the 16-container plant's imputations (its description).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

BASE = "n16_m2_dt120"
#: (copies of the 16-container plant, PUs) of every scaled plant, named ``n<16·copies>_m<PUs>_dt120``.
SCALED = ((2, 4), (4, 8), (8, 16), (2, 3), (4, 6), (8, 12))
FOLDER = Path(__file__).resolve().parent


def scaled_name(copies: int, n_pus: int) -> str:
    return f"n{16 * copies}_m{n_pus}_dt120"


def scaled_plant(copies: int, n_pus: int):
    """The plant of ``copies`` copies of the 16-container plant's containers and ``n_pus`` PUs (the rule above)."""
    from containergym_marl.config import load_config

    base = load_config(BASE)
    containers = tuple(dataclasses.replace(c, name=f"{c.name}.{j}") for j in range(1, copies + 1)
                       for c in base.containers)
    share = ("in proportion (one per 8 containers, as the 16-container plant)" if 2 * copies == n_pus
             else "scarce (3 per 32 containers)")
    description = (f"{copies} copies of the 16-container plant {BASE} (every container parameter and plant setting "
                   f"unchanged, copy j of container C named C.j) with m={n_pus} PUs, {share}; built by "
                   f"configs/scaled.py, not in the paper or its reference data.")
    return base.replace(name=scaled_name(copies, n_pus), containers=containers, num_processing_units=n_pus,
                        description=description)


def expected_files() -> dict[str, str]:
    """File name -> TOML text of every scaled plant, as the rule builds it."""
    return {f"{scaled_name(c, m)}.toml": scaled_plant(c, m).to_toml() for c, m in SCALED}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true", help="compare the files with the rule instead of writing them")
    ns = p.parse_args(argv)
    differ = []
    for name, text in expected_files().items():
        path = FOLDER / name
        if ns.check:
            if not path.is_file() or path.read_text() != text:
                differ.append(name)
        else:
            path.write_text(text)
    if differ:
        print(f"not what the rule gives: {', '.join(differ)}", file=sys.stderr)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
