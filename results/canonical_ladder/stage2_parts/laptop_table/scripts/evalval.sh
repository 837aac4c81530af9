#!/bin/bash
# usage: evalval.sh SPLIT NAME BASE_PREFIX NEW_PREFIX NEW_LABEL [BASE_LABEL [WORKTREE]]
#   BASE_LABEL defaults to cpu, WORKTREE (a clean checkout of the runs' commit) to /work/wt38 (4573a45)
#   session 38: evalval.sh {val,test} laptop_stage2_parts LB LR cpu-laptop
#               evalval.sh val laptop_label_retry LR LT label-retry cpu-laptop /work/wt38t   (c13b4c7)
SPLIT=$1; NAME=$2; B=$3; N=$4; NL=$5; BL=${6:-cpu}; WT=${7:-/work/wt38}
D=/work/exp/t38/laptop_i150_v8_t64_s0_paper
X=/work/exp/s38/x
OUT=/work/exp/s38/res
mkdir -p $OUT
export PYTHONPATH=$WT OMP_NUM_THREADS=1
cd $WT
/work/main/.venv/bin/scapo evaluate --data $D --split $SPLIT --no-progress --out $OUT --name ${NAME}_$SPLIT \
  --pred $BL=$X/${B}0/pred.npz $BL=$X/${B}1/pred.npz $BL=$X/${B}2/pred.npz \
         $NL=$X/${N}0/pred.npz $NL=$X/${N}1/pred.npz $NL=$X/${N}2/pred.npz > $OUT/eval_${NAME}_$SPLIT.log 2>&1
/work/main/.venv/bin/python bench/frame_consistency.py --data $D --split $SPLIT --out $OUT/${NAME}_${SPLIT}_frame_consistency \
  --pred ${B}0=$X/${B}0/pred.npz --pred ${B}1=$X/${B}1/pred.npz --pred ${B}2=$X/${B}2/pred.npz \
  --pred ${N}0=$X/${N}0/pred.npz --pred ${N}1=$X/${N}1/pred.npz --pred ${N}2=$X/${N}2/pred.npz >> $OUT/eval_${NAME}_$SPLIT.log 2>&1
