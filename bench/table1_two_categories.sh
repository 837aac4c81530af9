#!/usr/bin/env bash
# Issue 29's proof of the bench on the v2 data: Table 1 on laptop and eyeglasses only (150 instances x 8 views,
# 30 test instances each, objects under uniform SO(3) rotations, data seed 1), every registered method, cpu
# presets, training seeds 0,1,2, one-pass rows and the "+ refine" rows of every refinable method.
# Two chains, each pinned to one core with one torch thread (laptop on core 0, eyeglasses on core 1), seeds in
# the outer loop so that every method has seed 0 before any has seed 1. Resumable per cell: rerun after an
# interruption. Runs in the background (logs in $WORK/logs); when both chains are done, or to see the cells
# done so far, write the table with:
#   FINISH=1 bash bench/table1_two_categories.sh
# Run it from a clean worktree of the commit that the table should record (cells record the commit; the bench
# refuses a dirty checkout).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
WORK=${WORK:-bench_work/table1_two_categories}
OUT=${OUT:-results/table1_two_categories}
SCAPO=${SCAPO:-.venv/bin/scapo}
common=(--preset cpu --seed 1 --work "$WORK" --no-progress)
# optional (bench/baselines_equal_budget.sh sets them): METHODS, a subset of the registered methods; NAME, the table's
# file stem
[ -n "${METHODS:-}" ] && common+=(--methods "$METHODS")
[ -n "${NAME:-}" ] && common+=(--name "$NAME")
if [ -n "${FINISH:-}" ]; then
  exec "$SCAPO" bench table1 "${common[@]}" --seeds 0,1,2 --categories laptop,eyeglasses --finished-only \
    --out "$OUT" "$@"
fi
mkdir -p "$WORK/logs"
chain() {  # CORE CATEGORY
  local core=$1 cat=$2 s
  for s in 0 1 2; do
    OMP_NUM_THREADS=1 taskset -c "$core" "$SCAPO" bench table1 "${common[@]}" --seeds "$s" --categories "$cat" \
      --out "$WORK/logs/tables_${cat}_s$s" || return 1
  done
}
for pair in "0 laptop" "1 eyeglasses"; do
  set -- $pair
  nohup setsid bash -c "$(declare -p common SCAPO WORK); $(declare -f chain); chain $1 $2" \
    > "$WORK/logs/chain_$2.log" 2>&1 &
done
echo "started; follow with: tail -f $WORK/logs/chain_*.log"
