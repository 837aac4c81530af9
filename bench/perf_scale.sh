#!/usr/bin/env bash
# Issue 16's measurements, each against a reference measured in the same run, into results/perf/:
#   ICP's batched search vs the exhaustive one on the laptop test split of Table 1 (ms per cloud, median R, S);
#   the ManiSkill3 backend vs the SAPIEN backend (samples/s on the same jobs);
#   generation and evaluation time against dataset size (SIZES, default 100,1000,10000).
# Run on an otherwise idle machine (the ratios hold under load, the absolute times do not).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
$S bench perf --what icp --data "${ICP_DATA:-bench_work/table1_cpu/laptop_i80_v16_s1}" --limit "${ICP_LIMIT:-0}" \
  --out results/perf
$S bench perf --what maniskill --category laptop --instances 4 --views 32 --out results/perf
$S bench perf --what growth --category laptop --sizes "${SIZES:-100,1000,10000}" --workers 1 --out results/perf
