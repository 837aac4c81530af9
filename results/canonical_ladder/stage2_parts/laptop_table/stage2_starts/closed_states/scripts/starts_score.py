"""Ad hoc (session 44): per val view and each of stage2_starts' 24 cube-group starts, three scores of the posed
template against the view, and whether the start reaches the common object frame. Scores (normalised units, squared):
fwd  = mean over input points of the distance to the posed template (S_obj -> S_y2x; the built-in choice);
rev  = mean over template points of the distance to the input (S_y2x -> S_obj; the unseen side penalised);
vis  = the same over the template points visible from the camera only (hidden point removal, Katz et al. 2007, from
       the camera centre in the canonical frame, c = -R^T t), so that the unseen side is not penalised.
usage: python starts_score.py RUN DATA SPLIT OUT.npz"""
import sys

import numpy as np
import torch
from scipy.spatial import ConvexHull

from scapo.bench.ladder import frame_inliers
from scapo.data import load
from scapo.eval.evaluator import object_frame_twins
from scapo.methods.registry import load_run
from scapo.models import scapo_model as sm
from scapo.ops.chamfer import nearest_sq_dist

run, data, split, out = sys.argv[1:5]
ds = load(data, split)
twins = object_frame_twins(ds)
state = ds.arrays(["joint_state"])["joint_state"][:, 0].astype(np.float64)
G = sm.stage2_start_rotations("O")
rec = []
orig_from = sm.SCAPOModel._passes_from


def hpr(P, c, gamma=2.0):
    """Indices of the points of ``P (M, 3)`` visible from ``c (3,)`` (Katz, Tal, Basri 2007: spherical flip + hull)."""
    Q = P - c
    n = np.linalg.norm(Q, axis=1, keepdims=True).clip(1e-9)
    Rr = n.max() * 10 ** gamma
    F = Q + 2 * (Rr - n) * Q / n
    hull = ConvexHull(np.vstack([F, np.zeros((1, 3))]))
    v = hull.vertices
    return v[v < len(P)]


def _from(self, X, s1, frame=None):
    o = orig_from(self, X, s1, frame)
    fwd = nearest_sq_dist(o.S_obj, o.S_y2x).mean(-1).double().numpy()
    rev_d = nearest_sq_dist(o.S_y2x, o.S_obj).double().numpy()  # (B, M)
    c = (o.S_obj - X @ o.R).mean(1).double().numpy()  # -R^T t, the camera centre in the canonical frame
    Y = o.S_y2x.double().numpy()
    vis = np.array([rev_d[b, hpr(Y[b], c[b])].mean() for b in range(len(Y))])
    rec.append(np.stack([fwd, rev_d.mean(-1), vis], -1))
    return o


sm.SCAPOModel._passes_from = _from
T, D = [], []
for k in range(len(G)):
    sm.stage2_start_rotations = lambda name, k=k: G[k:k + 1]
    m = load_run(run, refine_steps=0, stage2_starts="O", progress=False)
    rec.clear()
    p = m.predict(ds)
    T.append(p.T_cam_obj)
    D.append(np.concatenate(rec))
    print(k, flush=True)
T, D = np.stack(T, 1), np.stack(D, 1)  # (M, K, 4, 4), (M, K, 3)
M, K = D.shape[:2]


def ang(a, b):
    return np.degrees(np.arccos(np.clip((np.einsum("...ij,...ij->...", a, b) - 1) / 2, -1, 1)))


# the common offset from the built-in choice's inliers (as starts_reach.py)
chosen = D[..., 0].argmin(1)
Tc = T[np.arange(M), chosen]
inl, _ = frame_inliers(Tc, twins)
tw = twins[:, :, :3, :3]
off = np.einsum("mji,mkjl->mkil", Tc[:, :3, :3], tw)
ref = off[np.flatnonzero(inl)[0], 0]
best_tw = ang(off, ref[None, None]).argmin(1)
U, _, Vt = np.linalg.svd(off[np.arange(M), best_tw][inl].sum(0))
C = U @ np.diag([1, 1, np.linalg.det(U @ Vt)]) @ Vt
reach = ang(np.einsum("mkji,mtjl->mktil", T[:, :, :3, :3], tw), C[None, None, None]).min(2) <= 15.0
np.savez(out, D=D, reach=reach, state=state, T=T, C=C, G=G.numpy(), score_names=np.array(["fwd", "rev", "vis"]))
print("saved", out)
