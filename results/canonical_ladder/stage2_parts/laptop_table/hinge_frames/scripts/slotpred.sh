#!/bin/bash
# usage: slotpred.sh NAME  (predict /work/exp/s38/x/NAME/run with base_slot=auto, refine_steps=0, at /work/wt39b)
N=$1; OUT=/work/exp/s39/slot/$N; mkdir -p $OUT
export PYTHONPATH=/work/wt39b OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
( cd /work/wt39b && git rev-parse HEAD ) > $OUT/commit.txt
date +%s > $OUT/t0
/work/main/.venv/bin/scapo predict --run /work/exp/s38/x/$N/run --data /work/exp/t38/laptop_i150_v8_t64_s0_paper --out $OUT/pred.npz --option refine_steps=0 --option base_slot=auto --no-progress > $OUT/predict.log 2>&1 && echo DONE > $OUT/status || echo FAIL > $OUT/status
date +%s > $OUT/t1
