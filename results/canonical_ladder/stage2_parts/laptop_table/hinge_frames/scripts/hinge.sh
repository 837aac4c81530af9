#!/bin/bash
# usage: hinge.sh NAME [eyeglasses]  (session 39: hinge-axis, then hinge-frames with the view prior, on a run's one-pass
#   predictions, at the clean worktree /work/wt39b, 92c5670). laptop (default): /work/exp/s38/x/NAME/pred.npz on the
#   laptop data, into /work/exp/s39/h/NAME; eyeglasses: /work/exp/s37/x/NAME/pred.npz on the eyeglasses data, into
#   /work/exp/s39/h/eg_NAME.
N=$1
if [ "${2:-laptop}" = eyeglasses ]; then
  SRC=/work/exp/s37/x; OUT=/work/exp/s39/h/eg_$N; D=/work/exp/t37/eyeglasses_i150_v8_t64_s0_paper
else
  SRC=/work/exp/s38/x; OUT=/work/exp/s39/h/$N; D=/work/exp/t38/laptop_i150_v8_t64_s0_paper
fi
mkdir -p $OUT
export PYTHONPATH=/work/wt39b OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
P=/work/main/.venv/bin/python
date +%s > $OUT/t0
$P /work/wt39b/bench/hinge_rows.py --axis --data $D --pred $SRC/$N/pred.npz --out-dir $OUT > $OUT/log 2>&1 &&
$P /work/wt39b/bench/hinge_rows.py --frames --view-prior --data $D --pred $OUT/pred+hinge-axis.npz --out-dir $OUT >> $OUT/log 2>&1 && echo DONE > $OUT/status || echo FAIL > $OUT/status
date +%s > $OUT/t1
