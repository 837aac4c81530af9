#!/bin/bash
# usage: hinge.sh NAME SRC_DIR  (hinge-axis, then hinge-frames+view-prior, on SRC_DIR/NAME/pred.npz; at /work/wt39b)
N=$1; SRC=${2:-/work/exp/s37/x}; OUT=/work/exp/s39/h/eg_$N; mkdir -p $OUT
export PYTHONPATH=/work/wt39b OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
D=/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper
P=/work/main/.venv/bin/python
date +%s > $OUT/t0
$P /work/wt39b/bench/hinge_rows.py --axis --data $D --pred $SRC/$N/pred.npz --out-dir $OUT > $OUT/log 2>&1 &&
$P /work/wt39b/bench/hinge_rows.py --frames --view-prior --data $D --pred $OUT/pred+hinge-axis.npz --out-dir $OUT >> $OUT/log 2>&1 && echo DONE > $OUT/status || echo FAIL > $OUT/status
date +%s > $OUT/t1
