"""Does SCAPO's initial part split find the true parts when the frame is given? A ground-truth diagnosis, no training.

Stage 2 starts from :mod:`scapo.models.part_init`: one split for every cloud (keypoints, each point to its nearest),
chosen among plane splits (two parts) and k-means solutions on a template cloud by a rigidity score across pairs of
clouds. Here every training cloud is put in its **true** object frame (the ground-truth object pose; on the ladder's
``aligned`` rung the clouds already are), normalised as the trainer does (centred, divided by twice the RMS radius),
and the split is scored against the true part labels (mean IoU over parts, the best assignment of slots to parts for
the whole split, as the evaluator's S). Rows:

- ``part_init``: the trainer's procedure (:func:`scapo.models.part_init.initial_split` on a 256-point subsample of
  the clouds, the medoid as the template), with its rigidity score (lower is better), and the best of its candidates;
- ``true centroids``: the true parts' centroids of the template as the keypoints (nearest keypoint), with the same
  rigidity score: whether the score prefers the true split;
- ``per-cloud centroids, nearest keypoint``: each cloud's own true part centroids as its keypoints, each point to the
  nearest: the target of the paper's ``L_seg`` at its best;
- ``static Gaussian bones``: the skinning field's own form (:func:`scapo.nn.skinning.skinning_weights`) with one
  Gaussian bone per true part fitted to all clouds' points: the best any single split shared by every cloud reaches;
- ``per-cloud Gaussian bones``: a bone per true part fitted to each cloud's own points: what the field reaches when its
  bones follow each cloud's articulation (SCAPO's keypoint head predicts them per cloud);
- ``split_init="fit"`` (:func:`scapo.models.part_init.choose_split`, as the trainer runs it on 64 clouds): the keypoint
  split against template splits fitted part by part to the clouds, the most rigid chosen; mIoU of its cloud labels and
  of the template's labels.

    python bench/diagnostics/split_init_diagnosis.py --data DATA --out results/canonical_ladder/split_init/NAME \\
        [--clouds 672]

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash).
"""

from __future__ import annotations

import itertools
import math
import sys
from pathlib import Path


def split_miou(labels, pred, num_parts: int) -> float:
    """Mean IoU over parts of ``pred (B, N)`` slot labels against ``labels (B, N)`` true parts (int64 tensors), with the
    one assignment of slots to parts (a permutation) that is best over all clouds; per cloud, then averaged."""
    import torch

    best = 0.0
    for perm in itertools.permutations(range(num_parts)):
        ious = []
        for p in range(num_parts):
            a, b = pred == perm[p], labels == p
            ious.append((a & b).sum(1).float() / (a | b).sum(1).float().clamp_min(1))
        best = max(best, float(torch.stack(ious, 1).mean()))
    return best


def gaussian_bones(points, labels, num_parts: int):
    """One Gaussian bone per true part: ``points (M, 3)``, ``labels (M,)`` -> centres ``(P, 3)``, orientations
    ``(P, 3, 3)`` (rows: the covariance's eigenvectors) and log standard deviations ``(P, 3)``, the arguments of
    :func:`scapo.nn.skinning.skinning_weights`. A part with under 4 points gets an isotropic bone of 0.1 at the
    origin."""
    import torch

    K, V, L = [], [], []
    for p in range(num_parts):
        q = points[labels == p]
        if len(q) < 4:
            K.append(torch.zeros(3)), V.append(torch.eye(3)), L.append(torch.full((3,), math.log(0.1)))
            continue
        mu = q.mean(0)
        e, U = torch.linalg.eigh(torch.cov(q.T) + 1e-6 * torch.eye(3))
        K.append(mu), V.append(U.T), L.append(0.5 * torch.log(e))
    return torch.stack(K), torch.stack(V), torch.stack(L)


