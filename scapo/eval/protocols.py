"""Named evaluation protocols: the scoring rules of the SCAPO paper, OP-Align's and EAP's released code.

A published number can only be compared with ours under the protocol that produced it. Each protocol
is a frozen :class:`Protocol`; :func:`get_protocol` looks one up by name (an unknown name lists the
known ones). The evaluator (:mod:`scapo.eval.evaluator`) applies one protocol to every method, and
every table records its name.

``scapo`` (default) follows SPEC section 8 and the SCAPO paper's text (Sec. 4): per-sample Hungarian
part matching on point IoU; canonical-frame offsets per part from training-split predictions (RANSAC
over per-sample offsets at 15 deg, chordal mean of the inliers' rotations, median translation);
geodesic rotation error; translation and pivot errors in bounding-box diagonals; the pivot as the
distance between the predicted and the GT axis lines, revolute joints only; Table 2 AP as the mean
over parts / joints ("mean mAP").

``op-align`` follows YC-Che/OP-Align, SPConvNets/models/art_metric.py (``standardization_order``,
``standardization_ransac``, ``evaluation_joint``, ``evaluation_pose``) and
SPConvNets/trainer_art.py (``val``), with SPConvNets/datasets/LightDataset.py (``__getitem__``):
two fixed part orders ([0,1],[1,0] for two parts; [0,1,2],[0,2,1] for three) chosen per sample by
point accuracy; every cloud scaled so that its mean distance to its centroid is 0.25, and
translation and pivot errors reported in those units; canonical-frame offsets by RANSAC (100
iterations, means of 5 random training samples, a rotation inlier within 10 deg, a translation
inlier within 0.25 units, rotation and translation chosen separately by inlier count); the pivot as
the distance from the predicted pivot point to the GT axis line, for every joint, prismatic ones
included; AP also as "min mAP" (a sample counts only if all its parts / joints pass; 5 and 10 deg);
points whose GT label is background (-1, real-world-style data) left out of the segmentation IoU, as
art_metric.py ``evaluation_segmentation`` does for real scans (``noise_exist``, set by trainer_art.py
``_setup_metric`` for ``dataset_type == 'Real'``); the part order is likewise chosen on object points only.
The other protocols count such points as false positives of the part they are predicted as.
When the swapped order wins on a symmetric category, that code multiplies the GT rotations by a fixed
half turn of its datasets' canonical frames (``standardization_order``); here the category's own symmetry
(the dataset card's, :mod:`scapo.sim.assets.symmetry`) gives the whole other ground truth (parts, poses
and joints exchanged), and categories without one (its laptop, suitcase and scissors matrices concern its
scans' frames; our procedural ones are not symmetric) get none. What differs from that code: the
AP distance thresholds are centimetres (5 / 10 cm), where its code compares 0.5 / 1.0 in its
dataset units; its typo that scores three-part "10 deg" AP with 5 deg is not reproduced; the
rotation mean is the chordal L2 mean (scipy), where it uses its own ``so3_mean``; on real scans its code
(SPConvNets/datasets/RealDataset.py) scales clouds, background included, to a mean centroid distance of
0.5 and reports t and pivot errors back in the scan's units, where the reported t and C here stay in the
0.25 units of the object points (the AP columns, in cm, do not depend on the unit).

``eap`` follows Meowuu7/equi-articulated-pose, SPConvNets/trainer_unsup_arti_align.py (the rotation
error folded to ``min(theta, 180 - theta)``; the pivot as the absolute difference of the centroid's
distances to the predicted and GT axes, none for prismatic joints) and
SPConvNets/datasets/MotionDataset.py (``part_pv_offset``: the distance of the centred cloud's origin
to the axis, in units of the bounding-box diagonal). What differs: part matching and the
canonical-frame alignment are the ``scapo`` ones (its code compares inside its own model's canonical
frame, which other methods do not have).
"""

from __future__ import annotations

from dataclasses import dataclass

from scapo.errors import PredictionError


