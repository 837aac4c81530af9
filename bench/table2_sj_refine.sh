#!/usr/bin/env bash
# Does SCAPO (SJ) keep the test-time refinement? The refinement (scapo.models.refine, our addition to the
# paper, chosen on val for the self-supervised cpu preset) takes each point's part from the fitted template and
# the joints from the template's own, so in the semi-supervised setting it replaces the outputs the labels
# trained. One choice for the five Table 2 categories, made on their val splits (never test) by the criterion
# of every earlier refinement choice (D+R, op-align protocol), between the Table 2 SJ runs' predictions (with
# the refinement, as bench/table2.sh wrote them) and the same runs predicted without it. Needs the SJ cells of
# bench/table2.sh finished; resumable (a predictions file newer than its run's checkpoint is kept). Writes
# results/table2_sj_refine_choice_val.json.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
S=.venv/bin/scapo
WORK=${WORK:-bench_work/table2_cpu}
RUN=${RUN:-scapo-sj_cpu+sj_s0}
data=()
for c in ${CATEGORIES:-basket drawer laptop scissors suitcase}; do
  d="$WORK/${c}_i80_v16_s1"
  [ -f "$d/predictions_$RUN.npz" ] || { echo "scapo: $d has no predictions_$RUN.npz; run bash bench/table2.sh first" >&2; exit 2; }
  f="$d/valchoice_${RUN}_norefine.npz"
  [ "$f" -nt "$d/run_$RUN/checkpoint.pt" ] || $S predict --run "$d/run_$RUN" --data "$d" --out "$f" --option refine_steps=0 \
      --option label=scapo-sj-no-refine
  data+=(--data "$d")
done
$S bench choose "${data[@]}" --protocol op-align --criterion D+R \
  --candidate "refine={data}/predictions_$RUN.npz" --candidate "norefine={data}/valchoice_${RUN}_norefine.npz" \
  --out results/table2_sj_refine_choice_val.json
