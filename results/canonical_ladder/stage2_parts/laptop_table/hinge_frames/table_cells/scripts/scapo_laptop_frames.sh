#!/bin/bash
# session 40: the table's three SCAPO laptop cells through the FRAMES=1 steps ahead of the whole HINGE/FRAMES run
# (the same commands and output names as bench/table1_paper_two_categories.sh, at 0dc6165 from /work/wt39t)
set -e
cd /work/exp/tab39/w
export PYTHONPATH=/work/wt39t OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
D=laptop_i150_v8_t64_s0_paper
$P /work/wt39t/bench/hinge_rows.py --axis --data $D --pred $D/predictions_scapo_*.npz --out-dir hinge_axis/laptop
$P /work/wt39t/bench/hinge_rows.py --frames --view-prior --skip-without-train --data $D --pred hinge_axis/laptop/*scapo*.npz --out-dir hinge_frames/laptop

# then the scores on test (OUT: this folder)
OUT=${OUT:-/work/exp/s40/pre}
/work/main/.venv/bin/scapo evaluate --data $D --pred $D/predictions_scapo_*.npz hinge_frames/laptop/*.npz --split test \
  --out $OUT --name scapo_laptop_frames_test --no-progress
args=$(for f in hinge_frames/laptop/*.npz; do n=$(basename $f .npz); echo -n " --pred ${n#predictions_}=$PWD/$f"; done)
$P /work/wt39t/bench/frame_consistency.py --data $PWD/$D $args --split test --out $OUT/scapo_laptop_frames_test_frame_consistency
