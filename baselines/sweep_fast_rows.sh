#!/usr/bin/env bash
# The paper's protocol with the native PPO: fast_ppo, fast_shared_ppo and fast_shared_ppo_team,
# 15 seeds on each of the nine rows at the paper's budget (2M samples for n = 5, 5M for n >= 11),
# evaluated with the paper's test protocol: 405 runs. Training alone costs about 28 core-hours (14 hours
# on 2 cores) at the settings files' shapes: the tuning runs (results/ppo_tuning/) took about 130 CPU-s
# per 2M-sample n = 5 run and 290-370 per 5M-sample n >= 11 run, one core each.
# The seeds go in three batches (1-5, 6-10, 11-15), so an interrupted sweep leaves every row with
# the same number of seeds. Resumable: rerun it to continue (finished runs and evaluations are
# reused, interrupted runs resume from their last checkpoint).
#
#   RUNS=runs/fast OUT=results/compare_fast bash baselines/sweep_fast_rows.sh
#   containergym-marl publish --runs runs/fast --compare results/compare_fast --to results/paper_rows \
#       --with-checkpoints --readme README.md --docs docs/results.md
#
# On a fresh machine, first bring the published runs back:
#   containergym-marl publish --runs runs/fast --compare results/compare_fast --to results/paper_rows --restore
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${RUNS:-runs/fast}
OUT=${OUT:-results/compare_fast}
CLI=${CLI:-containergym-marl}
# Ray's memory monitor kills training workers when another process on the machine takes memory; the
# kernel's OOM killer then picks the process that took it instead.
export RAY_memory_monitor_refresh_ms=${RAY_memory_monitor_refresh_ms:-0}
for seeds in "1 2 3 4 5" "6 7 8 9 10" "11 12 13 14 15"; do
  # shellcheck disable=SC2086
  $CLI compare --train \
    --configs n11_m2_dt120 n16_m2_dt120 n5_m2_dt120 n11_m11_dt120 n11_m2_dt60 n5_m2_dt60 n5_m5_dt120 n5_m5_dt60 n11_m11_dt60 \
    --methods fast_ppo fast_shared_ppo fast_shared_ppo_team \
    --seeds $seeds --timesteps paper --runs "$RUNS" --out "$OUT" --no-figures --curves "$@"
done
