#!/usr/bin/env bash
# Issue 30's acceptance experiment: the -style baselines with the components that define them (OP-Align-style,
# EAP-style, NPCS-style with per-part NPCS) at the equal cpu budget (the same 256 training points and the epochs that
# fill 15 minutes of training per cell on one core, measured by `scapo bench perf --what train --data`), on issue 29's
# Table 1 data (laptop and eyeglasses, 150 instances x 8 views, 30 test instances each, uniform SO(3) rotations,
# data seed 1), three training seeds, one-pass and "+ refine" rows. The versions before issue 30 are the rows of
# results/table1_two_categories (commit 66524f5, the same datasets: their hashes are in both provenances).
# Two chains, each pinned to one core with one torch thread (laptop on core 0, eyeglasses on core 1), seeds in the
# outer loop. Resumable per cell: rerun after an interruption. Run it from a clean worktree of the commit the table
# should record; when both chains are done (or to see the cells so far) write the table with:
#   FINISH=1 bash bench/baselines_equal_budget.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
WORK=${WORK:-bench_work/baselines_equal_budget}
OUT=${OUT:-results/baselines_equal_budget}
SCAPO=${SCAPO:-.venv/bin/scapo}
METHODS=${METHODS:-npcs,eap,op-align}
common=(--preset cpu --seed 1 --work "$WORK" --no-progress --methods "$METHODS" --name baselines_equal_budget)
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
