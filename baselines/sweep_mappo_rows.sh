#!/usr/bin/env bash
# The CTDE row: BenchMARL MAPPO (baselines/train_mappo.py) on the two contention rows it is compared on,
# 3 seeds each, at shared PPO's budget counted in agent steps (the table's samples: one per decision):
# 2M agent steps on n5_m2_dt120 = 400,000 plant steps, 5M on n11_m2_dt120 = 454,546 plant steps
# (BenchMARL trains whole iterations of 6,000 plant steps: 402,000 and 456,000). About 11 and 20 min a
# run on one free core. Resumable: rerun it to continue (finished runs are evaluated again only if their
# evaluation file is missing; interrupted runs resume from their newest checkpoint).
#
#   RUNS=runs/paper EVALUATIONS=results/compare_paper/evaluations bash baselines/sweep_mappo_rows.sh
#
# Needs the clients extra (.venv-clients: ./run test-clients sets it up). The evaluations land beside
# compare's, named mappo_s<seed>.json, so containergym-marl publish and the table take them as method "mappo".
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${RUNS:-runs/paper}
EVALUATIONS=${EVALUATIONS:-results/compare_paper/evaluations}
PYTHON=${PYTHON:-.venv-clients/bin/python}
SEEDS=${SEEDS:-1 2 3}
CONFIGS=${CONFIGS:-n5_m2_dt120 n11_m2_dt120}  # e.g. CONFIGS=n11_m2_dt120 in a second process beside the first
declare -A PLANT_STEPS=([n5_m2_dt120]=400000 [n11_m2_dt120]=454546)  # ceil(agent-step budget / n)
for config in $CONFIGS; do
  for seed in $SEEDS; do
    run="$RUNS/mappo_${config}_s${seed}"
    if [ -f "$EVALUATIONS/$config/mappo_s${seed}.json" ] && [ -f "$run/final_model.pt" ]; then
      echo "mappo $config seed $seed: finished and evaluated" >&2
      continue
    fi
    resume=()
    [ -f "$run/args.json" ] && resume=(--resume)
    echo "mappo $config seed $seed: ${resume[*]:-new run} ($(date -u +%H:%M:%S))" >&2
    "$PYTHON" baselines/train_mappo.py --config "$config" --seed "$seed" --timesteps "${PLANT_STEPS[$config]}" \
      --out "$run" --evaluations "$EVALUATIONS" "${resume[@]}"
  done
done
