#!/usr/bin/env bash
# Table 1 (the paper's synthetic categories: laptop, safe, eyeglasses, oven, washer) with every registered method,
# cpu presets (issue 30's equal budget), on the bench's data (150 instances per category, 30 of them test, the
# paper's viewpoints with 64 views per training instance and 8 per val/test instance; data seed 1), training seeds 0,1,2 (SEEDS=... for others), one-pass
# rows and the "+ refine" rows. Resumable per cell; DRY_RUN=1 lists the cells and which are done. Extra arguments go
# to scapo bench (a later --seeds or --categories wins). On 2 cores, bash bench/tables_two_cores.sh runs Tables 1,
# 2 and 3 in two pinned chains.
# VIEWPOINTS=sphere: the whole-sphere tables of issue 31 (results/table1_synthetic_sphere.*); default the paper's.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table1 --preset "${PRESET:-cpu}" --viewpoints "${VIEWPOINTS:-paper}" --seed 1 \
  --seeds "${SEEDS:-0,1,2}" \
  --work "${WORK:-bench_work/table1_cpu}" --out results ${DRY_RUN:+--dry-run} "$@"
