"""How well can a nearest-keypoint segmentation do at best? Per dataset and split, the part IoU (S, %, as the
evaluator computes it) of labelling every object point with its nearest part centroid, the centroids taken
from the ground truth of that very view (an oracle keypoint set), in two frames:

- observed: the articulated cloud (SCAPO applies ``L_seg`` / ``L_kp-seg`` to the aligned observation
  ``S_obj``, which is this cloud up to a rigid motion);
- rest: the object's rest-state NPCS coordinates (the articulation-normalised canonical shape ``S*``).

SCAPO's ``L_seg`` (paper Sec. 3.3) trains the skinning weights towards exactly this labelling (each point to
its nearest keypoint), and our initial part split (``scapo.models.part_init``) is a nearest-keypoint split,
so these numbers bound what those terms can teach: a Voronoi cell of two points is a half-space, which cannot
cut a small door flush with a large body. Beside them, the same oracle with Gaussian bones, the form of the
paper's skinning field (Sec. 3.2: each part a Gaussian; here its centre and covariance are fitted to the view's
true part points and ``Q`` is the inverse covariance; every point goes to the part of highest likelihood,
Mahalanobis distance plus log-determinant): what a segmentation label built from the bones' shapes could
teach instead. Usage: ``.venv/bin/python bench/diagnostics/seg_ceiling.py DATASET [DATASET ...]``; prints Markdown.
"""

import sys

import numpy as np

from scapo.data import load
from scapo.eval.metrics import segmentation_iou


def nearest_centroid_s(points: np.ndarray, labels: np.ndarray, num_parts: int) -> float:
    """Mean over views of the mean part IoU (%) of nearest-GT-centroid labels: ``points (M, N, 3)``,
    ``labels (M, N)`` int (-1 not object)."""
    out = []
    for x, lab in zip(points, labels):
        obj = lab >= 0
        c = np.stack([x[lab == p].mean(0) if (lab == p).any() else np.full(3, np.inf) for p in range(num_parts)])
        pred = np.full_like(lab, -1)
        pred[obj] = ((x[obj, None] - c[None]) ** 2).sum(-1).argmin(1)
        out.append(np.nanmean(segmentation_iou(pred, lab, num_parts)))
    return 100.0 * float(np.mean(out))


def gaussian_bone_s(points: np.ndarray, labels: np.ndarray, num_parts: int) -> float:
    """As :func:`nearest_centroid_s` with each part a Gaussian fitted to the view's true part points."""
    out = []
    for x, lab in zip(points.astype(np.float64), labels):
        obj = lab >= 0
        cost = np.full((int(obj.sum()), num_parts), np.inf)
        for p in range(num_parts):
            q = x[lab == p]
            if len(q) < 4:
                continue
            cov = np.cov(q.T)
            cov += 1e-6 * np.trace(cov) * np.eye(3)  # flat parts: a tiny isotropic floor keeps it invertible
            dx = x[obj] - q.mean(0)
            cost[:, p] = np.einsum("ni,ij,nj->n", dx, np.linalg.inv(cov), dx) + np.log(np.linalg.det(cov))
        pred = np.full_like(lab, -1)
        pred[obj] = cost.argmin(1)
        out.append(np.nanmean(segmentation_iou(pred, lab, num_parts)))
    return 100.0 * float(np.mean(out))


if __name__ == "__main__":
    from scapo.provenance import provenance

    print("# Segmentation ceilings: nearest keypoint and Gaussian bones at each view's true parts\n\n"
          "Written by `.venv/bin/python bench/diagnostics/seg_ceiling.py DATASET ...` (see its docstring). The learned "
          "segmentation's S is in the tables beside this file.\n")
    print("| dataset | split | views | nearest keypoint: S observed (%) | S rest / NPCS (%) | Gaussian bones: S "
          "observed (%) | S rest / NPCS (%) | moving-part share of points |\n|:--|:--|--:|--:|--:|--:|--:|--:|")
    hashes = {}
    for d in sys.argv[1:]:
        name = d.rstrip("/").split("/")[-1]
        hashes[name] = load(d, "test").dataset_hash[:16]
        for split in ("val", "test"):
            ds = load(d, split)
            a = ds.arrays(["points", "npcs", "part_label"])
            moving = np.mean([(lab[lab >= 0] > 0).mean() for lab in a["part_label"]])
            s = [f(a[k], a["part_label"], ds.num_parts) for f in (nearest_centroid_s, gaussian_bone_s)
                 for k in ("points", "npcs")]
            print(f"| {name} | {split} | {len(ds)} | " + " | ".join(f"{v:.1f}" for v in s) + f" | {moving:.2f} |")
    p = provenance(datasets=hashes)
    print("\nProvenance: " + ", ".join(f"{k}={p[k]}" for k in ("commit", "time", "datasets") if k in p))
