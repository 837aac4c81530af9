"""Where do stage 2's revolute axes start, and where does L_dir-align pull them, when the frame is given? A ground-truth
diagnosis, no training.

Every training cloud is put in its **true** object frame and normalised as the trainer does
(``split_init_diagnosis.object_frame_clouds``); the true axes are the dataset's (``joint_axis``, brought into the object
frame). Per revolute joint, the angle (deg, sign-free) between the true axis and:

- ``motion``: :func:`scapo.models.part_init.estimate_axes`, part_init's estimate (each part registered rigidly across
  random pairs of clouds, the axis from the child's rotations relative to its parent), the clouds split (a) by nearest
  true-part centroid (one split for every cloud, the start ``label_init`` gives) and (b) by the true labels;
- ``turn``: :func:`scapo.models.part_init.axis_from_turns` (``TrainConfig.axis_init = "turn"``), the direction the
  child's principal axes turn about across the clouds, with the same two splits;
- ``boundary fallback``: :func:`scapo.models.part_init.boundary_joint` on one cloud (the principal direction of the
  points nearest the bisecting plane of the two centroids), part_init's fallback;
- ``turn, fit``: the turn with the split ``split_init="fit"`` finds without labels
  (:func:`scapo.models.part_init.choose_split`), its slots named after the true parts they overlap best;
- ``L_dir-align target``: the per-cloud target of the paper's ``L_dir-align``
  (:func:`scapo.losses.scapo_losses.boundary_direction`, the principal direction of the two parts' most uncertain
  points) under the true split (soft weights from per-cloud Gaussian bones of the true parts), median over clouds and
  the share within 20 deg; with the boundary's elongation (second over first eigenvalue of its covariance, median; a
  line along the hinge gives near 0).

    python bench/diagnostics/axis_init_diagnosis.py --data DATA --out results/canonical_ladder/axis_init/NAME \\
        [--clouds 64]

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path


def _split_diagnosis():
    """``bench/diagnostics/split_init_diagnosis.py`` as a module (this folder's scripts import each other)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import split_init_diagnosis

    return split_init_diagnosis


def angle_deg(u, v) -> float:
    """Sign-free angle (deg) between two directions ``(3,)``; NaN when ``u`` is None."""
    if u is None:
        return float("nan")
    c = abs(float(u @ v)) / max(float(u.norm() * v.norm()), 1e-12)
    return math.degrees(math.acos(min(1.0, c)))


def dir_align_targets(X, labels, num_parts: int, parent: int, child: int, gamma: float = 0.1):
    """Per cloud: L_dir-align's target direction ``(B, 3)`` under the true split and the boundary's elongation ``(B,)``
    (second / first eigenvalue of the weighted covariance of the boundary points, as ``boundary_direction`` picks
    them). ``X (B, N, 3)``, ``labels (B, N)``."""
    import torch

    from scapo.losses.scapo_losses import boundary_direction
    from scapo.nn.skinning import skinning_weights

    sd = _split_diagnosis()
    bones = [sd.gaussian_bones(X[b], labels[b], num_parts) for b in range(len(X))]
    K, V, L = (torch.stack(t) for t in zip(*bones))
    w, _ = skinning_weights(X, K, V, L, gamma)
    target = boundary_direction(X, w, parent, child)
    score = 4.0 * w[..., parent] * w[..., child]
    k = max(8, int(0.1 * X.shape[1]))
    sel = score.topk(k, dim=1).indices
    p = X.gather(1, sel.unsqueeze(-1).expand(-1, k, 3))
    s = score.gather(1, sel).unsqueeze(-1) + 1e-8
    mu = (s * p).sum(1, keepdim=True) / s.sum(1, keepdim=True)
    ev = torch.linalg.eigvalsh(torch.einsum("bni,bnj->bij", s * (p - mu), p - mu))
    return target, ev[:, 1] / ev[:, 2].clamp_min(1e-12)


def diagnose(data: Path, clouds: int, seed: int = 0) -> tuple[dict, dict]:
    """The rows per revolute joint for the first ``clouds`` training clouds of ``data`` (see the module docstring).

    Raises:
        ScapoError: the dataset cannot be read, or it has no revolute joint."""
    import numpy as np
    import torch

    from scapo.data import load
    from scapo.errors import ScapoError
    from scapo.models import part_init

    sd = _split_diagnosis()
    X, labels, P, card = sd.object_frame_clouds(data, clouds)
    a = load(data, "train").arrays(["T_cam_obj", "joint_axis"])
    n = len(X)
    T = a["T_cam_obj"][:n]
    axes_obj = np.einsum("bji,bkj->bki", T[:, :3, :3], a["joint_axis"][:n])  # R^T d: (B, J, 3)
    jt = [int(t) for t in card["joint_type"]]
    jp = [(int(p), int(c)) for p, c in card["joint_parts"]]
    if 0 not in jt:
        raise ScapoError(f"{data}: no revolute joint; this diagnosis is about revolute axes")
    sub = X[:, :: max(1, X.shape[1] // 128)]
    lab = labels[:, :: max(1, X.shape[1] // 128)]
    K = torch.stack([sub[lab == p].mean(0) if bool((lab == p).any()) else torch.zeros(3) for p in range(P)])
    nearest = part_init.nearest_keypoint(sub, K.expand(len(sub), P, 3))
    # split_init="fit" without labels (part_init.choose_split on a 256-point template of the medoid cloud), its slots
    # then named after the true parts they overlap best (one permutation for all clouds: the diagnosis's only label use)
    import itertools

    m = part_init.medoid(sub)
    tpl = X[m, :: max(1, X.shape[1] // 256)]
    Kk, _ = part_init.initial_split(sub, sub.reshape(-1, 3)[:: max(1, sub.shape[0] * sub.shape[1] // 1024)], P,
                                    seed=seed)
    found = part_init.choose_split(sub, tpl, part_init.part_centroids(tpl, Kk), seed=seed)
    best = max(itertools.permutations(range(P)),
               key=lambda perm: sum(float(((found["cloud_labels"] == perm[q]) & (lab == q)).sum()) for q in range(P)))
    fit = torch.empty_like(found["cloud_labels"])
    for q in range(P):
        fit[found["cloud_labels"] == best[q]] = q
    fit_miou = sd.split_miou(lab, fit, P)
    rows = {}
    for j, ((pa, ch), t) in enumerate(zip(jp, jt)):
        if t != 0:
            continue
        # the axis's sign differs between joints (mirrored hinges), not between clouds: one true direction per joint
        ref = axes_obj[:, j]
        true = torch.tensor(ref[0] if len(ref) else np.zeros(3), dtype=torch.float32)
        spread = float(np.degrees(np.arccos(np.clip(np.abs(ref @ ref[0]), 0, 1))).max())
        row = {"true_axis_spread_deg": round(spread, 2)}
        for name, split in (("nearest_centroid", nearest), ("true_labels", lab)):
            g = torch.Generator().manual_seed(seed)
            if name == "nearest_centroid":
                motion = part_init.estimate_axes(sub, K, jt, jp, generator=g)[j]
            else:
                Q = 128
                ia, ib = part_init.random_pairs(len(sub), Q, g)
                _, R, tt = part_init.register_parts(sub[ia], sub[ib], split[ia], split[ib], P)
                Rm = R[:, ch] @ R[:, pa].transpose(1, 2)
                tm = tt[:, ch] - (Rm @ tt[:, pa].unsqueeze(-1)).squeeze(-1)
                motion = part_init.axis_from_motions(Rm, tm, 0)
            row[f"motion_{name}"] = round(angle_deg(motion, true), 2)
            row[f"turn_{name}"] = round(angle_deg(part_init.axis_from_turns(sub, split, ch), true), 2)
        _, fallback = part_init.boundary_joint(sub[0], K, pa, ch)
        row["boundary_fallback"] = round(angle_deg(fallback, true), 2)
        turn_fit = part_init.axis_from_turns(sub, fit, ch)
        row["turn_fit"] = round(angle_deg(turn_fit, true), 2) if turn_fit is not None else None
        row["fit_source"], row["fit_miou"] = found["source"], round(fit_miou, 4)
        target, elong = dir_align_targets(sub, lab, P, pa, ch)
        ang = torch.rad2deg(torch.arccos((target @ true / true.norm()).abs().clamp(max=1.0)))
        row["dir_align_target_median"] = round(float(ang.median()), 2)
        row["dir_align_target_within_20"] = round(float((ang < 20).float().mean()), 3)
        row["boundary_elongation_median"] = round(float(elong.median()), 4)
        rows[card["joint_names"][j] if card.get("joint_names") else f"joint {j}"] = row
    return {"clouds": n, "joints": rows}, card


def main(argv=None) -> int:
    from scapo.bench.diagnosis import finish_diagnosis, ground_truth_args
    from scapo.errors import ScapoError

    a = ground_truth_args(argv, __doc__.split("\n\n")[0], 64, 3, "an axis is read across clouds",
                          "training clouds used (the first ones; part_init reads 64)")
    if a is None:
        return 2
    try:
        r, card = diagnose(Path(a.data), a.clouds, a.seed)
    except ScapoError as e:
        print(f"scapo: {e}", file=sys.stderr)
        return 2
    cmd = "python bench/diagnostics/axis_init_diagnosis.py " + " ".join(sys.argv[1:] if argv is None else argv)
    lines = [f"# Revolute axes at the start of stage 2, with the frame given ({Path(a.data).name})", "",
             f"{r['clouds']} training clouds in their true object frame. Angle (deg, sign-free) to the true axis of: "
             "part_init's registration estimate (`motion`, `estimate_axes`) and the principal-axes turn "
             "(`turn`, `axis_init=turn`), each with the split by nearest true-part centroid (label_init's start) and "
             "by the true labels; part_init's boundary fallback; the target of L_dir-align under the true split "
             "(median over clouds, share within 20 deg) and the boundary's elongation (second / first eigenvalue; "
             "near 0 for a line along the hinge). `turn, fit`: the turn with `split_init=fit`'s split found without "
             "labels (`part_init.choose_split`; its slots named after the true parts they overlap best; its mean IoU "
             "in the last column).", "",
             "| joint | motion, nearest centroid | motion, true labels | turn, nearest centroid | turn, true labels | "
             "boundary fallback | L_dir-align target median | within 20 deg | boundary elongation | turn, fit | "
             "fit's split mIoU |",
             "|:--|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|"]
    for name, row in r["joints"].items():
        lines.append(f"| {name} | {row['motion_nearest_centroid']:.1f} | {row['motion_true_labels']:.1f} | "
                     f"{row['turn_nearest_centroid']:.1f} | {row['turn_true_labels']:.1f} | "
                     f"{row['boundary_fallback']:.1f} | {row['dir_align_target_median']:.1f} | "
                     f"{row['dir_align_target_within_20']:.2f} | {row['boundary_elongation_median']:.3f} | "
                     f"{'-' if row['turn_fit'] is None else format(row['turn_fit'], '.1f')} | "
                     f"{row['fit_miou']:.2f} ({row['fit_source']}) |")
    a.split = "train"  # the record's split: ground truth of the training clouds, no predictions
    return finish_diagnosis(a, [], lines, r, card, cmd)


if __name__ == "__main__":
    raise SystemExit(main())
