#!/bin/bash
# session 41: the scores on test of scapo_laptop_frames.sh again, on the frames files remade at 2eb3181 (the view
# prior's exchanged views negate the base joint's state) by results/table1_paper_hinge_5min/scripts/
# frames_state_sign.sh laptop, from the clean worktree /work/wt41b
set -e
cd /work/exp/s41/hf
export PYTHONPATH=/work/wt41b OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
D=laptop_i150_v8_t64_s0_paper
OUT=${OUT:-/work/exp/s41/pre}
/work/main/.venv/bin/scapo evaluate --data $D --pred $D/predictions_scapo_*.npz hinge_frames/laptop/*scapo*.npz \
  --split test --out $OUT --name scapo_laptop_frames_test --no-progress
args=$(for f in hinge_frames/laptop/*scapo*.npz; do n=$(basename $f .npz); echo -n " --pred ${n#predictions_}=$PWD/$f"; done)
$P /work/wt41b/bench/frame_consistency.py --data $PWD/$D $args --split test --out $OUT/scapo_laptop_frames_test_frame_consistency
