#!/usr/bin/env bash
# The canonical-frame ladder's rung 3 (single views in the paper's regime, laptop) with the `paper` presets of every
# trained method on one CUDA GPU (issue 52, item 5): the four methods train side by side, one process each, for
# BUDGET minutes of the GPU shared by the four (each measures its training speed under that sharing first), then
# predict one-pass and are scored on val; the combined table is written by a last `--finished-only` run.
# The dataset is the CPU ladder's (rendered by `scapo bench ladder --data-only`, copied to WORK/ladder/data/), so
# the machine needs no renderer.
#   WORK=gpu_carry BUDGET=5 OUT=results/canonical_ladder/gpu_paper bash bench/gpu_ladder.sh
#   DEVICE=cpu PRESET=test BUDGET=0.05 INSTANCES=10 VIEWS=2 TRAIN_VIEWS=12 SEED=0 WORK=/tmp/w OUT=/tmp/o \
#     bash bench/gpu_ladder.sh --allow-dirty      # a CPU smoke run
# Environment: PY (python3 with scapo importable), DEVICE (cuda), PRESET (paper), BUDGET (5), METHODS
# (scapo,op-align,eap,npcs), LIMIT (seconds per method process, 540), INSTANCES/VIEWS/TRAIN_VIEWS/SEED (60/8/16/1:
# the ladder's), THREADS (CPU threads per process, 4).
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
PY=${PY:-.venv/bin/python}
DEVICE=${DEVICE:-cuda}
PRESET=${PRESET:-paper}
BUDGET=${BUDGET:-5}
METHODS=${METHODS:-scapo,op-align,eap,npcs}
: "${WORK:?give WORK: the folder whose ladder/data/ holds the dataset of the rung}"
: "${OUT:?give OUT: the folder for the ladder table}"
common=(bench ladder --category laptop --rungs paper --preset "$PRESET" --device "$DEVICE" --budget-minutes "$BUDGET"
        --instances "${INSTANCES:-60}" --views "${VIEWS:-8}" --train-views "${TRAIN_VIEWS:-16}" --seed "${SEED:-1}"
        --work "$WORK" --no-progress)
mkdir -p "$OUT/logs"
start=$(date +%s)
pids=()
for m in ${METHODS//,/ }; do
  OMP_NUM_THREADS=${THREADS:-4} timeout "${LIMIT:-540}" "$PY" -m scapo.cli.main "${common[@]}" --methods "$m" \
    --out "$OUT/logs/$m" "$@" > "$OUT/logs/$m.log" 2>&1 &
  pids+=($!)
done
rc=0
for p in "${pids[@]}"; do wait "$p" || rc=$?; done
"$PY" -m scapo.cli.main "${common[@]}" --methods "$METHODS" --out "$OUT" --finished-only "$@" > "$OUT/logs/table.log" 2>&1 \
  || rc=$?
echo "bench/gpu_ladder.sh: $(( $(date +%s) - start )) s of wall time; exit $rc"
tail -n 3 "$OUT"/logs/*.log
exit $rc
