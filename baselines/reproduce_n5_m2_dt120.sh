#!/usr/bin/env bash
# Reproduces the README's results table on n5_m2_dt120: centralised PPO and shared (decentralised)
# PPO, 3 seeds each, at the paper's budget of 2M samples, evaluated with the paper's test protocol
# (delta = 120 s, T = 600, 15 episodes, seeds 10000-10014), plus the rule-based controllers.
#
#   bash baselines/reproduce_n5_m2_dt120.sh          # ~20 min per run, 2 runs at a time on 2 cores
#
# Finished runs are skipped and interrupted ones resumed, so the script can be rerun. Run
# directories go to runs/paper/; their small result files are copied to results/n5_m2_dt120/.
set -euo pipefail
cd "$(dirname "$0")/.."
CLI=${CLI:-containergym-marl}
CONFIG=n5_m2_dt120
BUDGET=${BUDGET:-2000000}
SEEDS=${SEEDS:-"1 2 3"}
JOBS=${JOBS:-2}

one_run() {  # algo seed
  local out="runs/paper/$1_${CONFIG}_s$2"
  if [ -f "$out/final_model.zip" ]; then echo "skip $out (finished)"; return; fi
  local resume=""
  if [ -d "$out" ]; then resume="--resume"; fi
  $CLI train --algo "$1" --config "$CONFIG" --seed "$2" --timesteps "$BUDGET" --out "$out" --no-progress $resume
}
export -f one_run; export CLI CONFIG BUDGET

for seed in $SEEDS; do for algo in ppo shared_ppo; do echo "$algo $seed"; done; done \
  | xargs -P "$JOBS" -L 1 bash -c 'one_run "$0" "$1"'

mkdir -p "results/$CONFIG"
for run in runs/paper/*_"$CONFIG"_s*; do
  for which in best final; do
    $CLI evaluate "$run" --model "$which" --json "$run/evaluation_$which.json" > /dev/null
  done
  dest="results/$CONFIG/$(basename "$run")"
  mkdir -p "$dest"
  cp "$run"/args.json "$run"/metrics.csv "$run"/evaluation_best.json "$run"/evaluation_final.json "$dest"/
done
for policy in rule_based rule_based_agents; do
  $CLI evaluate "$policy" --config "$CONFIG" --json "results/$CONFIG/$policy.json" > /dev/null
done
python -m containergym_marl.evaluation.table "results/$CONFIG"
