"""Closest-point lookups into a fixed point set through a precomputed voxel grid (a "closest-point map").

ICP against a fixed template asks the same question millions of times: which template point is nearest to
this query? Precomputing the answer at the centres of a regular grid around the template (one k-d tree query
per cell, scipy's ``cKDTree``, once) turns each later query into an array lookup, several times faster than a
k-d tree search for the small batches of a vectorised multi-start ICP. The answer is approximate: the point
returned is the one nearest to the centre of the query's cell, so its distance exceeds the true nearest
distance by at most the cell's diagonal (``sqrt(3) * cell``). Queries farther than ``reach`` from every
point (outside the grid, or in a cell with no point within ``reach + cell``) get an infinite distance.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class ClosestPointGrid:
    """Approximate nearest neighbours in ``points`` for queries within ``reach`` of them.

    Args:
        points: ``(n, 3)`` float, the fixed point set (any frame and unit; queries use the same).
        cell: edge of the grid's cubic cells, in the points' unit (> 0).
        reach: the largest distance of interest (> 0); the grid covers the points' bounding box grown by
            ``reach + cell`` on every side.
        max_cells: refuse grids larger than this (memory: 4 bytes per cell).

    Raises:
        ValueError: empty or non-finite ``points``, ``cell`` or ``reach`` not positive, or a grid of more than
            ``max_cells`` cells (use a larger ``cell``).
    """

    def __init__(self, points: np.ndarray, cell: float, reach: float, max_cells: int = 8_000_000):
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.isfinite(pts).all():
            raise ValueError(f"closest-point grid: need a non-empty finite (n, 3) point set, got shape {pts.shape}")
        if not (cell > 0 and reach > 0):
            raise ValueError(f"closest-point grid: cell and reach must be positive, got cell={cell}, reach={reach}")
        self.points, self.cell, self.reach = pts, float(cell), float(reach)
        self.origin = pts.min(0) - (reach + cell)
        self.shape = np.ceil((pts.max(0) + reach + cell - self.origin) / cell).astype(np.int64) + 1
        cells = int(np.prod(self.shape))
        if cells > max_cells:
            raise ValueError(f"closest-point grid: {cells} cells exceed {max_cells}; use a larger cell than {cell}")
        axes = [self.origin[i] + cell * np.arange(self.shape[i]) for i in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        # a query within `reach` of some point lies within reach + cell diagonal / 2 of its cell centre's answer
        _, idx = cKDTree(pts).query(centres, distance_upper_bound=reach + np.sqrt(3) * cell)
        index = np.where(idx < len(pts), idx, -1).astype(np.int32).reshape(tuple(self.shape))
        # the border cells (every query in them lies farther than reach + cell / 2 from every point) answer
        # "none", and queries outside the grid are clamped onto them
        index[[0, -1]], index[:, [0, -1]], index[:, :, [0, -1]] = -1, -1, -1
        self.index = index.reshape(-1)
        self._strides = np.array([self.shape[1] * self.shape[2], self.shape[2], 1], dtype=np.int64)
        self._high = self.shape - 1

    def query(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(distance (m,) float64, index (m,) int64)`` for queries ``q (m, 3)``.

        ``index`` is the point nearest to the centre of the query's cell and ``distance`` the exact distance
        from the query to it; ``inf`` (with index 0) where no point lies within reach of the cell.
        """
        q = np.asarray(q, dtype=np.float64)
        c = np.rint((q - self.origin) * (1.0 / self.cell)).astype(np.int64)
        np.minimum(np.maximum(c, 0, out=c), self._high, out=c)
        idx = self.index[c @ self._strides].astype(np.int64)
        none = idx < 0
        idx[none] = 0
        diff = q - self.points[idx]
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        d[none] = np.inf
        return d, idx
