"""The method-independent test-time refinement (scapo.steps.refine, issue 29): hand-built articulated models
with known poses, and its plumbing (options, labels, CLI, bench rows)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.errors import ConfigError, InputError
from scapo.methods import METHODS, describe
from scapo.steps.refine import TEST_TIME_REFINE, refine_prediction


def _T(R, t):
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    return M


def _box(rng, n, size, centre):
    return (rng.random((n, 3)) - 0.5) * np.asarray(size) + np.asarray(centre)


class Laptopish:
    """A base slab and a thinner, shorter lid on a revolute hinge along x (or a drawer on a prismatic joint
    along y); part frames are the canonical rest frame, so ``part_pose[1] = G @ joint(q)``."""

    def __init__(self, joint_type=0, seed=0):
        rng = np.random.default_rng(seed)
        self.jt = joint_type
        self.base = _box(rng, 300, (0.30, 0.30, 0.02), (0, 0, 0))
        if joint_type == 0:
            self.child = _box(rng, 200, (0.28, 0.20, 0.008), (0, 0.26, 0.02))
            self.axis, self.pivot = np.array([1.0, 0, 0]), np.array([0, 0.15, 0.02])
        else:
            self.child = _box(rng, 200, (0.24, 0.26, 0.05), (0.0, 0.0, 0.05))
            self.axis, self.pivot = np.array([0, 1.0, 0]), np.array([0, 0, 0.05])
        self.Y = np.concatenate([self.base, self.child])
        self.label = np.r_[np.zeros(300, int), np.ones(200, int)]

    def joint(self, q):
        if self.jt == 1:
            return _T(np.eye(3), self.axis * q)
        R = Rotation.from_rotvec(self.axis * q).as_matrix()
        return _T(R, self.pivot - R @ self.pivot)

    def poses(self, G, q):
        return np.stack([G, G @ self.joint(q)])

    def observe(self, G, q, n=400, seed=1):
        P = self.poses(G, q)
        pts = np.concatenate([self.base @ P[0, :3, :3].T + P[0, :3, 3], self.child @ P[1, :3, :3].T + P[1, :3, 3]])
        keep = np.random.default_rng(seed).permutation(len(pts))[:n]
        return pts[keep], self.label[keep]

    def prediction(self, G, q, n=400):
        P = self.poses(G, q)
        return {"part_pose": P[None], "T_cam_obj": P[0][None], "joint_axis": (G[:3, :3] @ self.axis)[None, None],
                "joint_pivot": (G[:3, :3] @ self.pivot + G[:3, 3])[None, None], "joint_state": np.array([[q]]),
                "part_label": np.zeros((1, n), int)}

    def refine(self, obs, pred, **kw):
        return refine_prediction(obs[None], pred, self.Y[None], self.label[None], [self.jt], [[0, 1]], **kw)


def _rot_err(A, B):
    return float(np.degrees(np.arccos(np.clip((np.trace(A[:3, :3].T @ B[:3, :3]) - 1) / 2, -1, 1))))


G_TRUE = _T(Rotation.from_euler("xyz", [30, -40, 70], degrees=True).as_matrix(), [0.05, -0.02, 1.0])


def test_refinement_undoes_a_small_pose_and_state_error_of_a_revolute_model():
    m = Laptopish(0)
    obs, lab = m.observe(G_TRUE, 1.2)
    G0 = G_TRUE @ _T(Rotation.from_rotvec([0.10, 0.05, -0.08]).as_matrix(), [0.01, 0, 0.01])
    pred = m.prediction(G0, 0.9)
    before = [_rot_err(pred["part_pose"][0, p], m.poses(G_TRUE, 1.2)[p]) for p in range(2)]
    out = m.refine(obs, pred)
    after = [_rot_err(out["part_pose"][0, p], m.poses(G_TRUE, 1.2)[p]) for p in range(2)]
    assert min(before) > 7 and max(after) < 2.5, (before, after)
    assert abs(out["joint_state"][0, 0] - 1.2) < 0.05
    assert (out["part_label"][0] == lab).mean() > 0.97
    assert out["refine_start"][0] == 0 and out["refine_residual"][0] < 0.2 * out["refine_residual_start"][0]
    # the joint moves with its parent part; T_cam_obj with the base part
    G1 = out["part_pose"][0, 0]
    assert np.allclose(out["T_cam_obj"][0], G1, atol=1e-9)
    assert np.allclose(out["joint_axis"][0, 0], G1[:3, :3] @ m.axis, atol=1e-6)
    assert np.allclose(out["joint_pivot"][0, 0], G1[:3, :3] @ m.pivot + G1[:3, 3], atol=1e-6)
    assert np.linalg.norm(out["joint_pivot"][0, 0] - (G_TRUE[:3, :3] @ m.pivot + G_TRUE[:3, 3])) < 0.01


def test_a_cube_rotation_start_replaces_a_prediction_90_degrees_off_and_a_correct_one_stays():
    m = Laptopish(0)
    obs, _ = m.observe(G_TRUE, 1.2)
    off = m.prediction(G_TRUE @ _T(Rotation.from_euler("z", 90, degrees=True).as_matrix(), np.zeros(3)), 1.2)
    out = m.refine(obs, off)
    assert out["refine_start"][0] > 0
    assert max(_rot_err(out["part_pose"][0, p], m.poses(G_TRUE, 1.2)[p]) for p in range(2)) < 4
    right = m.refine(obs, m.prediction(G_TRUE, 1.2))
    assert right["refine_start"][0] == 0
    assert max(_rot_err(right["part_pose"][0, p], m.poses(G_TRUE, 1.2)[p]) for p in range(2)) < 1.0
    # the one-pass start only: no search, the 90 degree error stays a local minimum
    local = m.refine(obs, off, config=TEST_TIME_REFINE.__class__(steps=20, lr=0.06, starts="network"))
    assert _rot_err(local["part_pose"][0, 0], m.poses(G_TRUE, 1.2)[0]) > 45


def test_refinement_fits_a_prismatic_state_in_metres():
    m = Laptopish(1)
    obs, _ = m.observe(G_TRUE, 0.12)
    out = m.refine(obs, m.prediction(G_TRUE, 0.07))
    assert abs(out["joint_state"][0, 0] - 0.12) < 0.01
    assert np.linalg.norm(out["part_pose"][0, 1, :3, 3] - m.poses(G_TRUE, 0.12)[1, :3, 3]) < 0.01


def test_refinement_refuses_bad_input_with_scapo_errors():
    m = Laptopish(0)
    obs, _ = m.observe(G_TRUE, 1.2)
    pred = m.prediction(G_TRUE, 1.2)
    with pytest.raises(InputError, match="scapo: refine: points"):
        refine_prediction(obs, pred, m.Y[None], m.label[None], [0], [[0, 1]])
    bad = obs.copy()
    bad[3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        m.refine(bad, pred)
    with pytest.raises(InputError, match="template_label must lie in"):
        refine_prediction(obs[None], pred, m.Y[None], (m.label + 1)[None], [0], [[0, 1]])
    with pytest.raises(InputError, match="joint_state"):
        refine_prediction(obs[None], {**pred, "joint_state": np.zeros((1, 2))}, m.Y[None], m.label[None], [0],
                          [[0, 1]])
    with pytest.raises(InputError, match="no point"):
        refine_prediction(obs[None], pred, np.zeros((1, 0, 3)), np.zeros((1, 0), int), [0], [[0, 1]])


def test_refinable_methods_labels_and_refusals(capsys):
    assert {m for m in METHODS.names() if METHODS.get(m).refinable} == {"scapo", "op-align", "eap"}
    assert describe("op-align+refine")[0] == "OP-Align-style + refine"
    assert describe("scapo+refine")[0] == "SCAPO (ours) + refine"
    with pytest.raises(ConfigError, match="replaces SCAPO's own"):
        METHODS.get("scapo").options(run="r", refine=True, refine_steps=5)
    from scapo.cli.main import main

    assert main(["predict", "--method", "icp", "--data", "d", "--out", "o.npz", "--refine"]) != 0
    err = capsys.readouterr().err
    assert "scapo predict: error: method 'icp' has no canonical shape" in err and "op-align, scapo" in err


def test_table1_gives_every_refinable_method_a_refine_row_from_its_one_pass_run():
    from scapo.bench.experiments import table1_cells

    cells = table1_cells(["icp", "npcs", "op-align", "scapo"], ["laptop"], "cpu", [0])
    refine = {c.label: c for c in cells if c.label.endswith("+refine")}
    assert set(refine) == {"op-align+refine", "scapo+refine"}
    assert dict(refine["scapo+refine"].options) == {"refine": True, "refine_steps": 0}
    assert dict(refine["op-align+refine"].options) == {"refine": True}
    assert all(c.run_key == c.key.replace("+refine", "") for c in refine.values())
    assert not table1_cells(["op-align"], ["laptop"], "cpu", [0], refine_rows=False)[-1].label.endswith("+refine")
