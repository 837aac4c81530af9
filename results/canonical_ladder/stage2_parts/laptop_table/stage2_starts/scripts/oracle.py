"""Oracle: the parts-signed frame from the TRUE labels, by joint state (val)."""
import sys
import numpy as np
sys.path.insert(0, "/work/main/bench")
import frame_by_state as fbs
from scapo.data import load
from scapo.bench.ladder import frame_inliers
from scapo.ops.signed_axes import choose_signed_pair, parts_signed_axes
from scapo.sim.assets.symmetry import Symmetry, twin

data = sys.argv[1]
split = sys.argv[2] if len(sys.argv) > 2 else "val"
tr = load(data, "train"); d = load(data, split)
gt = tr.arrays(["points", "part_label"])
rng = np.random.default_rng(0); idx = rng.choice(len(gt["points"]), 600, replace=False)
for axes in ("pca", "plane"):
    pair = choose_signed_pair(gt["points"][idx].astype(np.float64), gt["part_label"][idx], 0, 16, axes)
    print(axes, "pair", pair)
fields = ["T_cam_obj", "part_pose", "joint_pivot", "joint_axis", "joint_state", "bbox_diag"]
g = d.arrays(fields + ["points", "part_label"])
tw = twin({k: g[k] for k in fields}, Symmetry.from_dict(d.card["symmetry"]))
ref = np.stack([fbs.joint_frames(g["part_pose"], 0.0), fbs.joint_frames(tw["part_pose"], 0.0)], 1)
state = np.degrees(g["joint_state"][:, 0])
edges = fbs.state_bins(state, 4); which = np.clip(np.searchsorted(edges, state, side="right") - 1, 0, 3)
print("edges", np.round(edges, 1))
for axes in ("pca", "plane"):
    pair = choose_signed_pair(gt["points"][idx].astype(np.float64), gt["part_label"][idx], 0, 16, axes)
    E, ok = parts_signed_axes(g["points"].astype(np.float64), g["part_label"], pair, 0, 16, axes)
    T = np.tile(np.eye(4), (len(E), 1, 1)); T[:, :3, :3] = E
    inl, ang = frame_inliers(T, ref)
    print(axes, "ok", ok.mean(), "sym", inl.mean().round(3), [round(float(inl[which == k].mean()), 2) for k in range(4)])
