#!/usr/bin/env bash
# Table 3 (SCAPO's ablation) on laptop and eyeglasses with the data and work folder of bench/table1.sh (its SCAPO
# cells are the "Full" rows), training seeds 0,1,2 (SEEDS=... for others). Resumable per cell; DRY_RUN=1 lists the
# cells. Extra arguments go to scapo bench (a later --seeds wins).
# VIEWPOINTS=sphere: the whole-sphere tables of issue 31 (results/table3_ablation_sphere.*); default the paper's.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table3 --preset "${PRESET:-cpu}" --viewpoints "${VIEWPOINTS:-paper}" --seed 1 \
  --seeds "${SEEDS:-0,1,2}" \
  --categories laptop,eyeglasses --work "${WORK:-bench_work/table1_cpu}" --out results ${DRY_RUN:+--dry-run} "$@"
