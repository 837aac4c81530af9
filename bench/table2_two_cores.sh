#!/usr/bin/env bash
# Table 2 (bench/table2.sh settings) on a 2-core machine: two chains, each pinned to one core with one torch
# thread, each owning its categories, so no cell is ever computed twice at once:
#   core 0: scissors, suitcase        core 1: laptop, basket, drawer
# (CORE0=... / CORE1=... override the category lists). A chain can wait for a process to end first
# (AFTER0=PID / AFTER1=PID, e.g. the Table 3 chain still using that core). Resumable per cell: rerun after an
# interruption. Runs in the background; logs in bench_work/logs/. The chains write their partial tables into
# bench_work/logs/; the table of the cells done so far: bash bench/table2.sh --finished-only. Commit first:
# cells record the commit, "-dirty" with uncommitted changes.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
[ -z "$(git status --porcelain --untracked-files=no 2>/dev/null)" ] || echo "scapo: warning: uncommitted changes; the cells will record a -dirty commit" >&2
mkdir -p bench_work/logs
common=(--preset "${PRESET:-cpu}" --seed 1 --seeds "${SEEDS:-0}" --work "${WORK:-bench_work/table2_cpu}" --no-progress)
chain() {  # CORE CATEGORIES [PID to wait for]
  local core=$1 cats=$2 after=${3:-}
  if [ -n "$after" ]; then while kill -0 "$after" 2>/dev/null; do sleep 60; done; fi
  OMP_NUM_THREADS=1 taskset -c "$core" .venv/bin/scapo bench table2 "${common[@]}" --categories "$cats" \
    --out "bench_work/logs/table2_core$core"
}
nohup setsid bash -c "$(declare -p common); $(declare -f chain); chain 0 ${CORE0:-scissors,suitcase} ${AFTER0:-}" \
  > bench_work/logs/table2_core0.log 2>&1 &
nohup setsid bash -c "$(declare -p common); $(declare -f chain); chain 1 ${CORE1:-laptop,basket,drawer} ${AFTER1:-}" \
  > bench_work/logs/table2_core1.log 2>&1 &
echo "started; follow with: tail -f bench_work/logs/table2_core0.log bench_work/logs/table2_core1.log"
