"""session 41: the joint-state error of the laptop frames rows before (0dc6165) and after (2eb3181) the view prior's
exchanged views negate the base joint's state, per method and seed, with the share of test views the prior exchanged
(views whose labels differ from the hinge-axis file's). usage: state_sign_table.py OLD_JSON NEW_JSON HF_DIR OUT_MD"""
import glob
import json
import os
import sys

import numpy as np

from scapo.eval import Predictions

old, new, hf, out = sys.argv[1:5]


def rows(path):
    return {(r["method"], r["seed"]): r["summary"] for r in json.load(open(path))["results"]
            if r["method"].endswith("+hinge-frames+view-prior")}


before, after = rows(old), rows(new)
lines = ["# Laptop frames rows: the joint state in the views the view prior exchanges", "",
         "Test split of Table 1's laptop (0dc6165 cells). `before`: `laptop_frames.json` at 0dc6165 (session 40), "
         "where the frames step passed the network's joint state through in every view. `after`: the same steps at "
         "2eb3181, where a view whose base and lid the view prior exchanges gets the base joint's state negated "
         "(`HingeFrames.exchanged_states`). Exchanged share: test views whose labels the prior exchanged. Every "
         "other column of `laptop_frames.*` is unchanged (S, R, D, C, frame consistency are the same to the last "
         "digit).", "",
         "| frames row | seed | exchanged share (test) | state mean before | state mean after | state median before "
         "| state median after | hinge-axis row's state mean |",
         "|:--|--:|--:|--:|--:|--:|--:|--:|"]
axis = {(r["method"], r["seed"]): r["summary"] for r in json.load(open(new))["results"]
        if r["method"].endswith("+hinge-axis")}
for (m, s) in sorted(after):
    base = m.split("+")[0]
    fa = glob.glob(f"{hf}/hinge_axis/laptop/predictions_{base}_*_s{s}+hinge-axis.npz")
    ff = glob.glob(f"{hf}/hinge_frames/laptop/predictions_{base}_*_s{s}+hinge-axis+hinge-frames+view-prior.npz")
    a, f = Predictions.load(fa[0]), Predictions.load(ff[0])
    test = f.split == "test"
    key = {(i, v): k for k, (i, v) in enumerate(zip(a.instance_id, a.view_id))}
    idx = np.array([key[(i, v)] for i, v in zip(f.instance_id[test], f.view_id[test])])
    share = float((a.part_label[idx] != f.part_label[test]).any(1).mean())
    b, n, x = before[(m, s)], after[(m, s)], axis[(base + "+hinge-axis", s)]
    lines.append(f"| {m} | {s} | {share:.3f} | {b['state_deg']:.2f} | {n['state_deg']:.2f} | "
                 f"{b['state_deg_median']:.2f} | {n['state_deg_median']:.2f} | {x['state_deg']:.2f} |")
lines += ["", f"Written by `python {os.path.relpath(__file__)} {old} {new} {hf} {out}` (PYTHONPATH=/work/wt41b).", ""]
open(out, "w").write("\n".join(lines))
print("\n".join(lines))
