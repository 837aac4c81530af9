"""Which parts SCAPO's stage-2 pseudo-labels confuse: the ``split_labels.npy`` of runs trained with preset part
``split-labels`` (every training cloud labelled by the template fitted part by part, the labels stage 2 trains its
skinning weights towards) scored against the training split's true part labels, as
``bench/diagnostics/part_confusion.py``
scores a predictions file (no training; the true labels are read only here, never by the run).

Per run: the one assignment of label slots to the true parts with the best mean IoU over the training split, the
confusion matrix, the child IoU by joint state, and for mirror pairs (e.g. the eyeglasses' temples) whether the
exchange is a view-level swap or points mixed within views (see ``bench/diagnostics/part_confusion.py``). Where the
run wrote
``template_split.npz`` (the training sample stage 2's template came from and its split), also that split against the
true parts of the template's points; where it wrote ``frame_targets.npy`` (preset part ``stage2-parts``), the frame
consistency of the frames its pseudo-labels were made in.

    python bench/diagnostics/pseudo_label_confusion.py --data DATA --run LABEL=RUN_FOLDER [--run ...] --out \\
        results/.../NAME \\
        [--bins 0,20,50,180]

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each ``split_labels.npy``'s sha256). Exit status 2
after a ``scapo:`` message: a missing dataset or run folder, a run without ``split_labels.npy``, labels whose shape is
not the training split's ``(clouds, points)``, bad ``--bins``, or an output that cannot be written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _part_confusion():
    """``bench/diagnostics/part_confusion.py`` as a module (this folder's scripts import each other)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import part_confusion

    return part_confusion


def score_run(data: Path, run: Path, bins: list[float], pc=None) -> dict:
    """The rows of ``bench/diagnostics/part_confusion.py`` for ``run``'s ``split_labels.npy (clouds, points)`` int64
    against the true labels of ``data``'s training split.

    Raises:
        DatasetError: the run has no ``split_labels.npy``, or its shape is not the training split's part labels'."""
    import numpy as np

    from scapo.data import load
    from scapo.errors import DatasetError

    pc = pc or _part_confusion()
    f = Path(run) / "split_labels.npy"
    if not f.is_file():
        raise DatasetError(f"{run} has no split_labels.npy: give a run trained with preset part split-labels")
    try:
        pred = np.load(f, allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise DatasetError(f"{f} cannot be read as a numpy array ({e}); train the run again") from None
    ds = load(data, "train")
    gt = ds.arrays(["part_label", "joint_state", "T_cam_obj"])
    if pred.shape != gt["part_label"].shape:
        raise DatasetError(f"{f} holds labels of shape {pred.shape}, the training split of {data} "
                           f"{gt['part_label'].shape}: give the dataset the run was trained on")
    row = pc.score_labels(pred, gt["part_label"], gt["joint_state"], ds.card, bins)
    row["template"] = score_template(Path(run), gt["part_label"], len(ds.card["part_names"]), pc)
    row["frame_targets"] = score_frame_targets(Path(run), gt["T_cam_obj"])
    return row


def score_frame_targets(run: Path, gt_T) -> dict | None:
    """The object-frame consistency (:func:`scapo.eval.frames.frame_consistency`, strict) of the frames the run's
    pseudo-labels were made in and stage 2 trains in (``frame_targets.npy (clouds, 3, 3)`` float64, canonical ->
    camera, zeros where a cloud has none; preset part ``stage2-parts``) against the training split's true object
    rotations ``gt_T (clouds, 4, 4)``; None for a run without the file.

    Raises:
        DatasetError: a file that cannot be read or whose shape is not ``(clouds, 3, 3)``."""
    import numpy as np

    from scapo.errors import DatasetError
    from scapo.eval.frames import frame_consistency

    f = run / "frame_targets.npy"
    if not f.is_file():
        return None
    try:
        F = np.load(f, allow_pickle=False).astype(np.float64)
    except (OSError, ValueError, EOFError) as e:
        raise DatasetError(f"{f} cannot be read as a numpy array ({e}); train the run again") from None
    if F.shape != (len(gt_T), 3, 3):
        raise DatasetError(f"{f} holds frames of shape {F.shape}, not ({len(gt_T)}, 3, 3): give the dataset the run "
                           "was trained on")
    has = np.abs(F).sum((1, 2)) > 0
    T = np.tile(np.eye(4), (int(has.sum()), 1, 1))
    T[:, :3, :3] = F[has]
    return {"with_target": round(float(has.mean()), 4),
            "consistency": round(frame_consistency(T, gt_T[has]), 4) if has.any() else None}


def score_template(run: Path, truth, num_parts: int, pc) -> dict | None:
    """The template's split against the true labels of its points, from the run's ``template_split.npz`` (written by
    the trainer since this script's commit; None for a run without it): the training sample it came from, the true
    parts' point counts, and per split (``labels``, the start; ``labels_refit``, the split fitted again) its parts'
    point counts, the one best slot assignment's mean IoU over parts and the confusion (rows: true parts).

    Raises:
        DatasetError: a file that cannot be read, or whose sample or point indices are not in the training split."""
    import zipfile

    import numpy as np

    from scapo.errors import DatasetError

    f = run / "template_split.npz"
    if not f.is_file():
        return None
    try:
        with np.load(f, allow_pickle=False) as z:
            rec = {k: z[k] for k in z.files}
        sample, points = int(rec["sample"]), rec["points"].astype(np.int64)
        true = truth[sample][points]
    except (OSError, ValueError, EOFError, KeyError, IndexError, zipfile.BadZipFile) as e:
        raise DatasetError(f"{f} cannot be read or does not index the training split ({e}); give the dataset the "
                           "run was trained on") from None
    out = {"sample": sample, "true_part_points": np.bincount(true[true >= 0], minlength=num_parts).tolist()}
    for key in ("labels", "labels_refit"):
        if key in rec and rec[key].shape == true.shape:
            lab = rec[key][None]
            perm, miou = pc.best_assignment(lab, true[None], num_parts)
            out[key] = {"part_points": np.bincount(rec[key][rec[key] >= 0], minlength=num_parts).tolist(),
                        "mean_iou": round(miou, 4), "assignment": list(perm),
                        "confusion": pc.confusion(lab, true[None], perm, num_parts).round(4).tolist()}
    return out


def template_lines(rows: dict, card: dict) -> list[str]:
    """Markdown lines for the runs whose frame targets (:func:`score_frame_targets`) and template split
    (:func:`score_template`) were scored."""
    names = card["part_names"]
    lines = []
    ft = {label: r["frame_targets"] for label, r in rows.items() if r.get("frame_targets")}
    if ft:
        lines = ["## The frames the pseudo-labels were made in (`frame_targets.npy`)", "",
                 "Object-frame consistency against the true object rotations (share within 15 deg of one common "
                 "offset; 1: one canonical frame), over the clouds with a target.", "",
                 "| run | clouds with a target | frame consistency |", "|:--|--:|--:|"]
        for label, v in ft.items():
            cons = "-" if v["consistency"] is None else f"{v['consistency']:.3f}"
            lines.append(f"| {label} | {v['with_target']:.3f} | {cons} |")
        lines.append("")
    start = len(lines)
    for label, r in rows.items():
        t = r.get("template")
        if not t:
            continue
        if len(lines) == start:
            lines += ["## The template's split against its points' true parts", "",
                     "| run | split | training sample | true points per part | split's points per part | mean IoU | "
                     "confusion (rows true: " + ", ".join(names) + ") |", "|:--|:--|--:|:--|:--|--:|:--|"]
        for key in ("labels", "labels_refit"):
            if key in t:
                conf = "; ".join(" ".join(f"{v:.2f}" for v in row) for row in t[key]["confusion"])
                lines.append(f"| {label} | {'start' if key == 'labels' else 'refit'} | {t['sample']} | "
                             f"{t['true_part_points']} | {t[key]['part_points']} | {t[key]['mean_iou']:.3f} | {conf} |")
    return [*lines, ""] if len(lines) > start else lines


def main(argv=None) -> int:
    from scapo.bench.diagnosis import finish_diagnosis
    from scapo.errors import ScapoError

    pc = _part_confusion()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--run", action="append", default=[], help="LABEL=RUN_FOLDER (a scapo train output)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--bins", default="0,20,50,180", help="joint-state bin edges (deg or m)")
    a = ap.parse_args(argv)
    runs = [r.partition("=") for r in a.run]
    bad = [f for f in [a.data] if not Path(f).is_dir()] + [f for _, _, f in runs if not Path(f).is_dir()]
    if bad or not runs or any(not label for label, _, _ in runs):
        print(f"scapo: {bad[0] if bad else 'no --run LABEL=RUN_FOLDER'}: give a dataset folder (--data) and run "
              "folders (--run LABEL=FOLDER)", file=sys.stderr)
        return 2
    bins = pc.bin_edges(a.bins)
    if bins is None:
        print(f"scapo: --bins {a.bins!r}: give two or more increasing numbers, e.g. 0,20,50,180", file=sys.stderr)
        return 2
    try:
        from scapo.data import load

        rows = {label: score_run(Path(a.data), Path(f), bins, pc) for label, _, f in runs}
        card = load(a.data, "train").card
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    a.split = "train"
    lines = pc.render(a, rows, card) + template_lines(rows, card)
    lines[0] = lines[0].replace("# Part confusion", "# Pseudo-label confusion (split_labels.npy)")
    files = [(label, "=", str(Path(f) / "split_labels.npy")) for label, _, f in runs]
    command = "python bench/diagnostics/pseudo_label_confusion.py " + " ".join(sys.argv[1:] if argv is None else argv)
    return finish_diagnosis(a, files, lines, rows, card, command)


if __name__ == "__main__":
    raise SystemExit(main())
