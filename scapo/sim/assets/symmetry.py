"""Symmetric categories: objects that a rigid map takes onto themselves with some parts exchanged.

Two procedural categories declare one (:data:`SYMMETRIES`; ``scapo assets symmetry`` measures every category and
checks the declarations, :mod:`scapo.data.symmetry_measure`): the basket (exactly) and the laptop, whose base and
lid a half turn about the hinge's bisector exchanges within what a 1024-point depth cloud resolves (the base is thicker
and deeper than the lid, as on real laptops, by less than the clouds' point spacing).

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
    """A proper rigid map of the object frame that maps the object onto itself, exchanging parts.

    Attributes:
        parts: (P,) the part each part becomes (``parts[p]`` is the twin label of asset part p).
        joints: (J,) the joint each joint becomes, likewise.
        rotation: (3, 3) the rotation in the object frame (rest state).
        front: (3,) object-frame direction: of the two ground truths of a view, labels by view keep the one
            whose camera lies farther along ``front``; None: labels stay the asset's (the parts differ on the
            mesh, and only a depth cloud leaves them open, as the laptop's base and lid).
        center: the point the rotation turns about: "origin" (the rest bbox centre) or "pivot:J" (the rest pivot
            of joint J, whose parent must be the base part; per instance, so one declaration serves a category).
        slack: the tolerance (rest bbox diagonals) within which the map must hold on the posed meshes
            (:func:`scapo.data.symmetry_measure.declared_symmetry_error`): 0.004 for exact symmetries; larger for one
            that holds only in a depth cloud, with its reason in ``note``.
        note: why the symmetry is declared (printed by ``scapo assets symmetry``).
    """

    parts: tuple[int, ...]
    joints: tuple[int, ...]
    rotation: tuple[tuple[float, ...], ...]
    front: tuple[float, float, float] | None
    center: str = "origin"
    slack: float = 0.004
    note: str = ""

    def __post_init__(self):
        R = np.asarray(self.rotation, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ConfigError(f"a symmetry's rotation must be a proper 3x3 rotation, got {self.rotation}")
        for name, perm in (("parts", self.parts), ("joints", self.joints)):
            if sorted(perm) != list(range(len(perm))):
                raise ConfigError(f"a symmetry's {name} must be a permutation of 0..{len(perm) - 1}, got {perm}")
        if self.center != "origin" and not (self.center.startswith("pivot:") and self.center[6:].isascii()
                                            and self.center[6:].isdigit()
                                            and int(self.center[6:]) < len(self.joints)):
            raise ConfigError(f"a symmetry's center must be 'origin' or 'pivot:J' with J a joint index, got "
                              f"{self.center!r}")
        if self.front is not None and self.center != "origin":
            raise ConfigError("labels by view (front) need a symmetry about the origin")
        if not self.slack >= 0:
            raise ConfigError(f"a symmetry's slack must be >= 0, got {self.slack}")

    @property
    def pivot_joint(self) -> int | None:
        """The joint whose pivot is the centre, or None (the origin)."""
        return None if self.center == "origin" else int(self.center[6:])

    def transform(self, center: np.ndarray | None = None) -> np.ndarray:
        """(..., 4, 4) the map in the object frame: the rotation about ``center (..., 3)`` (rest, object frame; the
        origin when None)."""
        R = np.asarray(self.rotation, dtype=np.float64)
        c = np.zeros(3) if center is None else np.asarray(center, dtype=np.float64)
        T = np.zeros(c.shape[:-1] + (4, 4))
        T[..., :3, :3] = R
        T[..., :3, 3] = c - np.einsum("ij,...j->...i", R, c)
        T[..., 3, 3] = 1.0
        return T

    def to_dict(self) -> dict:
        """JSON form (the dataset card's ``symmetry``); the fields added after the basket's keep their defaults'
        absence, so that the basket's card (and its dataset hash) are unchanged."""
        d = {"parts": list(self.parts), "joints": list(self.joints),
             "rotation": np.asarray(self.rotation, dtype=np.float64).tolist(),
             "front": None if self.front is None else list(self.front)}
        if self.center != "origin":
            d["center"] = self.center
        if self.slack != 0.004:
            d["slack"] = self.slack
        if self.note:
            d["note"] = self.note
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Symmetry:
        """Inverse of :meth:`to_dict`.

        Raises:
            ConfigError: missing or malformed entries.
        """
        try:
            front = d["front"]
            return cls(tuple(int(p) for p in d["parts"]), tuple(int(j) for j in d["joints"]),
                       tuple(tuple(float(x) for x in row) for row in d["rotation"]),
                       None if front is None else tuple(float(x) for x in front), str(d.get("center", "origin")),
                       float(d.get("slack", 0.004)), str(d.get("note", "")))
        except (KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"not a symmetry ({type(e).__name__}: {e}); expected parts, joints, rotation, "
                              "front") from None


_RZ_180 = ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0))
_S = 0.5 ** 0.5
#: half turn about (-1, 0, 1)/sqrt(2): the bisector of a laptop at rest (base towards -x, lid up +z)
_R_BISECT_XZ = ((0.0, 0.0, -1.0), (0.0, -1.0, 0.0), (-1.0, 0.0, 0.0))

