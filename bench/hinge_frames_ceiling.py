"""The ceiling of the ``hinge_frames`` step: a diagnosis with ground truth, not a method row (issue 52).

The step reads each part's rotation from its hinge (:mod:`scapo.methods.hinge`): the joint's axis and pivot and the
split of the points. This script gives it the **true** split, axes and pivots of every sample (train and the scored
split) and keeps the method's own part poses (they set only the per-part offsets, fitted on the training split), then
applies the step with the view prior. Scored by ``scapo evaluate``, the part rotation errors say what the step can
reach once a method's split and joints are right; the gap to the method's own ``+hinge-frames`` row is the split's.

    python bench/hinge_frames_ceiling.py --data DATA --pred PREDICTIONS.npz [...] --out-dir DIR

Writes ``DIR/<name>+true-joints+hinge-frames+view-prior.npz`` (label ``<method>-true-joints+hinge-frames+view-prior``;
``info["diagnosis"]`` says what came from the ground truth). The input files need their training-split predictions
(a self-supervised method's file has them).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def with_true_joints(data, preds):
    """A copy of ``preds`` whose ``part_label``, ``joint_axis`` and ``joint_pivot`` are the dataset's ground truth of
    each sample (marked as passed through the hinge step, so that :func:`scapo.methods.hinge.hinge_frame_predictions`
    takes it).

    Raises:
        PredictionError: samples the dataset lacks, or another dataset's predictions.
    """
    from scapo.data import load
    from scapo.errors import PredictionError
    from scapo.eval.predictions import Predictions

    lab, axis, piv = preds.part_label.copy(), preds.joint_axis.copy(), preds.joint_pivot.copy()
    for split in np.unique(preds.split):
        d = load(data, str(split))
        if preds.dataset_hash and d.card.get("dataset_hash") and preds.dataset_hash != d.card.get("dataset_hash"):
            raise PredictionError(f"predictions of {preds.method!r} were made on another dataset than {data}")
        a = d.arrays(["part_label", "joint_axis", "joint_pivot"])
        key = {(int(i), int(v)): k for k, (i, v) in enumerate(zip(a["instance_id"], a["view_id"]))}
        rows = np.flatnonzero(preds.split == split)
        try:
            src = [key[(int(preds.instance_id[r]), int(preds.view_id[r]))] for r in rows]
        except KeyError as e:
            raise PredictionError(f"predictions of {preds.method!r} name sample {e.args[0]}, which the {split} "
                                  f"split of {data} lacks") from None
        lab[rows], axis[rows], piv[rows] = a["part_label"][src], a["joint_axis"][src], a["joint_pivot"][src]
    kw = {k: getattr(preds, k) for k in ("instance_id", "view_id", "split", "part_pose", "joint_parts", "joint_type",
                                         "joint_state", "T_cam_obj")}
    info = {**preds.info, "hinge": {"diagnosis": "the true split, axes and pivots"},
            "diagnosis": "ground truth: part_label, joint_axis, joint_pivot; the method's own part poses"}
    return Predictions(method=f"{preds.method}-true-joints", part_label=lab, joint_axis=axis, joint_pivot=piv,
                       needs_alignment=preds.needs_alignment, supervision=dict(preds.supervision),
                       dataset_hash=preds.dataset_hash, info=info, **kw)


def main(argv=None) -> int:
    from scapo.errors import ScapoError
    from scapo.eval.predictions import Predictions
    from scapo.methods.hinge import hinge_frame_predictions

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--pred", nargs="+", required=True)
    ap.add_argument("--out-dir", required=True)
    a = ap.parse_args(argv)
    out = Path(a.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for f in a.pred:
            p = hinge_frame_predictions(a.data, with_true_joints(a.data, Predictions.load(f)), view_prior=True)
            dst = out / (Path(f).stem + "+true-joints+hinge-frames+view-prior.npz")
            p.save(dst)
            print(f"wrote {dst}")
    except (ScapoError, OSError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
