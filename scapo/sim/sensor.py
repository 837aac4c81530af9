"""Depth-sensor models applied to rendered pictures before back-projection.

``clean`` keeps SAPIEN's exact positions. ``realistic`` imitates a consumer RGB-D camera and an
imperfect instance mask, for real-world-style data (SPEC section 5):

- axial depth noise with standard deviation ``sigma_base + sigma_quad * (z - 0.4)^2`` (m), the
  model of Nguyen, Izadi and Lovell, "Modeling Kinect sensor noise", 3DIMPVT 2012;
- flying pixels at depth discontinuities (depth interpolated towards the neighbour);
- dropped pixels (random and at depth edges);
- a dilated object mask that lets nearby background (support plane) points in, labelled -1.

Noise moves a point along its camera ray, so no intrinsics are needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scapo.errors import ConfigError


@dataclass(frozen=True)
class SensorConfig:
    """Parameters of the realistic sensor model (ignored for ``kind == "clean"``)."""

    kind: str = "clean"
    """"clean" (exact positions, object points only) or "realistic"."""
    sigma_base: float = 0.0012
    """Axial noise at 0.4 m (m)."""
    sigma_quad: float = 0.0019
    """Quadratic growth of the axial noise with distance (m / m^2)."""
    flying_prob: float = 0.3
    """Probability that a pixel on a depth edge becomes a flying pixel."""
    edge_threshold: float = 0.02
    """Depth jump between neighbours that marks an edge (m)."""
    drop_prob: float = 0.02
    """Probability that any pixel returns no depth."""
    edge_drop_prob: float = 0.2
    """Extra drop probability on depth edges."""
    mask_dilation: int = 2
    """Pixels by which the object mask grows into the background."""

    def __post_init__(self):
        if self.kind not in ("clean", "realistic"):
            raise ConfigError(f"sensor kind must be 'clean' or 'realistic', got {self.kind!r}")


SENSORS = {"clean": SensorConfig("clean"), "realistic": SensorConfig("realistic")}


def apply_sensor(
    points_cam: np.ndarray, valid: np.ndarray, object_mask: np.ndarray, cfg: SensorConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Corrupt an organised point image and choose the pixels that become the observation.

    Args:
        points_cam: (H, W, 3) float32 camera-frame (OpenCV) positions, metres.
        valid: (H, W) bool, pixels that hit any surface (object or background).
        object_mask: (H, W) bool, pixels on the object.
        cfg: sensor parameters. rng: random generator.

    Returns:
        (points (H, W, 3) float32 corrupted positions, keep (H, W) bool pixels in the observation).
        For ``clean`` this is the input and ``object_mask``.
    """
    if cfg.kind == "clean":
        return points_cam, object_mask
    z = points_cam[..., 2].astype(np.float64)
    zf = np.where(valid, z, np.inf)
    # depth edges: any 4-neighbour with a jump above the threshold (or no return at all)
    pad = np.pad(zf, 1, constant_values=np.inf)
    neigh = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    with np.errstate(invalid="ignore"):  # inf - inf between two pixels without depth: no edge there
        jump = np.abs(neigh - zf[None])
    jump = np.where(np.isfinite(jump), jump, np.inf)
    edge = valid & (jump.max(0) > cfg.edge_threshold)
    sigma = cfg.sigma_base + cfg.sigma_quad * (z - 0.4) ** 2
    z_new = z + rng.normal(size=z.shape) * sigma
    # flying pixels: depth interpolated towards the farthest neighbour that returned depth
    far = np.where(np.isfinite(neigh), neigh, -np.inf).max(0)
    flying = edge & np.isfinite(far) & (far - z > cfg.edge_threshold) & (rng.random(z.shape) < cfg.flying_prob)
    if flying.any():
        u = rng.random(z.shape)
        z_new = np.where(flying, z + u * (far - z), z_new)
    scale = np.where(valid & (z > 1e-6), z_new / np.maximum(z, 1e-6), 1.0)
    noisy = (points_cam * scale[..., None]).astype(np.float32)
    keep = ndimage.binary_dilation(object_mask, iterations=cfg.mask_dilation) if cfg.mask_dilation > 0 else object_mask
    keep = keep & valid
    drop = rng.random(z.shape) < cfg.drop_prob
    drop |= edge & (rng.random(z.shape) < cfg.edge_drop_prob)
    return noisy, keep & ~drop
