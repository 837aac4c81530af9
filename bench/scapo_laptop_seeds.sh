#!/usr/bin/env bash
# SCAPO (cpu preset, training seeds 0 1 2) against ICP on procedural laptops (70 instances x 20 views:
# 56 train, 7 val, 7 test), the successor of scapo_laptop.sh. The refinement's multi-start margin is
# chosen on the val split (never on test) among MARGINS, by the lowest val D + R averaged over seeds;
# the tables (protocols scapo and op-align) report mean +- std over seeds, then medians and rates.
# Resumable per cell: generation resumes, a finished run is not retrained, an existing predictions file
# (written atomically) is not recomputed.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
WORK=${WORK:-bench_work/scapo_laptop_seeds}
PRESET=${PRESET:-cpu}
SEEDS=${SEEDS:-0 1 2}
MARGINS=${MARGINS:-0.15 0.3 0.5}
OUT=${OUT:-results/scapo_laptop_${PRESET}_seeds}
$S generate --category laptop --instances 70 --views 20 --seed 0 --val-fraction 0.1 --cropped keep --out "$WORK/data" --no-progress
[ -f "$WORK/pred_icp.npz" ] || $S predict --method icp --data "$WORK/data" --out "$WORK/pred_icp.npz"
for s in $SEEDS; do
  run="$WORK/run_${PRESET}_s$s"
  $S train --data "$WORK/data" --preset "$PRESET" --seed "$s" --out "$run" --no-progress
  for m in $MARGINS; do
    f="$WORK/pred_scapo_s${s}_m$m.npz"
    [ -f "$f" ] || $S predict --run "$run" --data "$WORK/data" --out "$f" --option "refine_margin=$m"
  done
  f="$WORK/pred_scapo_s${s}_norefine.npz"
  [ -f "$f" ] || $S predict --run "$run" --data "$WORK/data" --out "$f" --option refine_steps=0 \
      --option label=scapo-no-refine
done
mkdir -p "$OUT"
candidates=()
for m in $MARGINS; do candidates+=(--candidate "$m=$WORK/pred_scapo_s*_m$m.npz"); done
$S bench choose --data "$WORK/data" "${candidates[@]}" --criterion D+R --out "$OUT/choice_refine_margin_val.json"
margin=$(grep -o '"chosen": "[^"]*"' "$OUT/choice_refine_margin_val.json" | cut -d'"' -f4)
scapo_files=()
norefine_files=()
for s in $SEEDS; do
  scapo_files+=("$WORK/pred_scapo_s${s}_m$margin.npz")
  norefine_files+=("$WORK/pred_scapo_s${s}_norefine.npz")
  cp "$WORK/run_${PRESET}_s$s/timing.json" "$OUT/timing_scapo_${PRESET}_s$s.json"
  cp "$WORK/run_${PRESET}_s$s/losses.png" "$OUT/losses_scapo_${PRESET}_s$s.png"
done
for protocol in scapo op-align; do
  $S evaluate --data "$WORK/data" --protocol "$protocol" --out "$OUT/$protocol" --name table1 \
      --pred "$WORK/pred_icp.npz" "${scapo_files[@]}" "${norefine_files[@]}"
done
