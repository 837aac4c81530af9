#!/usr/bin/env bash
# The stage-2 branch correction (TrainConfig.branch_flip, scapo/models/branch.py) chosen on the val split:
# one run with it on per category (cpu preset, training seed 0) beside the run without it ("off": the
# val predictions with the upright prior at 90 deg behind results/scapo_upright_choice/, laptop seed 0 of
# bench/table1.sh's data and the eyeglasses development run on data seed 0), then `scapo bench choose`
# (criterion D+R). Existing predictions are reused; training is resumable; CORE=0|1 pins one core.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
W=bench_work/branch_dev
L=bench_work/table1_cpu/laptop_i80_v16_s1
E=bench_work/table1_cpu/eyeglasses_i80_v16_s0
U=bench_work/upright
mkdir -p "$W" results/scapo_branch_choice
export OMP_NUM_THREADS=1
for pair in "laptop_s0:$L" "eye_s0:$E"; do
  name=${pair%%:*}; data=${pair#*:}
  [ -f "$W/pred_$name.npz" ] && continue
  # the cpu preset with the correction on (no preset is registered for a setting that was not adopted)
  taskset -c "${CORE:-0}" .venv/bin/python - "$data" "$W/$name" <<'PY'
import sys
from dataclasses import replace
from scapo.models.presets import get_preset
from scapo.models.train import train
train(sys.argv[1], sys.argv[2], replace(get_preset("cpu"), branch_flip=True, name="cpu+branch"), progress=False)
PY
  taskset -c "${CORE:-0}" $S predict --method scapo --run "$W/$name" --data "$data" --out "$W/pred_$name.npz"
done
$S bench choose --data "$L" --candidate "off=$U/laptop_s0c_u90.npz" --candidate "on=$W/pred_laptop_s0.npz" \
  --criterion D+R --out results/scapo_branch_choice/laptop_val.json
$S bench choose --data "$E" --candidate "off=$U/eye_s0_u90.npz" --candidate "on=$W/pred_eye_s0.npz" \
  --criterion D+R --out results/scapo_branch_choice/eyeglasses_dev_val.json
