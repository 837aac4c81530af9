"""ICP baseline (the paper's "ICP" row): per-part rigid registration to a category template.

Uses ground-truth segmentation at test time, as in the paper.

Template: one training instance at rest, the medoid of the training instances' part extents;
the ``npcs`` coordinates (rest-state object frame / bbox diagonal) of all its training views,
pooled per part, thinned by farthest-point sampling and scaled by its bbox diagonal. It lives in
the GT canonical frame, so no canonical-frame alignment is needed.

Registration is hierarchical, with point-to-point ICP (``small_gicp``): (1) the whole observed object is registered
to the whole template from a fixed set of rotation hypotheses (the 60 rotations of the icosahedral group, centroids
aligned; a short coarse run on a subsample, one vectorised ICP over all hypotheses, then the best few, at least 45
deg apart, refined by small_gicp); (2) for each of those, the observed points of each GT part are registered to that
part's template, starting from the object-level pose and from local perturbations of it (+-45 deg about the three
object axes, through the part centroid). Every pose is scored two-sidedly: observation -> template residual plus the
residual of the template points visible to the camera (a coarse z-buffer) -> observation, both truncated. The
object-level candidate whose parts fit best overall wins. Starting parts from the object level keeps thin, nearly
symmetric parts (plates, doors) from flipping independently; the object as a whole can still flip front-to-back when
the template and the instance differ in shape.

The optional ``search="batched"`` (``ICPConfig.search``) runs the same hypotheses and starts as
vectorised multi-start ICPs on subsamples, answering nearest-template-point queries from a
precomputed closest-point grid (:mod:`scapo.ops.closest_point`), and refines with small_gicp only
each object candidate's best start per part before the same final choice. It is an order of
magnitude faster but not the same search: on near-symmetric objects it lands on the other
member of a front/back pair in a different share of views (``scapo bench perf --what icp`` shows
both searches' speed and accuracy in one run), so Table 1's ICP row uses the exhaustive search.

Outputs: part poses (template frame -> camera); joints derived from the relative motion of the
child part against its parent (axis and angle of the relative rotation, pivot from
``(I - R) c = t``; translation direction for prismatic joints), with the sign chosen to agree with
the template's rest-state joint axis (pooled from training ground truth), which also stands in
when the relative motion is too small to define an axis; segmentation: every point takes the
part of the nearest registered template point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import small_gicp
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from scapo.data.dataset import ArticulationDataset
from scapo.errors import ConfigError, DatasetError
from scapo.eval.predictions import Predictions
from scapo.methods.joints import joint_from_part_poses, rest_joints
from scapo.methods.registry import register_method
from scapo.ops.closest_point import ClosestPointGrid
from scapo.ops.groups import rotation_group
from scapo.ops.rigid import as_transform, invert_transform, transform_points
from scapo.ops.sampling import farthest_point_indices


@dataclass(frozen=True)
class ICPConfig:
    """Options of the ICP baseline."""

    template_points: int = 2048
    """Points per part template (farthest-point sample of the pooled training NPCS; fewer if fewer exist)."""
    hypotheses: str = "I"
    """Initial rotations: a scipy rotation group ("I": 60 icosahedral, "O": 24 octahedral)."""
    max_iterations: int = 30
    """ICP iterations per hypothesis."""
    max_correspondence: float = 0.15
    """Inlier distance for correspondences and the truncated score, in template bbox diagonals."""
    refine_top: int = 3
    """Object-level hypotheses refined and carried into part-level registration; the one whose
    parts fit best (two-sided score summed over parts) wins."""
    visibility_cell: float = 4.0
    """Pixel size of the z-buffer grid used to find template points visible to the camera."""
    min_joint_angle_deg: float = 1.0
    """Below this relative rotation the template's rest axis is used instead of the motion's."""
    seed: int = 0
    progress: bool = False
    """Show a progress bar while predicting."""
    search: str = "exhaustive"
    """"exhaustive": every hypothesis and start refined by its own ICP (small_gicp), as Table 1's ICP row;
    "batched": the same hypotheses and starts run as vectorised ICPs on a subsample (:meth:`ICPBaseline.
    batched_icp`, nearest template points from a precomputed closest-point grid), and only the winning
    candidate's parts refined by small_gicp (``scapo bench perf --what icp`` measures both searches' speed and
    accuracy in one run; results/perf/)."""
    batch_points: int = 96
    """"batched" search: observed points per hypothesis (a regular subsample)."""
    batch_iterations: int = 8
    """"batched" search: iterations of the vectorised ICP."""
    batch_object_points: int = 256
    """"batched" search: observed points per object-level hypothesis (the whole object; a regular subsample)."""
    grid_cell: float = 0.02
    """"batched" search: cell of the closest-point grid (:class:`~scapo.ops.closest_point.ClosestPointGrid`) that
    answers its nearest-template-point queries, in template bbox diagonals."""

    def __post_init__(self):
        checks = {"search": self.search in ("exhaustive", "batched"), "batch_points": self.batch_points >= 16,
                  "batch_iterations": self.batch_iterations >= 1,
                  "batch_object_points": self.batch_object_points >= 16,
                  "grid_cell": 0 < self.grid_cell <= self.max_correspondence,
                  "template_points": self.template_points >= 16,
                  "max_iterations": self.max_iterations >= 1,
                  "max_correspondence": self.max_correspondence > 0, "refine_top": self.refine_top >= 1,
                  "visibility_cell": self.visibility_cell > 0, "min_joint_angle_deg": self.min_joint_angle_deg >= 0,
                  "hypotheses": self.hypotheses in ("I", "O", "T")}
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"invalid ICP option(s) {', '.join(f'{k}={getattr(self, k)!r}' for k in bad)}: need "
                              "template_points >= 16, max_iterations >= 1, refine_top >= 1, max_correspondence > 0, "
                              "visibility_cell > 0, min_joint_angle_deg >= 0, hypotheses in I, O, T, search in "
                              "exhaustive, batched, batch_points >= 16, batch_object_points >= 16, "
                              "batch_iterations >= 1, 0 < grid_cell <= max_correspondence")


class ICPBaseline:
    """Per-part ICP against a category template (see module docstring)."""

    name = "icp"
    needs_alignment = False
    supervision = {"pose": False, "segmentation": True, "joint": False}

    def __init__(self, config: ICPConfig | None = None, **overrides):
        import dataclasses

        self.config = dataclasses.replace(config or ICPConfig(), **overrides)
        self.templates: list[np.ndarray] = []
        self._index: dict = {}
        self._grids: dict = {}

    # ------------------------------------------------------------------ fit
    def fit(self, train: ArticulationDataset) -> None:
        """Build per-part templates and rest-state joint axes/pivots from the training split."""
        if len(train) == 0:
            raise DatasetError(f"{train.root}: the training split is empty; ICP builds its template from it")
        a = train.arrays(["npcs", "part_label", "bbox_diag", "part_pose", "joint_axis", "joint_pivot", "joint_parts",
                          "joint_type"])
        inst = a["instance_id"]
        # template instance: the medoid of the training instances' per-part NPCS extents
        ids = np.unique(inst)
        feats = []
        for i in ids:
            sel = inst == i
            f = []
            for p in range(train.num_parts):
                q = a["npcs"][sel][a["part_label"][sel] == p]
                f.append(np.percentile(q, 98, axis=0) - np.percentile(q, 2, axis=0) if len(q) else np.zeros(3))
            feats.append(np.concatenate(f))
        feats = np.array(feats)
        medoid = ids[int(np.argmin(np.abs(feats[:, None] - feats[None]).sum(-1).sum(1)))]
        sel = inst == medoid
        self.template_instance = int(medoid)
        self.scale = float(a["bbox_diag"][sel].mean())
        rng = np.random.default_rng(self.config.seed)
        self.templates = []
        for p in range(train.num_parts):
            pts = a["npcs"][sel][a["part_label"][sel] == p].astype(np.float64)
            if len(pts) < 64:
                raise DatasetError(f"{train.root}: part {p} of template instance {medoid} has only {len(pts)} "
                                   "training points; render more views per instance")
            idx = farthest_point_indices(pts.astype(np.float32), min(self.config.template_points, len(pts)), rng)
            self.templates.append(pts[idx] * self.scale)
        # rest-state joints in the object frame (pooled GT of training samples, median)
        self.joint_parts, self.joint_type, self.rest_axis, rest_pivot = rest_joints(a)
        self.rest_pivot = rest_pivot * self.scale
        self._object_template = np.concatenate(self.templates)
        self._index, self._grids = {}, {}
        for key, pts in [("object", self._object_template), *enumerate(self.templates)]:
            cloud = small_gicp.PointCloud(pts)
            self._index[key] = (cloud, small_gicp.KdTree(cloud), cKDTree(pts))
        self._hyp = rotation_group(self.config.hypotheses)
        local = [np.eye(3)]
        for ax in np.eye(3):
            for deg in (-45, 45):
                local.append(Rotation.from_rotvec(np.radians(deg) * ax).as_matrix())
        self._local = np.stack(local)

    # ------------------------------------------------------------------ predict
    def _align(self, key, observed: np.ndarray, init_T_cam_tpl: np.ndarray, iters: int,
               source: small_gicp.PointCloud | None = None) -> tuple[np.ndarray, float]:
        """Refine ``init_T_cam_tpl`` with ICP on template ``key``; returns (T_cam_tpl, score). ``source``: the
        small_gicp cloud of ``observed`` where the caller has built it already."""
        cloud, tree, kd = self._index[key]
        max_corr = self.config.max_correspondence * self.scale
        res = small_gicp.align(cloud, small_gicp.PointCloud(observed) if source is None else source, tree,
                               init_T_target_source=invert_transform(init_T_cam_tpl), registration_type="ICP",
                               max_correspondence_distance=max_corr, max_iterations=iters)
        T = np.asarray(res.T_target_source)
        d, _ = kd.query(transform_points(T, observed))
        return invert_transform(T), float(np.mean(np.minimum(d, max_corr) ** 2))

    def _visible_score(self, key, T_cam_tpl: np.ndarray, observed: np.ndarray, K: np.ndarray,
                       observed_tree: cKDTree | None = None) -> float:
        """Truncated squared distance from the template points visible in the camera to the observation.

        Visibility is a z-buffer on a grid of ``visibility_cell`` pixels. Together with the
        observation-to-template residual this is a two-sided check that rejects poses under
        which template surfaces face the camera where nothing was observed (e.g. flipped plates).
        """
        tpl = self._index[key][2].data
        p = transform_points(T_cam_tpl, tpl)
        p = p[p[:, 2] > 1e-3]
        if len(p) == 0:
            return np.inf
        uv = (p @ K.T)[:, :2] / p[:, 2:3]
        cell = np.floor(uv / self.config.visibility_cell).astype(np.int64)
        key_id = (cell[:, 0] - cell[:, 0].min()) * 100003 + (cell[:, 1] - cell[:, 1].min())
        order = np.lexsort((p[:, 2], key_id))
        first = np.ones(len(order), dtype=bool)
        first[1:] = key_id[order][1:] != key_id[order][:-1]
        visible = p[order][first]
        max_corr = self.config.max_correspondence * self.scale
        d, _ = (observed_tree if observed_tree is not None else cKDTree(observed)).query(visible)
        return float(np.mean(np.minimum(d, max_corr) ** 2))

    def object_candidates(self, observed: np.ndarray, K: np.ndarray) -> list[np.ndarray]:
        """The ``refine_top`` best object-level poses (4, 4), whole template -> camera.

        Every hypothesis is aligned on a coarse subsample (about 256 points, 8 iterations) by one vectorised ICP over
        all hypotheses (:meth:`batched_icp`) and scored two-sidedly on the whole template (:meth:`_visible_scores`
        with ``every_point``, the same z-buffer score as :meth:`_visible_score`); the best few, at least 45 deg apart,
        are refined by small_gicp on all points. Aligning the coarse hypotheses one by one with small_gicp instead
        gave the same val scores at 1.7x the time (docs/results_notes.md, Speed)."""
        obs = observed.astype(np.float64)
        coarse = obs[:: max(1, len(obs) // 256)]
        c_obs, c_tpl = obs.mean(0), self._object_template.mean(0)
        T0 = np.stack([as_transform(R, c_obs - R @ c_tpl) for R in self._hyp])
        T, sc = self.batched_icp("object", coarse, T0, 8)
        sc = sc + self._visible_scores("object", T, small_gicp.KdTree(coarse), K, every_point=True)
        kept: list[np.ndarray] = []  # best-first, at least 45 deg apart (non-maximum suppression)
        for k in np.argsort(sc, kind="stable"):
            if all(np.trace(T[k, :3, :3] @ q[:3, :3].T) < 1 + 2 * np.cos(np.radians(45)) for q in kept):
                kept.append(T[k])
            if len(kept) == self.config.refine_top:
                break
        source = small_gicp.PointCloud(obs)
        return [self._align("object", obs, T0, self.config.max_iterations, source)[0] for T0 in kept]

    def register_part(self, observed: np.ndarray, part: int, T_init: np.ndarray, K: np.ndarray
                      ) -> tuple[np.ndarray, float]:
        """(pose (4, 4), score) of template ``part`` in the camera, refined from ``T_init`` and local perturbations."""
        obs = observed.astype(np.float64)
        c = obs.mean(0)
        source = small_gicp.PointCloud(obs)
        fits = [self._align(part, obs, as_transform(dR @ T_init[:3, :3], dR @ (T_init[:3, 3] - c) + c),
                            self.config.max_iterations, source) for dR in self._local]
        T = np.stack([f[0] for f in fits])
        sc = np.array([f[1] for f in fits]) + self._visible_scores(part, T, small_gicp.KdTree(obs), K,
                                                                   every_point=True)
        best = int(np.argmin(sc))  # the first of equal scores, as a loop keeping strictly smaller ones
        return T[best], float(sc[best])

    # ------------------------------------------------------------------ batched search
    def _grid(self, key) -> ClosestPointGrid:
        """The closest-point grid of template ``key`` ("object" or a part index), built at first use."""
        if key not in self._grids:
            try:
                self._grids[key] = ClosestPointGrid(self._index[key][2].data, self.config.grid_cell * self.scale,
                                                    self.config.max_correspondence * self.scale)
            except ValueError as e:  # e.g. a grid_cell so small that the grid would not fit in memory
                raise ConfigError(f"ICP option grid_cell={self.config.grid_cell}: {e}") from None
        return self._grids[key]

    def batched_icp(self, key, src: np.ndarray, T0: np.ndarray, iters: int) -> tuple[np.ndarray, np.ndarray]:
        """Point-to-point ICP of ``src (n, 3)`` (camera frame) onto template ``key`` from ``H`` starts at once.

        Args:
            T0: ``(H, 4, 4)`` template -> camera starting poses. iters: iterations (closest template point
                within ``max_correspondence``, then the weighted Kabsch fit of every start, vectorised).

        Returns:
            ``(T (H, 4, 4) template -> camera, score (H,))``: the truncated mean squared residual of ``src``.
        """
        tpl = self._index[key][2].data
        max_corr = self.config.max_correspondence * self.scale
        nearest = self._grid(key).query
        A = invert_transform(T0)  # camera -> template
        R, t = A[:, :3, :3].copy(), A[:, :3, 3].copy()
        H, n = len(T0), len(src)
        for _ in range(iters):
            X = np.matmul(src, R.transpose(0, 2, 1)) + t[:, None]  # (H, n, 3)
            d, idx = nearest(X.reshape(-1, 3))
            d, idx = d.reshape(H, n), idx.reshape(H, n)
            w = (d < max_corr).astype(np.float64)
            wsum = w.sum(1)
            ok = wsum >= 3
            Y = tpl[idx]
            wn = w / np.maximum(wsum, 1)[:, None]
            mu_p = wn @ src
            mu_y = np.matmul(wn[:, None], Y)[:, 0]
            C = np.matmul(((src - mu_p[:, None]) * w[..., None]).transpose(0, 2, 1), Y - mu_y[:, None])
            U, _, Vt = np.linalg.svd(C)
            V, Ut = Vt.transpose(0, 2, 1), U.transpose(0, 2, 1)
            D = np.ones((H, 1, 3))
            D[:, 0, 2] = np.sign(np.linalg.det(V @ Ut))
            Rn = (V * D) @ Ut  # V diag(1, 1, det) U^T
            tn = mu_y - np.matmul(Rn, mu_p[..., None])[..., 0]
            R = np.where(ok[:, None, None], Rn, R)
            t = np.where(ok[:, None], tn, t)
        X = np.matmul(src, R.transpose(0, 2, 1)) + t[:, None]
        d, _ = nearest(X.reshape(-1, 3))
        score = np.mean(np.minimum(d.reshape(H, n), max_corr) ** 2, axis=1)
        A = np.tile(np.eye(4), (H, 1, 1))
        A[:, :3, :3], A[:, :3, 3] = R, t
        return invert_transform(A), score

    def _visible_scores(self, key, T_cam_tpl: np.ndarray, observed_tree: small_gicp.KdTree, K: np.ndarray,
                        every_point: bool = False) -> np.ndarray:
        """:meth:`_visible_score` of ``H`` poses ``(H, 4, 4)`` at once: on every template point with
        ``every_point`` (the same score), else on a subsample of the template (about ``4 * batch_points`` points,
        spread over it by its farthest-point order; the batched search's, which costs accuracy on eyeglasses,
        docs/results_notes.md, Speed); ``observed_tree``: a small_gicp k-d tree of the observed points (it answers
        these batches about three times as fast as scipy's)."""
        tpl = self._index[key][2].data
        if not every_point:
            tpl = tpl[:: max(1, len(tpl) // (4 * self.config.batch_points))]
        H = len(T_cam_tpl)
        p = np.matmul(tpl, T_cam_tpl[:, :3, :3].transpose(0, 2, 1)) + T_cam_tpl[:, None, :3, 3]
        hyp = np.repeat(np.arange(H), len(tpl))
        p = p.reshape(-1, 3)
        front = p[:, 2] > 1e-3
        p, hyp = p[front], hyp[front]
        out = np.full(H, np.inf)
        if len(p) == 0:
            return out
        uv = (p @ K.T)[:, :2] / p[:, 2:3]
        cell = np.floor(uv / self.config.visibility_cell).astype(np.int64)
        cell -= cell.min(0)
        key_id = (hyp * (cell[:, 0].max() + 1) + cell[:, 0]) * (cell[:, 1].max() + 1) + cell[:, 1]
        z = p[:, 2]
        order = np.lexsort((z, key_id))  # by cell, then nearest first
        key_id = key_id[order]
        first = np.ones(len(order), dtype=bool)
        first[1:] = key_id[1:] != key_id[:-1]
        vis, vh = p[order[first]], hyp[order[first]]
        max_corr = self.config.max_correspondence * self.scale
        _, sq = observed_tree.batch_nearest_neighbor_search(vis)
        sums = np.bincount(vh, np.minimum(np.asarray(sq), max_corr ** 2), minlength=H)
        counts = np.bincount(vh, minlength=H)
        out[counts > 0] = sums[counts > 0] / counts[counts > 0]
        return out

    def _subsample(self, pts: np.ndarray, n: int | None = None) -> np.ndarray:
        """A regular subsample of about ``n`` (default ``batch_points``) of ``pts``."""
        return pts[:: max(1, len(pts) // (n or self.config.batch_points))]

    def _batched_object_candidates(self, obs: np.ndarray, K: np.ndarray, obs_tree) -> np.ndarray:
        """:meth:`object_candidates` as batched ICPs (see ``ICPConfig.search``): ``(refine_top, 4, 4)``."""
        coarse = self._subsample(obs, self.config.batch_object_points)
        c_obs, c_tpl = obs.mean(0), self._object_template.mean(0)
        T0 = np.stack([as_transform(R, c_obs - R @ c_tpl) for R in self._hyp])
        # a few iterations for every hypothesis, then the rest for the best third (most never recover)
        first = min(3, self.config.batch_iterations)
        T, sc = self.batched_icp("object", coarse, T0, first)
        keep = np.argsort(sc, kind="stable")[: max(self.config.refine_top * 4, len(T0) // 3)]
        if self.config.batch_iterations > first:
            T, sc = self.batched_icp("object", coarse, T[keep], self.config.batch_iterations - first)
        else:
            T, sc = T[keep], sc[keep]
        vis = self._visible_scores("object", T, obs_tree, K)
        kept: list[np.ndarray] = []
        for k in np.argsort(sc + vis, kind="stable"):
            if all(np.trace(T[k, :3, :3] @ q[:3, :3].T) < 1 + 2 * np.cos(np.radians(45)) for q in kept):
                kept.append(T[k])
            if len(kept) == self.config.refine_top:
                break
        # the kept few, refined on more points
        return self.batched_icp("object", self._subsample(obs, 4 * self.config.batch_points), np.stack(kept),
                                self.config.batch_iterations)[0]

    def _batched_part_poses(self, pts: np.ndarray, gl: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Part poses ``(P, 4, 4)`` of one cloud by the batched search.

        For every part, the perturbed starts from every object candidate run as one batched ICP and each
        candidate keeps its best start (subsample residual plus visible-template residual); then, as in the
        exhaustive search, each candidate's parts are refined by small_gicp on all their points and the
        candidate whose parts fit best (:meth:`register_part`'s two-sided score, weighted by part size) wins.
        """
        obj = pts[gl >= 0]
        cands = self._batched_object_candidates(
            obj, K, small_gicp.KdTree(self._subsample(obj, self.config.batch_object_points)))
        C, L, P = len(cands), len(self._local), len(self.templates)
        parts = [pts[gl == p] for p in range(P)]
        starts_of = np.zeros((C, P, 4, 4))
        for p, obs in enumerate(parts):
            centre = obs.mean(0)  # perturbations turn about the part's centroid, as in register_part
            R0 = np.einsum("lij,cjk->clik", self._local, cands[:, :3, :3]).reshape(-1, 3, 3)
            t0 = (np.einsum("lij,cj->cli", self._local, cands[:, :3, 3] - centre) + centre).reshape(-1, 3)
            starts = np.tile(np.eye(4), (C * L, 1, 1))
            starts[:, :3, :3], starts[:, :3, 3] = R0, t0
            T, sc = self.batched_icp(p, self._subsample(obs), starts, self.config.batch_iterations)
            fit = (sc + self._visible_scores(p, T, small_gicp.KdTree(obs), K)).reshape(C, L)
            starts_of[:, p] = T.reshape(C, L, 4, 4)[np.arange(C), fit.argmin(1)]
        best = None
        trees = [cKDTree(obs) for obs in parts]
        for c in range(C):
            total, poses = 0.0, []
            for p, obs in enumerate(parts):
                T, score = self._align(p, obs, starts_of[c, p], self.config.max_iterations)
                total += len(obs) * (score + self._visible_score(p, T, obs, K, trees[p]))
                poses.append(T)
            if best is None or total < best[0]:
                best = (total, np.stack(poses))
        return best[1]

    def predict(self, dataset: ArticulationDataset) -> Predictions:
        a = dataset.arrays(["points", "part_label", "joint_type", "K"])
        M, N = a["points"].shape[:2]
        P, J = dataset.num_parts, dataset.num_joints
        poses = np.tile(np.eye(4), (M, P, 1, 1))
        labels = np.full((M, N), -1, dtype=np.int64)
        axis = np.zeros((M, J, 3))
        pivot = np.zeros((M, J, 3))
        state = np.zeros((M, J))
        it = range(M)
        if self.config.progress:
            from scapo.report import progress_bar

            it = progress_bar(it, desc=f"icp {dataset.split}", unit="cloud")
        for m in it:
            pts = a["points"][m].astype(np.float64)
            gl = a["part_label"][m]
            if self.config.search == "batched":
                poses[m] = self._batched_part_poses(pts, gl, a["K"][m])
            else:
                best = None
                for T_obj in self.object_candidates(pts[gl >= 0], a["K"][m]):
                    fits = [self.register_part(pts[gl == p], p, T_obj, a["K"][m]) for p in range(P)]
                    total = sum(np.count_nonzero(gl == p) * f[1] for p, f in enumerate(fits))
                    if best is None or total < best[0]:
                        best = (total, np.stack([f[0] for f in fits]))
                poses[m] = best[1]
            # segmentation induced by the registered template
            dist = np.stack([self._index[p][2].query(transform_points(invert_transform(poses[m, p]), pts))[0]
                             for p in range(P)], 1)
            labels[m] = dist.argmin(1)
            for j, (pa, ch) in enumerate(self.joint_parts):
                axis[m, j], pivot[m, j], state[m, j] = joint_from_part_poses(
                    poses[m, pa], poses[m, ch], int(self.joint_type[j]), self.rest_axis[j], self.rest_pivot[j],
                    self.config.min_joint_angle_deg)
        return Predictions(
            method=self.name, instance_id=a["instance_id"], view_id=a["view_id"],
            split=np.full(M, dataset.split), part_label=labels, part_pose=poses,
            joint_parts=np.tile(self.joint_parts, (M, 1, 1)), joint_type=np.tile(self.joint_type, (M, 1)),
            joint_axis=axis, joint_pivot=pivot, joint_state=state, T_cam_obj=poses[:, 0].copy(),
            needs_alignment=self.needs_alignment, supervision=dict(self.supervision),
            info={"config": self.config.__dict__},
        )


def icp_speed(preset: str = "-", device: str | None = None, iters: int = 5, num_points: int = 1024,
              data=None) -> list[dict]:
    """ICP's prediction time on the first ``iters`` test clouds of ``data`` after fitting its template on the
    training split (CPU; ms per cloud). Raises ConfigError without ``data``."""
    import time

    import torch

    from scapo.data.dataset import load

    if data is None:
        raise ConfigError("timing ICP needs --data DATASET: its template is fitted on the training split")
    m = ICPBaseline()
    m.fit(load(data, "train"))
    test = load(data, "test")
    keep = test.manifest.index[: max(1, iters)]
    test.manifest = test.manifest.loc[keep]
    t = time.perf_counter()
    m.predict(test)
    ms = 1000 * (time.perf_counter() - t) / len(keep)
    return [{"preset": "-", "device": "cpu", "infer_ms_per_cloud_b1": round(ms, 2),
             "infer_clouds_per_s_b1": round(1000 / ms, 2), "clouds_timed": len(keep),
             "threads": torch.get_num_threads()}]


@register_method("icp", options=ICPConfig, display="ICP", supervision=ICPBaseline.supervision, needs_alignment=False,
                 summary="per-part rigid ICP to a category template (GT segmentation at test time)", speed=icp_speed,
                 quick_options={"max_iterations": 3, "hypotheses": "T", "refine_top": 1, "template_points": 64},
                 paper_row="ICP")
def make_icp(**options) -> ICPBaseline:
    """ICP baseline; options are :class:`ICPConfig` fields."""
    return ICPBaseline(**options)
