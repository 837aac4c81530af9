"""Evaluator: perfect predictions score perfectly; slot permutations, frame offsets and bad files."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.data import load
from scapo.errors import PredictionError
from scapo.eval import Predictions, evaluate
from scapo.ops.rigid import as_transform


def oracle(data, split, perm=None, offsets=None, needs_alignment=False, state_offset=0.0, flip_axis=False,
           reverse_joints=False):
    """Ground truth written as predictions; optionally with permuted slots and per-part frame offsets, and
    with every joint written the other way round (parent and child exchanged, so the state negated)."""
    ds = load(data, split)
    a = ds.arrays()
    P = ds.num_parts
    perm = np.arange(P) if perm is None else np.asarray(perm)  # slot of GT part p is perm[p]
    inv = np.argsort(perm)
    poses = a["part_pose"].copy()
    if offsets is not None:  # predicted canonical frame differs: P_pred = P_gt @ inv(O)
        poses = poses @ np.linalg.inv(offsets)[None]
    axis = -a["joint_axis"] if flip_axis else a["joint_axis"]
    state = (-1 if flip_axis else 1) * (a["joint_state"] - state_offset)
    joint_parts = perm[a["joint_parts"]]
    if reverse_joints:
        joint_parts, state = joint_parts[..., ::-1].copy(), -state
    return Predictions(
        method="oracle", instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(len(ds), split),
        part_label=perm[a["part_label"]], part_pose=poses[:, inv], joint_parts=joint_parts,
        joint_type=a["joint_type"], joint_axis=axis, joint_pivot=a["joint_pivot"], joint_state=state,
        T_cam_obj=a["T_cam_obj"], needs_alignment=needs_alignment, dataset_hash=ds.dataset_hash)


def assert_perfect(summary):
    assert summary["S"] == pytest.approx(100.0)
    for k in ("R", "t", "D", "C", "state_deg"):
        assert summary[k] == pytest.approx(0.0, abs=1e-4), k
    assert summary["ap_part_5"] == 100.0 and summary["ap_joint_5"] == 100.0 and summary["seg_75"] == 100.0


def test_ground_truth_scores_perfectly(laptop_data):
    assert_perfect(evaluate(laptop_data, oracle(laptop_data, "test")).summary)


def test_permuted_slots_are_matched(laptop_data):
    res = evaluate(laptop_data, oracle(laptop_data, "test", perm=[1, 0]))
    assert_perfect(res.summary)
    res = evaluate(laptop_data, oracle(laptop_data, "test", perm=[1, 0]), protocol="per-category")
    assert_perfect(res.summary)


def test_a_joint_written_from_child_to_parent_has_its_state_negated(laptop_data):
    # a self-supervised model may call the screen its base: its joint then runs screen -> base and its
    # state is the base's motion relative to the screen, the negative of the GT state
    assert_perfect(evaluate(laptop_data, oracle(laptop_data, "test", perm=[1, 0], reverse_joints=True)).summary)
    kw = dict(perm=[1, 0], needs_alignment=True, state_offset=0.3, flip_axis=True, reverse_joints=True)
    preds = Predictions.concatenate([oracle(laptop_data, "test", **kw), oracle(laptop_data, "train", **kw)])
    assert_perfect(evaluate(laptop_data, preds).summary)


def test_canonical_frame_offsets_are_estimated_from_training_predictions(laptop_data):
    offs = np.stack([as_transform(Rotation.from_euler("xyz", [30, -50, 100], degrees=True).as_matrix(), [0.1, 0, 0.2]),
                     as_transform(Rotation.from_euler("xyz", [-10, 80, 5], degrees=True).as_matrix(), [0, 0.3, 0])])
    kw = dict(perm=[1, 0], offsets=offs, needs_alignment=True, state_offset=0.4, flip_axis=True)
    preds = Predictions.concatenate([oracle(laptop_data, "test", **kw), oracle(laptop_data, "train", **kw)])
    res = evaluate(laptop_data, preds)
    assert_perfect(res.summary)
    assert res.alignment is not None
    np.testing.assert_allclose(res.alignment.part_offset, offs, atol=1e-6)
    # without alignment the same predictions are far off
    preds.needs_alignment = False
    assert evaluate(laptop_data, preds).summary["R"] > 20


def test_errors_are_measured(laptop_data):
    p = oracle(laptop_data, "test")
    R = Rotation.from_rotvec([0, 0, np.radians(10)]).as_matrix()
    p.part_pose[:, :, :3, :3] = R @ p.part_pose[:, :, :3, :3]
    p.joint_axis = np.einsum("ij,mkj->mki", R, p.joint_axis)
    res = evaluate(laptop_data, p)
    assert res.summary["R"] == pytest.approx(10.0, abs=1e-6)
    assert res.summary["D"] == pytest.approx(10.0, abs=1e-3) or res.summary["D"] < 10.0
    assert res.summary["S"] == pytest.approx(100.0)


def test_bad_predictions_are_refused(laptop_data, tmp_path):
    p = oracle(laptop_data, "test")
    with pytest.raises(PredictionError, match="miss 6 of 12 test samples"):
        evaluate(laptop_data, p.select(np.arange(len(p)) < 6))
    bad = oracle(laptop_data, "test")
    bad.joint_axis[0, 0, 0] = np.nan
    with pytest.raises(PredictionError, match="joint_axis.*NaN"):
        bad.validate()
    with pytest.raises(PredictionError, match="shape"):
        Predictions(**{**p.__dict__, "part_pose": p.part_pose[:, :, :3]})
    other = oracle(laptop_data, "test")
    other.dataset_hash = "0" * 64
    with pytest.raises(PredictionError, match="made on dataset"):
        evaluate(laptop_data, other)
    path = p.save(tmp_path / "p.npz")
    assert_perfect(evaluate(laptop_data, path).summary)
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(PredictionError, match="cannot be read"):
        Predictions.load(tmp_path / "junk.npz")


def test_the_alignment_estimator_finds_the_common_offset_when_a_share_of_the_samples_are_half_turns():
    """A hand case of the default estimator ("ransac-offsets"): 60 of 100 training samples have the canonical-frame
    offset ``Q`` (a 40-deg turn, with 2-deg noise, translation (0.1, 0, 0)), 40 have ``Q`` turned by a half turn about
    z (a flipped frame, translation (0.5, 0, 0)). The offset is ``Q`` within a degree, its translation the inliers'
    median, its inlier ratio 0.6; OP-Align's "ransac-sample-means" (a mean of 5 samples) finds it within a few degrees."""
    from scipy.spatial.transform import Rotation

    from scapo.eval.alignment import estimate_alignment
    from scapo.eval.metrics import rotation_error_deg
    from scapo.ops.rigid import as_transform, invert_transform

    rng = np.random.default_rng(0)
    Q = Rotation.from_euler("xyz", [40, 10, -20], degrees=True).as_matrix()
    flip = Rotation.from_euler("z", 180, degrees=True).as_matrix()
    offsets = []
    for m in range(100):
        noise = Rotation.from_rotvec(rng.normal(size=3) * np.radians(1.0)).as_matrix()
        R, t = (Q @ noise, [0.1, 0, 0]) if m < 60 else (Q @ flip @ noise, [0.5, 0, 0])
        offsets.append(as_transform(R, np.array(t)))
    O = np.stack(offsets)[:, None]  # (M, 1, 4, 4): P_gt = P_pred @ O with P_gt the identity
    gt = np.tile(np.eye(4), (100, 1, 1, 1))
    axis, state = np.tile([0.0, 0.0, 1.0], (100, 1, 1)), np.zeros((100, 1))
    est = estimate_alignment(invert_transform(O), gt, axis, axis, state, state)
    assert rotation_error_deg(est.part_offset[0, :3, :3], Q) < 1.0
    np.testing.assert_allclose(est.part_offset[0, :3, 3], [0.1, 0, 0], atol=1e-9)
    assert est.inlier_ratio[0] == pytest.approx(0.6)
    means = estimate_alignment(invert_transform(O), gt, axis, axis, state, state, method="ransac-sample-means",
                               inlier_deg=10.0)
    assert rotation_error_deg(means.part_offset[0, :3, :3], Q) < 4.0  # a mean of 5 noisy samples