@dataclass(frozen=True)
class Protocol:
    """How predictions are matched, aligned and scored (see the module docstring for the sources)."""

    name: str
    """Name used by ``--protocol`` and recorded in every table."""
    matching: str = "hungarian"
    """"hungarian" (per sample, max point IoU), "hungarian-category" (one assignment per category) or
    "fixed-orders" (OP-Align's two part orders chosen by point accuracy)."""
    alignment: str = "ransac-offsets"
    """Canonical-frame estimator: "ransac-offsets" (RANSAC over per-sample offsets, chordal mean of
    the inliers, median translation; metres) or "ransac-sample-means" (OP-Align's means of random
    training samples; in the protocol's units)."""
    alignment_deg: float = 15.0
    """Rotation inlier threshold of the alignment (degrees)."""
    alignment_t: float = 0.25
    """Translation inlier threshold of "ransac-sample-means" (the protocol's units)."""
    pivot: str = "line-line"
    """"line-line" (distance between the axis lines), "point-line" (predicted pivot point to the GT
    axis line) or "origin-offset" (difference of the centroid's distances to the two axes)."""
    pivot_prismatic: bool = False
    """Whether prismatic joints get a pivot score (else C is not applicable for them)."""
    fold_rotation: bool = False
    """Report part rotation errors as ``min(theta, 180 - theta)``."""
    units: str = "bbox-diag"
    """Unit of the reported t and C: "bbox-diag" (rest bounding-box diagonal) or "centroid-0.25"
    (each cloud scaled to a mean centroid distance of 0.25, as OP-Align)."""
    min_ap: bool = False
    """Also report OP-Align's "min mAP" (all parts / joints of a sample must pass)."""
    symmetric_gt: bool = False
    """For a dataset of a symmetric category (its card's ``symmetry``, :mod:`scapo.sim.assets.symmetry`): score a
    sample whose matched part order is the symmetry's against the other valid ground truth (the twin)."""
    seg_background: str = "false-positive"
    """Points whose GT label is -1 (background, flying pixels: real-world-style data only) in the
    segmentation IoU: "false-positive" (counted against the part they are predicted as) or "ignored"
    (left out, as OP-Align's code scores real scans)."""

    def __post_init__(self):
        allowed = {"matching": ("hungarian", "hungarian-category", "fixed-orders"),
                   "alignment": ("ransac-offsets", "ransac-sample-means"),
                   "pivot": ("line-line", "point-line", "origin-offset"), "units": ("bbox-diag", "centroid-0.25"),
                   "seg_background": ("false-positive", "ignored")}
        for k, values in allowed.items():
            if getattr(self, k) not in values:
                raise ValueError(f"protocol {self.name!r}: {k} must be one of {values}, got {getattr(self, k)!r}")


PROTOCOLS: dict[str, Protocol] = {
    "scapo": Protocol("scapo"),
    "scapo-per-category": Protocol("scapo-per-category", matching="hungarian-category"),
    "op-align": Protocol("op-align", matching="fixed-orders", alignment="ransac-sample-means", alignment_deg=10.0,
                         alignment_t=0.25, pivot="point-line", pivot_prismatic=True, units="centroid-0.25",
                         min_ap=True, seg_background="ignored", symmetric_gt=True),
    "eap": Protocol("eap", pivot="origin-offset", fold_rotation=True),
}
#: Names of earlier versions, kept so that old commands and provenance still resolve.
ALIASES = {"per-sample": "scapo", "per-category": "scapo-per-category"}


def get_protocol(name: str | Protocol) -> Protocol:
    """The protocol called ``name`` (or an alias of it).

    Raises:
        PredictionError: an unknown name (the message lists the known ones).
    """
    if isinstance(name, Protocol):
        return name
    key = ALIASES.get(name, name)
    if key not in PROTOCOLS:
        raise PredictionError(f"unknown protocol {name!r}; known protocols: {', '.join(PROTOCOLS)}")
    return PROTOCOLS[key]


def fixed_orders(num_parts: int) -> tuple[tuple[int, ...], ...]:
    """OP-Align's candidate part orders for ``num_parts`` parts (art_metric.py ``standardization_order``).

    Raises:
        PredictionError: for other than 2 or 3 parts (OP-Align defines none).
    """
    if num_parts == 2:
        return ((0, 1), (1, 0))
    if num_parts == 3:
        return ((0, 1, 2), (0, 2, 1))
    raise PredictionError(f"the op-align protocol defines part orders for 2 and 3 parts, not {num_parts}")
