"""Test-time refinement as a method-independent step ("+ refine" rows for every method that can use it, so no row gets
a search another lacks).

A method with a canonical shape or template (SCAPO's template, OP-Align-style's decoded canonical shape,
EAP-style's decoded canonical parts) gives, with its one-pass prediction of a view, a whole-object model:
template points ``y_m`` each in the canonical frame of its part ``l_m``, placed in the camera frame by the
prediction's part poses, ``x_m = part_pose[l_m] y_m``. This step fits that articulated model to the observed
cloud, view by view, from the observed points only (no label, no gravity), and returns the prediction with
the fitted pose, joint states and segmentation. It is the same fit for every method:

- parameters: a rigid motion of the whole model (rotation about the observed cloud's centroid, translation)
  and one increment per joint, moving the joint's child subtree about the method's own predicted joint
  (revolute: rotation about the axis through the pivot; prismatic: translation along the axis), composed
  along the kinematic tree (:class:`scapo.nn.template_fit.TemplatePoser` with one-hot weights, the
  prediction's posed model as its rest state and the joint increments starting at 0);
- objective: the one-sided Chamfer term, mean squared distance from each observed point to its nearest
  model point (the model is a whole object, the view a partial one), in units of the cloud's size
  (``2 x`` its RMS radius), by Adam with a cosine schedule (:func:`scapo.nn.template_fit.fit_template`,
  shared with SCAPO's own refinement);
- starts (``starts = "octahedral"``): the one-pass answer and the 23 other rotations of the cube group
  applied in the predicted object frame about the model's centroid are screened by a short fit each; the best
  alternative is fitted fully beside the one-pass start and replaces it only when its residual is lower
  by the relative ``margin``;
- outputs: every part pose, ``T_cam_obj`` and each joint's axis and pivot move with the fitted motion of
  their part (a joint with its parent part); joint states get the fitted increments (prismatic ones in
  metres); each observed point takes the part of its nearest fitted model point.

Settings (:data:`TEST_TIME_REFINE`) are those of SCAPO's ``cpu`` preset refinement (20 steps, lr 0.06,
octahedral starts, margin 0.15; chosen on the val split, see
``results/cpu_preset_history.md``) without its upright prior: Table 1's objects turn uniformly in SO(3), and a
gravity cue would be a cue the one-pass rows are denied. Methods without a whole-object model (NPCS-style
predicts coordinates of the observed points only; ICP is itself a template fit) do not take this step.
An addition to the paper (its SCAPO row is one-pass).
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import torch

from scapo.errors import InputError
from scapo.nn.template_fit import RefineConfig, fit_template
from scapo.ops.groups import octahedral_rotations

TEST_TIME_REFINE = RefineConfig(steps=20, lr=0.06, starts="octahedral", margin=0.15, upright_deg=0.0)
"""The settings of the method-independent step (see the module docstring)."""


def refine_info(refined: dict) -> dict:
    """What predictions record of the step (their ``info``): ``refine``, the settings of :data:`TEST_TIME_REFINE`,
    and ``refine_start_rate``, the share of views where a cube start replaced the one-pass one (``refined``: the
    output of :func:`refine_prediction`)."""
    return {"refine": dataclasses.asdict(TEST_TIME_REFINE),
            "refine_start_rate": round(float((np.asarray(refined["refine_start"]) > 0).mean()), 4)}


def _check(name: str, a: np.ndarray, shape: tuple) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != len(shape) or any(s is not None and d != s for d, s in zip(a.shape, shape)):
        want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
        raise InputError(f"scapo: refine: {name} must have shape {want}, got {a.shape}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise InputError(f"scapo: refine: {name} holds NaN or infinite values; predict again or drop those views")
    return a


def refine_prediction(points, pred: dict, template, template_label, joint_types, joint_parts,
                      config: RefineConfig = TEST_TIME_REFINE, batch_size: int = 32) -> dict:
    """Fit each view's predicted articulated model to its observed points (see the module docstring).

    Args:
        points: (B, N, 3) observed clouds, camera frame, metres.
        pred: the one-pass prediction, numpy arrays: ``part_pose (B, P, 4, 4)`` (part frame -> camera, metres),
            ``T_cam_obj (B, 4, 4)``, ``joint_axis (B, J, 3)`` (unit, camera frame), ``joint_pivot (B, J, 3)``
            (camera frame, m), ``joint_state (B, J)`` (rad / m), ``part_label (B, N)``.
        template: (B, M, 3) the method's whole-object model, point ``m`` in the canonical frame of its part
            ``template_label[:, m]`` (metres).
        template_label: (B, M) int, part of each template point, in ``[0, P)``.
        joint_types: (J,) 0 revolute / 1 prismatic. joint_parts: (J, 2) (parent, child) part indices.
        config: the fit's settings (:class:`~scapo.nn.template_fit.RefineConfig`; ``steps > 0``;
            ``upright_deg`` is ignored: no gravity cue).
        batch_size: views fitted together (a view's result does not depend on the others of its batch).

    Returns:
        a copy of ``pred`` with refined ``part_pose``, ``T_cam_obj``, ``joint_axis``, ``joint_pivot``,
        ``joint_state``, ``part_label`` (float64 / int64) and per view ``refine_residual`` and
        ``refine_residual_start`` (B,) (mean squared distance, cloud-size units) and ``refine_start`` (B,)
        (0: the one-pass start kept; k: the k-th cube rotation won).

    Raises:
        InputError: arrays of the wrong shape, non-finite values, template labels out of range, or a view
            whose template has no point.
        ValueError: ``config.steps`` is 0.
    """
    if config.steps <= 0:
        raise ValueError("refine_prediction needs config.steps > 0")
    X = _check("points", points, (None, None, 3)).astype(np.float32)
    B = X.shape[0]
    P = np.asarray(pred["part_pose"]).shape[1] if np.ndim(pred.get("part_pose")) == 4 else 0
    jt = tuple(int(t) for t in np.asarray(joint_types).reshape(-1))
    jp = tuple(tuple(int(v) for v in p) for p in np.asarray(joint_parts).reshape(-1, 2))
    J = len(jt)
    pose = _check("part_pose", pred.get("part_pose"), (B, P, 4, 4)).astype(np.float64)
    T_obj = _check("T_cam_obj", pred.get("T_cam_obj"), (B, 4, 4)).astype(np.float64)
    axis = _check("joint_axis", pred.get("joint_axis"), (B, J, 3)).astype(np.float64)
    pivot = _check("joint_pivot", pred.get("joint_pivot"), (B, J, 3)).astype(np.float64)
    state = _check("joint_state", pred.get("joint_state"), (B, J)).astype(np.float64)
    Y = _check("template", template, (B, None, 3)).astype(np.float64)
    lab = _check("template_label", template_label, (B, Y.shape[1])).astype(np.int64)
    if Y.shape[1] == 0 or P == 0:
        raise InputError("scapo: refine: the template has no point (or the prediction no part); nothing to fit")
    if lab.min() < 0 or lab.max() >= P:
        raise InputError(f"scapo: refine: template_label must lie in [0, {P}), got [{lab.min()}, {lab.max()}]")
    out = {k: np.array(v, copy=True) for k, v in pred.items()}
    res = {k: np.zeros(B) for k in ("refine_residual", "refine_residual_start")}
    res["refine_start"] = np.zeros(B, dtype=np.int64)
    out["part_label"] = np.zeros(X.shape[:2], dtype=np.int64)
    cfg = SimpleNamespace(joint_types=jt, joint_parts=jp, num_parts=P)
    for s in range(0, B, max(1, int(batch_size))):
        sl = slice(s, min(B, s + max(1, int(batch_size))))
        r = _refine_batch(cfg, X[sl], pose[sl], axis[sl], pivot[sl], Y[sl], lab[sl], config)
        V = r["V"]  # (b, P, 4, 4) rigid motion of each part, camera frame, metres
        out["part_pose"][sl] = V @ pose[sl]
        out["T_cam_obj"][sl] = V[:, 0] @ T_obj[sl]  # the base part (slot 0) carries the object frame
        for j, (pa, _) in enumerate(jp):
            Vp = V[:, pa]
            out["joint_axis"][sl, j] = np.einsum("bij,bj->bi", Vp[:, :3, :3], axis[sl, j])
            out["joint_pivot"][sl, j] = np.einsum("bij,bj->bi", Vp[:, :3, :3], pivot[sl, j]) + Vp[:, :3, 3]
        out["joint_state"][sl] = state[sl] + r["delta"]
        out["part_label"][sl] = r["label"]
        for k in ("refine_residual", "refine_residual_start", "refine_start"):
            res[k][sl] = r[k]
    for k in ("part_pose", "T_cam_obj", "joint_axis", "joint_pivot", "joint_state"):
        out[k] = out[k].astype(np.float64)
    out.update(res)
    return out


def _refine_batch(cfg, X: np.ndarray, pose: np.ndarray, axis: np.ndarray, pivot: np.ndarray, Y: np.ndarray,
                  lab: np.ndarray, rc: RefineConfig) -> dict:
    """One batch of :func:`refine_prediction`, in normalised units ``x_n = (x - c) / s`` (``c`` the observed
    centroid, ``s`` twice its RMS radius)."""
    b, M = lab.shape
    P, J = cfg.num_parts, len(cfg.joint_types)
    c = X.mean(1, keepdims=True).astype(np.float64)  # (b, 1, 3)
    s = 2.0 * np.sqrt(((X - c) ** 2).sum(-1).mean(-1)).clip(1e-6)  # (b,)
    # the prediction's posed model, the rest state of the fit
    Rm = pose[np.arange(b)[:, None], lab]  # (b, M, 4, 4)
    posed = np.einsum("bmij,bmj->bmi", Rm[..., :3, :3], Y) + Rm[..., :3, 3]
    dt = torch.float32
    rest = torch.from_numpy((posed - c) / s[:, None, None]).to(dt)
    Xn = torch.from_numpy((X - c) / s[:, None, None]).to(dt)
    weights = torch.nn.functional.one_hot(torch.from_numpy(lab), P).to(dt)
    piv = torch.from_numpy((pivot - c) / s[:, None, None]).to(dt) if J else torch.zeros(b, 0, 3, dtype=dt)
    ax = torch.from_numpy(axis).to(dt) if J else torch.zeros(b, 0, 3, dtype=dt)
    ax = torch.nn.functional.normalize(ax, dim=-1) if J else ax
    eye = torch.eye(3, dtype=dt).expand(b, 3, 3).contiguous()
    zero_t = torch.zeros(b, 3, dtype=dt)
    state0 = torch.zeros(b, J, dtype=dt)
    if rc.starts == "network":
        r = fit_template(cfg, Xn, rest, weights, piv, ax, eye, zero_t, state0, None, rc.steps, rc.lr, rc.points,
                         rc.seed)
        start = torch.zeros(b, dtype=torch.long)
    else:
        C = octahedral_rotations(dt, Xn.device)  # (K, 3, 3), identity first
        K = C.shape[0]
        Q = torch.from_numpy(pose[:, 0, :3, :3]).to(dt)  # the predicted object frame's axes
        Rk = Q[:, None] @ C[None] @ Q.transpose(1, 2)[:, None]  # (b, K, 3, 3): C in that frame
        m = rest.mean(1)  # (b, 3) the model's centroid: the starts turn about it
        tk = m[:, None] - (Rk @ m[:, None, :, None]).squeeze(-1)  # (b, K, 3)

        def rep(v, k):
            return v.repeat_interleave(k, 0)

        screen = fit_template(cfg, Xn, rep(rest, K), rep(weights, K), rep(piv, K), rep(ax, K), Rk.reshape(b * K, 3, 3),
                      tk.reshape(b * K, 3), rep(state0, K), None, rc.screen_steps, rc.lr, rc.screen_points, rc.seed,
                      repeat_obs=K, segment=False)["residual"].reshape(b, K)
        alt = 1 + screen[:, 1:].argmin(1)
        ar = torch.arange(b)
        Rs = torch.stack([Rk[:, 0], Rk[ar, alt]], 1).reshape(2 * b, 3, 3)
        ts = torch.stack([tk[:, 0], tk[ar, alt]], 1).reshape(2 * b, 3)
        r = fit_template(cfg, Xn, rep(rest, 2), rep(weights, 2), rep(piv, 2), rep(ax, 2), Rs, ts, rep(state0, 2), None,
                 rc.steps, rc.lr, rc.points, rc.seed, repeat_obs=2)
        res = r["residual"].reshape(b, 2)
        pick = (res[:, 1] < (1.0 - rc.margin) * res[:, 0]).long()
        sel = ar * 2 + pick
        r = {k: (v[sel] if torch.is_tensor(v) and v.shape[0] == 2 * b else v) for k, v in r.items()}
        start = torch.where(pick.bool(), alt, torch.zeros_like(alt))
    R, t, T = r["R"].double().numpy(), r["t"].double().numpy(), r["T"].double().numpy()
    # motion of each part in normalised units: x_n -> R (T_p x_n) + t; in metres V = [U | c - U c + s u]
    U = np.einsum("bij,bpjk->bpik", R, T[:, :, :3, :3])
    u = np.einsum("bij,bpj->bpi", R, T[:, :, :3, 3]) + t[:, None]
    V = np.tile(np.eye(4), (b, P, 1, 1))
    V[:, :, :3, :3] = U
    V[:, :, :3, 3] = c - np.einsum("bpij,bj->bpi", U, c[:, 0]) + s[:, None, None] * u
    delta = r["state"].double().numpy()
    prismatic = np.array([t_ == 1 for t_ in cfg.joint_types], dtype=bool)
    delta = np.where(prismatic[None], delta * s[:, None], delta)
    return {"V": V, "delta": delta, "label": r["weights"].argmax(-1).numpy(),
            "refine_residual": r["residual"].double().numpy(),
            "refine_residual_start": r["residual_start"].double().numpy(), "refine_start": start.numpy()}
