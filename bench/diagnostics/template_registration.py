"""Can a method's object frame be made one frame by registering each view rigidly to a category template? A diagnosis
on predictions files already written (no training).

Each view's cloud is brought into the method's canonical frame by its predicted object pose (``T_cam_obj``; 128 points,
centred), a template is built from the training views, and every view is registered rigidly to it (trimmed
point-to-point ICP, the 90 % nearest matches, 8 Kabsch steps) from each start of a hypothesis set; the start with the
smallest residual gives the view's correction ``R_c``, and the corrected object frame is ``R R_c^T``. Rows, on the
training split and on ``--split``, frame consistency (the share of views within 15 deg of the offset most share, as the
ladder's ``frame cons.``) before and after:

- ``I, template synchronised``: starts {identity}; the template is the union of the training views in their current
  frames, rebuilt from the corrected views ``--rounds`` times (no labels);
- ``O, template synchronised``: starts at the 24 rotations of the cube (the half turns among them), likewise;
- ``I, oracle template`` / ``O, oracle template``: the template built **from ground truth** (each training view brought
  into one view's frame by the true poses), registered once: what rigid registration to a perfect template gives,
  a ceiling, not a method.

    python bench/diagnostics/template_registration.py --data DATA --pred LABEL=PREDICTIONS.npz --out \\
        results/.../NAME [--rounds 3]

Writes ``<out>.{md,json}`` with provenance (commit, dataset hash, each file's sha256).
"""

from __future__ import annotations

from pathlib import Path

POINTS, TEMPLATE_POINTS, KEEP, STEPS, CHUNK = 128, 1024, 0.9, 8, 512


def icp_starts(S, U, starts):
    """Register each cloud of ``S (B, n, 3)`` to the template ``U (m, 3)`` from every start ``starts (K, 3, 3)``
    (canonical -> template rotations): ``(R (B, 3, 3), residual (B,), start index (B,))`` of the best start (trimmed
    mean squared nearest-neighbour distance after ``STEPS`` Kabsch steps, the ``KEEP`` nearest matches)."""
    import torch

    from scapo.ops.align import kabsch
    from scapo.ops.chamfer import pairwise_sq_dist

    B, n, _ = S.shape
    K = starts.shape[0]
    A = S.unsqueeze(1).expand(B, K, n, 3).reshape(B * K, n, 3)
    R = starts.unsqueeze(0).expand(B, K, 3, 3).reshape(B * K, 3, 3)
    t = torch.zeros(B * K, 3)
    for it in range(STEPS + 1):
        cur = A @ R.transpose(1, 2) + t[:, None]
        mins = [pairwise_sq_dist(cur[i:i + CHUNK], U[None].expand(len(cur[i:i + CHUNK]), -1, -1)).min(-1)
                for i in range(0, B * K, CHUNK)]
        dmin, j = torch.cat([m.values for m in mins]), torch.cat([m.indices for m in mins])
        w = (dmin <= dmin.quantile(KEEP, dim=1, keepdim=True)).to(S.dtype)
        res = (dmin * w).sum(1) / w.sum(1)
        if it == STEPS:
            break
        R, t = kabsch(A, U[j], w)
    res = res.reshape(B, K)
    k = res.argmin(1)
    return R.reshape(B, K, 3, 3)[torch.arange(B), k], res.min(1).values, k


def template(S, R, generator):
    """``TEMPLATE_POINTS`` random points ``(m, 3)`` of the union of the clouds ``S (B, n, 3)`` turned by ``R (B, 3, 3)``
    and centred."""
    import torch

    X = S @ R.transpose(1, 2)
    U = (X - X.mean(1, keepdim=True)).reshape(-1, 3)
    return U[torch.randperm(len(U), generator=generator)[:TEMPLATE_POINTS]]


