#!/usr/bin/env bash
# Issue 16's measurements, each against a reference measured in the same run, into results/perf/:
#   ICP's batched search vs the exhaustive one on a dataset's val split (ICP_DATA: a dataset with a val split, e.g.
#   the fair race's paper-regime data, WORK/ladder/data/laptop_paper_i150_v8_t64_s1 of bench/fair_race.sh);
#   the ManiSkill3 backend vs the SAPIEN backend (samples/s on the same jobs);
#   generation and evaluation time against dataset size (SIZES, default 100,1000,10000).
# Run on an otherwise idle machine (the ratios hold under load, the absolute times do not).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
$S bench perf --what icp --data "${ICP_DATA:?give ICP_DATA, a dataset with a val split}" --split val \
  --limit "${ICP_LIMIT:-0}" --out results/perf
$S bench perf --what maniskill --category laptop --instances 4 --views 32 --out results/perf
$S bench perf --what growth --category laptop --sizes "${SIZES:-100,1000,10000}" --workers 1 --out results/perf
