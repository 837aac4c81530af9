"""Render-and-compare scores of a twin (``scapo evaluate --twin``): does it look and move like the object?

For one sample of a generated dataset (the true object can be rendered again: its asset, state and camera are
known), with the twin exported from a method's prediction of that sample (:func:`scapo.twin.export_twin`):

1. **Looks like the view.** The twin at the predicted state and the true object at the true state, both
   rendered from the observed camera: the IoU of their object masks, the mean depth difference where both
   are seen (cm), and the symmetric Chamfer distance between the observed cloud and the twin's rendered cloud
   (mean nearest-neighbour distance each way, in bbox diagonals).
2. **Moves like the object.** Both opened further by the same motion from their observed states (``move_deg``
   for revolute joints, ``move_frac`` of the bbox diagonal for prismatic ones; the other way where the true
   object's range ends), rendered again from the same camera: the same three numbers. No table in the field
   reports whether an estimated articulation moves the object as it really moves; this does.

Each render uses the renderer of :mod:`scapo.sim.render` (exact positions and segmentation).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from scapo.data.dataset import load
from scapo.data.generate import instance_asset_path, load_instance
from scapo.files import read_json
from scapo.ops.rigid import invert_transform
from scapo.sim.assets.urdf import ArticulationSpec, load_partnet_mobility
from scapo.sim.render import Renderer

TWIN_METRICS = ("twin_mask_iou", "twin_depth_cm", "twin_chamfer", "twin_moved_mask_iou", "twin_moved_depth_cm",
                "twin_moved_chamfer")


def _picture(renderer: Renderer, spec: ArticulationSpec, state: np.ndarray, T_world_cam: np.ndarray):
    """(points (H, W, 3) camera frame, object mask (H, W)) of ``spec`` at ``state`` (from its rest) seen from
    ``T_world_cam`` (the world is ``spec``'s object frame)."""
    renderer.load(spec)
    renderer.set_state(state)
    pts, part_map, _ = renderer.capture(T_world_cam)
    # a degenerate twin surface (a sliver of a hull) can give pixels without a finite position: not seen
    return pts, (part_map >= 0) & np.isfinite(pts).all(-1)


def _compare(a, b, observed: np.ndarray | None, diag: float) -> tuple[float, float, float]:
    """(mask IoU, mean |depth difference| in cm where both masks are set, Chamfer in bbox diagonals) between
    pictures ``a`` (twin) and ``b`` (truth); Chamfer against ``observed`` points when given, else ``b``'s."""
    (pa, ma), (pb, mb) = a, b
    union = np.count_nonzero(ma | mb)
    iou = np.count_nonzero(ma & mb) / union if union else float("nan")
    both = ma & mb
    depth = float(100 * np.abs(pa[..., 2][both] - pb[..., 2][both]).mean()) if both.any() else float("nan")
    ta = pa[ma].astype(np.float64)
    tb = observed if observed is not None else pb[mb].astype(np.float64)
    if len(ta) == 0 or len(tb) == 0:
        return iou, depth, float("nan")
    ta, tb = ta[:: max(1, len(ta) // 4096)], tb[:: max(1, len(tb) // 4096)]
    chamfer = (cKDTree(ta).query(tb)[0].mean() + cKDTree(tb).query(ta)[0].mean()) / 2 / diag
    return iou, depth, float(chamfer)


def score_twin(twin: str | Path, renderer: Renderer | None = None, move_deg: float = 30.0,
               move_frac: float = 0.1) -> dict:
    """Scores of one exported twin (see the module docstring); keys :data:`TWIN_METRICS` plus ``sample``.

    Raises:
        DatasetError: the twin's dataset cannot be opened or re-rendered (its config or assets are gone).
    """
    twin = Path(twin)
    t = read_json(twin / "twin.json", "twin description", ValueError, "export the twin again")
    ds = load(t["dataset"], t["split"])
    item = ds[int(t["sample"])]
    from scapo.data.config import GenerateConfig

    cfg = GenerateConfig.from_dict(json.loads((Path(t["dataset"]) / "config.json").read_text()))
    true = load_instance(cfg, instance_asset_path(cfg, Path(t["dataset"]), item["instance_id"]))
    tw = load_partnet_mobility(twin)
    own = renderer is None
    renderer = renderer or Renderer(cfg.render.camera, cfg.render.shader)
    try:
        diag = float(item["bbox_diag"])
        T_cam_obj = np.asarray(item["T_cam_obj"])
        cam_true = invert_transform(T_cam_obj)  # the true object's world is its object frame
        cam_twin = tw.T_obj_root @ invert_transform(np.asarray(t["T_cam_root"]))
        # the twin's joints (its URDF order) and their predicted states; its rest is qpos 0 clamped into the limits
        q_twin = np.array([j["state"] for j in t["joints"]])
        rest_twin = np.array([j.rest_qpos for j in tw.gt_joints])
        q_true = np.asarray(item["joint_state"], dtype=np.float64)
        out = {"sample": int(t["sample"])}
        a = _picture(renderer, tw, q_twin - rest_twin, cam_twin)
        b = _picture(renderer, true, q_true, cam_true)
        out["twin_mask_iou"], out["twin_depth_cm"], out["twin_chamfer"] = _compare(
            a, b, item["points"][item["part_label"] >= 0].astype(np.float64), diag)
        # the same motion on both: every joint of the true object moved, the twin's joint of the same child part
        move = np.where(true.joint_type == 0, np.radians(move_deg), move_frac * diag)
        lim = true.joint_limit
        step = np.where(q_true + move <= lim[:, 1], move, -move)
        # a twin joint gets the motion of the true joint whose child part its child slot matched on this view
        gt_of_slot = {int(sl): p for p, sl in enumerate(t["gt_part_slots"]) if sl >= 0}
        true_joint_of_child = {j.child_part: k for k, j in enumerate(true.gt_joints)}
        d_twin = np.zeros(len(q_twin))
        for k, jd in enumerate(t["joints"]):
            p = gt_of_slot.get(int(jd["child"]))
            if p is not None and p in true_joint_of_child:
                d_twin[k] = step[true_joint_of_child[p]]
        a = _picture(renderer, tw, q_twin + d_twin - rest_twin, cam_twin)
        b = _picture(renderer, true, q_true + step, cam_true)
        out["twin_moved_mask_iou"], out["twin_moved_depth_cm"], out["twin_moved_chamfer"] = _compare(a, b, None, diag)
        return out
    finally:
        if own:
            renderer.close()



def twin_scores(data: str | Path, predictions, split: str = "test", limit: int = 0, move_deg: float = 30.0,
                progress: bool = False):
    """Per-sample twin scores of one method on ``split`` of ``data``: every sample's twin exported into a
    temporary folder (:func:`~scapo.twin.export.export_twin`) and scored (:func:`score_twin`); a sample whose
    prediction gives the base part too few points gets NaN (its failure is counted, not dropped).

    Returns a ``pandas.DataFrame`` with ``sample`` and :data:`TWIN_METRICS`. ``limit``: the first ``limit``
    samples only (0: all)."""
    import tempfile

    import pandas as pd

    from scapo.errors import ConfigError
    from scapo.eval.predictions import Predictions
    from scapo.twin.export import export_twin

    preds = predictions if isinstance(predictions, Predictions) else Predictions.load(predictions)
    n = len(load(data, split))
    n = min(n, limit) if limit else n
    cfg = json.loads((Path(data) / "config.json").read_text())
    from scapo.data.config import GenerateConfig

    g = GenerateConfig.from_dict(cfg)
    renderer = Renderer(g.render.camera, g.render.shader)
    rows = []
    it = range(n)
    if progress:
        from scapo.report import progress_bar

        it = progress_bar(it, desc=f"twin {preds.method}", unit="sample")
    try:
        with tempfile.TemporaryDirectory(prefix="scapo-twin-") as tmp:
            for k in it:
                try:
                    export_twin(data, preds, k, Path(tmp) / f"t{k}", split=split)
                    rows.append(score_twin(Path(tmp) / f"t{k}", renderer, move_deg=move_deg))
                except ConfigError:  # no twin can be built from this prediction
                    rows.append({"sample": k, **{m: float("nan") for m in TWIN_METRICS}})
    finally:
        renderer.close()
    return pd.DataFrame(rows)


def twin_summary(per_sample) -> dict:
    """Means and medians of the per-sample twin scores, and the share of samples with a twin (%)."""
    out = {"twin_built": 100.0 * float(per_sample["twin_mask_iou"].notna().mean()) if len(per_sample) else float("nan")}
    for m in TWIN_METRICS:
        v = per_sample[m].to_numpy(dtype=np.float64)
        v = v[np.isfinite(v)]
        out[m] = float(v.mean()) if v.size else float("nan")
        out[f"{m}_median"] = float(np.median(v)) if v.size else float("nan")
    return out


__all__ = ["TWIN_METRICS", "score_twin", "twin_scores", "twin_summary"]


def twin_table(data: str | Path, predictions: list, labels: list[str], names: list[str], split: str = "test",
               limit: int = 0, out: str | Path | None = None, name: str = "table") -> str:
    """Every method's twins scored by render and compare (:func:`twin_scores`): a markdown table (one row per
    predictions file, ``names`` its display names, ``labels`` its method labels) of the share of twins built and
    each :data:`TWIN_METRICS` mean (median); with ``out``, also ``<name>_twin.{md,csv,json}`` there (per-sample
    rows, provenance). Returns the table. Raises as :func:`twin_scores`; OutputError: ``out`` not writable."""
    import pandas as pd

    from scapo.files import atomic_write_text, check_output_dir
    from scapo.provenance import provenance
    from scapo.report import markdown_table

    if out is not None:
        out = check_output_dir(out, "evaluation output folder")
    rows, per = [], []
    for p, label, display in zip(predictions, labels, names):
        ps = twin_scores(data, p, split=split, limit=limit)
        ps.insert(0, "method", label)
        per.append(ps)
        s = twin_summary(ps)
        rows.append([display, f"{s['twin_built']:.0f}",
                     *[f"{s[m]:.3f} ({s[m + '_median']:.3f})" for m in TWIN_METRICS]])
    header = ["Method", "twin built %", *[f"{m} mean (median)" for m in TWIN_METRICS]]
    table = markdown_table(header, rows, ["l", *["r"] * (len(header) - 1)])
    if out is not None:
        prov = provenance(dataset_hash=load(data, split).dataset_hash, dataset=str(data), split=split,
                          predictions=[str(p) for p in predictions], twin_samples=int(len(per[0])) if per else 0)
        legend = ("Render and compare (scapo.twin.score): each test sample's prediction exported as a URDF twin; "
                  "mask IoU, depth difference (cm) and Chamfer distance (bbox diagonals) between the twin at the "
                  "predicted state and the true object at the true state, from the observed camera; 'moved': both "
                  "opened a further 30 deg (prismatic: 10 % of the bbox diagonal) and compared again.")
        atomic_write_text(out / f"{name}_twin.md", "\n".join(["# Twins", "", table, "", legend, "",
                                                               f"Provenance: {prov}", ""]))
        atomic_write_text(out / f"{name}_twin.csv", pd.concat(per).to_csv(index=False))
        atomic_write_text(out / f"{name}_twin.json", json.dumps({"provenance": prov, "rows": rows}, indent=1,
                                                                default=str) + "\n")
    return table
