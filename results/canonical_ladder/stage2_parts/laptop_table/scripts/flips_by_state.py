"""Session 38, ad-hoc diagnosis (reads the ground truth; training never does): where the cpu-laptop runs' part
rotations flip, by the laptop's joint state, and how good their pseudo-labels are by the same state.

    PYTHONPATH=<worktree> python flips_by_state.py OUT.md [RUNS, e.g. LB0,LR0,LT0]

Inputs are the session's run folders (/work/exp/s38/x/{LB,LR}{0,1,2}), their val per-sample metrics
(/work/exp/s38/res/laptop_stage2_parts_val_*_per_sample.csv) and the dataset (/work/exp/t38/...).
"""
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from scapo.data import load
from scapo.eval.predictions import Predictions
from scapo.methods.hinge import prediction_arrays

DATA = Path("/work/exp/t38/laptop_i150_v8_t64_s0_paper")
X, RES = Path("/work/exp/s38/x"), Path("/work/exp/s38/res")
BINS = [-90, -40, -20, 0, 20, 40, 90]
# LB: cpu, LR: cpu-laptop, LT: cpu-laptop/label-retry; each row's val per-sample metrics from its evaluation
LABELS = {"LB": "cpu", "LR": "cpu-laptop", "LT": "label-retry"}
STEM = {"LB": "laptop_stage2_parts", "LR": "laptop_stage2_parts", "LT": "laptop_label_retry"}
RUNS = sys.argv[2].split(",") if len(sys.argv) > 2 else ["LB0", "LB1", "LB2", "LR0", "LR1", "LR2"]


def binned(state, values):
    cut = pd.cut(state, BINS)
    return pd.Series(values).groupby(cut, observed=False).mean()


lines = ["# Where cpu-laptop's part rotations flip, by joint state (val), and its pseudo-labels (train)", "",
         "Ad-hoc diagnosis with the ground truth (session 38, `scripts/flips_by_state.py`). State: the laptop's "
         "revolute joint state in degrees from the rest state. Flip: a part with R sym over 90 deg (the symmetric "
         "ground truth already forgiven). Slot 0 on the base: the network's slot 0 holds mostly true base points.", ""]
hdr = "| run | " + " | ".join(f"({a}, {b}]" for a, b in zip(BINS[:-1], BINS[1:])) + " |"
sep = "|:--|" + "--:|" * (len(BINS) - 1)
lines += ["## Share of val views with a flipped part (R sym > 90 deg), by state", "", hdr, sep]
lines_slot = ["## Share of val views whose slot 0 holds the base, by state", "", hdr, sep]
counts = None
for n in RUNS:
    p = Predictions.load(X / n / "pred.npz")
    rows = np.flatnonzero(p.split == "val")
    arr = prediction_arrays(DATA, p, ("part_label", "joint_state"))
    gt, st = arr["part_label"][rows], np.degrees(arr["joint_state"][rows][:, 0])
    mine = p.part_label[rows] == 0
    on_base = (mine & (gt == 0)).sum(1) / np.maximum(mine.sum(1), 1) > 0.5
    key = {(int(i), int(v)): k for k, (i, v) in enumerate(zip(p.instance_id[rows], p.view_id[rows]))}
    label = LABELS[n[:2]]
    d = pd.read_csv(RES / f"{STEM[n[:2]]}_val_{label}_laptop_s{n[-1]}_per_sample.csv")
    order = np.array([key[(i, v)] for i, v in zip(d.instance_id, d.view_id)])
    flip = ((d.R_sym_p0 > 90) | (d.R_sym_p1 > 90)).to_numpy()
    b = binned(st[order], flip.astype(float))
    if counts is None:
        counts = pd.Series(np.ones(len(order))).groupby(pd.cut(st[order], BINS), observed=False).sum()
    lines.append(f"| {label} s{n[-1]} | " + " | ".join(f"{v:.2f}" for v in b) + " |")
    s = binned(st[order], on_base[order].astype(float))
    lines_slot.append(f"| {label} s{n[-1]} | " + " | ".join(f"{v:.2f}" for v in s) + " |")
lines.append("| val views | " + " | ".join(f"{int(c)}" for c in counts) + " |")
lines += [""] + lines_slot + [""]

tr = load(DATA, "train")
a = tr.arrays(["part_label", "joint_state"])
gl, ts = a["part_label"], np.degrees(a["joint_state"][:, 0])
lines += ["## Pseudo-label mean IoU (train, best of the two slot orders per cloud), by state", "", hdr, sep]
for n in [r for r in RUNS if r[:2] != "LB"]:
    pl = np.load(X / n / "run" / "split_labels.npy")
    ious = []
    for order in ((0, 1), (1, 0)):
        m = [((pl == order[k]) & (gl == k)).sum(1) / np.maximum(((pl == order[k]) | (gl == k)).sum(1), 1)
             for k in range(2)]
        ious.append((m[0] + m[1]) / 2)
    best = np.maximum(*ious)
    lines.append(f"| {LABELS[n[:2]]} s{n[-1]} | " + " | ".join(f"{v:.2f}" for v in binned(ts, best)) + " |")
c = pd.Series(np.ones(len(ts))).groupby(pd.cut(ts, BINS), observed=False).sum()
lines.append("| train clouds | " + " | ".join(f"{int(v)}" for v in c) + " |")
Path(sys.argv[1]).write_text("\n".join(lines) + "\n")
print("\n".join(lines))
