#!/bin/bash
# session 40: bench/table1_paper_two_categories.sh HINGE=1's hinge_rows calls, one file at a time (the same outputs;
# a file already written is kept, so an interrupted run goes on), at 0dc6165 from /work/wt39t. usage: hinge_all.sh CATEGORY
set -e
cat=$1
cd /work/exp/tab39/w
export PYTHONPATH=/work/wt39t OMP_NUM_THREADS=1
P=/work/main/.venv/bin/python
data=${cat}_i150_v8_t64_s0_paper
for f in $data/predictions_*.npz; do
  n=$(basename $f .npz)
  [ -f hinge/$cat/$n+hinge.npz ] || $P /work/wt39t/bench/hinge_rows.py --data $data --pred $f --out-dir hinge/$cat
  [ -f hinge_axis/$cat/$n+hinge-axis.npz ] || $P /work/wt39t/bench/hinge_rows.py --axis --data $data --pred $f --out-dir hinge_axis/$cat
done
echo done > /work/exp/s40/hinge_$cat.status
