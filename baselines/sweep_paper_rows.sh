#!/usr/bin/env bash
# The comparison on every row: the eight paper configurations and the 16-container plant;
# rule-based controllers, centralised PPO, shared PPO (individual and team rewards), 3 seeds each
# at the paper's budget (2M samples for n = 5, 5M for n >= 11), evaluated with the paper's test
# protocol. Resumable: rerun it to continue (finished runs and evaluations are reused, interrupted
# runs resume from their last checkpoint); results/paper_rows/compute.md reports the training time it took.
#
#   RUNS=runs/paper OUT=results/compare_paper bash baselines/sweep_paper_rows.sh
#   containergym-marl publish --runs runs/paper --compare results/compare_paper --to results/paper_rows
#
# Seeds 4 and 5 on the rows where the PUs are scarce (arguments after the script's own win):
#   bash baselines/sweep_paper_rows.sh --configs n16_m2_dt120 n11_m2_dt120 n5_m2_dt120 n11_m2_dt60 n5_m2_dt60 --seeds 1 2 3 4 5
#
# The published folder carries the sweep between machines: publish with --with-checkpoints (interrupted
# runs keep their newest checkpoint) and commit; on the next machine, first
#   containergym-marl publish --runs runs/paper --compare results/compare_paper --to results/paper_rows --restore
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${RUNS:-runs/paper}
OUT=${OUT:-results/compare_paper}
CLI=${CLI:-containergym-marl}
# Ray's memory monitor kills training workers when another process on the machine takes memory; the
# kernel's OOM killer then picks the process that took it instead.
export RAY_memory_monitor_refresh_ms=${RAY_memory_monitor_refresh_ms:-0}
exec $CLI compare --train \
  --configs n11_m2_dt120 n11_m2_dt60 n5_m2_dt120 n5_m2_dt60 n16_m2_dt120 n5_m5_dt120 n5_m5_dt60 n11_m11_dt120 n11_m11_dt60 \
  --methods rule_based rule_based_agents ppo shared_ppo shared_ppo_team \
  --seeds 1 2 3 --timesteps paper --runs "$RUNS" --out "$OUT" "$@"
