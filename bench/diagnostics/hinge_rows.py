"""The hinge step (:mod:`scapo.steps.hinge`) applied to predictions files already written, e.g. a table's cells.

    python bench/diagnostics/hinge_rows.py --data DATA --pred PREDICTIONS.npz [...] --out-dir DIR [--axis] \\
        [--bar-axis] [--frames]

Writes ``DIR/<name>+hinge.npz`` for each input (the label ``<method>+hinge``; the source's label in
``info["hinge_source"]``), to be scored beside the sources by ``scapo evaluate --pred SOURCES... HINGED...``. The
step reads only each prediction and the points, so this is what ``scapo predict --option hinge=true`` gives, without
predicting again: the one-pass predictions keep the commit that made them, and the step's own commit is this one's.
With ``--frames`` each file then goes through the ``hinge_frames`` step (``<name>+hinge[-axis]+hinge-frames.npz``;
its offsets are fitted on the file's own training-split predictions, which a self-supervised method's file holds).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def with_true_joints(data, preds):
    """A copy of ``preds`` whose ``part_label``, ``joint_axis`` and ``joint_pivot`` are the dataset's ground truth of
    each sample (marked as passed through the hinge step, so that :func:`scapo.steps.hinge.hinge_frame_predictions`
    takes it).

    Raises:
        PredictionError: samples the dataset lacks, or another dataset's predictions.
    """
    from scapo.eval.predictions import Predictions
    from scapo.steps.hinge import prediction_arrays

    gt = prediction_arrays(data, preds, ("part_label", "joint_axis", "joint_pivot"))
    kw = {k: getattr(preds, k) for k in ("instance_id", "view_id", "split", "part_pose", "joint_parts", "joint_type",
                                         "joint_state", "T_cam_obj")}
    info = {**preds.info, "hinge": {"diagnosis": "the true split, axes and pivots"},
            "diagnosis": "ground truth: part_label, joint_axis, joint_pivot; the method's own part poses"}
    return Predictions(method=f"{preds.method}-true-joints", part_label=gt["part_label"],
                       joint_axis=gt["joint_axis"], joint_pivot=gt["joint_pivot"],
                       needs_alignment=preds.needs_alignment, supervision=dict(preds.supervision),
                       dataset_hash=preds.dataset_hash, info=info, **kw)


def with_true_labels(data, preds):
    """A copy of ``preds`` whose ``part_label`` is the dataset's ground truth of each sample (slots = true parts, so
    slot 0 the root), everything else the method's: a diagnosis of the steps that read the split (``--true-labels``).

    Raises:
        PredictionError: samples the dataset lacks, or another dataset's predictions.
    """
    from scapo.eval.predictions import Predictions
    from scapo.steps.hinge import prediction_arrays

    gt = prediction_arrays(data, preds, ("part_label",))
    kw = {k: getattr(preds, k) for k in ("instance_id", "view_id", "split", "part_pose", "joint_parts", "joint_type",
                                         "joint_state", "T_cam_obj", "joint_axis", "joint_pivot")}
    info = {**preds.info, "diagnosis": "ground truth: part_label; the method's own joints and part poses"}
    return Predictions(method=f"{preds.method}-true-labels", part_label=gt["part_label"],
                       needs_alignment=preds.needs_alignment, supervision=dict(preds.supervision),
                       dataset_hash=preds.dataset_hash, info=info, **kw)


def main(argv=None) -> int:
    from scapo.errors import PredictionError, ScapoError
    from scapo.eval.predictions import Predictions
    from scapo.steps.hinge import hinge_frame_predictions, hinge_predictions

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--pred", nargs="+", required=True)
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--axis", action="store_true", help="also the axes from the parts' planes (hinge_axis=true)")
    ap.add_argument("--bar-axis", action="store_true",
                    help="also the axes of bar-shaped children from their parents' principal directions, the rank "
                         "chosen on each file's training split (scapo.steps.hinge.bar_axis_choice)")
    ap.add_argument("--frames", action="store_true",
                    help="then the part rotations from the hinges (hinge_frames=true; offsets fitted on each file's "
                         "training split); a file already hinged goes through this step alone")
    ap.add_argument("--view-prior", action="store_true",
                    help="with --frames: each view's root part chosen by the training views' prior "
                         "(hinge_view_prior=true)")
    ap.add_argument("--true-joints", action="store_true",
                    help="a diagnosis, not a row: with --frames, the true split, axes and pivots replace each file's "
                         "before the frames step (bench/diagnostics/hinge_frames_ceiling.py)")
    ap.add_argument("--true-labels", action="store_true",
                    help="a diagnosis, not a row: the true split replaces each file's labels before the hinge step "
                         "(the method's own axes, pivots and part poses)")
    ap.add_argument("--skip-without-train", action="store_true",
                    help="with --frames: pass over (and name on stderr) a file with no training-split predictions "
                         "(a supervised method's or ICP's) instead of stopping")
    a = ap.parse_args(argv)
    out = Path(a.out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        for f in a.pred:
            p = Predictions.load(f)
            stem = Path(f).stem
            if a.frames and a.skip_without_train and not (p.split == "train").any():
                print(f"scapo: skipped {f}: no training-split predictions to fit the hinge frames on (predict it "
                      "with --option hinge_frames=true)", file=sys.stderr)
                continue
            if a.true_joints:
                if not a.frames:
                    raise PredictionError("--true-joints diagnoses the frames step; give --frames too")
                p = with_true_joints(a.data, p)
                stem += "+true-joints"
            elif "hinge" not in p.info:
                if a.true_labels:
                    p = with_true_labels(a.data, p)
                    stem += "+true-labels"
                p = hinge_predictions(a.data, p, axis_from_planes=a.axis, axis_from_bars=a.bar_axis)
                stem += ("+hinge-axis" if a.axis else "+hinge") + ("-bar" if a.bar_axis else "")
            elif not a.frames:
                raise PredictionError(f"{f} already went through the hinge step")
            if a.frames:
                p = hinge_frame_predictions(a.data, p, view_prior=a.view_prior)
                stem += "+hinge-frames" + ("+view-prior" if a.view_prior else "")
            dst = out / (stem + ".npz")
            p.save(dst)
            print(f"wrote {dst}")
    except (ScapoError, OSError) as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
