"""The two-ray re-split about a revolute joint (scapo.steps.hinge) on hand-built two-slab views."""

from __future__ import annotations

import numpy as np
import pytest

from scapo.errors import InputError
from scapo.steps.hinge import hinge_fit, hinge_prediction


def _slabs(rng, opening_deg=110.0, n=600):
    """A laptop-like view: two thin slabs (0.3 m long, 0.2 m along the hinge, 2 mm thick) meeting at a hinge on the
    z axis through the origin, turned and moved into a camera frame. Returns points, true labels (0 base, 1 lid),
    the camera-frame pivot and axis, and the in-plane distance of each point to the hinge."""
    s = rng.uniform(0.0, 0.3, n)
    z = rng.uniform(0.0, 0.2, n)
    lab = (np.arange(n) >= n // 2).astype(np.int64)
    ang = np.where(lab == 1, np.radians(opening_deg), 0.0)
    pts = np.stack([s * np.cos(ang), s * np.sin(ang), z], 1) + rng.normal(0, 0.002, (n, 3))
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=rng).as_matrix()
    t = np.array([0.1, -0.05, 1.2])
    return pts @ R.T + t, lab, t, R[:, 2], s


def test_the_hinge_fit_moves_the_split_and_the_pivot_back_to_the_hinge():
    rng = np.random.default_rng(0)
    pts, gt, pivot, axis, s = _slabs(rng)
    lab = gt.copy()
    lab[(gt == 0) & (s < 0.1)] = 1  # the network's error: base points near the hinge given to the lid
    piv_bad = pivot + 0.06 * np.cross(axis, [1.0, 0.0, 0.0]) / np.linalg.norm(np.cross(axis, [1.0, 0.0, 0.0]))
    new, piv = hinge_fit(pts, lab, piv_bad, axis, 0, 1)
    assert (lab == gt).mean() < 0.9
    assert (new == gt).mean() > 0.98  # only points within a few mm of the hinge may stay ambiguous
    w = piv - pivot
    assert np.linalg.norm(w - (w @ axis) * axis) < 0.01  # on the hinge line to 1 cm
    assert abs((piv - piv_bad) @ axis) < 1e-9  # moved in the plane normal to the axis only


def test_the_hinge_fit_leaves_other_parts_and_thin_parts_alone():
    rng = np.random.default_rng(1)
    pts, gt, pivot, axis, _ = _slabs(rng)
    lab = gt.copy()
    lab[:20] = 2  # a third part: never relabelled
    new, _ = hinge_fit(pts, lab, pivot, axis, 0, 1)
    assert (new[:20] == 2).all()
    few = gt.copy()
    few[gt == 1] = 0
    few[np.flatnonzero(gt == 1)[:5]] = 1  # the child has 5 points: no fit, nothing changes
    new, piv = hinge_fit(pts, few, pivot + 0.05, axis, 0, 1)
    assert (new == few).all() and np.allclose(piv, pivot + 0.05)


def test_the_hinge_prediction_skips_prismatic_joints_and_checks_its_input():
    rng = np.random.default_rng(2)
    pts, gt, pivot, axis, s = _slabs(rng)
    lab = gt.copy()
    lab[(gt == 0) & (s < 0.1)] = 1
    out = {"part_label": np.stack([lab, lab]), "joint_axis": np.tile(axis, (2, 1, 1)),
           "joint_pivot": np.tile(pivot + 0.03 * axis + 0.04 * np.cross(axis, [0, 0, 1.0]), (2, 1, 1)), "other": 7}
    res = hinge_prediction(np.stack([pts, pts]), out, [0], [[0, 1]])
    assert (res["part_label"] == gt).mean() > 0.98 and res["other"] == 7
    assert res["hinge_changed"].shape == (2,) and (res["hinge_changed"] > 0.1).all()
    same = hinge_prediction(np.stack([pts, pts]), out, [1], [[0, 1]])  # a prismatic joint: no hinge to fit
    assert (same["part_label"] == out["part_label"]).all() and (same["hinge_pivot_move"] == 0).all()
    with pytest.raises(InputError, match="hinge_prediction needs"):
        hinge_prediction(pts, out, [0], [[0, 1]])
    bad = pts.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        hinge_fit(bad, lab, pivot, axis, 0, 1)
    with pytest.raises(InputError, match="zero length"):
        hinge_fit(pts, lab, pivot, np.zeros(3), 0, 1)


