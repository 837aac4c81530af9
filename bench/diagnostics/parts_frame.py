"""Where SCAPO's parts-signed frame holds and where it breaks: a ground-truth diagnosis of ``stage2_frame="parts"``.

For each run (trained with ``TrainConfig.stage2_frame = "parts"`` on DATA; issue 52):

- val, per prediction pass (stage 2 run again in the frame read from the base it labels,
  :meth:`scapo.models.scapo_model.SCAPOModel.parts_frames`; the method's predictions use
  ``scapo.models.scapo_model.PARTS_PASSES``): the object-frame consistency (share of views within 15 deg of the common
  offset, :func:`scapo.eval.frames.frame_consistency`) of stage 2's frame and of the base pose (``T_cam_obj``, with
  the root's motion), and the share of points whose base / not-base label is right; pass 0 is the stage-1 frame; the
  last row is the frame read from the true labels (what the step can reach with a perfect base);
- train: the run's target frames (``frame_targets.npy``) against the ground truth (frame consistency), its
  pseudo-labels' (``split_labels.npy``) base accuracy in clouds whose target is in / off the common frame, the share of
  clouds whose two children of the base (a mirror pair: the eyeglasses' temples) are exchanged (more points in the
  exchanged slots than in the kept ones; in / off frame), and the run's signed ranks with, per rank, the share of
  clouds where the other parts' centroid lies along it among the two farthest (the vote that chose the ranks);
- both, by quartile of the smallest joint state of the base's children (where the frame is lost: folded temples).

    python bench/diagnostics/parts_frame.py --data DATA --run LABEL=RUN [--run ...] [--passes 4] [--split val] --out OUT

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each run's checkpoint sha256).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

CONSISTENCY_DEG = 15.0


def _rotations_as_poses(R) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    T = np.tile(np.eye(4), (len(R), 1, 1))
    T[:, :3, :3] = R
    return T


def _common_inliers(R: np.ndarray, gt: np.ndarray, deg: float = CONSISTENCY_DEG) -> np.ndarray:
    """``(B,)`` bool: the samples whose offset ``R^T R_gt`` is within ``deg`` of the offsets' robust mean
    (:func:`scapo.eval.alignment.robust_rotation_mean`, the evaluator's alignment step)."""
    from scapo.eval.alignment import robust_rotation_mean

    return robust_rotation_mean(np.einsum("bji,bjk->bik", R, gt), inlier_deg=deg)[1]


def _mirror_children(card: dict) -> tuple[int, int] | None:
    kids = [int(c) for p, c in card["joint_parts"] if int(p) == 0]
    return (kids[0], kids[1]) if len(kids) >= 2 else None


def smallest_child_state(data: Path, split: str, card: dict) -> np.ndarray | None:
    """``(B,)`` float64: per sample of ``split`` the smallest joint state (rad or m, from the rest state) among the
    joints whose parent is the base (part 0), in the split's sample order; None without such a joint. An eyeglasses
    temple is folded at 0."""
    from scapo.data import load

    joints = [j for j, (parent, _) in enumerate(card["joint_parts"]) if int(parent) == 0]
    if not joints:
        return None
    q = np.asarray(load(data, split).manifest["joint_state"].tolist(), dtype=np.float64).reshape(-1, len(
        card["joint_parts"]))
    return q[:, joints].min(1)


def by_state(state: np.ndarray | None, inl: np.ndarray, acc: np.ndarray, bins: int = 4) -> list[dict] | None:
    """Per quantile bin of ``state (B,)`` (:func:`smallest_child_state`; ``bins`` bins over the split): the samples,
    the bin's state range, the share in the common frame (``inl (B,)`` bool) and the mean base accuracy (``acc
    (B,)``); None without a state."""
    if state is None or len(state) == 0:
        return None
    edges = np.quantile(state, np.linspace(0.0, 1.0, bins + 1))
    which = np.clip(np.searchsorted(edges, state, side="right") - 1, 0, bins - 1)
    return [{"bin": b, "state_from": float(edges[b]), "state_to": float(edges[b + 1]),
             "samples": int((which == b).sum()),
             "in_frame": float(inl[which == b].mean()) if (which == b).any() else None,
             "base_acc": float(acc[which == b].mean()) if (which == b).any() else None} for b in range(bins)]


def val_passes(model, data: Path, passes: int, split: str = "val") -> list[dict]:
    """Rows per pass on one split, val by default (see the module docstring)."""
    import torch

    from scapo.data import load
    from scapo.eval.frames import frame_consistency

    d = load(data, split)
    a = d.arrays(["points", "T_cam_obj", "part_label"])
    gt, true = a["T_cam_obj"], torch.from_numpy(a["part_label"])
    model.eval()
    rows = []
    with torch.no_grad():
        X, _ = model.normalize(torch.from_numpy(a["points"]).float())
        out = model(X, stage=2)
        labels = out.w.argmax(-1)
        rows.append({"pass": 0, "frame": frame_consistency(_rotations_as_poses(out.enc.R), gt),
                     "base_pose": None, "base_label_acc": float(((labels == 0) == (true == 0)).float().mean())})
        for k in range(1, passes + 1):
            out = model(X, stage=2, frame=model.parts_frames(X, labels))
            labels = out.w.argmax(-1)
            base = out.R @ out.T_x[:, 0, :3, :3]
            rows.append({"pass": k, "frame": frame_consistency(_rotations_as_poses(out.R), gt),
                         "base_pose": frame_consistency(_rotations_as_poses(base), gt),
                         "base_label_acc": float(((labels == 0) == (true == 0)).float().mean())})
        if passes > 0:  # the last pass by the children's smallest joint state (where the views it loses lie)
            rows[-1]["by_state"] = by_state(smallest_child_state(data, split, d.card),
                                            _common_inliers(out.R.double().numpy(), gt[:, :3, :3]),
                                            ((labels == 0) == (true == 0)).double().mean(1).numpy())
        tf = model.parts_frames(X, true)
        found = tf.flatten(1).abs().sum(-1) > 0
        reach = frame_consistency(_rotations_as_poses(tf[found]), gt[found.numpy()])
        rows.append({"pass": "true labels", "frame": reach, "base_pose": None, "base_label_acc": 1.0})
    return rows


def train_targets(run: Path, data: Path, card: dict) -> dict:
    """The run's target frames and pseudo-labels on the training split (see the module docstring).

    Raises:
        DatasetError: the run has no target frames or pseudo-labels (not a ``stage2_frame="parts"`` run, or one
            stopped before stage 2), or they do not match the training split."""
    from scapo.data import load
    from scapo.errors import DatasetError
    from scapo.eval.frames import frame_consistency
    from scapo.ops.signed_axes import _signed_candidates

    tf, sl = run / "frame_targets.npy", run / "split_labels.npy"
    if not tf.is_file() or not sl.is_file():
        raise DatasetError(f"{run}: no frame_targets.npy / split_labels.npy; train it with stage2_frame=parts (and "
                           "split_labels) past the start of stage 2")
    a = load(data, "train").arrays(["points", "part_label", "T_cam_obj"])
    T, pl = np.load(tf, allow_pickle=False), np.load(sl, allow_pickle=False)
    true = a["part_label"]
    if T.shape != (len(true), 3, 3) or pl.shape != true.shape:
        raise DatasetError(f"{run}: its target frames {T.shape} / pseudo-labels {pl.shape} do not match the "
                           f"{true.shape} training split of {data}")
    has = np.abs(T).sum((1, 2)) > 0
    inl = np.zeros(len(T), dtype=bool)
    inl[has] = _common_inliers(T[has], a["T_cam_obj"][has, :3, :3])
    base_acc = ((pl == 0) == (true == 0)).mean(1)
    out = {"clouds": int(len(T)), "with_target": int(has.sum()),
           "targets_frame": frame_consistency(_rotations_as_poses(T[has]), a["T_cam_obj"][has]),
           "base_acc_in": float(base_acc[inl].mean()) if inl.any() else None,
           "base_acc_off": float(base_acc[has & ~inl].mean()) if (has & ~inl).any() else None}
    pair = _mirror_children(card)
    if pair is not None:
        c1, c2 = pair
        keep = ((true == c1) & (pl == c1)).sum(1) + ((true == c2) & (pl == c2)).sum(1)
        swap = ((true == c1) & (pl == c2)).sum(1) + ((true == c2) & (pl == c1)).sum(1)
        exch = swap > keep
        out["mirror_exchanged_in"] = float(exch[inl].mean()) if inl.any() else None
        out["mirror_exchanged_off"] = float(exch[has & ~inl].mean()) if (has & ~inl).any() else None
    offs = np.array([o for _, o, ok in _signed_candidates(a["points"].astype(np.float64), pl, 0, 8) if ok])
    top2 = np.argsort(-np.abs(offs), 1)[:, :2] if len(offs) else np.zeros((0, 2), dtype=int)
    out["rank_top2_share"] = [float((top2 == r).any(1).mean()) if len(top2) else None for r in range(3)]
    out["by_state"] = by_state(smallest_child_state(data, "train", card), inl, base_acc)
    return out


def main(argv=None) -> int:
    import hashlib

    from scapo.bench.diagnosis import write_diagnosis
    from scapo.data import load
    from scapo.errors import ScapoError
    from scapo.models import load as load_run

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--run", action="append", required=True, metavar="LABEL=RUN")
    ap.add_argument("--passes", type=int, default=4)
    ap.add_argument("--split", default="val", help="the split the passes are scored on (default val)")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    runs = []
    for spec in a.run:
        label, sep, path = spec.partition("=")
        if not sep or not label or not path:
            print(f"scapo: --run {spec!r}: write LABEL=RUN", file=sys.stderr)
            return 2
        runs.append((label, Path(path)))
    if a.passes < 1:
        print(f"scapo: --passes {a.passes}: give at least 1", file=sys.stderr)
        return 2
    rows = {}
    try:
        card = load(a.data, a.split).card
        for label, run in runs:
            model = load_run(run, refine_steps=0).model
            if not model.uses_parts_frame:
                print(f"scapo: {run} was not trained with stage2_frame=parts; nothing to diagnose", file=sys.stderr)
                return 2
            sha = hashlib.sha256((run / "checkpoint.pt").read_bytes()).hexdigest()[:16]
            rows[label] = {"run": str(run), "signed_ranks": [int(k) for k in model.parts_pair],
                           "val": val_passes(model, Path(a.data), a.passes, a.split),
                           "train": train_targets(run, Path(a.data), card), "checkpoint_sha256_16": sha}
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    lines = render(a, rows)
    command = "python bench/diagnostics/parts_frame.py " + " ".join(sys.argv[1:] if argv is None else argv)
    lines += ["", f"Written by `{command}`."]
    try:
        write_diagnosis(a.out, lines, {"command": command, "dataset": str(a.data),
                                       "dataset_hash": card.get("dataset_hash"), "rows": rows},
                        {label: str(run / "checkpoint.pt") for label, run in runs})
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


def _f(x, nd: int = 2) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def render(a, rows: dict) -> list[str]:
    """The Markdown lines: the val passes per run, then the training targets per run."""
    lines = [f"# The parts-signed frame, pass by pass ({Path(a.data).name})", "",
             f"{a.split.capitalize()}: object-frame consistency (share within 15 deg of the common offset) of stage "
             "2's frame and of the base pose (T_cam_obj, with the root's motion) after each prediction pass (0: the "
             "stage-1 frame; "
             "'true labels': the frame read from the true base), and the share of points whose base / not-base "
             "label is right. Ground truth is read for the diagnosis only.", "",
             "| run | pass | frame | base pose | base label acc. |", "|:--|:--|--:|--:|--:|"]
    for label, r in rows.items():
        for p in r["val"]:
            lines.append(f"| {label} | {p['pass']} | {_f(p['frame'])} | {_f(p['base_pose'])} | "
                         f"{_f(p['base_label_acc'], 3)} |")
    lines += ["", "Train: the target frames' consistency against the ground truth; the pseudo-labels' base accuracy "
              "in clouds whose target is in / off the common frame; the share of clouds whose mirror pair (two "
              "children of the base) is exchanged, in / off frame; the signed ranks and, per rank (0: largest "
              "variance), the share of clouds where it is among the two the other parts lie farthest along.", "",
              "| run | targets' frame | base acc. in / off | mirror exchanged in / off | signed ranks "
              "| rank top-2 share |",
              "|:--|--:|:--|:--|:--|:--|"]
    for label, r in rows.items():
        t = r["train"]
        lines.append(f"| {label} | {_f(t['targets_frame'])} | {_f(t['base_acc_in'], 3)} / {_f(t['base_acc_off'], 3)} "
                     f"| {_f(t.get('mirror_exchanged_in'))} / {_f(t.get('mirror_exchanged_off'))} | "
                     f"{tuple(r['signed_ranks'])} | {' / '.join(_f(x) for x in t['rank_top2_share'])} |")
    states = [(label, r) for label, r in rows.items() if r["train"].get("by_state")]
    if states:
        lines += ["", "By the smallest joint state of the base's children (quartiles over each split; an eyeglasses "
                  "temple is folded at 0): the share of samples in the common frame and the base accuracy, for the "
                  "training targets and pseudo-labels and for the last val pass.", "",
                  "| run | split | quartile | state range | samples | in frame | base acc. |",
                  "|:--|:--|--:|:--|--:|--:|--:|"]
        for label, r in states:
            last = [p for p in r["val"] if p.get("by_state")]
            for split, bins in (("train", r["train"]["by_state"]), (a.split, last[-1]["by_state"] if last else [])):
                for b in bins:
                    lines.append(f"| {label} | {split} | {b['bin'] + 1} | {b['state_from']:.3f}-{b['state_to']:.3f} "
                                 f"| {b['samples']} | {_f(b['in_frame'])} | {_f(b['base_acc'], 3)} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
