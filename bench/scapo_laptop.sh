#!/usr/bin/env bash
# SCAPO (cpu preset) against ICP on procedural laptops: the acceptance experiment of the SCAPO issue.
# Generates 70 laptops x 20 views (63 training instances), trains SCAPO with the cpu preset on the
# unlabeled training clouds, predicts with both methods (SCAPO with and without its test-time
# refinement) and writes one table with provenance.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
WORK=${WORK:-bench_work/scapo_laptop}
PRESET=${PRESET:-cpu}
OUT=${OUT:-results/scapo_laptop_${PRESET}}
$S generate --category laptop --instances 70 --views 20 --seed 0 --cropped keep --out "$WORK/data"
$S train --data "$WORK/data" --preset "$PRESET" --out "$WORK/run_$PRESET"
$S predict --run "$WORK/run_$PRESET" --data "$WORK/data" --out "$WORK/pred_scapo_$PRESET.npz"
# the same run without the test-time refinement (the paper's one-pass prediction), as a second row
$S predict --run "$WORK/run_$PRESET" --data "$WORK/data" --out "$WORK/pred_scapo_${PRESET}_norefine.npz" \
    --option refine_steps=0 --option label=scapo-no-refine
$S predict --method icp --data "$WORK/data" --out "$WORK/pred_icp.npz"
$S evaluate --data "$WORK/data" --pred "$WORK/pred_icp.npz" "$WORK/pred_scapo_$PRESET.npz" \
    "$WORK/pred_scapo_${PRESET}_norefine.npz" --out "$OUT" --name table1
cp "$WORK/run_$PRESET/losses.png" "$OUT/losses_scapo_$PRESET.png"
cp "$WORK/run_$PRESET/timing.json" "$OUT/timing_scapo_$PRESET.json"
