"""Ground-truth self-consistency checks shared by the rendering tests."""

import numpy as np
import trimesh

from scapo.ops.rigid import invert_transform, joint_motion, transform_points
from scapo.sim.assets import load_part_mesh


def surface_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the closest triangle (brute force, no spatial index)."""
    tri = mesh.triangles
    out = np.empty(len(points))
    for k in range(0, len(points), 64):
        p = points[k:k + 64]
        cp = trimesh.triangles.closest_point(np.repeat(tri[None], len(p), 0).reshape(-1, 3, 3),
                                             np.repeat(p, len(tri), 0))
        out[k:k + 64] = np.linalg.norm(cp - np.repeat(p, len(tri), 0), axis=1).reshape(len(p), len(tri)).min(1)
    return out


def check_sample(sample: dict, spec, min_points: int, image_size=(256, 256), tol=1e-3, surface_points=64) -> None:
    """Assert the SPEC section 5 invariants of one rendered sample (clean sensor)."""
    pts = sample["points"].astype(np.float64)
    lab = sample["part_label"]
    pose = sample["part_pose"]
    diag = float(sample["bbox_diag"])
    P, J = spec.num_parts, spec.num_joints
    N = len(pts)
    assert pts.shape == (N, 3) and sample["npcs"].shape == (N, 3) and lab.shape == (N,)
    assert pose.shape == (P, 4, 4) and sample["joint_axis"].shape == (J, 3)
    assert np.isfinite(pts).all() and (lab >= 0).all()
    # every part keeps the minimum number of points
    assert np.bincount(lab, minlength=P).min() >= min_points
    # part 0 (base) pose is the object pose
    np.testing.assert_allclose(pose[0], sample["T_cam_obj"], atol=1e-9)
    # inverse(part_pose[p]) maps points to npcs * bbox_diag (within 1 mm)
    for p in range(P):
        rest = transform_points(invert_transform(pose[p]), pts[lab == p])
        np.testing.assert_allclose(rest, sample["npcs"][lab == p] * diag, atol=tol)
        # ... and those rest-state points lie on part p's mesh (within 1 mm)
        sel = rest[:: max(1, len(rest) // surface_points)]
        d = surface_distance(load_part_mesh(spec, p), sel)
        assert d.max() < tol, f"part {p}: rest-state points are {d.max() * 1000:.2f} mm off the part mesh"
    # joints: states within limits; child motion = rotation about / translation along the joint
    assert (sample["joint_state"] >= sample["joint_limit"][:, 0] - 1e-9).all()
    assert (sample["joint_state"] <= sample["joint_limit"][:, 1] + 1e-9).all()
    np.testing.assert_allclose(np.linalg.norm(sample["joint_axis"], axis=1), 1.0, atol=1e-9)
    for child in set(sample["joint_parts"][:, 1].tolist()):
        js = [j for j in range(J) if sample["joint_parts"][j, 1] == child]
        parent = sample["joint_parts"][js[0], 0]
        expected = np.eye(4)
        for j in js:  # several joints on one part (screw: prismatic + revolute) compose in URDF order
            expected = expected @ joint_motion(int(sample["joint_type"][j]), sample["joint_axis"][j],
                                               sample["joint_pivot"][j], float(sample["joint_state"][j]))
        got = pose[child] @ invert_transform(pose[parent])
        np.testing.assert_allclose(got, expected, atol=1e-6)
    # the simulator agrees with our own forward kinematics of the URDF
    fk = spec.link_poses(sample["joint_state"])
    for p in range(P):
        link = next(n for n, i in spec.part_of_link.items() if i == p)
        motion = fk[link] @ invert_transform(spec.rest_link_poses[link])
        np.testing.assert_allclose(pose[p], sample["T_cam_obj"] @ motion, atol=1e-5)
    # points are in front of the camera and project into the image
    uvw = pts @ sample["K"].T
    assert (pts[:, 2] > 0).all()
    uv = uvw[:, :2] / uvw[:, 2:]
    W, H = image_size
    assert (uv[:, 0] >= -0.5).all() and (uv[:, 0] <= W + 0.5).all()
    assert (uv[:, 1] >= -0.5).all() and (uv[:, 1] <= H + 0.5).all()