def diagnose(data: Path, preds, split: str, rounds: int) -> dict:
    """The rows (see the module docstring) for one predictions file."""
    import numpy as np
    import torch

    from scapo.eval.frames import frame_consistency
    from scapo.ops.groups import rotation_group
    from scapo.steps.hinge import prediction_arrays

    gt = prediction_arrays(data, preds, ("points", "T_cam_obj"))
    g = torch.Generator().manual_seed(0)
    sel = torch.randperm(gt["points"].shape[1], generator=g)[:POINTS]

    def canon(rows):
        T = preds.T_cam_obj[rows]
        S = torch.tensor(np.einsum("bji,bnj->bni", T[:, :3, :3], gt["points"][rows] - T[:, None, :3, 3]),
                         dtype=torch.float32)[:, sel]
        return S - S.mean(1, keepdim=True)

    rtr, rsp = np.flatnonzero(preds.split == "train"), np.flatnonzero(preds.split == split)
    Str, Ssp = canon(rtr), canon(rsp)
    starts = {"I": torch.eye(3)[None], "O": torch.tensor(rotation_group("O"), dtype=torch.float32)}

    def corrected(rows, Rc):
        T = preds.T_cam_obj[rows].copy()
        T[:, :3, :3] = T[:, :3, :3] @ Rc.numpy().transpose(0, 2, 1).astype(T.dtype)
        return T

    def cons(rows, T):
        return round(float(frame_consistency(T, gt["T_cam_obj"][rows])), 4)

    out = {"before": {"train": cons(rtr, preds.T_cam_obj[rtr]), split: cons(rsp, preds.T_cam_obj[rsp])}}
    O = np.einsum("bji,bjk->bik", preds.T_cam_obj[rtr][:, :3, :3], gt["T_cam_obj"][rtr][:, :3, :3])  # R^T R_gt
    oracle = torch.tensor(O[0] @ O.transpose(0, 2, 1), dtype=torch.float32)  # each view into view 0's frame
    for name, G in starts.items():
        R = torch.eye(3).expand(len(Str), 3, 3)
        U = template(Str, R, g)
        for _ in range(rounds):
            R, _, _ = icp_starts(Str, U, G)
            U = template(Str, R, g)
        Rs, _, _ = icp_starts(Ssp, U, G)
        out[f"{name}, template synchronised"] = {"train": cons(rtr, corrected(rtr, R)),
                                                 split: cons(rsp, corrected(rsp, Rs))}
        U = template(Str, oracle, g)
        R, _, _ = icp_starts(Str, U, G)
        Rs, _, _ = icp_starts(Ssp, U, G)
        out[f"{name}, oracle template"] = {"train": cons(rtr, corrected(rtr, R)), split: cons(rsp, corrected(rsp, Rs))}
    return out


def main(argv=None) -> int:
    import torch

    from scapo.bench.diagnosis import run_diagnosis

    torch.set_num_threads(1)
    return run_diagnosis(argv, __doc__, "template_registration.py",
                         lambda a, p: diagnose(Path(a.data), p, a.split, a.rounds), render,
                         [("--rounds", {"type": int, "default": 3, "help": "template synchronisation rounds"})],
                         lambda a: None if a.rounds >= 1 else f"--rounds must be at least 1, got {a.rounds}")


def render(a, rows: dict, card: dict) -> list[str]:
    """The Markdown lines: every file's frame consistency before and after each registration."""
    lines = [f"# Rigid registration to a category template ({Path(a.data).name}, train / {a.split})", "",
             "Frame consistency (share of views within 15 deg of the common object-frame offset) of the method's "
             "frames, and after registering each view rigidly to a template built from the training views (from the "
             "identity, or from the 24 cube rotations), the template synchronised without labels or built from "
             "ground truth (oracle: a ceiling, not a method).", "",
             "| predictions | frames | train | " + a.split + " |", "|:--|:--|--:|--:|"]
    for label, r in rows.items():
        for name, v in r.items():
            lines.append(f"| {label} | {name} | {v['train']:.2f} | {v[a.split]:.2f} |")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
