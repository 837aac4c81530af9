"""Rendering: ground truth is self-consistent for every category; rejected views are counted."""

import dataclasses

import numpy as np
import pytest
from gt_checks import check_sample

from scapo.errors import RejectedViewError, RenderError
from scapo.ops.rigid import look_at
from scapo.sim.assets import build_instance, list_categories, load_template, parse_urdf
from scapo.sim.render import RenderConfig, ViewConfig, render_many, render_sample, render_with_retries

pytestmark = pytest.mark.render


@pytest.mark.parametrize("category", list_categories())
def test_ground_truth_is_self_consistent(category, renderer):
    cfg = RenderConfig()
    view = ViewConfig.from_template(load_template(category).view)
    jobs = []
    for inst in range(2):
        spec = parse_urdf(build_instance(category, inst, seed=11).urdf, category=category)
        jobs += [((inst, v), spec, (11, inst, v)) for v in range(3)]
    n = 0
    for (inst, v), sample, _ in render_many(renderer, jobs, cfg, view):
        spec = jobs[inst * 3 + v][1]
        check_sample(sample, spec, cfg.min_part_points)
        n += 1
    assert n == 6


def test_random_rotation_views_cover_so3(renderer):
    spec = parse_urdf(build_instance("laptop", 0, seed=0).urdf)
    view = dataclasses.replace(ViewConfig.from_template(load_template("laptop").view), viewpoints="sphere")
    cfg = dataclasses.replace(RenderConfig(), min_part_fraction=0.02)
    ups = []
    for v in range(8):
        s, _ = render_with_retries(renderer, spec, cfg, view, (5, v))
        check_sample(s, spec, cfg.min_part_points)
        ups.append(s["T_cam_obj"][:3, 2])  # object +z in the camera frame
    ups = np.array(ups)
    assert (ups[:, 1] > 0.3).any() and (ups[:, 1] < -0.3).any()  # seen upright and upside down


def test_camera_that_sees_nothing_is_a_rejected_view(renderer):
    spec = parse_urdf(build_instance("safe", 0, seed=0).urdf)
    away = look_at(np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, 5.0]), up=np.array([1.0, 0, 0]))
    with pytest.raises(RejectedViewError, match="too few object pixels"):
        render_sample(renderer, spec, RenderConfig(), ViewConfig(), np.random.default_rng(0), T_world_cam=away)
    # a view distribution that can never see enough: all attempts rejected -> clear error naming the object
    far = ViewConfig(distance=(200.0, 201.0))
    cfg = dataclasses.replace(RenderConfig(), max_attempts=3)
    with pytest.raises(RenderError, match="all 3 sampled views were rejected"):
        render_with_retries(renderer, spec, cfg, far, (0, 0))


def test_rejections_are_counted_and_retried(renderer):
    # a strict visibility threshold rejects some views; the sample still comes out, with its count
    spec = parse_urdf(build_instance("eyeglasses", 0, seed=0).urdf)
    cfg = dataclasses.replace(RenderConfig(), min_part_fraction=0.2, max_attempts=200)
    view = ViewConfig.from_template(load_template("eyeglasses").view)
    total = 0
    for v in range(4):
        s, reasons = render_with_retries(renderer, spec, cfg, view, (1, v))
        assert s["attempts"] == sum(reasons.values()) + 1
        total += sum(reasons.values())
    assert total > 0


def test_same_seed_same_sample(renderer):
    spec = parse_urdf(build_instance("drawer", 1, seed=0).urdf)
    view = ViewConfig.from_template(load_template("drawer").view)
    a, _ = render_with_retries(renderer, spec, RenderConfig(), view, (3, 4))
    b, _ = render_with_retries(renderer, spec, RenderConfig(), view, (3, 4))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_realistic_sensor_adds_noise_and_background(renderer):
    from scapo.sim.sensor import SENSORS

    spec = parse_urdf(build_instance("oven", 0, seed=0).urdf)
    view = ViewConfig.from_template(load_template("oven").view)
    cfg = dataclasses.replace(RenderConfig(), sensor=SENSORS["realistic"])
    s, _ = render_with_retries(renderer, spec, cfg, view, (2, 0))
    assert (s["part_label"] == -1).any(), "imperfect mask should let background points in"
    assert np.isfinite(s["points"]).all()
    clean, _ = render_with_retries(renderer, spec, RenderConfig(), view, (2, 0))
    np.testing.assert_allclose(s["T_cam_obj"], clean["T_cam_obj"])  # same view and state as the clean render
    # object points stay within the sensor's noise level of the surface (flying pixels are few)
    from gt_checks import surface_distance

    from scapo.ops.rigid import invert_transform, transform_points
    from scapo.sim.assets import load_part_mesh

    d = []
    for p in range(spec.num_parts):
        rest = transform_points(invert_transform(s["part_pose"][p]), s["points"][s["part_label"] == p])
        d.append(surface_distance(load_part_mesh(spec, p), rest[::8]))
    d = np.concatenate(d)
    sensor = cfg.sensor
    sigma = sensor.sigma_base + sensor.sigma_quad * (np.median(s["points"][:, 2]) - 0.4) ** 2
    assert np.median(d) < 2 * sigma and np.mean(d < 3 * sigma) > 0.8
    assert (d > 1e-4).mean() > 0.5  # and they are noisy
    # a point labelled with a part is on that part (flying pixels are background): all of them, not a median
    lab = s["part_label"]
    for p in range(spec.num_parts):
        rest = transform_points(invert_transform(s["part_pose"][p]), s["points"][lab == p])
        assert surface_distance(load_part_mesh(spec, p), rest).max() < 6 * sigma
    # background (support plane, flying pixels) only near the object, never metres behind it
    centre = s["T_cam_obj"][:3, 3]
    assert np.linalg.norm(s["points"][lab < 0] - centre, axis=1).max() < 1.5 * s["bbox_diag"]
    assert 0.0 < (lab < 0).mean() < 0.3


def test_cropped_views_are_rejected_flagged_or_kept(renderer):
    spec = parse_urdf(build_instance("laptop", 0, seed=0).urdf)
    view = ViewConfig.from_template(load_template("laptop").view)
    close = look_at(np.array([-0.45 * spec.bbox_diag, 0.0, 0.2 * spec.bbox_diag]), np.zeros(3), np.array([0, 0, 1.0]))
    far = look_at(np.array([-2.0 * spec.bbox_diag, 0.0, 0.8 * spec.bbox_diag]), np.zeros(3), np.array([0, 0, 1.0]))
    state = np.array([1.2])
    with pytest.raises(RejectedViewError, match="cropped"):
        render_sample(renderer, spec, RenderConfig(cropped="reject"), view, np.random.default_rng(0), state, close)
    flag = RenderConfig(cropped="flag")
    assert render_sample(renderer, spec, flag, view, np.random.default_rng(0), state, close)["cropped"]
    assert not render_sample(renderer, spec, flag, view, np.random.default_rng(0), state, far)["cropped"]
    assert "cropped" not in render_sample(renderer, spec, RenderConfig(), view, np.random.default_rng(0), state, close)
