#!/usr/bin/env bash
# The upright prior of SCAPO's test-time refinement (RefineConfig.upright_deg) chosen on the val split:
# predictions of finished cpu-preset runs with the prior off (0) and at 90 deg, then `scapo bench choose`
# (criterion D+R, averaged over the runs). Laptop: the two runs of bench/table1.sh's laptop data
# (training seeds 0 and 1); eyeglasses: one development run on a separate draw of the data (data seed 0).
# Needs those runs (bash bench/table1.sh; the eyeglasses run: scapo train --data
# bench_work/table1_cpu/eyeglasses_i80_v16_s0 --preset cpu --seed 0 --out bench_work/scapo_dev/eye_cpu_s0).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
W=bench_work/upright_sh
mkdir -p "$W" results/scapo_upright_choice
L=bench_work/table1_cpu/laptop_i80_v16_s1
E=bench_work/table1_cpu/eyeglasses_i80_v16_s0
for deg in 0 90; do
  for s in 0 1; do
    f="$W/laptop_s${s}_u$deg.npz"
    [ -f "$f" ] || $S predict --run "$L/run_scapo_cpu_s$s" --data "$L" --option refine_upright_deg=$deg --out "$f"
  done
  f="$W/eye_s0_u$deg.npz"
  [ -f "$f" ] || $S predict --run bench_work/scapo_dev/eye_cpu_s0 --data "$E" --option refine_upright_deg=$deg --out "$f"
done
$S bench choose --data "$L" --candidate "0=$W/laptop_s*_u0.npz" --candidate "90=$W/laptop_s*_u90.npz" \
  --criterion D+R --out results/scapo_upright_choice/laptop_val.json
$S bench choose --data "$E" --candidate "0=$W/eye_s0_u0.npz" --candidate "90=$W/eye_s0_u90.npz" \
  --criterion D+R --out results/scapo_upright_choice/eyeglasses_dev_val.json