@pytest.mark.parametrize("script", ["hinge_diagnosis", "frame_consistency", "compute_hinge", "slot_identity"])
def test_the_hinge_diagnosis_and_the_frame_consistency_refuse_missing_inputs(script, tmp_path, capsys):
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / f"{script}.py"
    spec = importlib.util.spec_from_file_location(script, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--data", str(tmp_path / "none"), "--pred", f"x={tmp_path / 'p.npz'}", "--out",
                     str(tmp_path / "o")]) == 2
    assert "scapo:" in capsys.readouterr().err and not (tmp_path / "o.md").exists()


def test_the_axis_from_the_parts_planes_corrects_a_tilted_axis_and_keeps_it_for_a_bar():
    from scipy.spatial.transform import Rotation

    from scapo.steps.hinge import plane_axis

    rng = np.random.default_rng(3)
    pts, gt, pivot, axis, s = _slabs(rng)
    tilt = Rotation.from_rotvec(np.radians(10.0) * np.cross(axis, [1.0, 0, 0]) / np.linalg.norm(
        np.cross(axis, [1.0, 0, 0]))).apply(axis)
    lab = gt.copy()
    lab[(gt == 0) & (s < 0.1)] = 1
    out = {"part_label": lab[None], "joint_axis": tilt[None, None], "joint_pivot": pivot[None, None]}
    res = hinge_prediction(pts[None], out, [0], [[0, 1]], axis_from_planes=True)
    err = np.degrees(np.arccos(min(1.0, abs(float(res["joint_axis"][0, 0] @ axis)))))
    assert err < 1.0 and (res["part_label"][0] == gt).mean() > 0.98
    assert res["joint_axis"][0, 0] @ tilt > 0 and 9.0 < res["hinge_axis_turn"][0, 0] < 11.0
    bar = pts.copy()  # the child squeezed into a bar along the hinge's normal plane: no plane, the axis is kept
    child = gt == 1
    bar[child] = pivot + np.outer(s[child], (pts[child] - pivot).mean(0) / np.linalg.norm((pts[child] - pivot).mean(0)))
    assert np.allclose(plane_axis(bar, gt, 0, 1, tilt), tilt)


