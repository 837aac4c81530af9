"""Share of views whose object touches the image border, per dataset and split (Table 1's datasets keep such
views: they predate the crop rule of ``scapo generate --cropped``).

A stored sample has no image, so its points are projected with its ``K``: a view counts as cropped when a
point lies within 2 pixels of the border. Farthest-point sampling need not keep a border pixel, so this is a
lower bound. Usage: ``.venv/bin/python bench/diagnostics/cropped_share.py DATASET [DATASET ...]``; prints Markdown.
"""

import sys

import numpy as np

from scapo.data import load


def cropped_share(path: str, split: str, margin: float = 2.0) -> tuple[int, float]:
    ds = load(path, split)
    a = ds.arrays(["points", "K"])
    uvw = np.einsum("bij,bnj->bni", a["K"], a["points"].astype(np.float64))
    u, v = uvw[..., 0] / uvw[..., 2], uvw[..., 1] / uvw[..., 2]
    w, h = 2 * a["K"][:, 0, 2], 2 * a["K"][:, 1, 2]  # the principal point is the image centre in our renders
    crop = ((u < margin) | (v < margin) | (u > w[:, None] - margin) | (v > h[:, None] - margin)).any(1)
    return len(crop), float(crop.mean())


if __name__ == "__main__":
    from scapo.provenance import provenance

    print("| dataset | split | views | cropped (%, lower bound) |\n|:--|:--|--:|--:|")
    hashes = {}
    for d in sys.argv[1:]:
        hashes[d.rstrip("/").split("/")[-1]] = load(d, "test").dataset_hash[:16]
        for split in ("train", "val", "test"):
            try:
                n, share = cropped_share(d, split)
            except Exception:  # noqa: BLE001 - a dataset without that split
                continue
            print(f"| {d.rstrip('/').split('/')[-1]} | {split} | {n} | {100 * share:.1f} |")
    p = provenance(datasets=hashes)
    print("\nProvenance: " + ", ".join(f"{k}={p[k]}" for k in ("commit", "time", "datasets") if k in p))
