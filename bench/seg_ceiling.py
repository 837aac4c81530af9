"""How well can a nearest-keypoint segmentation do at best? Per dataset and split, the part IoU (S, %, as the
evaluator computes it) of labelling every object point with its nearest part centroid, the centroids taken
from the ground truth of that very view (an oracle keypoint set), in two frames:

- observed: the articulated cloud (SCAPO applies ``L_seg`` / ``L_kp-seg`` to the aligned observation
  ``S_obj``, which is this cloud up to a rigid motion);
- rest: the object's rest-state NPCS coordinates (the articulation-normalised canonical shape ``S*``).

SCAPO's ``L_seg`` (paper Sec. 3.3) trains the skinning weights towards exactly this labelling (each point to
its nearest keypoint), and our initial part split (``scapo.models.part_init``) is a nearest-keypoint split,
so these numbers bound what those terms can teach: a Voronoi cell of two points is a half-space, which cannot
cut a small door flush with a large body. Usage: ``.venv/bin/python bench/seg_ceiling.py DATASET
[DATASET ...]``; prints Markdown.
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


if __name__ == "__main__":
    from scapo.provenance import provenance

    print("# Nearest-keypoint segmentation: its best S (keypoints at each view's true part centroids)\n\n"
          "Written by `.venv/bin/python bench/seg_ceiling.py DATASET ...` (see its docstring). The learned "
          "segmentation's S is in the tables beside this file.\n")
    print("| dataset | split | views | S observed (%) | S rest / NPCS (%) | moving-part share of points |\n"
          "|:--|:--|--:|--:|--:|--:|")
    hashes = {}
    for d in sys.argv[1:]:
        name = d.rstrip("/").split("/")[-1]
        hashes[name] = load(d, "test").dataset_hash[:16]
        for split in ("val", "test"):
            ds = load(d, split)
            a = ds.arrays(["points", "npcs", "part_label"])
            moving = np.mean([(lab[lab >= 0] > 0).mean() for lab in a["part_label"]])
            s_obs = nearest_centroid_s(a["points"], a["part_label"], ds.num_parts)
            s_rest = nearest_centroid_s(a["npcs"], a["part_label"], ds.num_parts)
            print(f"| {name} | {split} | {len(ds)} | {s_obs:.1f} | {s_rest:.1f} | {moving:.2f} |")
    p = provenance(datasets=hashes)
    print("\nProvenance: " + ", ".join(f"{k}={p[k]}" for k in ("commit", "time", "datasets") if k in p))