def _glasses(rng, n=400, angles=None):
    """An eyeglasses-like view: a front (0.14 m wide along y, 0.04 m high along z, 1 cm deep) and two temples (bars
    0.13 m long) hinged at its ends about z, each open by its own angle in 0..90 deg (0: shut behind the front),
    turned and moved into a camera frame (``angles``: the two openings in deg). Returns points, labels (0 front, 1
    and 2 the temples), the camera-frame axis (the front's height) and the rotation."""
    from scipy.spatial.transform import Rotation

    lab = np.repeat([0, 1, 2], [n // 2, n // 4, n - n // 2 - n // 4])
    f = lab == 0
    pts = np.zeros((n, 3))
    pts[f] = np.stack([rng.uniform(0, 0.01, f.sum()), rng.uniform(-0.07, 0.07, f.sum()),
                       rng.uniform(-0.02, 0.02, f.sum())], 1)
    for part, side in ((1, 1.0), (2, -1.0)):
        m = lab == part
        ang = np.radians(rng.uniform(0, 90) if angles is None else angles[part - 1])
        d = np.array([np.sin(ang), -side * np.cos(ang), 0.0])
        pts[m] = np.array([0.015, side * 0.07, 0.01]) + np.outer(rng.uniform(0, 0.13, m.sum()), d) \
            + rng.normal(0, 0.002, (m.sum(), 3))
    R = Rotation.random(random_state=rng).as_matrix()
    return pts @ R.T + np.array([0.0, 0.0, 0.6]), lab, R[:, 2], R


def test_a_bar_childs_axis_is_its_parents_principal_direction_chosen_over_the_training_views():
    """``bar_axes``: an eyeglasses temple turns about the front's height (its middle principal direction); the rank
    is chosen over views, each view's axis read from its own front, and the split kept; a laptop's lid is no bar."""
    from scapo.steps.hinge import bar_axis, bar_axis_choice

    rng = np.random.default_rng(0)
    views = [_glasses(rng) for _ in range(24)]
    pts, lab = np.stack([v[0] for v in views]), np.stack([v[1] for v in views])
    assert bar_axis_choice(pts, lab, [0, 0], [[0, 1], [0, 2]]) == [1, 1]
    assert bar_axis_choice(pts, lab, [0, 1], [[0, 1], [0, 2]]) == [1, None]  # a prismatic joint has no bar axis
    assert bar_axis_choice(pts[:5], lab[:5], [0, 0], [[0, 1], [0, 2]]) == [None, None]  # too few views
    for (p, lb, axis, _) in views[:6]:
        wrong = np.cross(axis, [1.0, 0.0, 0.0])  # a predicted axis 90 deg off
        a = bar_axis(p, lb, 0, 1, wrong)
        assert abs(a @ axis) > np.cos(np.radians(3.0)) and a @ wrong >= 0
    pivots = np.zeros((len(pts), 2, 3))
    out = {"part_label": lab, "joint_axis": np.repeat(np.cross(pts[:, :1, :], pts[:, 1:2, :]), 2, 1),
           "joint_pivot": pivots + pts.mean(1, keepdims=True)}
    res = hinge_prediction(pts, out, [0, 0], [[0, 1], [0, 2]], bar_axes=[1, 1])
    err = [np.degrees(np.arccos(min(1.0, abs(float(res["joint_axis"][b, j] @ views[b][2]))))) for b in range(len(pts))
           for j in range(2)]
    assert np.median(err) < 3.0 and (res["part_label"] == lab).all()
    slabs = [_slabs(rng) for _ in range(12)]  # a lid is a plate: no bar, no rank
    assert bar_axis_choice(np.stack([v[0] for v in slabs]), np.stack([v[1] for v in slabs]), [0], [[0, 1]]) == [None]
    with pytest.raises(InputError):
        bar_axis_choice(pts[:, :, :2], lab, [0, 0], [[0, 1], [0, 2]])


def test_a_part_on_several_hinges_reads_its_axes_from_its_first_only():
    """An eyeglasses front is the parent of both hinges: its axes come from the first, at one offset in the front;
    where the first temple is shut the front keeps the method's rotation, never the second hinge's axes (those sit
    in the front at another offset: a half turn)."""
    from scapo.steps.hinge import part_axes

    rng = np.random.default_rng(1)
    views = [_glasses(rng, angles=(0.0 if k % 2 else 60.0, 70.0)) for k in range(8)]
    pts, lab = np.stack([v[0] for v in views]), np.stack([v[1] for v in views])
    Rs = np.stack([v[3] for v in views])
    z = Rs[:, :, 2]
    pivots = np.stack([np.stack([R @ np.array([0.015, 0.07, 0.01]), R @ np.array([0.015, -0.07, 0.01])])
                       for R in Rs]) + np.array([0.0, 0.0, 0.6])
    out = {"part_label": lab, "joint_axis": np.stack([z, z], 1), "joint_pivot": pivots,
           "part_pose": np.tile(np.eye(4), (len(pts), 3, 1, 1))}
    E, ok = part_axes(pts, out, [0, 0], [[0, 1], [0, 2]])
    shut = np.arange(len(pts)) % 2 == 1
    assert (ok[shut, 0] == 0).all() and ok[~shut, 0].all() and ok[:, 2].all()
    canon = np.einsum("bji,bjk->bik", Rs[~shut], E[~shut, 0])  # the front's axes in its own frame: one rotation
    assert np.allclose(canon, canon[0], atol=0.05)


def test_the_hinge_axis_option_needs_the_hinge_step():
    from scapo.errors import ConfigError
    from scapo.methods.learned import LearnedOptions

    with pytest.raises(ConfigError, match="hinge=true"):
        LearnedOptions(run="r", hinge_axis=True)
    assert LearnedOptions(run="r", hinge=True, hinge_axis=True).label_suffix() == "+hinge-axis"
    assert LearnedOptions(run="r", hinge=True).label_suffix() == "+hinge"
    with pytest.raises(ConfigError, match="hinge=true"):
        LearnedOptions(run="r", hinge_bar_axis=True)
    assert LearnedOptions(run="r", hinge=True, hinge_bar_axis=True, hinge_frames=True).label_suffix() == \
        "+hinge-bar+hinge-frames"
    assert LearnedOptions(run="r", hinge=True, axis_sweep=True).label_suffix() == "+hinge+axis-sweep"
    with pytest.raises(ConfigError, match="axis_sweep"):  # two steps that both set the axes
        LearnedOptions(run="r", hinge=True, hinge_bar_axis=True, axis_sweep=True)


def test_one_step_options_type_holds_every_rule_and_builds_every_label():
    """``scapo.steps.StepOptions``: the prediction steps of every trained method (the baselines' and SCAPO's options
    inherit them), every needs/excludes rule in one place, the label built in one place in the order earlier tables'
    rows carry it; ``base_frame`` and ``base_slot``, once SCAPO's alone, are offered to every trained method."""
    from scapo.errors import ConfigError
    from scapo.methods.learned import LearnedOptions
    from scapo.methods.scapo import SCAPOOptions
    from scapo.steps import StepOptions, StepPipeline, step_options

    for cls in (StepOptions, LearnedOptions, SCAPOOptions):
        kw = {} if cls is StepOptions else {"run": "r"}
        for bad, match in (({"base_frame": "bogus"}, "base_frame must be"), ({"base_slot": "x"}, "base_slot must be"),
                           ({"hinge": True, "hinge_frames": True, "base_frame": "principal"}, "both set the part"),
                           ({"hinge": True, "hinge_frames": True, "base_slot": "auto"}, "chooses its own base slot"),
                           ({"hinge_view_prior": True}, "hinge_frames=true too")):
            with pytest.raises(ConfigError, match=match):
                cls(**kw, **bad)
        o = cls(**kw, refine=True, hinge=True, hinge_axis=True, hinge_frames=True, hinge_view_prior=True)
        assert o.label_suffix() == "+refine+hinge-axis+hinge-frames+view-prior"
        assert cls(**kw, base_frame="parts", base_slot="auto").label_suffix() == "+base-parts+slot-auto"
        assert cls(**kw, base_slot="1").object_slot_only and not cls(**kw, base_slot="0").object_slot_only
        assert not cls(**kw).fitted and cls(**kw, axis_sweep=True).fitted and cls(**kw).label_suffix() == ""
    opts = SCAPOOptions(run="r", hinge=True, refine_steps=0, base_slot="auto")
    assert step_options(opts) == StepOptions(hinge=True, base_slot="auto")
    pipe = StepPipeline(opts, [0], [[0, 1]])
    with pytest.raises(ConfigError, match=r"prediction steps \+hinge\+slot-auto are fitted on a training split"):
        pipe.apply(np.zeros((1, 8, 3)), {})


def _posed_slabs(rng, opening_deg, n=600):
    """Two thin slabs meeting at a hinge on the object's z axis (the base along +x, the lid turned by the opening
    about +z), turned by a random rotation R and moved to t. Returns points, labels, R, t, the lid's object-frame
    rotation Rz(opening)."""
    from scipy.spatial.transform import Rotation

    s, z = rng.uniform(0.0, 0.3, n), rng.uniform(0.0, 0.2, n)
    lab = (np.arange(n) >= n // 2).astype(np.int64)
    ang = np.where(lab == 1, np.radians(opening_deg), 0.0)
    pts = np.stack([s * np.cos(ang), s * np.sin(ang), z], 1) + rng.normal(0, 0.002, (n, 3))
    R = Rotation.random(random_state=rng).as_matrix()
    t = rng.uniform(-0.2, 0.2, 3) + np.array([0.0, 0.0, 1.2])
    return pts @ R.T + t, lab, R, t, Rotation.from_euler("z", opening_deg, degrees=True).as_matrix()


def _angle_deg(A, B):
    return float(np.degrees(np.arccos(np.clip((np.trace(A.T @ B) - 1) / 2, -1.0, 1.0))))


def test_the_part_axes_are_rigid_with_each_part_whatever_the_view_and_the_axis_sign():
    from scapo.steps.hinge import part_axes

    rng = np.random.default_rng(1)
    want = np.stack([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]], 1)  # [a, u, a x u] in the part's own coordinates
    for view in range(6):
        opening = rng.uniform(40, 150)
        pts, lab, R, t, Rlid = _posed_slabs(rng, opening)
        sign = -1.0 if view % 2 else 1.0  # the predicted axis's sign does not matter: the pair's chirality fixes it
        out = {"part_label": lab[None], "joint_axis": sign * R[:, 2][None, None], "joint_pivot": t[None, None],
               "part_pose": np.zeros((1, 2, 4, 4))}
        E, ok = part_axes(pts[None], out, [0], [[0, 1]])
        assert ok.all()
        assert _angle_deg(R.T @ E[0, 0], want) < 2.0, view
        assert _angle_deg((R @ Rlid).T @ E[0, 1], want) < 2.0, view
    for opening in (180.0, 1.0):  # open flat or shut: the chirality is undefined and the view keeps its rotations
        pts, lab, R, t, _ = _posed_slabs(rng, opening)
        out = {"part_label": lab[None], "joint_axis": R[:, 2][None, None], "joint_pivot": t[None, None],
               "part_pose": np.zeros((1, 2, 4, 4))}
        assert not part_axes(pts[None], out, [0], [[0, 1]])[1].any()
        assert not part_axes(pts[None], out, [1], [[0, 1]])[1].any()  # a prismatic joint gives no axes
    with pytest.raises(InputError, match="part_axes"):
        part_axes(pts[None], {**out, "joint_pivot": np.full((1, 1, 3), np.nan)}, [0], [[0, 1]])


def test_hinge_frames_give_every_view_the_rotation_most_training_views_agree_on():
    from scipy.spatial.transform import Rotation

    from scapo.steps.hinge import HingeFrames

    rng = np.random.default_rng(2)
    Q = Rotation.random(2, random_state=rng).as_matrix()  # the method's canonical part frames, in object terms
    views = [_posed_slabs(rng, rng.uniform(40, 150), n=300) for _ in range(12)]
    pts = np.stack([v[0] for v in views])
    gt = np.stack([np.stack([v[2] @ Q[0], v[2] @ v[4] @ Q[1]]) for v in views])  # (12, 2, 3, 3) truth
    net = gt.copy()
    net[8:] = Rotation.random(8, random_state=rng).as_matrix().reshape(4, 2, 3, 3)  # a third of the views scatter
    pose = np.tile(np.eye(4), (12, 2, 1, 1))
    pose[..., :3, :3] = net
    pose[..., :3, 3] = rng.normal(size=(12, 2, 3))
    C = Rotation.random(random_state=rng).as_matrix()  # the method's object frame, against its base part's
    T = pose[:, 0].copy()
    T[:, :3, :3] = T[:, :3, :3] @ C
    out = {"part_label": np.stack([v[1] for v in views]), "part_pose": pose, "T_cam_obj": T,
           "joint_axis": np.stack([v[2][:, 2] for v in views])[:, None], "joint_pivot": np.stack([v[3] for v in views])[:, None]}
    step = HingeFrames([0], [[0, 1]])
    with pytest.raises(InputError, match="fitted"):
        step(pts, out)
    step.fit(pts, out)
    assert np.allclose(step.support, 8 / 12)
    res = step(pts, out)
    for i in range(12):
        for p in range(2):
            assert _angle_deg(res["part_pose"][i, p, :3, :3], gt[i, p]) < 2.0, (i, p)
    assert np.allclose(res["part_pose"][..., :3, 3], pose[..., :3, 3])  # the canonical origins are kept
    assert np.allclose(res["T_cam_obj"][:, :3, :3], res["part_pose"][:, 0, :3, :3] @ C)  # rigid with the root
    assert np.allclose(res["T_cam_obj"][:, :3, 3], T[:, :3, 3])
    assert (res["frame_snap_deg"][8:] > 5).all() and step.info(res)["replaced_share"] == 1.0


def test_the_hinge_frames_option_needs_the_hinge_step_and_excludes_the_base_axes_snap():
    from scapo.errors import ConfigError
    from scapo.methods.learned import LearnedOptions
    from scapo.methods.scapo import SCAPOOptions

    with pytest.raises(ConfigError, match="hinge=true"):
        LearnedOptions(run="r", hinge_frames=True)
    assert LearnedOptions(run="r", hinge=True, hinge_axis=True, hinge_frames=True).label_suffix() == \
        "+hinge-axis+hinge-frames"
    with pytest.raises(ConfigError, match="give one"):
        SCAPOOptions(run="r", hinge=True, hinge_frames=True, base_frame="principal")
    from scapo.steps.hinge import HingeFrames

    with pytest.raises(ConfigError, match="prismatic: predict without hinge_frames"):
        HingeFrames([1], [[0, 1]])  # a drawer


def test_the_view_prior_gives_back_the_base_slot_a_view_gave_to_the_lid_and_stays_off_for_the_whole_sphere():
    from scipy.spatial.transform import Rotation

    from scapo.steps.hinge import HingeFrames

    def views(rng, k, sphere):
        vs = []
        for _ in range(k):
            pts, lab, R, t, Rlid = _posed_slabs(rng, rng.uniform(50, 140), n=300)
            R2 = Rotation.random(random_state=rng).as_matrix() if sphere else \
                Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()  # the paper's narrow viewpoints
            vs.append((((pts - t) @ R) @ R2.T + t, lab, R2, t, Rlid))
        return vs

    def prediction(vs):
        pose = np.tile(np.eye(4), (len(vs), 2, 1, 1))
        pose[:, 0, :3, :3] = [v[2] for v in vs]
        pose[:, 1, :3, :3] = [v[2] @ v[4] for v in vs]
        return np.stack([v[0] for v in vs]), {
            "part_label": np.stack([v[1] for v in vs]), "part_pose": pose, "T_cam_obj": pose[:, 0].copy(),
            "joint_axis": np.stack([v[2][:, 2] for v in vs])[:, None],
            "joint_pivot": np.stack([v[3] for v in vs])[:, None]}

    rng = np.random.default_rng(3)
    pts, train = prediction(views(rng, 16, False))
    step = HingeFrames([0], [[0, 1]], view_prior=True).fit(pts, train)
    assert step.prior is not None and step.prior_share > 0.7
    tp, test = prediction(views(rng, 6, False))
    gt, truth = test["part_label"].copy(), test["part_pose"].copy()
    test["part_label"][:3] = 1 - gt[:3]  # three views give the base's slot to the lid, and their poses follow
    test["part_pose"][:3] = truth[:3, ::-1]
    test["joint_state"] = np.full((6, 1), 0.7)
    test["joint_state"][:3] = -0.7  # the exchanged views' joint: the base seen turning from the lid
    res = step(tp, test)
    assert res["frame_swapped"].tolist() == [True] * 3 + [False] * 3 and (res["part_label"] == gt).all()
    assert np.allclose(res["joint_state"], 0.7)  # the exchange gives the lid's turn from the base back
    for i in range(6):
        for p in range(2):
            assert _angle_deg(res["part_pose"][i, p, :3, :3], truth[i, p, :3, :3]) < 2.0, (i, p)
    assert step.base == 0 and not HingeFrames([0], [[0, 1]]).fit(pts, train).view_prior  # off unless asked for
    mixed = {**train, "part_label": train["part_label"].copy(), "part_pose": train["part_pose"].copy()}
    mixed["part_label"][::2] = 1 - train["part_label"][::2]  # half the training views give the base's slot to the lid
    mixed["part_pose"][::2] = train["part_pose"][::2, ::-1]
    half = HingeFrames([0], [[0, 1]], view_prior=True).fit(pts, mixed)
    assert half.prior is not None and _angle_deg(half.prior, step.prior) < 10
    assert (half(tp, test)["part_label"] == gt).all()
    lid_first = {**train, "part_label": 1 - train["part_label"], "part_pose": train["part_pose"][:, ::-1].copy()}
    assert HingeFrames([0], [[0, 1]], view_prior=True).fit(pts, lid_first).base == 1  # the slot that turns least
    sp, sphere = prediction(views(rng, 24, True))
    assert HingeFrames([0], [[0, 1]], view_prior=True).fit(sp, sphere).prior is None


def test_a_diagnosis_writes_its_markdown_and_a_record_of_its_inputs_or_refuses_an_unwritable_place(tmp_path):
    import json

    from scapo.bench.diagnosis import write_diagnosis
    from scapo.errors import OutputError

    src = tmp_path / "p.npz"
    src.write_bytes(b"abc")
    md, js = write_diagnosis(tmp_path / "out" / "d", ["# t", "x"], {"rows": {"a": 1}}, {"a": str(src)})
    assert md.read_text() == "# t\nx\n"
    rec = json.loads(js.read_text())
    assert rec["rows"] == {"a": 1} and rec["predictions"]["a"]["sha256_16"] == "ba7816bf8f01cfea"
    assert "commit" in rec["provenance"]
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match="cannot"):
        write_diagnosis(tmp_path / "file" / "d", ["x"], {}, {})


def test_the_sweep_reads_a_bar_childs_axis_in_the_base_frame_and_turns_it_into_each_view():
    """``axis_sweep`` (:mod:`scapo.steps.sweep`): hand-built eyeglasses views (front, two temple bars opening
    20-90 deg about the height axis z) under random camera rotations, with the true base poses: the temples' long
    directions in the base frame sweep the plane normal to z, so the fitted axes are z within 2 deg, and each view's
    axis becomes its base rotation of z, signed as the method's own; a wrong method axis is replaced. A joint whose
    child has too few points keeps the method's axes; a child direction that does not move is read as the axis; the
    step refuses to run unfitted."""
    import torch

    from scapo.errors import TrainingError
    from scapo.ops.groups import random_rotation
    from scapo.ops.sweep import sweep_axis
    from scapo.steps.sweep import SweepAxes
    from tests.test_frames import _glasses_view

    rng = np.random.default_rng(2)
    V = 24
    Q = random_rotation(V, torch.float64, torch.Generator().manual_seed(3)).numpy()
    views = [_glasses_view(rng, 20 + 70 * k / V) for k in range(V)]
    pts = np.stack([v[0] for v in views]) @ Q.transpose(0, 2, 1) + np.array([0.0, 0.0, 0.8])
    lab = np.stack([v[1] for v in views])
    T = np.tile(np.eye(4), (V, 1, 1))
    T[:, :3, :3] = Q
    wrong = np.tile(np.array([0.0, 1.0, 0.0]), (V, 2, 1))  # the method's axes: the front's width
    out = {"part_label": lab, "T_cam_obj": T, "joint_axis": np.einsum("vij,vkj->vki", Q, wrong)}
    step = SweepAxes([0, 0], [(0, 1), (0, 2)])
    with pytest.raises(TrainingError, match="fit"):
        step(out)
    step.fit(pts, out)
    for a, found in zip(step.axes, step.info()):
        assert abs(a[2]) > np.cos(np.radians(2.0)) and found["mode"] == "sweep" and found["views"] == V
    new = step(out)["joint_axis"]
    true = Q[:, :, 2]  # z in the camera
    cos = np.abs((new * true[:, None]).sum(-1))
    assert cos.min() > np.cos(np.radians(2.0))
    assert ((new * out["joint_axis"]).sum(-1) >= 0).all() and np.allclose(np.linalg.norm(new, axis=-1), 1.0)
    few = lab.copy()
    few[few == 2] = 0  # no view shows the second temple
    kept = SweepAxes([0, 0], [(0, 1), (0, 2)]).fit(pts, {**out, "part_label": few})
    assert kept.axes[1] is None and np.array_equal(kept(out)["joint_axis"][:, 1], out["joint_axis"][:, 1])
    still, info = sweep_axis(np.tile([0.0, 0.6, 0.8], (10, 1)) + rng.normal(0, 0.01, (10, 3)))
    assert info["mode"] == "still" and abs(still @ [0.0, 0.6, 0.8]) > 0.99
    with pytest.raises(ValueError, match="at least 2"):
        sweep_axis(np.zeros((1, 3)))


def test_slot_identity_tells_a_right_split_with_exchanged_slots_from_a_wrong_one(laptop_data, tmp_path):
    """``bench/diagnostics/slot_identity.py`` on hand-made labels of the training split: pseudo-labels right in every view but with
    base and lid exchanged in a third of the views score 1 per view and 2/3 for the best single permutation; a network
    that follows them in all but one view is counted so; a run without ``split_labels.npy`` is refused."""
    import importlib.util
    from pathlib import Path
    from types import SimpleNamespace

    from scapo.data import load
    from scapo.errors import PredictionError

    path = Path(__file__).resolve().parents[1] / "bench" / "diagnostics" / "slot_identity.py"
    spec = importlib.util.spec_from_file_location("slot_identity", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    tr = load(laptop_data, "train")
    gt = tr.arrays(["part_label"])["part_label"]
    V = len(gt)
    flip = np.arange(V) % 3 == 0
    pseudo = np.where(flip[:, None], 1 - gt, gt)
    run = tmp_path / "run"
    run.mkdir()
    np.save(run / "split_labels.npy", pseudo)
    net = pseudo.copy()
    net[1] = 1 - net[1]  # the network leaves the pseudo-labels' permutation in one view
    keys = list(tr.keys())
    preds = SimpleNamespace(method="scapo", info={"run": str(run)}, part_label=net[::-1].copy(),
                            instance_id=np.array([k[0] for k in keys])[::-1], view_id=np.array([k[1] for k in keys])[::-1],
                            split=np.array(["train"] * V))
    r = mod.slot_identity(laptop_data, preds)
    assert r["views"] == V and r["pseudo_per_view_best"] == 1.0 and r["perms"] == [[0, 1], [1, 0]]
    assert r["pseudo_best_single_perm"] == pytest.approx(1 - flip.mean(), abs=1e-4)
    assert r["pseudo_perm_shares"] == [pytest.approx(1 - flip.mean(), abs=1e-4), pytest.approx(flip.mean(), abs=1e-4)]
    assert r["net_follows_pseudo"] == pytest.approx(1 - 1 / V, abs=1e-4)
    (run / "split_labels.npy").unlink()
    with pytest.raises(PredictionError, match="split_labels.npy"):
        mod.slot_identity(laptop_data, preds)
