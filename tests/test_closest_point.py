"""Closest-point grid: its answers against an exact k-d tree search."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from scapo.ops.closest_point import ClosestPointGrid


def test_grid_answers_are_within_a_cell_diagonal_of_the_exact_nearest_point():
    rng = np.random.default_rng(0)
    pts = rng.random((500, 3)) * [0.4, 0.2, 0.05]
    cell, reach = 0.01, 0.05
    grid = ClosestPointGrid(pts, cell, reach)
    q = pts[rng.integers(0, len(pts), 4000)] + rng.normal(0, 0.03, (4000, 3))
    d, idx = grid.query(q)
    d_exact, _ = cKDTree(pts).query(q)
    near = d_exact < reach
    assert near.mean() > 0.5 and np.isfinite(d[near]).all()
    # the returned point is a real one at the returned distance, at most a cell diagonal worse than the best
    np.testing.assert_allclose(d[near], np.linalg.norm(q[near] - pts[idx[near]], axis=1))
    assert np.all(d[near] >= d_exact[near] - 1e-12)
    assert np.all(d[near] <= d_exact[near] + np.sqrt(3) * cell + 1e-12)
    assert np.mean(d[near] - d_exact[near] < 1e-12) > 0.5  # mostly the exact nearest point
    # far queries (outside the grid, or in cells with no point within reach) are "none"
    far = d_exact > reach + 2 * np.sqrt(3) * cell
    assert far.any() and np.isinf(d[far]).all()
    d_out, _ = grid.query(np.array([[5.0, 5.0, 5.0], [-5.0, 0.1, 0.0]]))
    assert np.isinf(d_out).all()


def test_grid_rejects_bad_input():
    with pytest.raises(ValueError, match="non-empty finite"):
        ClosestPointGrid(np.zeros((0, 3)), 0.01, 0.05)
    with pytest.raises(ValueError, match="non-empty finite"):
        ClosestPointGrid(np.array([[0.0, np.nan, 0.0]]), 0.01, 0.05)
    with pytest.raises(ValueError, match="positive"):
        ClosestPointGrid(np.zeros((4, 3)), 0.0, 0.05)
    with pytest.raises(ValueError, match="larger cell"):
        ClosestPointGrid(np.array([[0.0, 0, 0], [10.0, 10, 10]]), 0.001, 0.05)


def test_icp_refuses_a_grid_cell_too_small_for_memory(laptop_data):
    from scapo.data import load
    from scapo.errors import ConfigError
    from scapo.methods.icp import ICPBaseline

    m = ICPBaseline(search="batched", grid_cell=1e-4)
    m.fit(load(laptop_data, "train"))
    with pytest.raises(ConfigError, match="grid_cell=0.0001.*larger cell"):
        m._grid("object")
