"""Which frames a method's object frame falls into: the branches of its object-frame offsets, a ground-truth diagnosis.

For each predictions file, on one split (val by default): the object-frame offsets ``O = R_pred^T R_gt`` of the base
part (``part_pose[:, 0]``, the object frame of every method here) are grouped greedily: the offset with the most others
within 15 deg (the frame consistency's threshold, :data:`scapo.eval.frames.CONSISTENCY_DEG`) and those others form the
largest branch, then the same on the rest. For the largest branches: their share of the samples and the rotation that
takes the largest branch's offset to theirs (angle, and axis in the true object frame). A frame that is one frame gives
one branch; a frame split by a near-symmetry of the object gives two large branches a half turn apart about the axis of
that symmetry (eyeglasses: about the front's normal, ``results/canonical_ladder/aligned/``).

    python bench/diagnostics/frame_branches.py --data DATA --pred LABEL=PREDICTIONS.npz [--pred ...] [--split val] \\
        --out NAME

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

from pathlib import Path


def branches(offsets, inlier_deg: float = 15.0, keep: int = 4) -> list[dict]:
    """Greedy branches of rotation offsets ``(M, 3, 3)``: a list, largest first, of ``{"share", "size", "angle_deg",
    "axis"}`` (the rotation from the largest branch's centre to this one's: ``angle_deg``, unit ``axis (3,)`` in the
    offsets' right frame, zeros for the first), at most ``keep`` of them."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    R = Rotation.from_matrix(np.asarray(offsets, dtype=np.float64))
    M = len(R)
    ang = np.array([(R[i].inv() * R).magnitude() for i in range(M)])  # (M, M) pairwise angles, rad
    near = ang < np.radians(inlier_deg)
    left = np.ones(M, dtype=bool)
    found = []
    while left.any() and len(found) < keep:
        counts = (near & left[None, :]).sum(1) * left
        c = int(np.argmax(counts))
        members = near[c] & left
        found.append((c, int(members.sum())))
        left &= ~members
    out = []
    for c, size in found:
        rv = (R[found[0][0]].inv() * R[c]).as_rotvec()
        a = float(np.linalg.norm(rv))
        out.append({"share": round(size / M, 4), "size": size, "angle_deg": round(float(np.degrees(a)), 1),
                    "axis": [round(float(x), 3) for x in (rv / a if a > 1e-9 else np.zeros(3))]})
    return out


def file_offsets(data: Path, preds, split: str):
    """The base part's offsets ``R_pred^T R_gt (M, 3, 3)`` of ``split``'s samples of a predictions file.

    Raises:
        PredictionError: predictions of another dataset, or none on ``split``."""
    import numpy as np

    from scapo.errors import PredictionError
    from scapo.steps.hinge import prediction_arrays

    rows = np.flatnonzero(preds.split == split)
    if len(rows) == 0:
        raise PredictionError(f"predictions of {preds.method!r} have no {split} samples; predict on a dataset with a "
                              f"{split} split")
    gt = prediction_arrays(data, preds, ("part_pose",))["part_pose"][rows]
    return np.einsum("bji,bjk->bik", preds.part_pose[rows][:, 0, :3, :3], gt[:, 0, :3, :3])


def main(argv=None) -> int:
    from scapo.bench.diagnosis import run_diagnosis

    def score(a, p) -> dict:
        off = file_offsets(Path(a.data), p, a.split)
        return {"samples": int(len(off)), "branches": branches(off)}

    return run_diagnosis(argv, __doc__, "frame_branches.py", score, render)


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines of the branches of every file."""
    lines = [f"# The object frame's branches ({Path(a.data).name}, {a.split})", "",
             "Greedy groups of the base part's offsets R_pred^T R_gt within 15 deg, largest first: share of the "
             "samples; the rotation from the largest group's offset to this group's (degrees, about an axis in the "
             "true object frame). One frame: one group holding every sample.", "",
             "| predictions | samples | branch 1 | branch 2 | branch 3 | branch 4 |", "|:--|--:|--:|--:|--:|--:|"]
    for label, r in rows.items():
        cells = [f"{b['share']:.2f}" if i == 0 else
                 f"{b['share']:.2f}: {b['angle_deg']:.0f} deg about ({', '.join(f'{x:.1f}' for x in b['axis'])})"
                 for i, b in enumerate(r["branches"])]
        cells += [""] * (4 - len(cells))
        lines.append(f"| {label} | {r['samples']} | " + " | ".join(cells) + " |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
