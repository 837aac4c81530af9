#!/usr/bin/env bash
# Table 1 (the paper's synthetic categories) with every registered method, cpu presets, on the bench's data
# (150 instances x 8 views per category, 30 of them test, objects under uniform SO(3) rotations; data seed 1),
# training seeds 0,1,2 on laptop and eyeglasses and 0 elsewhere (issue 31 makes it three everywhere).
# Resumable per cell; DRY_RUN=1 lists the cells and which are done. Extra arguments go to scapo bench.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table1 --preset "${PRESET:-cpu}" --seed 1 --seeds 0,1,2 \
  --category-seeds safe=0 --category-seeds oven=0 --category-seeds washer=0 \
  --work "${WORK:-bench_work/table1_cpu}" --out results ${DRY_RUN:+--dry-run} "$@"
