"""Symmetric categories: objects that a rotation maps onto themselves with some parts exchanged.

A procedural basket is such an object: turned by 180 deg about its vertical axis it is the same basket,
with ``handle_a`` where ``handle_b`` was (both handles have the same shape, joint axis and limits). Its
part labels are then not a property of what a camera sees: one view has two equally valid ground
truths, the asset's and its *twin* (the same observation with the exchanged parts and the object frame
turned by the symmetry). A supervised method trained on the asset's labels is asked to guess which
handle the generator called ``handle_a`` (it cannot; on the realistic basket the NPCS-style reference
fell to 0 % Part 10/10), and a method whose part order is the twin's is scored against the wrong poses.

Two remedies, both used by OP-Align for its symmetric real categories, are provided:

- Labels by view (generation, ``RenderConfig.symmetric_labels = "view"``): of the two ground truths
  the one whose ``front`` side faces the camera is kept (for the basket: ``handle_a`` is the handle on
  the camera's side), as pose datasets restrict the pose range of symmetric objects so that the label
  is a function of the image (Rad and Lepetit, "BB8", ICCV 2017, Sec. 3.3).
- Twin ground truth in scoring (the ``op-align`` protocol): when a sample's part order is the
  symmetry's, the twin is scored instead (YC-Che/OP-Align, SPConvNets/models/art_metric.py
  ``standardization_order``, which multiplies the GT rotations of its basket, laptop, suitcase and
  scissors scans by a fixed 180 deg rotation when the swapped order wins).

The symmetry is given in the object frame of the procedural assets (origin at the centre of the
rest-state bounding box, which a symmetry maps onto itself), so it is a rotation only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scapo.errors import ConfigError


@dataclass(frozen=True)
class Symmetry:
    """A proper rotation of the object frame that maps the object onto itself, exchanging parts.

    Attributes:
        parts: (P,) the part each part becomes (``parts[p]`` is the twin label of asset part p).
        joints: (J,) the joint each joint becomes, likewise.
        rotation: (3, 3) the rotation in the object frame (rest state; origin at the bbox centre).
        front: (3,) object-frame direction: of the two ground truths of a view, labels by view keep the one
            whose camera lies farther along ``front``.
    """

    parts: tuple[int, ...]
    joints: tuple[int, ...]
    rotation: tuple[tuple[float, ...], ...]
    front: tuple[float, float, float]

    def __post_init__(self):
        R = np.asarray(self.rotation, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ConfigError(f"a symmetry's rotation must be a proper 3x3 rotation, got {self.rotation}")
        for name, perm in (("parts", self.parts), ("joints", self.joints)):
            if sorted(perm) != list(range(len(perm))):
                raise ConfigError(f"a symmetry's {name} must be a permutation of 0..{len(perm) - 1}, got {perm}")

    def to_dict(self) -> dict:
        """JSON form (the dataset card's ``symmetry``)."""
        return {"parts": list(self.parts), "joints": list(self.joints),
                "rotation": np.asarray(self.rotation, dtype=np.float64).tolist(), "front": list(self.front)}

    @classmethod
    def from_dict(cls, d: dict) -> Symmetry:
        """Inverse of :meth:`to_dict`.

        Raises:
            ConfigError: missing or malformed entries.
        """
        try:
            return cls(tuple(int(p) for p in d["parts"]), tuple(int(j) for j in d["joints"]),
                       tuple(tuple(float(x) for x in row) for row in d["rotation"]),
                       tuple(float(x) for x in d["front"]))
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"not a symmetry ({type(e).__name__}: {e}); expected parts, joints, rotation, "
                              "front") from None


_RZ_180 = ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0))

#: Symmetries of the procedural categories (categories not named here have none). basket: body symmetric under a
#: half turn about z; handle_a (pivot on -x, axis +y) and handle_b (pivot on +x, axis -y) exchange, with equal
#: limits (scapo/sim/assets/categories.py ``basket``, sim_assets/templates/basket.json).
SYMMETRIES: dict[str, Symmetry] = {
    "basket": Symmetry(parts=(0, 2, 1), joints=(1, 0), rotation=_RZ_180, front=(-1.0, 0.0, 0.0)),
}


def twin(gt: dict, sym: Symmetry) -> dict:
    """The other ground truth of the same observation: parts and joints exchanged, the object frame turned.

    Args:
        gt: ground-truth arrays of one sample or of M samples (leading axis M): any of ``part_label (N,)``,
            ``npcs (N,3)``, ``part_pose (P,4,4)``, ``T_cam_obj (4,4)``, ``joint_axis (J,3)``,
            ``joint_pivot (J,3)``, ``joint_state (J,)``, ``joint_limit (J,2)``; other entries are copied as they
            are (``joint_type`` and ``joint_parts`` are the category's and the same for the twin).

    Returns:
        A new dict: labels ``p -> parts[p]``; twin part ``parts[p]`` posed ``part_pose[p] @ S^-1`` (S the
        symmetry as a 4x4 transform); ``T_cam_obj @ S^-1``; NPCS ``R_S npcs`` (rest object-frame coordinates);
        joint ``joints[j]`` takes joint j's camera-frame axis, pivot, state and limits (the same physical
        joint). Applying it twice returns the input when the symmetry is an involution (a half turn).
    """
    S_inv = np.eye(4)
    R = np.asarray(sym.rotation, dtype=np.float64)
    S_inv[:3, :3] = R.T
    parts, joints = np.asarray(sym.parts), np.asarray(sym.joints)
    inv_parts, inv_joints = np.argsort(parts), np.argsort(joints)  # twin index -> asset index
    out = dict(gt)
    if "part_label" in gt:
        lab = np.asarray(gt["part_label"])
        out["part_label"] = np.where(lab >= 0, parts[np.clip(lab, 0, None)], lab).astype(lab.dtype)
    if "npcs" in gt:
        npcs = np.asarray(gt["npcs"])
        out["npcs"] = np.einsum("ij,...j->...i", R, npcs.astype(np.float64)).astype(npcs.dtype)
    if "part_pose" in gt:
        out["part_pose"] = np.asarray(gt["part_pose"])[..., inv_parts, :, :] @ S_inv
    if "T_cam_obj" in gt:
        out["T_cam_obj"] = np.asarray(gt["T_cam_obj"]) @ S_inv
    for k in ("joint_axis", "joint_pivot", "joint_limit"):
        if k in gt:
            out[k] = np.asarray(gt[k])[..., inv_joints, :].copy()
    if "joint_state" in gt:
        out["joint_state"] = np.asarray(gt["joint_state"])[..., inv_joints].copy()
    return out


def by_view(sample: dict, sym: Symmetry) -> dict:
    """Labels by view: ``sample`` or its :func:`twin`, whichever has its camera farther along ``front``
    (object frame; the asset's labels on a tie).

    Args:
        sample: one sample's ground truth with ``T_cam_obj (4,4)`` (see :func:`twin` for the other fields).
    """
    front = np.asarray(sym.front, dtype=np.float64)
    cam = np.linalg.inv(np.asarray(sample["T_cam_obj"], dtype=np.float64))[:3, 3]  # camera in the object frame
    cam_twin = np.asarray(sym.rotation, dtype=np.float64) @ cam
    return twin(sample, sym) if front @ cam_twin > front @ cam + 1e-12 else sample
