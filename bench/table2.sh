#!/usr/bin/env bash
# Table 2 in real-world style: basket, drawer, laptop, scissors, suitcase rendered with the realistic sensor
# (150 instances x 8 views per category, 30 of them test, upright as real scans are; data seed 1), every registered
# method plus the semi-supervised rows (OP-Align-style and SCAPO with preset cpu/sj), cpu presets, training seeds
# 0,1,2 (SEEDS=... for others), op-align protocol. Resumable per cell; DRY_RUN=1 lists the cells and which are
# done. Its own work folder (the datasets differ from Table 1's). Extra arguments go to scapo bench (a later --seeds
# wins).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec .venv/bin/scapo bench table2 --preset "${PRESET:-cpu}" --seed 1 --seeds "${SEEDS:-0,1,2}" \
  --work "${WORK:-bench_work/table2_cpu}" --out results ${DRY_RUN:+--dry-run} "$@"
