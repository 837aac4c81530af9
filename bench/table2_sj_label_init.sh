#!/usr/bin/env bash
# SCAPO (SJ) with the template's parts started from the segmentation labels (TrainConfig.label_init, the /sj
# presets since its commit) against the runs trained before it (part_init's unlabeled split in an arbitrary
# order), on the val splits of the five Table 2 categories (never test), by the criterion of the earlier
# refinement choices (D+R, op-align protocol; the val S is in the file too). bench/table2.sh set the earlier
# runs aside as stale (<dataset>/stale/scapo-sj_cpu+sj_s0-<UTC time>/) when it retrained them; the first
# of them per category is compared. Writes results/table2_sj_label_init_choice_val.json.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
WORK=${WORK:-bench_work/table2_cpu}
RUN=${RUN:-scapo-sj_cpu+sj_s0}
data=()
for c in ${CATEGORIES:-basket drawer laptop scissors suitcase}; do
  d="$WORK/${c}_i80_v16_s1"
  old=$(ls -d "$d"/stale/"$RUN"-*/ 2>/dev/null | sort | head -1)
  [ -n "$old" ] && [ -f "$old/predictions_$RUN.npz" ] || { echo "scapo: $d has no earlier (stale) $RUN run" >&2; exit 2; }
  [ -f "$d/predictions_$RUN.npz" ] || { echo "scapo: $d has no predictions_$RUN.npz; run bash bench/table2.sh first" >&2; exit 2; }
  mkdir -p "$d/valchoice_label_init"
  ln -sfn "$(cd "$old" && pwd)/predictions_$RUN.npz" "$d/valchoice_label_init/part_init.npz"
  data+=(--data "$d")
done
.venv/bin/scapo bench choose "${data[@]}" --protocol op-align --criterion D+R \
  --candidate "label_init={data}/predictions_$RUN.npz" --candidate "part_init={data}/valchoice_label_init/part_init.npz" \
  --out results/table2_sj_label_init_choice_val.json