def test_a_joint_that_connects_the_wrong_parts_scores_as_unmatched(laptop_data):
    """Hand case: the oracle's joints written between slot 0 and itself (not the laptop's two parts): every joint is
    unmatched, so its direction error is 90 deg, its pivot error one bounding-box diagonal, its state unscored, no
    joint passes any AP threshold; the parts keep their perfect scores."""
    preds = oracle(laptop_data, "test")
    preds.joint_parts = np.zeros_like(preds.joint_parts)
    res = evaluate(laptop_data, preds)
    s, ps = res.summary, res.per_sample
    assert (ps["joints_matched"] == 0).all() and s["joint_match_rate"] == 0.0
    assert ps["D"].to_numpy() == pytest.approx(90.0) and s["D"] == pytest.approx(90.0)
    assert ps["C"].to_numpy() == pytest.approx(1.0)  # the scapo protocol's unit: the bounding-box diagonal
    assert np.isnan(ps["state_deg"]).all()
    assert s["ap_joint_5"] == s["ap_joint_15"] == 0.0 and s["S"] == pytest.approx(100.0) and s["ap_part_5"] == 100.0


def test_part_ap_under_a_known_translation_error_at_each_threshold(laptop_data):
    """Hand case: the base part moved 7 cm along x in every test view, the lid exact: the base fails 5 deg / 5 cm and
    passes 10 / 10 and 15 / 15, the lid passes all; part AP (the mean over parts) is 50, 100, 100 %, and the base's
    translation error is 7 cm."""
    preds = oracle(laptop_data, "test")
    preds.part_pose = preds.part_pose.copy()
    preds.part_pose[:, 0, 0, 3] += 0.07
    res = evaluate(laptop_data, preds)
    s = res.summary
    assert (s["ap_part_5"], s["ap_part_10"], s["ap_part_15"]) == (50.0, 100.0, 100.0)
    assert res.per_sample["t_cm"].to_numpy() == pytest.approx(3.5)  # the mean over the two parts


def test_joint_ap_under_a_known_pivot_error_at_each_threshold(laptop_data):
    """Hand case: every joint's pivot moved 7 cm perpendicular to its (exact) axis: the pivot error is 7 cm (parallel
    lines: the point-to-line distance), so the joint fails 5 deg / 5 cm and passes 10 / 10 and 15 / 15: joint AP 0,
    100, 100 %; the directions stay exact."""
    preds = oracle(laptop_data, "test")
    a = preds.joint_axis / np.linalg.norm(preds.joint_axis, axis=-1, keepdims=True)
    side = np.cross(a, [0.0, 0.0, 1.0])
    side = np.where(np.linalg.norm(side, axis=-1, keepdims=True) > 1e-6, side, np.cross(a, [1.0, 0.0, 0.0]))
    preds.joint_pivot = preds.joint_pivot + 0.07 * side / np.linalg.norm(side, axis=-1, keepdims=True)
    res = evaluate(laptop_data, preds)
    s = res.summary
    assert res.per_sample["C_cm"].to_numpy() == pytest.approx(7.0)
    assert (s["ap_joint_5"], s["ap_joint_10"], s["ap_joint_15"]) == (0.0, 100.0, 100.0)
    assert s["D"] == pytest.approx(0.0, abs=1e-6)
