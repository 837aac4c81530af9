"""The realistic sensor model on synthetic depth images (no rendering): labels, ranges, the detector mask."""

import dataclasses

import numpy as np
import pytest

from scapo.errors import ConfigError
from scapo.sim.sensor import SENSORS, SensorConfig, apply_sensor


def _scene(h=64, w=64, z_obj=1.0, z_far=3.0):
    """A 20 x 20 pixel square object (part 0, left half; part 1, right half) at z_obj in front of a wall at
    z_far; a floor strip (z slightly behind the object) under it. Returns points, valid, part_map."""
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    z = np.full((h, w), z_far)
    part = np.full((h, w), -1, dtype=np.int64)
    obj = (u >= 22) & (u < 42) & (v >= 22) & (v < 42)
    z[obj] = z_obj
    part[obj & (u < 32)] = 0
    part[obj & (u >= 32)] = 1
    floor = (v >= 42) & (v < 50)
    z[floor] = z_obj + 0.02 * (v[floor] - 41)
    f = 64.0
    pts = np.stack([(u - w / 2) / f * z, (v - h / 2) / f * z, z], -1).astype(np.float32)
    return pts, np.ones((h, w), bool), part


def test_clean_sensor_returns_the_object_unchanged():
    pts, valid, part = _scene()
    out, keep, label = apply_sensor(pts, valid, part, SENSORS["clean"], np.random.default_rng(0))
    assert out is pts and (keep == (part >= 0)).all() and (label == part).all()


def test_realistic_sensor_labels_flying_pixels_background_and_crops_far_background():
    pts, valid, part = _scene()
    cfg = dataclasses.replace(SENSORS["realistic"], flying_prob=1.0, drop_prob=0.0, edge_drop_prob=0.0)
    out, keep, label = apply_sensor(pts, valid, part, cfg, np.random.default_rng(1))
    kept_z = out[..., 2][keep]
    # the wall 2 m behind is outside the depth crop: no kept point is far from the object
    assert kept_z.max() < 1.5
    # labelled points lie on their surface (z = 1 m) within 5 sigma of the sensor noise
    sigma = cfg.sigma_base + cfg.sigma_quad * (1.0 - 0.4) ** 2
    on_obj = keep & (label >= 0)
    assert np.abs(out[..., 2][on_obj] - 1.0).max() < 5 * sigma
    # object pixels on the silhouette became flying pixels: kept as background, never with a part label
    edge_obj = (part >= 0) & (label < 0)
    assert edge_obj.sum() > 0 and (np.abs(out[..., 2][edge_obj & keep] - 1.0) > 5 * sigma).any()
    # background enters only in a band of mask_dilation pixels around the silhouette (the floor strip)
    bg = keep & (part < 0)
    assert bg.any()
    vv, uu = np.nonzero(bg)
    assert uu.min() >= 22 - cfg.mask_dilation and uu.max() < 42 + cfg.mask_dilation and vv.max() < 42 + cfg.mask_dilation
    # the noise grows with depth (Nguyen et al. 2012)
    far = apply_sensor(pts * np.float32(3.0), valid, part, dataclasses.replace(cfg, flying_prob=0.0),
                       np.random.default_rng(2))
    near = apply_sensor(pts, valid, part, dataclasses.replace(cfg, flying_prob=0.0), np.random.default_rng(2))
    inner = np.zeros_like(valid)
    inner[25:39, 25:39] = True
    assert np.std(far[0][..., 2][inner] - 3.0) > 3 * np.std(near[0][..., 2][inner] - 1.0)


def test_flying_pixels_can_be_dropped_and_the_range_is_limited():
    pts, valid, part = _scene()
    cfg = dataclasses.replace(SENSORS["realistic"], flying_prob=1.0, flying="drop")
    out, keep, label = apply_sensor(pts, valid, part, cfg, np.random.default_rng(3))
    assert not (keep & (part >= 0) & (label < 0)).any()
    cfg = dataclasses.replace(SENSORS["realistic"], max_range=0.5)
    _, keep, _ = apply_sensor(pts, valid, part, cfg, np.random.default_rng(3))
    assert not keep.any()
    pts, valid, part = _scene(z_far=19.0)  # beyond the default 5 m range: no return, so no flying pixels either
    cfg = dataclasses.replace(SENSORS["realistic"], flying_prob=1.0, depth_margin=100.0)
    out, keep, label = apply_sensor(pts, valid, part, cfg, np.random.default_rng(4))
    assert out[..., 2][keep].max() < 1.5


@pytest.mark.parametrize("bad", [dict(flying="smear"), dict(drop_prob=1.5), dict(max_range=0.0),
                                 dict(mask_dilation=-1), dict(kind="lidar")])
def test_bad_sensor_parameters_are_refused(bad):
    with pytest.raises(ConfigError):
        SensorConfig(**{"kind": "realistic", **bad})


def test_measured_noise_matches_the_configured_model():
    """Nguyen et al. 2012: sigma(z) = sigma_base + sigma_quad (z - 0.4)^2; measured on a flat object at 1 m and 2.5 m."""
    h = w = 160
    cfg = dataclasses.replace(SENSORS["realistic"], flying_prob=0.0, drop_prob=0.0, edge_drop_prob=0.0)
    for z0 in (1.0, 2.5):
        u, v = np.meshgrid(np.arange(w), np.arange(h))
        pts = np.stack([(u - w / 2) / 100 * z0, (v - h / 2) / 100 * z0, np.full((h, w), z0)], -1).astype(np.float32)
        part = np.zeros((h, w), dtype=np.int64)
        out, keep, label = apply_sensor(pts, np.ones((h, w), bool), part, cfg, np.random.default_rng(5))
        inner = np.zeros((h, w), bool)
        inner[5:-5, 5:-5] = True
        measured = np.std(out[..., 2][inner & keep] - z0)
        expected = cfg.sigma_base + cfg.sigma_quad * (z0 - 0.4) ** 2
        assert measured == pytest.approx(expected, rel=0.05)
