#!/usr/bin/env bash
# Every registered method on procedural laptops (80 instances x 16 views: 64 train, 8 val, 8 test
# instances), CPU-sized presets, trained on this machine's cores: ICP, NPCS-style (supervised),
# EAP-style, OP-Align-style and SCAPO, each trained method over SEEDS. Tables under the scapo and
# op-align protocols (mean +- std over seeds, then medians and rates) go to OUT, with each run's
# training wall time in OUT/training_time.csv. NPCS-style's joint estimate (from the relative motion
# or the parent's pose) is chosen on the val split; its default in scapo/methods/npcs.py follows.
# Resumable per cell: generation resumes, a finished run is not retrained (an interrupted one resumes
# from its last epoch), an existing predictions file (written atomically) is not recomputed.
# TABLE_ONLY=1 trains nothing and makes the tables from the runs that finished.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
WORK=${WORK:-bench_work/methods_laptop}
PRESET=${PRESET:-cpu}
SEEDS=${SEEDS:-0 1}
METHODS=${METHODS:-npcs eap op-align scapo}
OUT=${OUT:-results/methods_laptop_${PRESET}}
$S generate --category laptop --instances 80 --views 16 --seed 1 --val-fraction 0.1 --cropped keep --out "$WORK/data" --no-progress
[ -f "$WORK/pred_icp.npz" ] || $S predict --method icp --data "$WORK/data" --out "$WORK/pred_icp.npz"
for s in $SEEDS; do
  for m in $METHODS; do
    run="$WORK/run_${m}_${PRESET}_s$s"
    f="$WORK/pred_${m}_${PRESET}_s$s.npz"
    if [ "${TABLE_ONLY:-0}" = 1 ]; then  # tables from the finished runs only (timing.json marks a finished run)
      [ -f "$f" ] || [ ! -f "$run/timing.json" ] || $S predict --run "$run" --data "$WORK/data" --out "$f"
      continue
    fi
    $S train --method "$m" --data "$WORK/data" --preset "$PRESET" --seed "$s" --out "$run" --no-progress
    [ -f "$f" ] || $S predict --run "$run" --data "$WORK/data" --out "$f"
  done
done
mkdir -p "$OUT"
# NPCS-style: joints from the relative motion (ANCSH) or from the parent's pose, chosen on val (lowest D)
cands=()
for j in motion parent; do
  for s in $SEEDS; do
    f="$WORK/pred_npcs_${PRESET}_s${s}_joints_$j.npz"
    [ -f "$WORK/run_npcs_${PRESET}_s$s/timing.json" ] || continue
    [ -f "$f" ] || $S predict --run "$WORK/run_npcs_${PRESET}_s$s" --data "$WORK/data" --out "$f" --option joints=$j
  done
  cands+=(--candidate "$j=$WORK/pred_npcs_${PRESET}_s*_joints_$j.npz")
done
$S bench choose --data "$WORK/data" "${cands[@]}" --criterion D --out "$OUT/npcs_joints_choice.json"
preds=("$WORK/pred_icp.npz")
for m in $METHODS; do for s in $SEEDS; do
  f="$WORK/pred_${m}_${PRESET}_s$s.npz"; [ -f "$f" ] && preds+=("$f")
done; done
{
  echo "method,seed,train_seconds"
  for m in $METHODS; do for s in $SEEDS; do
    t="$WORK/run_${m}_${PRESET}_s$s/timing.json"
    [ -f "$t" ] && echo "$m,$s,$(.venv/bin/python -c "import json,sys;print(json.load(open(sys.argv[1]))['seconds'])" "$t")"
  done; done
} > "$OUT/training_time.csv.tmp" && mv "$OUT/training_time.csv.tmp" "$OUT/training_time.csv"
for proto in scapo op-align; do
  $S evaluate --data "$WORK/data" --pred "${preds[@]}" --protocol "$proto" --out "$OUT/$proto" --name table_methods
done
