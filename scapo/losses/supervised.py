"""Supervised terms for the semi-supervised setting of the paper's Table 2 ("SJ": trained with segmentation
and joint labels, as OP-Align (SJ) and SCAPO are there; Sec. 4, "Results on the Real-World Dataset").

The paper does not state the form of these terms, and OP-Align's public code trains without them (its
``Art_Metric.forward(mode="train")`` reads no labels), so we use the plain choices, shared by every method
that takes the option so that the rows compare like with like:

- segmentation (``S``): the negative log-likelihood of each labelled point's GT part under the method's
  per-point part probabilities, points labelled -1 (background) left out. Part slot k is trained to be GT
  part k, so the method's parts come out in the dataset's order.
- joints (``J``): per joint ``1 - |cos|`` between the predicted and GT directions (the sign is free, as in
  metric D) plus, for revolute joints, the distance from the predicted pivot to the GT axis line (in the
  method's normalised units, where the cloud's RMS radius is about 0.5), both in the camera frame.

A method's supervision option is a string of these letters: "" (self-supervised, the default), "S", "J" or
"SJ"; its predictions carry the marks (``Predictions.supervision``) and a label suffix (``-sj``), so a table
shows "SCAPO (SJ)" with its Segmentation and Joint marks beside the self-supervised row.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from scapo.errors import ConfigError

SUPERVISION_CHOICES = ("", "S", "J", "SJ")
#: Dataset fields a method reads in training for each supervision letter.
SUPERVISED_FIELDS = {"S": ("part_label",), "J": ("joint_axis", "joint_pivot")}


def check_supervision(value: str) -> str:
    """Validate a supervision option (``""``, ``"S"``, ``"J"``, ``"SJ"``; case-insensitive, any order).

    Raises:
        ConfigError: other letters.
    """
    v = "".join(sorted(set(str(value).upper()), key="SJ".index)) if set(str(value).upper()) <= set("SJ") else None
    if v is None:
        raise ConfigError(f"supervision must be one of {', '.join(repr(c) for c in SUPERVISION_CHOICES)} (S: "
                          f"segmentation labels, J: joint labels), got {value!r}")
    return v


def supervision_marks(value: str) -> dict:
    """The table marks of a self-supervised method trained with ``value``: pose never, S and J as given."""
    v = check_supervision(value)
    return {"pose": False, "segmentation": "S" in v, "joint": "J" in v}


def supervised_fields(value: str) -> tuple[str, ...]:
    """Extra dataset fields training with ``value`` reads (beyond ``points``)."""
    return tuple(f for c in check_supervision(value) for f in SUPERVISED_FIELDS[c])


def seg_nll(prob: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """Mean NLL of GT parts: ``prob (B, N, P)`` per-point part probabilities, ``labels (B, N)`` int (-1: none).

    Returns a scalar; 0 when no point is labelled."""
    keep = labels >= 0
    if not keep.any():
        return prob.sum() * 0.0
    p = prob.clamp_min(1e-6).log()
    return F.nll_loss(p[keep], labels[keep].long())


def joint_loss(axis: torch.Tensor, pivot: torch.Tensor, gt_axis: torch.Tensor, gt_pivot: torch.Tensor,
               joint_types) -> torch.Tensor:
    """Direction and (revolute) pivot-to-GT-line distance, averaged over joints and batch.

    Args:
        axis, pivot: ``(B, J, 3)`` predicted direction (any length) and pivot, camera frame, normalised units.
        gt_axis, gt_pivot: ``(B, J, 3)`` GT in the same frame and units. joint_types: ``(J,)`` 0 / 1.
    """
    a = F.normalize(axis, dim=-1)
    g = F.normalize(gt_axis, dim=-1)
    direction = 1.0 - (a * g).sum(-1).abs()
    d = pivot - gt_pivot
    off = d - (d * g).sum(-1, keepdim=True) * g
    revolute = torch.tensor([int(t) == 0 for t in joint_types], device=axis.device, dtype=axis.dtype)
    dist = (off.norm(dim=-1) * revolute).sum(-1) / revolute.sum().clamp_min(1.0)
    return direction.mean() + dist.mean()
