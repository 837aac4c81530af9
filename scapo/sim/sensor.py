"""Depth-sensor models applied to rendered pictures before back-projection.

``clean`` keeps SAPIEN's exact positions of the object's pixels. ``realistic`` imitates a consumer
structured-light / time-of-flight RGB-D camera followed by the usual instance-segmentation front end
of real-data pipelines (a 2-D detector mask, then a depth crop around the object), for
real-world-style data (SPEC section 5). In order:

1. Range: pixels farther than ``max_range`` return no depth (consumer sensors: Kinect v1 about
   0.5-4 m, Khoshelham and Oude Elberink, "Accuracy and resolution of Kinect depth data", Sensors
   2012).
2. Axial noise along the camera ray, standard deviation ``sigma_base + sigma_quad * (z - 0.4)^2``
   (m), the fit of Nguyen, Izadi and Lovell, "Modeling Kinect sensor noise for improved 3D
   reconstruction and tracking", 3DIMPVT 2012 (Eq. 6: 0.0012 + 0.0019 (z - 0.4)^2). Lateral noise is
   not modelled (sub-pixel for these distances in that paper).
3. Flying pixels at depth discontinuities: the depth of an edge pixel is mixed with the farther
   neighbour's, so the point floats between the two surfaces. Such a point lies on no surface; it is
   labelled background (-1) or dropped (``flying``), never given a part label.
4. Dropped pixels: at random and, more often, on depth edges (missing returns at silhouettes).
5. Detector-style mask: the object's silhouette grown by ``mask_dilation`` pixels (a detector's mask
   is a little too large), and inside that band only pixels whose depth lies within the visible
   object's depth range widened by ``depth_margin`` times the visible object's extent (the depth crop
   real pipelines apply after the mask). Background therefore enters only near the object: the
   support plane around its foot, flying pixels at its edges; never the far floor behind it.
6. Optional support plane under the object (``ground``); without it the band holds only flying pixels.

A point's label is what its pixel hits: the part for object pixels (with noise), -1 for background
and flying pixels. Noise moves a point along its camera ray, so no intrinsics are needed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scapo.errors import ConfigError

FLYING = ("background", "drop")


@dataclass(frozen=True)
class SensorConfig:
    """Parameters of the realistic sensor model (ignored for ``kind == "clean"``)."""

    kind: str = "clean"
    """"clean" (exact positions, object points only) or "realistic"."""
    sigma_base: float = 0.0012
    """Axial noise at 0.4 m (m); Nguyen et al. 2012."""
    sigma_quad: float = 0.0019
    """Quadratic growth of the axial noise with distance (m / m^2); Nguyen et al. 2012."""
    flying_prob: float = 0.3
    """Probability that a pixel on a depth edge becomes a flying pixel."""
    edge_threshold: float = 0.02
    """Depth jump between 4-neighbours that marks a depth edge (m)."""
    drop_prob: float = 0.02
    """Probability that any pixel returns no depth."""
    edge_drop_prob: float = 0.2
    """Extra drop probability on depth edges."""
    mask_dilation: int = 2
    """Pixels by which the detector mask grows beyond the object's silhouette."""
    max_range: float = 5.0
    """Farthest depth the sensor returns (m)."""
    depth_margin: float = 0.1
    """Depth crop: background pixels of the mask are kept within the visible object's depth range widened by
    this fraction of the visible object's extent (its axis-aligned box diagonal, camera frame) on each side."""
    flying: str = "background"
    """What a flying pixel becomes: "background" (kept, label -1) or "drop"."""
    ground: bool = True
    """Render a support plane under the object (not with random SO(3) views, where "under" is undefined)."""

    def __post_init__(self):
        if self.kind not in ("clean", "realistic"):
            raise ConfigError(f"sensor kind must be 'clean' or 'realistic', got {self.kind!r}")
        if self.flying not in FLYING:
            raise ConfigError(f"sensor flying must be one of {FLYING}, got {self.flying!r}")
        for name in ("sigma_base", "sigma_quad", "edge_threshold", "depth_margin"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"sensor {name} must be >= 0, got {getattr(self, name)}")
        for name in ("flying_prob", "drop_prob", "edge_drop_prob"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"sensor {name} must be a probability in [0, 1], got {getattr(self, name)}")
        if self.mask_dilation < 0 or not self.max_range > 0:
            raise ConfigError(f"sensor mask_dilation must be >= 0 and max_range > 0, got {self.mask_dilation} and "
                              f"{self.max_range}")


SENSORS = {"clean": SensorConfig("clean"), "realistic": SensorConfig("realistic")}


def apply_sensor(
    points_cam: np.ndarray, valid: np.ndarray, part_map: np.ndarray, cfg: SensorConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corrupt an organised point image and choose the pixels that become the observation.

    Args:
        points_cam: (H, W, 3) float32 camera-frame (OpenCV) positions, metres.
        valid: (H, W) bool, pixels that hit any surface (object or background).
        part_map: (H, W) int64 part index of each pixel, -1 where no object part is hit.
        cfg: sensor parameters. rng: random generator (its draws depend only on the picture's size).

    Returns:
        ``points (H, W, 3) float32`` corrupted positions, ``keep (H, W) bool`` the pixels in the
        observation, ``label (H, W) int64`` each kept pixel's label: its part for object pixels, -1 for
        background and flying pixels. For ``clean``: the input, the object pixels and ``part_map``.
    """
    object_mask = part_map >= 0
    if cfg.kind == "clean":
        return points_cam, object_mask, part_map
    z = points_cam[..., 2].astype(np.float64)
    valid = valid & (z <= cfg.max_range)
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
    # flying pixels: depth mixed towards the farthest neighbour that returned depth
    far = np.where(np.isfinite(neigh), neigh, -np.inf).max(0)
    flying = edge & np.isfinite(far) & (far - z > cfg.edge_threshold) & (rng.random(z.shape) < cfg.flying_prob)
    u = rng.random(z.shape)
    z_new = np.where(flying, z + u * (far - z), z_new)
    scale = np.where(valid & (z > 1e-6), z_new / np.maximum(z, 1e-6), 1.0)
    noisy = (points_cam * scale[..., None]).astype(np.float32)
    drop = rng.random(z.shape) < cfg.drop_prob
    drop |= edge & (rng.random(z.shape) < cfg.edge_drop_prob)
    label = np.where(object_mask & ~flying, part_map, -1).astype(np.int64)
    surface_obj = object_mask & valid & ~flying
    band = ndimage.binary_dilation(object_mask, iterations=cfg.mask_dilation) if cfg.mask_dilation > 0 else object_mask
    keep = band & valid & ~drop
    if cfg.flying == "drop":
        keep &= ~flying
    # depth crop around the visible object: background (and flying pixels) only near it
    obj_pts = noisy[surface_obj & keep]
    if len(obj_pts):
        extent = float(np.linalg.norm(obj_pts.max(0) - obj_pts.min(0)))
        z_lo = float(obj_pts[:, 2].min()) - cfg.depth_margin * extent
        z_hi = float(obj_pts[:, 2].max()) + cfg.depth_margin * extent
        zn = noisy[..., 2]
        keep &= (label >= 0) | ((zn >= z_lo) & (zn <= z_hi))
    else:
        keep &= label >= 0
    return noisy, keep, label
