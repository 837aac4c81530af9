#!/usr/bin/env bash
# train.sh PRESET SEED [extra --set ...]: one SCAPO run on the table's laptop data, one torch thread
set -e
p="$1"; s="$2"; shift 2
name="run_scapo_${p//\//+}_s$s"
cd /work/wt43
PYTHONPATH=/work/wt43 OMP_NUM_THREADS=1 /work/main/.venv/bin/scapo train --data /work/exp/s43/w/laptop_i150_v8_t64_s0_paper \
  --preset "$p" --seed "$s" --out /work/exp/s43/runs/$name --no-progress "$@" > /work/exp/s43/runs/$name.log 2>&1
