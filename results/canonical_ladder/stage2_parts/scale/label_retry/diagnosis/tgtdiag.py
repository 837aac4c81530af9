"""Diagnosis (session 37): which training clouds' stage-2 target frames leave the one frame, and how.

Reads a run's frame_targets.npy and split_labels.npy and the training split's true labels and rotations (the run
never reads them). For every cloud with a target: the offset O_i = T_i^T R_gt_i; the consensus offset (most inliers
within 15 deg); each outlier's residual rotation O_c^T O_i (object frame) as angle and axis; and the signed base
axes recomputed with the TRUE labels in the same frame construction, to tell label errors from sign-cue errors.

    python tgtdiag.py DATA RUN OUT.json
"""
import json
import sys

import numpy as np
from scipy.spatial.transform import Rotation

from scapo.data import load
from scapo.ops import signed_axes

data, run, out = sys.argv[1:4]
ds = load(data, "train")
gt = ds.arrays(["points", "part_label", "T_cam_obj"])
F = np.load(f"{run}/frame_targets.npy")
lab = np.load(f"{run}/split_labels.npy")
has = np.abs(F).sum((1, 2)) > 0
Rg = gt["T_cam_obj"][:, :3, :3]
O = np.einsum("mji,mjk->mik", F, Rg)  # canonical <- object
idx = np.flatnonzero(has)


def ang(A, B):
    c = (np.einsum("...ij,...ij->...", A, B) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


best, bi = -1, None
for h in idx[:: max(1, len(idx) // 400)]:
    n = (ang(O[idx], O[h][None]) <= 15).sum()
    if n > best:
        best, bi = n, h
Oc = O[bi]
# refine consensus: chordal mean of inliers
inl = idx[ang(O[idx], Oc[None]) <= 15]
U, _, Vt = np.linalg.svd(O[inl].mean(0))
Oc = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
res = np.einsum("ji,mjk->mik", Oc, O)  # object-frame residual Oc^T O_i
rv = Rotation.from_matrix(res[idx]).as_rotvec()
a = np.degrees(np.linalg.norm(rv, axis=1))
axis = rv / np.maximum(np.linalg.norm(rv, axis=1, keepdims=True), 1e-9)
bad = a > 15
print(f"clouds {len(F)} with target {has.sum()} consistency {1 - bad.mean():.3f}")
ax_abs = np.abs(axis[bad])
dom = np.argmax(ax_abs, 1)
print("bad:", bad.sum(), "angle hist", np.histogram(a[bad], [15, 45, 90, 135, 160, 181])[0].tolist())
print("bad dominant object axis (x,y,z) counts", np.bincount(dom, minlength=3).tolist(),
      "mean |axis comp| along dominant", ax_abs.max(1).mean().round(3) if bad.any() else None)
half_x = bad & (a > 150) & (np.abs(axis[:, 0]) > 0.9)
print("half turns about object x:", int(half_x.sum()))
# label quality per cloud: pseudo-label accuracy under the best global slot permutation
import itertools
P = int(gt["part_label"].max()) + 1
tl = gt["part_label"]
best_perm, best_acc = None, -1
for perm in itertools.permutations(range(P)):
    acc = np.mean(np.array(perm)[np.clip(lab, 0, P - 1)] == tl)
    if acc > best_acc:
        best_acc, best_perm = acc, perm
mapped = np.array(best_perm)[np.clip(lab, 0, P - 1)]
base_true = int(best_perm[0])
base_iou = []
for m in range(len(lab)):
    p, t = lab[m] == 0, tl[m] == base_true
    base_iou.append((p & t).sum() / max((p | t).sum(), 1))
base_iou = np.array(base_iou)
print("best perm", best_perm, "acc", round(best_acc, 3), "base slot -> true part", base_true)
print("base IoU good clouds", base_iou[idx[~bad]].mean().round(3), "bad clouds", base_iou[idx[bad]].mean().round(3))
# frame from TRUE labels, same construction (camera frame points)
pts = gt["points"]
tl_slot = np.full_like(tl, -1)
for s, t in enumerate(best_perm):
    tl_slot[tl == t] = s
pair = signed_axes.choose_signed_pair(pts, lab, 0, min_points=8, axes="plane")
pair_t = signed_axes.choose_signed_pair(pts, tl_slot, 0, min_points=8, axes="plane")
E_p, ok_p = signed_axes.parts_signed_axes(pts, lab, pair, 0, 8, axes="plane")
E_t, ok_t = signed_axes.parts_signed_axes(pts, tl_slot, pair_t, 0, 8, axes="plane")
print("pairs pseudo", pair, "true", pair_t)
for name, E, ok in (("pseudo", E_p, ok_p), ("true", E_t, ok_t)):
    Ob = np.einsum("mji,mjk->mik", E, Rg)
    k = np.flatnonzero(ok)
    cnt = max((ang(Ob[k], Ob[h][None]) <= 15).sum() for h in k[:: max(1, len(k) // 300)])
    print(f"signed-axes frames from {name} labels (plane): consistency {cnt / len(k):.3f} over {len(k)}")
json.dump({"consistency": float(1 - bad.mean()), "bad": int(bad.sum()), "half_x": int(half_x.sum()),
           "angle": a.tolist(), "axis": axis.tolist(), "idx": idx.tolist(), "base_iou": base_iou.tolist()},
          open(out, "w"))