#: Symmetries of the procedural categories (categories not named here have none), as measured by
#: ``scapo assets symmetry`` (results/symmetry/). basket: body symmetric under a half turn about z; handle_a (pivot on
#: -x, axis +y) and handle_b (pivot on +x, axis -y) exchange, with equal limits (scapo/sim/assets/categories.py
#: ``basket``). laptop: base and lid exchanged by the half turn about the bisector of the hinge at rest, as OP-Align's
#: evaluation forgives for its laptops (YC-Che/OP-Align, SPConvNets/models/art_metric.py ``standardization_order``).
SYMMETRIES: dict[str, Symmetry] = {
    "basket": Symmetry(parts=(0, 2, 1), joints=(1, 0), rotation=_RZ_180, front=(-1.0, 0.0, 0.0)),
    "laptop": Symmetry(
        parts=(1, 0), joints=(0,), rotation=_R_BISECT_XZ, front=None, center="pivot:0", slack=0.012,
        note="base and lid exchanged by the half turn about the hinge's bisector: the base is 1-2 cm thicker and "
             "5-22 % deeper than the lid is tall, below the spacing of a 1024-point depth cloud (about 1 cm), as "
             "on real laptops; labels stay the asset's (base = the thick part)"),
}


def _centers(gt: dict, sym: Symmetry) -> np.ndarray | None:
    """The symmetry's centre per sample (rest object frame), from the sample's own ground truth."""
    j = sym.pivot_joint
    if j is None:
        return None
    if "T_cam_obj" not in gt or "joint_pivot" not in gt:
        raise ConfigError("the twin of a symmetry about a joint's pivot needs T_cam_obj and joint_pivot")
    T = np.linalg.inv(np.asarray(gt["T_cam_obj"], dtype=np.float64))  # camera -> object (base part at rest)
    p = np.asarray(gt["joint_pivot"], dtype=np.float64)[..., j, :]
    return np.einsum("...ij,...j->...i", T[..., :3, :3], p) + T[..., :3, 3]


def twin(gt: dict, sym: Symmetry) -> dict:
    """The other ground truth of the same observation: parts and joints exchanged, the object frame turned.

    Args:
        gt: ground-truth arrays of one sample or of M samples (leading axis M): any of ``part_label (N,)``,
            ``npcs (N,3)``, ``part_pose (P,4,4)``, ``T_cam_obj (4,4)``, ``joint_axis (J,3)``,
            ``joint_pivot (J,3)``, ``joint_state (J,)``, ``joint_limit (J,2)``, ``bbox_diag ()``; other entries are
            copied as they are (``joint_type`` and ``joint_parts`` are the category's and the same for the twin).
            A symmetry about a joint's pivot needs ``T_cam_obj`` and ``joint_pivot`` (its centre, per sample), and
            ``bbox_diag`` to move ``npcs``.

    Returns:
        A new dict: labels ``p -> parts[p]``; twin part ``parts[p]`` posed ``part_pose[p] @ S^-1`` (S the
        symmetry as a 4x4 transform); ``T_cam_obj @ S^-1``, or the twin base's pose when the symmetry exchanges
        the base part (as the laptop's; ``part_pose`` is then needed); NPCS ``S npcs`` (rest object-frame
        coordinates, in bbox diagonals); joint ``joints[j]`` takes joint j's camera-frame axis, pivot, state and
        limits (the same physical joint). Applying it twice returns the input when the symmetry is an involution
        (a half turn).

    Raises:
        ConfigError: a symmetry about a pivot without the fields it needs.
    """
    S = sym.transform(_centers(gt, sym))
    S_inv = np.linalg.inv(S)
    parts, joints = np.asarray(sym.parts), np.asarray(sym.joints)
    inv_parts, inv_joints = np.argsort(parts), np.argsort(joints)  # twin index -> asset index
    out = dict(gt)
    if "part_label" in gt:
        lab = np.asarray(gt["part_label"])
        out["part_label"] = np.where(lab >= 0, parts[np.clip(lab, 0, None)], lab).astype(lab.dtype)
    if "npcs" in gt:
        npcs = np.asarray(gt["npcs"])
        moved = np.einsum("...ij,...nj->...ni", S[..., :3, :3], npcs.astype(np.float64))
        if np.any(S[..., :3, 3] != 0):
            if "bbox_diag" not in gt:
                raise ConfigError("the twin of npcs under a symmetry with a translation needs bbox_diag")
            moved = moved + S[..., None, :3, 3] / np.asarray(gt["bbox_diag"], dtype=np.float64)[..., None, None]
        out["npcs"] = moved.astype(npcs.dtype)
    if "part_pose" in gt:
        out["part_pose"] = np.asarray(gt["part_pose"])[..., inv_parts, :, :] @ S_inv[..., None, :, :]
    if "T_cam_obj" in gt:  # the object frame is the base part's (SPEC: part_pose[0] == T_cam_obj)
        out["T_cam_obj"] = (out["part_pose"][..., 0, :, :].copy() if "part_pose" in gt and parts[0] != 0
                            else np.asarray(gt["T_cam_obj"]) @ S_inv)
    for k in ("joint_axis", "joint_pivot", "joint_limit"):
        if k in gt:
            out[k] = np.asarray(gt[k])[..., inv_joints, :].copy()
    if "joint_state" in gt:
        out["joint_state"] = np.asarray(gt["joint_state"])[..., inv_joints].copy()
    return out


def by_view(sample: dict, sym: Symmetry) -> dict:
    """Labels by view: ``sample`` or its :func:`twin`, whichever has its camera farther along ``front``
    (object frame; the asset's labels on a tie; always the asset's for a symmetry without ``front``).

    Args:
        sample: one sample's ground truth with ``T_cam_obj (4,4)`` (see :func:`twin` for the other fields).
    """
    if sym.front is None:
        return sample
    front = np.asarray(sym.front, dtype=np.float64)
    cam = np.linalg.inv(np.asarray(sample["T_cam_obj"], dtype=np.float64))[:3, 3]  # camera in the object frame
    cam_twin = np.asarray(sym.rotation, dtype=np.float64) @ cam
    return twin(sample, sym) if front @ cam_twin > front @ cam + 1e-12 else sample
