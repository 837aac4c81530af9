#!/usr/bin/env bash
# Table 1 (paper viewpoints, laptop + eyeglasses) at 70ca330, the chains split by predicted cost (session 45):
# A: scapo laptop s0-2, then op-align both; B: npcs, eap, icp both, then scapo eyeglasses s0-2.
set -uo pipefail
cd /work/wt45
export PYTHONPATH=/work/wt45 OMP_NUM_THREADS=1
S=/work/main/.venv/bin/scapo
W=/work/exp/s45/t1
while kill -0 9659 2>/dev/null; do sleep 10; done
common=(bench table1 --viewpoints paper --seeds 0,1,2 --budget-minutes 5 --no-refine-rows --work "$W"
        --name table1_paper_two_categories --no-progress --archive /work/main/results/tables_cells/table1_paper_two_categories)
( $S "${common[@]}" --categories laptop --out "$W/out_a1" --methods scapo
  $S "${common[@]}" --categories laptop,eyeglasses --out "$W/out_a2" --methods op-align ) > "$W/chain_a.log" 2>&1 &
a=$!
for i in $(seq 90); do grep -q "datasets ready\|computed\|scapo train\|Epoch\|step" "$W/chain_a.log" 2>/dev/null && break; sleep 2; done
sleep 20
( $S "${common[@]}" --categories laptop,eyeglasses --out "$W/out_b1" --methods npcs,eap,icp
  $S "${common[@]}" --categories eyeglasses --out "$W/out_b2" --methods scapo ) > "$W/chain_b.log" 2>&1 &
b=$!
wait $a $b
$S "${common[@]}" --categories laptop,eyeglasses --finished-only --out /work/exp/s45/out > "$W/finish.log" 2>&1
echo done > "$W/ALL_DONE"
