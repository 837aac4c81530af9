#!/usr/bin/env bash
# Table 1 (the paper's synthetic categories) with every registered method, cpu presets: 80 instances x
# 16 views per category (data seed 1), training seeds 0,1,2 on laptop and eyeglasses and 0 elsewhere.
# Resumable per cell; DRY_RUN=1 lists the cells and which are done. Extra arguments go to scapo bench.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table1 --preset "${PRESET:-cpu}" --seed 1 --seeds 0,1,2 \
  --category-seeds safe=0 --category-seeds oven=0 --category-seeds washer=0 \
  --work "${WORK:-bench_work/table1_cpu}" --out results ${DRY_RUN:+--dry-run} "$@"
