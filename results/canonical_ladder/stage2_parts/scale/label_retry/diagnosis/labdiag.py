import json, sys
import numpy as np
from scapo.data import load
data, snap = sys.argv[1:3]
ds = load(data, "train")
gt = ds.arrays(["part_label", "joint_state"])
d = json.load(open(f"{snap}_tgtdiag.json"))
lab = np.load(f"{snap}/split_labels.npy")
idx = np.array(d["idx"]); a = np.array(d["angle"]); bad = idx[a > 15]; good = idx[a <= 15]
tl = gt["part_label"]; js = gt["joint_state"]
print("joint_state shape", js.shape)
for name, s in (("good", good), ("bad", bad)):
    C = np.zeros((3, 3))
    for m in s:
        for p in range(3):
            for t in range(3):
                C[p, t] += ((lab[m] == p) & (tl[m] == t)).sum()
    print(name, len(s), "rows slot, cols true part; share of slot's points\n", (C / C.sum(1, keepdims=True)).round(2),
          "\nslot sizes", (C.sum(1) / len(s)).round(1), "true sizes", (C.sum(0) / len(s)).round(1))
    mn = js[s].min(1); mx = js[s].max(1)
    print(" min temple state quartiles", np.percentile(mn, [25, 50, 75]).round(2), "max", np.percentile(mx, [25, 50, 75]).round(2))
# base share of visible points
