#!/bin/bash
# session 40: label_stride 1/2/4 on the table's finished cpu-laptop s0 run (its final model), from the clean worktree
# /work/wt40 (5d27d74); one torch thread, with the table's two chains on the machine's two cores.
set -e
cd "$(dirname "$0")"
export PYTHONPATH=/work/wt40 OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
D=/work/exp/tab39/w/laptop_i150_v8_t64_s0_paper
R=$D/run_scapo_cpu-laptop+epochs-5-4_s0
$P stride_labels.py $R $D stride_labels_laptop_s0.json > stride_labels.log 2>&1
$P stride_frames.py $R $D stride_frames_laptop_s0.json > stride_frames.log 2>&1
$P stride_check.py $R $D stride_check_laptop_s0.json > stride_check.log 2>&1
echo done > status