def bone_labels(X, K, V, L, gamma: float = 0.1):
    """Slot of each point of ``X (B, N, 3)`` under Gaussian bones ``K (B|1, P, 3)``, ``V (B|1, P, 3, 3)``,
    ``L (B|1, P, 3)``: the argmax of the skinning weights."""
    from scapo.nn.skinning import skinning_weights

    B, P = X.shape[0], K.shape[-2]
    w, _ = skinning_weights(X, K.expand(B, P, 3), V.expand(B, P, 3, 3), L.expand(B, P, 3), gamma)
    return w.argmax(-1)


def diagnose(X, labels, num_parts: int, seed: int = 0) -> dict:
    """The rows of the diagnosis for object-frame clouds ``X (B, N, 3)`` (normalised) with true ``labels (B, N)``."""
    import torch

    from scapo.models import part_init

    g = torch.Generator().manual_seed(seed)
    sub_idx = torch.randperm(X.shape[1], generator=g)[:256]
    sub = X[:, sub_idx]
    m = part_init.medoid(sub[:64])
    template = X[m]
    P = num_parts

    def nearest(K):
        return part_init.nearest_keypoint(X, K.expand(X.shape[0], P, 3))

    K, scores = part_init.initial_split(sub, template, P, seed=seed)
    cands = part_init.candidate_keypoints(template, P, generator=torch.Generator().manual_seed(seed))
    Kt = torch.stack([template[labels[m] == p].mean(0) if (labels[m] == p).any() else torch.zeros(3)
                      for p in range(P)])
    true_score = float(part_init.score_keypoints(sub, Kt[None], generator=torch.Generator().manual_seed(seed))[0])
    Ks, Vs, Ls = gaussian_bones(X.reshape(-1, 3), labels.reshape(-1), P)
    per = [gaussian_bones(X[b], labels[b], P) for b in range(X.shape[0])]
    Kp, Vp, Lp = (torch.stack(t) for t in zip(*per))
    shares = [float((labels == p).float().mean()) for p in range(P)]
    per_nearest = part_init.nearest_keypoint(X, Kp)
    # split_init="fit" as the trainer runs it: 64 clouds of ~128 points, a 256-point template from the medoid
    few = sub[:64, ::2]
    found = part_init.choose_split(few, template[sub_idx], part_init.part_centroids(template[sub_idx], K), seed=seed)
    few_labels = labels[:64][:, sub_idx[::2]]
    fit = {"miou": round(split_miou(few_labels, found["cloud_labels"], P), 4), "source": found["source"],
           "score": round(found["scores"][found["chosen"]], 6), "keypoint_score": round(found["scores"][0], 6),
           "keypoints_miou": round(split_miou(few_labels, nearest(K)[:64][:, sub_idx[::2]], P), 4),
           "template_miou": round(split_miou(labels[m][sub_idx][None], found["template_labels"][None], P), 4),
           "candidates": len(found["scores"])}
    return {
        "clouds": int(X.shape[0]), "points": int(X.shape[1]), "part_shares": [round(s, 4) for s in shares],
        "part_init": {"miou": round(split_miou(labels, nearest(K), P), 4), "score": round(float(scores.min()), 6),
                      "candidates": int(len(cands)),
                      "best_candidate_miou": round(max(split_miou(labels, nearest(k), P) for k in cands), 4)},
        "true_centroids": {"miou": round(split_miou(labels, nearest(Kt), P), 4), "score": round(true_score, 6)},
        "per_cloud_nearest_keypoint": {"miou": round(split_miou(labels, per_nearest, P), 4)},
        "static_gaussian_bones": {"miou": round(split_miou(labels, bone_labels(X, Ks[None], Vs[None], Ls[None]), P),
                                                4)},
        "per_cloud_gaussian_bones": {"miou": round(split_miou(labels, bone_labels(X, Kp, Vp, Lp), P), 4)},
        "split_fit": fit,
    }


