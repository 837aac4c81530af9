"""The frame-consistency measure (:mod:`scapo.eval.frames`): hand-built offsets, and the evaluator's summary."""

from __future__ import annotations

import numpy as np
import pytest

from scapo.data import load
from scapo.eval import Predictions, evaluate
from scapo.eval.frames import frame_consistency, split_consistency
from scapo.ops.groups import random_rotation as _random_rotation


def random_rotation(n: int, seed: int):
    import torch

    return _random_rotation(n, generator=torch.Generator().manual_seed(seed))


def test_frame_consistency_on_hand_built_offsets():
    M = 40
    gt = np.tile(np.eye(4), (M, 1, 1))
    gt[:, :3, :3] = random_rotation(M, seed=1).numpy()
    offset = random_rotation(1, seed=2).numpy()[0]
    pred = gt.copy()
    pred[:, :3, :3] = gt[:, :3, :3] @ offset.T  # one canonical frame: R_pred^T R_gt = offset for every sample
    assert frame_consistency(pred, gt) == 1.0
    bad = pred.copy()
    bad[:10, :3, :3] = random_rotation(10, seed=3).numpy()  # a quarter in frames of their own
    assert frame_consistency(bad, gt) == pytest.approx(0.75, abs=0.03)
    scattered = pred.copy()
    scattered[:, :3, :3] = random_rotation(M, seed=4).numpy()
    assert frame_consistency(scattered, gt) < 0.2
    # a second valid ground truth per sample (a symmetric category's twin, its own rotation per sample): the samples
    # predicted in their twin's frame agree only when the twins are given
    twin_gt = gt.copy()
    twin_gt[:, :3, :3] = random_rotation(M, seed=5).numpy()
    mixed = pred.copy()
    mixed[::2, :3, :3] = twin_gt[::2, :3, :3] @ offset.T
    assert frame_consistency(mixed, gt) == pytest.approx(0.5, abs=0.03)
    assert frame_consistency(mixed, np.stack([gt, twin_gt], 1)) == 1.0
    big = np.tile(np.eye(4), (240, 1, 1))  # a table's test split: every offset of both ground truths is tried
    big[:, :3, :3] = random_rotation(240, seed=6).numpy()
    near = big.copy()
    near[:, :3, :3] = random_rotation(240, seed=7).numpy()
    assert frame_consistency(near, np.stack([big, near], 1)) == 1.0 >= frame_consistency(near, big)
    with pytest.raises(ValueError):
        frame_consistency(pred[:, :3], gt[:, :3])
    with pytest.raises(ValueError):
        frame_consistency(pred, np.stack([gt, twin_gt], 1)[:-1])
    assert np.isnan(frame_consistency(np.zeros((0, 4, 4)), np.zeros((0, 4, 4))))




def _oracle(data, split: str, T_cam_obj: np.ndarray) -> Predictions:
    ds = load(data, split)
    a = ds.arrays()
    return Predictions(method="frames", instance_id=a["instance_id"], view_id=a["view_id"],
                       split=np.full(len(ds), split), part_label=a["part_label"], part_pose=a["part_pose"],
                       joint_parts=a["joint_parts"], joint_type=a["joint_type"], joint_axis=a["joint_axis"],
                       joint_pivot=a["joint_pivot"], joint_state=a["joint_state"], T_cam_obj=T_cam_obj,
                       needs_alignment=False, dataset_hash=ds.dataset_hash)


def test_the_evaluator_scores_the_predicted_object_frame(laptop_data):
    # the ground-truth object frame turned by one fixed offset is one canonical frame (1.0); with every other
    # sample's frame turned a further 90 deg about x, half the samples agree
    T = load(laptop_data, "test").arrays(["T_cam_obj"])["T_cam_obj"].astype(np.float64)
    offset = random_rotation(1, seed=2).numpy()[0].astype(np.float64)
    one = T.copy()
    one[:, :3, :3] = T[:, :3, :3] @ offset.T
    res = evaluate(laptop_data, _oracle(laptop_data, "test", one))
    assert res.summary["frame_consistency"] == 1.0 == res.summary["frame_consistency_sym"]
    assert res.per_sample["frame_inlier"].all()
    quarter = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    two = one.copy()
    two[::2, :3, :3] = one[::2, :3, :3] @ quarter
    res = evaluate(laptop_data, _oracle(laptop_data, "test", two))
    share = max(len(T[::2]), len(T[1::2])) / len(T)
    assert res.summary["frame_consistency"] == pytest.approx(share)
    assert res.per_sample["frame_inlier"].sum() == round(share * len(T))
    # the same definition as the diagnoses' split_consistency
    assert split_consistency(laptop_data, _oracle(laptop_data, "test", two), "test")[0] == pytest.approx(share)
