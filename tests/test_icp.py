"""ICP baseline: registration core against a known transform; end to end through the evaluator."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from scapo.data import load
from scapo.eval import evaluate
from scapo.eval.metrics import rotation_error_deg
from scapo.methods import METHODS, run_method
from scapo.methods.icp import ICPBaseline
from scapo.ops.rigid import as_transform, invert_transform, transform_points


def test_register_part_recovers_a_known_transform(laptop_data):
    # 100 iterations: a laptop's base is a thin wedge slab, on which point-to-point ICP turns slowly (the method's
    # default 30 stop it 2.3 deg short from this 20 deg start; 200 reach 0.4 deg): the registration is what is tested
    m = ICPBaseline(max_iterations=100)
    m.fit(load(laptop_data, "train"))
    K = np.array([[300.0, 0, 128], [0, 300.0, 128], [0, 0, 1]])
    T = as_transform(Rotation.from_euler("xyz", [20, -15, 30], degrees=True).as_matrix(), [0.05, -0.02, 1.2])
    obs = transform_points(T, m.templates[0][::3])
    # start 20 degrees off; ICP (with its local perturbations) converges to the truth
    start = T @ as_transform(Rotation.from_rotvec([0, math.radians(20), 0]).as_matrix(), [0.02, 0, 0])
    est, score = m.register_part(obs, 0, start, K)
    assert rotation_error_deg(est[:3, :3], T[:3, :3]) < 1.5  # ICP stops at 0.1 deg / 1 mm steps
    assert np.linalg.norm(est[:3, 3] - T[:3, 3]) < 5e-3 and score < 1e-4
    # the object-level search finds the template pose from scratch
    whole = transform_points(T, m._object_template[::2])
    cands = m.object_candidates(whole, K)
    assert min(rotation_error_deg(c[:3, :3], T[:3, :3]) for c in cands) < 2.0
    np.testing.assert_allclose(invert_transform(est) @ T, np.eye(4), atol=2e-2)


@pytest.fixture(scope="module")
def icp_run(laptop_data, tmp_path_factory):
    """ICP's predictions of the laptop test split (its path and the returned object), made once for the module
    (the evaluator's and the figure's tests read them; the module runs on one pytest-xdist worker). With the
    registered quick options (0.3 s instead of ~5 s): these tests are of the path through the evaluator and the
    figure; the search itself is tested above and below, the default search end to end in tests/test_bench.py."""
    path = tmp_path_factory.mktemp("icp") / "icp.npz"
    return path, run_method("icp", laptop_data, path, **METHODS.get("icp").quick_options)


def test_icp_through_the_evaluator_gives_plausible_numbers(laptop_data, icp_run):
    path, preds = icp_run
    assert len(preds) == len(load(laptop_data, "test"))  # no alignment needed: test split only
    res = evaluate(laptop_data, path)
    s = res.summary
    for k in ("S", "D", "C", "R", "t"):
        assert np.isfinite(s[k]), k
    assert 30.0 < s["S"] <= 100.0
    assert 0.0 < s["R"] < 180.0 and 0.0 < s["D"] <= 90.0 and 0.0 < s["t"] < 1.0 and 0.0 < s["C"] < 2.0
    assert res.info["supervision"]["segmentation"] is True


def test_prediction_figure_draws_ground_truth_and_predictions(laptop_data, icp_run, tmp_path, cache_dir):
    from PIL import Image

    from scapo.bench.viz import prediction_figure
    from scapo.eval.predictions import Predictions

    path, _ = icp_run
    png = prediction_figure(laptop_data, Predictions.load(path), tmp_path / "fig.png", count=2, cache_dir=cache_dir)
    img = np.asarray(Image.open(png).convert("L"))
    assert img.shape[0] > 200 and img.shape[1] > 200
    assert img.std() > 5.0  # not blank: points, axes and titles were drawn


def test_batched_search_matches_the_exhaustive_one_on_a_small_split(laptop_data):
    """ICP's batched search (one vectorised ICP over all hypotheses and starts) segments as well as the
    exhaustive one (within 5 IoU points on four clouds); its speed is measured by scapo bench perf --what icp."""
    from scapo.bench.perf import bench_icp

    rows = bench_icp(laptop_data, limit=4, split="test")  # the fixture has no val split
    ex, ba = rows
    assert ex["search"] == "exhaustive" and ba["search"] == "batched" and ba["clouds"] == 4
    assert abs(ba["S"] - ex["S"]) < 5.0 and ba["ms_per_cloud"] > 0
