"""Evaluation protocols (scapo, op-align, eap) on hand-built cases where they must disagree; every
expected value is worked out by hand or by brute force, not by the implementation."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.data import generate, load, make_config
from scapo.errors import UnknownNameError
from scapo.eval import Predictions, evaluate
from scapo.eval.alignment import ransac_sample_means
from scapo.eval.protocols import PROTOCOLS, get_protocol


def ground_truth_predictions(data, split="test", perm=None, edit=None) -> Predictions:
    """The ground truth written as predictions (slot of GT part p is perm[p]); ``edit(arrays)`` changes them."""
    ds = load(data, split)
    a = ds.arrays()
    P = ds.num_parts
    perm = np.arange(P) if perm is None else np.asarray(perm)
    inv = np.argsort(perm)
    arrays = dict(part_label=np.where(a["part_label"] >= 0, perm[np.maximum(a["part_label"], 0)], -1),
                  part_pose=a["part_pose"][:, inv].copy(), joint_parts=perm[a["joint_parts"]],
                  joint_type=a["joint_type"], joint_axis=a["joint_axis"].copy(), joint_pivot=a["joint_pivot"].copy(),
                  joint_state=a["joint_state"].copy(), T_cam_obj=a["T_cam_obj"])
    if edit is not None:
        edit(arrays, a)
    return Predictions(method="gt", instance_id=a["instance_id"], view_id=a["view_id"], split=np.full(len(ds), split),
                       needs_alignment=False, dataset_hash=ds.dataset_hash, **arrays)


@pytest.fixture(scope="module")
def drawer(tmp_path_factory):
    out = tmp_path_factory.mktemp("drawer") / "d"
    generate(make_config("drawer", 2, 3, seed=1, test_fraction=0.5, val_fraction=0.0), out, progress=False)
    return out


@pytest.fixture(scope="module")
def eyeglasses(tmp_path_factory):
    out = tmp_path_factory.mktemp("eye") / "e"
    generate(make_config("eyeglasses", 3, 3, seed=2, test_fraction=0.34, val_fraction=0.0), out, progress=False)
    return out


def test_protocols_are_named_frozen_and_unknown_names_listed():
    assert list(PROTOCOLS)[:4] == ["scapo", "scapo-per-category", "op-align", "eap"]  # then any added one
    assert get_protocol("per-sample").name == "scapo"  # the name used before protocols had names
    with pytest.raises(UnknownNameError, match="known protocols: scapo, scapo-per-category, op-align, eap"):
        get_protocol("nope")
    with pytest.raises(dataclasses.FrozenInstanceError):
        PROTOCOLS["scapo"].units = "cm"


def test_ground_truth_is_perfect_under_every_protocol(laptop_data, eyeglasses):
    for data in (laptop_data, eyeglasses):
        for name in PROTOCOLS:
            s = evaluate(data, ground_truth_predictions(data), protocol=name).summary
            assert s["S"] == pytest.approx(100.0) and s["R"] == pytest.approx(0.0, abs=1e-5), name
            assert s["D"] == pytest.approx(0.0, abs=1e-5) and s["C"] == pytest.approx(0.0, abs=1e-7), name
            assert s["R_under5"] == 100.0 and s["R_over90"] == 0.0


def test_a_part_flipped_by_180_deg_is_180_under_scapo_and_0_under_eap(laptop_data):
    flip = Rotation.from_rotvec([0.0, 0.0, math.pi]).as_matrix()

    def edit(arr, _):
        arr["part_pose"][:, 1, :3, :3] = arr["part_pose"][:, 1, :3, :3] @ flip  # turned about its own z axis

    preds = ground_truth_predictions(laptop_data, edit=edit)
    scapo = evaluate(laptop_data, preds, protocol="scapo")
    eap = evaluate(laptop_data, preds, protocol="eap")
    np.testing.assert_allclose(scapo.per_sample["R_p1"], 180.0, atol=1e-6)
    np.testing.assert_allclose(eap.per_sample["R_p1"], 0.0, atol=1e-6)
    assert scapo.summary["R"] == pytest.approx(90.0, abs=1e-6) and scapo.summary["R_over90"] == 50.0
    assert eap.summary["R"] == pytest.approx(0.0, abs=1e-6)


def test_op_align_scores_the_pivot_of_a_prismatic_joint_and_scapo_does_not(drawer):
    shift_m = 0.05

    def edit(arr, a):
        d = a["joint_axis"][:, 0]
        side = np.cross(d, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side, axis=-1, keepdims=True)  # perpendicular to the axis
        arr["joint_pivot"][:, 0] += shift_m * side

    preds = ground_truth_predictions(drawer, edit=edit)
    a = load(drawer, "test").arrays()
    assert (a["joint_type"] == 1).all()
    scapo = evaluate(drawer, preds, protocol="scapo")
    assert math.isnan(scapo.summary["C"]) and scapo.per_sample["C_j0"].isna().all()
    op = evaluate(drawer, preds, protocol="op-align")
    # brute force: OP-Align's unit is the cloud's mean distance to its centroid / 0.25
    for k in range(len(a["points"])):
        pts = [p for p, lab in zip(a["points"][k].astype(np.float64), a["part_label"][k]) if lab >= 0]
        c = sum(pts) / len(pts)
        mcd = sum(float(np.sqrt(((p - c) ** 2).sum())) for p in pts) / len(pts)
        assert op.per_sample["C_j0"].iloc[k] == pytest.approx(shift_m * 0.25 / mcd, rel=1e-6)


def test_op_align_leaves_background_points_out_of_the_iou_and_scapo_counts_them(tmp_path):
    """Real-world-style clouds hold background points (GT -1). OP-Align's code scores real scans on the object
    points only (art_metric.py evaluation_segmentation with noise_exist); the scapo protocol counts a background
    point predicted as a part against that part. One protocol rule, the same for every method."""
    data = tmp_path / "real"
    generate(make_config("laptop", 2, 2, seed=3, sensor="realistic", test_fraction=0.5, val_fraction=0.0), data,
             progress=False)
    gt = load(data, "test").arrays()["part_label"]
    assert (gt < 0).any() and (gt >= 0).any()

    def background_as_part0(arrays, a):
        arrays["part_label"] = np.where(a["part_label"] >= 0, arrays["part_label"], 0)

    clean = ground_truth_predictions(data)  # background predicted as -1: perfect under both
    grabbing = ground_truth_predictions(data, edit=background_as_part0)
    for name in ("scapo", "op-align"):
        assert evaluate(data, clean, protocol=name).summary["S"] == pytest.approx(100.0)
    per_sample = evaluate(data, grabbing, protocol="scapo").per_sample
    expected = [100.0 * np.mean([np.sum(g == 0) / np.sum(g <= 0), 1.0]) for g in gt]  # part 0 takes every background point
    np.testing.assert_allclose(per_sample["S"], expected)
    assert per_sample["S"].max() < 100.0
    op = evaluate(data, grabbing, protocol="op-align").summary
    assert op["S"] == pytest.approx(100.0) and op["seg_75"] == 100.0 and op["min_seg_75"] == 100.0


def test_min_map_is_below_mean_map_when_one_of_three_parts_fails(eyeglasses):
    turn = Rotation.from_rotvec([0.0, 0.0, math.radians(30)]).as_matrix()

    def edit(arr, _):
        arr["part_pose"][:, 2, :3, :3] = arr["part_pose"][:, 2, :3, :3] @ turn

    preds = ground_truth_predictions(eyeglasses, edit=edit)
    s = evaluate(eyeglasses, preds, protocol="op-align").summary
    # by hand: two of three parts pass in every sample -> mean mAP 2/3, min mAP 0
    assert s["ap_part_5"] == pytest.approx(200.0 / 3.0) and s["min_ap_part_5"] == 0.0
    assert s["ap_part_10"] == pytest.approx(200.0 / 3.0) and s["min_ap_part_10"] == 0.0
    assert s["min_ap_joint_5"] == 100.0 and s["min_seg_75"] == 100.0
    assert "min_ap_part_5" not in evaluate(eyeglasses, preds, protocol="scapo").summary


def test_op_align_units_differ_from_bbox_diagonals_by_the_cloud_scale(laptop_data):
    v = np.array([0.006, -0.008, 0.0])  # 1 cm

    def edit(arr, _):
        arr["part_pose"][:, :, :3, 3] += v

    preds = ground_truth_predictions(laptop_data, edit=edit)
    a = load(laptop_data, "test").arrays()
    scapo = evaluate(laptop_data, preds, protocol="scapo").per_sample
    op = evaluate(laptop_data, preds, protocol="op-align").per_sample
    pts = a["points"].astype(np.float64)
    mcd = np.linalg.norm(pts - pts.mean(1, keepdims=True), axis=-1).mean(1)  # every laptop point is an object point
    np.testing.assert_allclose(scapo["t"], 0.01 / a["bbox_diag"], rtol=1e-9)
    np.testing.assert_allclose(op["t"], 0.01 * 0.25 / mcd, rtol=1e-6)
    np.testing.assert_allclose(op["t_cm"], 1.0, rtol=1e-9)  # centimetres are centimetres under every protocol
    assert not np.allclose(op["t"], scapo["t"])


def test_op_align_matches_parts_by_its_two_fixed_orders_only(eyeglasses, laptop_data):
    swapped = ground_truth_predictions(laptop_data, perm=[1, 0])
    assert evaluate(laptop_data, swapped, protocol="op-align").summary["S"] == pytest.approx(100.0)
    temples = ground_truth_predictions(eyeglasses, perm=[0, 2, 1])  # one of OP-Align's two orders
    assert evaluate(eyeglasses, temples, protocol="op-align").summary["S"] == pytest.approx(100.0)
    other = ground_truth_predictions(eyeglasses, perm=[1, 0, 2])  # not one of them: Hungarian finds it, OP-Align not
    assert evaluate(eyeglasses, other, protocol="scapo").summary["S"] == pytest.approx(100.0)
    assert evaluate(eyeglasses, other, protocol="op-align").summary["S"] < 50.0


def test_op_align_alignment_estimator_recovers_the_inlier_offset():
    rng = np.random.default_rng(0)
    true_R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    M, P = 40, 2
    R = np.tile(true_R, (M, P, 1, 1))
    t = np.tile([0.1, 0.0, -0.05], (M, P, 1))
    outliers = rng.choice(M, 12, replace=False)  # 30 % of the samples
    R[outliers] = Rotation.random(len(outliers) * P, random_state=1).as_matrix().reshape(-1, P, 3, 3)
    t[outliers] += 1.0
    Rm, tm, r_ratio, t_ratio = ransac_sample_means(R, t)
    # OP-Align keeps the first mean with the most inliers: all 28 inliers (an all-inlier draw gives the exact
    # offset; a draw with one outlier may tie it while staying within the 10 deg inlier threshold)
    assert r_ratio == pytest.approx(28 / 40) and t_ratio == pytest.approx(28 / 40)
    angle = np.degrees(np.arccos(np.clip((np.einsum("pij,pij->p", Rm, np.tile(true_R, (P, 1, 1))) - 1) / 2, -1, 1)))
    assert (angle < 10.0).all()
    # a translation mean with one outlier (shifted by 1 in x, y, z) is 0.35 away: only all-inlier draws win
    np.testing.assert_allclose(tm, np.tile([0.1, 0.0, -0.05], (P, 1)), atol=1e-12)


def test_evaluate_cli_prints_the_paper_table_then_medians_and_flip_rates(laptop_data, tmp_path, capsys):
    from scapo.cli.main import main

    path = ground_truth_predictions(laptop_data).save(tmp_path / "gt.npz")
    assert main(["evaluate", "--data", str(laptop_data), "--pred", str(path), "--protocol", "op-align",
                 "--out", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert out.index("| **S** ↑ | gt |") < out.index("## Medians and rates") < out.index("R>90 (%)")
    assert "Protocol: op-align" in out
    md = (tmp_path / "t" / "table1.md").read_text()
    assert "protocol: op-align" in md and "## Medians and rates" in md


@pytest.fixture
def toy_protocol():
    """A protocol defined outside the package: a new pivot rule (a function) and a new entry naming it."""
    from scapo.eval.protocols import PIVOT_DISTANCES, Protocol, register_protocol

    @PIVOT_DISTANCES.register("pivot-point-distance")
    def pivot_point_distance(case):  # the distance between the two pivot points, ignoring the axes
        return np.linalg.norm(case.pivot - case.gt_pivot, axis=-1)

    register_protocol(Protocol("toy", pivot="pivot-point-distance", fold_rotation=True))
    yield "toy"
    PROTOCOLS.remove("toy")
    PIVOT_DISTANCES.remove("pivot-point-distance")


def test_a_protocol_defined_outside_the_package_scores_through_the_cli(toy_protocol, laptop_data, tmp_path, capsys):
    from scapo.cli.main import main

    def edit(arr, _):  # every pivot moved 5 cm along its own axis: the same line, another point
        arr["joint_pivot"] = arr["joint_pivot"] + 0.05 * arr["joint_axis"]

    preds = ground_truth_predictions(laptop_data, edit=edit)
    preds.save(tmp_path / "p.npz")
    toy = evaluate(laptop_data, tmp_path / "p.npz", protocol="toy")
    scapo = evaluate(laptop_data, tmp_path / "p.npz", protocol="scapo")
    assert toy.summary["C_cm"] == pytest.approx(5.0) and scapo.summary["C_cm"] == pytest.approx(0.0, abs=1e-6)
    assert toy.info["protocol"] == "toy"
    assert main(["evaluate", "--data", str(laptop_data), "--pred", str(tmp_path / "p.npz"), "--protocol", "toy"]) == 0
    assert "toy" in capsys.readouterr().out
