#!/usr/bin/env bash
# The canonical-frame diagnosis ladder (scapo bench ladder) of one category on a 2-core machine: the rungs' datasets
# first, then two chains of cells side by side (one torch thread each: the budget is in core-minutes), then the
# table from every finished cell. Resumable: run it again after an interruption.
#   CATEGORY=laptop BUDGET=5 bash bench/ladder.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
scapo="${SCAPO:-.venv/bin/scapo}"
cat="${CATEGORY:-laptop}"
common=(bench ladder --category "$cat" --seed "${DATA_SEED:-1}" --budget-minutes "${BUDGET:-5}" --work "${WORK:-bench_work}"
        --out "${OUT:-results/canonical_ladder}" --no-progress)
"$scapo" "${common[@]}" --data-only --workers 2
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --methods "${CHAIN_A:-scapo,eap}" > "${WORK:-bench_work}/ladder_${cat}_a.log" 2>&1 &
a=$!
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --methods "${CHAIN_B:-op-align,npcs}" > "${WORK:-bench_work}/ladder_${cat}_b.log" 2>&1 &
b=$!
wait $a $b
"$scapo" "${common[@]}" --methods "${METHODS:-scapo,op-align,eap,npcs}"