def object_frame_clouds(data: Path, clouds: int):
    """The first ``clouds`` training clouds of ``data`` in their true object frame, normalised as the trainer does:
    ``(X (B, N, 3) float32, labels (B, N) int64, num_parts, card)``."""
    import numpy as np
    import torch

    from scapo.data import load

    ds = load(data, "train")
    a = ds.arrays(["points", "part_label", "T_cam_obj"])
    n = min(clouds, len(a["points"]))
    T = a["T_cam_obj"][:n]
    pts = np.einsum("bji,bnj->bni", T[:, :3, :3], a["points"][:n] - T[:, None, :3, 3])  # R^T (x - t)
    X = torch.tensor(pts, dtype=torch.float32)
    X = X - X.mean(1, keepdim=True)
    X = X / (2.0 * (X ** 2).sum(-1).mean(-1).sqrt().clamp_min(1e-6))[:, None, None]
    return X, torch.from_numpy(a["part_label"][:n]).long(), ds.num_parts, ds.card


def main(argv=None) -> int:
    from scapo.bench.diagnosis import finish_diagnosis, ground_truth_args
    from scapo.errors import ScapoError

    a = ground_truth_args(argv, __doc__.split("\n\n")[0], 672, 2, "a split is scored across pairs of clouds",
                          "training clouds used (the first ones)")
    if a is None:
        return 2
    try:
        X, labels, P, card = object_frame_clouds(Path(a.data), a.clouds)
        if P < 2:
            raise ScapoError(f"{a.data}: {P} part(s); a part split needs at least two")
        r = diagnose(X, labels, P, a.seed)
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    cmd = "python bench/diagnostics/split_init_diagnosis.py " + " ".join(sys.argv[1:] if argv is None else argv)
    pi = r["part_init"]
    lines = [f"# The initial part split with the frame given ({Path(a.data).name})", "",
             f"{r['clouds']} training clouds in their true object frame; true part shares "
             f"{', '.join(f'{s:.2f}' for s in r['part_shares'])}. mIoU: mean IoU over parts against the true labels "
             "(one slot-to-part assignment for all clouds). Score: part_init's rigidity residual (lower is "
             "better).", "",
             "| split | mIoU | rigidity score |", "|:--|--:|--:|",
             f"| part_init (the trainer's choice) | {pi['miou']:.3f} | {pi['score']:.6f} |",
             f"| best of part_init's {pi['candidates']} candidates | {pi['best_candidate_miou']:.3f} | |",
             f"| true parts' centroids as keypoints | {r['true_centroids']['miou']:.3f} | "
             f"{r['true_centroids']['score']:.6f} |",
             f"| per-cloud true centroids, nearest keypoint (L_seg's target) | "
             f"{r['per_cloud_nearest_keypoint']['miou']:.3f} | |",
             f"| static Gaussian bones of the true parts | {r['static_gaussian_bones']['miou']:.3f} | |",
             f"| per-cloud Gaussian bones of the true parts | {r['per_cloud_gaussian_bones']['miou']:.3f} | |", "",
             "`split_init=\"fit\"` as the trainer runs it (`part_init.choose_split`: 64 of the clouds, 128 points "
             "each, a 256-point template from the medoid; its rigidity score is over its own 128 pairs, so it is "
             "comparable within this table only):", "",
             "| split (64 clouds) | mIoU | template mIoU | rigidity score |", "|:--|--:|--:|--:|",
             f"| keypoint split (part_init) | {r['split_fit']['keypoints_miou']:.3f} | | "
             f"{r['split_fit']['keypoint_score']:.6f} |",
             f"| chosen of {r['split_fit']['candidates']} candidates: {r['split_fit']['source']} | "
             f"{r['split_fit']['miou']:.3f} | {r['split_fit']['template_miou']:.3f} | {r['split_fit']['score']:.6f} |"]
    a.split = "train"  # the record's split: ground truth of the training clouds, no predictions
    return finish_diagnosis(a, [], lines, r, card, cmd)


if __name__ == "__main__":
    raise SystemExit(main())
