#!/usr/bin/env bash
# Tables 1 and 3 (bench/table1.sh and bench/table3.sh settings) on a 2-core machine: two chains, each pinned
# to one core with one torch thread, each owning its categories, so no cell is ever computed twice at once:
#   core 0: Table 1 on laptop, safe, oven, washer, then Table 3 on laptop
#   core 1: Table 1 on eyeglasses, then Table 3 on eyeglasses
# (measured: two 2-thread trainings sharing 2 cores ran > 3x slower each than one alone). Resumable per
# cell: rerun after an interruption. Runs in the background; logs in bench_work/logs/. The tables of the
# cells done so far: bash bench/table1.sh --finished-only (and table3.sh). Commit first: cells record the
# commit, "-dirty" with uncommitted changes.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
[ -z "$(git status --porcelain --untracked-files=no 2>/dev/null)" ] || echo "scapo: warning: uncommitted changes; the cells will record a -dirty commit" >&2
mkdir -p bench_work/logs
common=(--preset "${PRESET:-cpu}" --seed 1 --work "${WORK:-bench_work/table1_cpu}" --no-progress)
chain() {  # CORE TABLE1-CATEGORIES TABLE3-CATEGORIES [extra table1 arguments]
  local core=$1 cats1=$2 cats3=$3
  shift 3
  OMP_NUM_THREADS=1 taskset -c "$core" .venv/bin/scapo bench table1 "${common[@]}" --seeds 0,1,2 "$@" \
    --categories "$cats1" --out "bench_work/logs/table1_core$core"
  OMP_NUM_THREADS=1 taskset -c "$core" .venv/bin/scapo bench table3 "${common[@]}" --seeds "${SEEDS:-0}" \
    --categories "$cats3" --out "bench_work/logs/table3_core$core"
}
nohup setsid bash -c "$(declare -p common); $(declare -f chain); chain 0 laptop,safe,oven,washer laptop \
  --category-seeds safe=0 --category-seeds oven=0 --category-seeds washer=0" > bench_work/logs/core0.log 2>&1 &
nohup setsid bash -c "$(declare -p common); $(declare -f chain); chain 1 eyeglasses eyeglasses" \
  > bench_work/logs/core1.log 2>&1 &
echo "started; follow with: tail -f bench_work/logs/core0.log bench_work/logs/core1.log"
