#!/usr/bin/env bash
# Controlled SCAPO experiments on the ladder's rungs (scapo bench ladder --variant): one change at a time against the
# default row, at the ladder's budget, scored on val. Run bench/ladder.sh first (the datasets and speeds are shared).
#   RUNGS=one VARIANTS="scapo:principal:encoder.frame=principal,anchors=O" bash bench/ladder_variants.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
scapo="${SCAPO:-.venv/bin/scapo}"
args=()
for v in ${VARIANTS:-scapo:anchorsO:anchors=O scapo:aug1:losses.aug_consist=1 scapo:principal:encoder.frame=principal,anchors=O}; do
  args+=(--variant "$v")
done
OMP_NUM_THREADS=1 "$scapo" bench ladder --category "${CATEGORY:-laptop}" --seed "${DATA_SEED:-1}" --budget-minutes "${BUDGET:-5}" \
  --work "${WORK:-bench_work}" --out "${OUT:-results/canonical_ladder}" --no-progress --rungs "${RUNGS:-one}" \
  --methods scapo --seeds "${SEEDS:-0}" "${args[@]}"
