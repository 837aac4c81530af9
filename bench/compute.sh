#!/usr/bin/env bash
# Accuracy against training compute (scapo bench compute) on a 2-core machine: the dataset and every method's
# training speed first (one after another), then two chains of cells side by side (one torch thread each: the
# budget is in core-minutes), then the table and figure from every finished cell. Resumable: run it again after an
# interruption (a cell's training resumes from its checkpoint).
#   CATEGORY=laptop BUDGETS=5,15,45,120 bash bench/compute.sh
# The curve of a table's own cells (--from-table: the dataset, measured speeds, per-category presets and budget rule
# of a 'bench table1 --budget-minutes' work folder; the table's finished seed-0 runs are reused at its own budget):
#   TABLE_WORK=bench_work/table1_paper BUDGETS=5,15,45,120 bash bench/compute.sh
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
scapo="${SCAPO:-.venv/bin/scapo}"
cat="${CATEGORY:-laptop}"
if [ -n "${TABLE_WORK:-}" ]; then
  work="$TABLE_WORK"
  common=(bench compute --from-table --category "$cat" --seed "${DATA_SEED:-0}" --budgets "${BUDGETS:-5,15,45,120}"
          --work "$work" --no-progress)
else
  work="${WORK:-bench_work}"
  common=(bench compute --category "$cat" --seed "${DATA_SEED:-1}" --budgets "${BUDGETS:-5,15,45,120}" --work "$work"
          --no-progress)
fi
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --data-only --workers 2 --methods "${METHODS:-scapo,op-align,eap,npcs}"
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --out "$work/compute_a" --methods "${CHAIN_A:-scapo,op-align}" \
  > "$work/compute_${cat}_a.log" 2>&1 &
a=$!
OMP_NUM_THREADS=1 "$scapo" "${common[@]}" --out "$work/compute_b" --methods "${CHAIN_B:-npcs,eap}" \
  > "$work/compute_${cat}_b.log" 2>&1 &
b=$!
wait $a $b
"$scapo" "${common[@]}" --finished-only --out "${OUT:-results}" --methods "${METHODS:-scapo,op-align,eap,npcs}"
