#!/usr/bin/env bash
# Does SCAPO meet test clouds at the density it trained at? Its cpu preset trains on random 256-point subsets of the
# 1024-point clouds and predicts on all 1024 points, as NPCS-style did before its inference moved to the training
# density (results/paper_regime/). One SCAPO run (cpu preset, seed 0) on the paper regime's 8-view laptop dataset
# (bench/paper_regime.sh's laptop_i150_v8_s1_paper), predicted one-pass (refine_steps=0) on that dataset and on the
# same views rendered with 256 points (--points 256: the same seeds, so the same states and cameras; 239 of 240 test
# views identical, one redrawn), each scored on its own dataset (the canonical-frame alignment from that dataset's
# training split). Writes results/diagnostics/scapo_density/. About 25 min on 2 cores.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
WORK=${WORK:-bench_work/paper_regime}
D=${DATA:-$WORK/laptop_i150_v8_s1_paper}
D256=$WORK/scapo_density/laptop_n256
RUN=$WORK/scapo_density/run_scapo_cpu_s0
OUT=${OUT:-results/diagnostics/scapo_density}
S=.venv/bin/scapo
$S generate --category laptop --instances 150 --views 8 --viewpoints paper --seed 1 --test-fraction 0.2 \
  --val-fraction 0.1 --points 256 --out "$D256" --no-progress --workers 2
$S train --data "$D" --preset cpu --seed 0 --out "$RUN" --no-progress
for n in 1024 256; do
  data=$D; [ "$n" = 256 ] && data=$D256
  f=$WORK/scapo_density/pred_n$n.npz
  [ -f "$f" ] || $S predict --run "$RUN" --data "$data" --option refine_steps=0 --out "$f"
  $S evaluate --data "$data" --pred "$f" --out "$OUT" --name "scapo_n$n"
done
