#!/bin/bash
# usage: trainX.sh WORKTREE DATA PRESET SEED NAME [--set ...]
WT=$1; DATA=$2; PRESET=$3; SEED=$4; NAME=$5; shift 5
OUT=/work/exp/s38/x/$NAME
mkdir -p $OUT
export PYTHONPATH=$WT OMP_NUM_THREADS=1 MKL_NUM_THREADS=1
S=/work/main/.venv/bin/scapo
( cd $WT && git rev-parse HEAD ) > $OUT/commit.txt
date +%s > $OUT/t0
$S train --data $DATA --preset $PRESET --seed $SEED --out $OUT/run --no-progress "$@" > $OUT/train.log 2>&1 || { echo FAIL train > $OUT/status; exit 1; }
date +%s > $OUT/t1
$S predict --run $OUT/run --data $DATA --out $OUT/pred.npz --option refine_steps=0 --no-progress > $OUT/predict.log 2>&1 || { echo FAIL predict > $OUT/status; exit 1; }
date +%s > $OUT/t2
echo DONE > $OUT/status
