#!/usr/bin/env bash
# One-command GPU run (issue 30): Table 1's cells for one category with the `paper` presets of every trained
# method (their originals' sizes and schedules) plus ICP, on CUDA: train (seed 0), predict (one-pass and
# "+ refine" rows), evaluate, and write results/gpu/table1_gpu_<preset>_<category>.{md,csv,json,tex} with
# provenance (commit, preset, dataset hash, device, wall time and steps per cell). Resumable per cell: rerun
# after an interruption and finished cells are kept. Target: within 25 minutes on one H100-class GPU.
#   bash bench/gpu.sh                          # the GPU run (refuses without CUDA)
#   DEVICE=cpu PRESET=test INSTANCES=10 VIEWS=2 bash bench/gpu.sh --allow-dirty   # a CPU smoke run (the test)
# Environment: CATEGORY (laptop), SEEDS (0), METHODS (every registered method), INSTANCES, VIEWS (the
# bench's 150 x 8), WORK (bench_work/gpu), OUT (results/gpu), SCAPO (.venv/bin/scapo). Extra arguments go to
# `scapo bench table1`.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
SCAPO=${SCAPO:-.venv/bin/scapo}
PRESET=${PRESET:-paper}
CATEGORY=${CATEGORY:-laptop}
DEVICE=${DEVICE:-cuda}
extra=()
[ -n "${INSTANCES:-}" ] && extra+=(--instances "$INSTANCES")
[ -n "${VIEWS:-}" ] && extra+=(--views "$VIEWS")
[ -n "${METHODS:-}" ] && extra+=(--methods "$METHODS")
if [ "${DEVICE%%:*}" = cuda ]; then
  py="$(dirname "$SCAPO")/python"
  if ! "$py" -c "import sys, torch; sys.exit(0 if torch.cuda.is_available() else 1)"; then
    echo "scapo: bench/gpu.sh: no CUDA device here; for a smoke run on CPU use DEVICE=cpu PRESET=test" >&2
    exit 2
  fi
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
fi
start=$(date +%s)
"$SCAPO" bench table1 --preset "$PRESET" --device "$DEVICE" --seed 1 --seeds "${SEEDS:-0}" \
  --categories "$CATEGORY" --work "${WORK:-bench_work/gpu}" --out "${OUT:-results/gpu}" \
  --name "table1_gpu_${PRESET}_${CATEGORY}" --no-progress "${extra[@]}" "$@"
echo "bench/gpu.sh: $(( $(date +%s) - start )) s of wall time (this invocation)"
