#!/usr/bin/env bash
# train.sh SEED...: Table 1's SCAPO eyeglasses cells (cpu-eyeglasses, epochs-6-5, the table's schedule) on the table's
# eyeglasses data (184eb9d3), one torch thread each, from the clean worktree /work/wt44 (1046751); seeds in sequence
set -e
for s in "$@"; do
  name="run_scapo_cpu-eyeglasses+epochs-6-5_s$s"
  [ -f /work/exp/s44/runs/$name/checkpoint.pt ] && [ -f /work/exp/s44/runs/$name/run.json ] && continue
  cd /work/wt44
  PYTHONPATH=/work/wt44 OMP_NUM_THREADS=1 /work/main/.venv/bin/scapo train --data /work/exp/s43/w/eyeglasses_i150_v8_t64_s0_paper \
    --preset cpu-eyeglasses/epochs-6-5 --seed "$s" --out /work/exp/s44/runs/$name --no-progress > /work/exp/s44/runs/$name.log 2>&1
done
