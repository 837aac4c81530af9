"""Symmetries of a category, measured: which rigid maps take an object onto itself, and how many single
views such a map explains as well as the truth.

A category's declared symmetries (:data:`scapo.sim.assets.symmetry.SYMMETRIES`) are what the evaluator may
forgive; anything else that one view cannot tell apart from the truth makes a benchmark measure ambiguity
instead of accuracy. This module measures both, on the built meshes and on rendered views, so that the
declarations are data that a test can hold against the objects (``tests/test_symmetry_measure.py``) and
``scapo assets symmetry --category C`` can print.

Three measurements, all in float64, lengths in units of the instance's rest ``bbox_diag``:

1. **Self-maps of the posed object** (:func:`object_self_maps`). The object's surface (points drawn
   area-uniformly on every part's meshes, posed at a sampled joint state, object frame) is turned by each of
   the 23 non-identity rotations of the cube group about its bounding-box centre, refined by rigid
   point-to-point ICP onto the untouched surface, and kept when the refined map turns the object by more
   than ``min_angle_deg`` and at most 2 % of either surface lies farther than 0.02 bbox diagonals from the other
   (:class:`Tolerance`). Such a map, not declared, is a symmetry the category hides.
2. **Declared symmetries hold** (:func:`declared_symmetry_error`): the object at state ``q`` turned by a
   declared :class:`~scapo.sim.assets.symmetry.Symmetry` must coincide with the object at the permuted
   state (parts and joints exchanged), within the same tolerance. **Part symmetries**
   (:func:`part_symmetries`): each part turned about its principal axes through its area centroid by
   45 .. 180 deg; a part that every turn maps onto itself has a continuous symmetry about that axis (a round
   door), one that only the half turn maps has a discrete one.
3. **Ambiguous views** (:func:`view_ambiguity`), two independent criteria on the same rendered view:

   - *full surface, one-sided* (the measure behind the declared symmetries, ``results/symmetry/``): the whole posed
     object moved rigidly by each cube-group rotation about its box centre, refined by ICP of the observed points onto
     it; the view is ambiguous when a refined map ending more than ``min_angle_deg`` from the truth explains the
     observed points (mean distance observed -> surface) within ``ratio`` x the truth's + ``slack``.
   - *visible surface, two-sided*: from each end point above, ICP is continued on the part of the moved
     surface the camera sees (a z-buffer of the surface points through the sample's intrinsics), scoring
     the mean of both directions of the Chamfer distance between the observed points and that visible
     surface, against the same score of the truth.

   A map is *declared* when its rotation is within ``min_angle_deg`` of a declared symmetry (moved to the
   camera frame); the shares of views ambiguous under undeclared maps are the numbers to keep under 5 %.

The cube-group search and the 30 deg / 1.25x / 0.004 diag rule follow the measurement in ``results/symmetry/``; the
symmetric mean distance as a self-map criterion is the "maximum symmetric surface distance" family of BOP
(Hodan et al., ECCV 2020 workshop, ``pose_error.py`` ``mssd``), used as a mean here because a point
sampling's maximum is noise.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from scapo.errors import ConfigError
from scapo.ops.align import umeyama
from scapo.ops.groups import rotation_group
from scapo.ops.rigid import as_transform, invert_transform, transform_points
from scapo.sim.assets.symmetry import SYMMETRIES, Symmetry
from scapo.sim.assets.urdf import ArticulationSpec, load_part_mesh


@dataclass(frozen=True)
class Tolerance:
    """When a moved object counts as "the same", for a map that turns it by more than ``min_angle_deg``.

    Views (and declared symmetries): ``distance <= ratio * reference + slack`` (bbox diagonals), the reference being
    the truth's own distance (or an independent resampling's), so that the rule does not depend on the point
    density. Meshes (undeclared self-maps): at most ``mesh_share`` of either surface farther than ``mesh_distance``
    from the other (the share that a feature must cover to break a symmetry; BOP's MSSD asks the same with a
    maximum, which a point sampling makes noisy)."""

    ratio: float = 1.25
    slack: float = 0.004
    min_angle_deg: float = 30.0
    mesh_distance: float = 0.02
    """meshes: a point "coincides" when the other surface is within this many bbox diagonals ..."""
    mesh_share: float = 0.02
    """... and a map is a self-map when at most this share of either surface does not coincide"""

    def __post_init__(self):
        bad = [k for k, ok in {"ratio": self.ratio >= 1.0, "slack": self.slack >= 0.0,
                                "min_angle_deg": 0.0 < self.min_angle_deg < 180.0,
                                "mesh_distance": self.mesh_distance > 0.0,
                                "mesh_share": 0.0 <= self.mesh_share < 1.0}.items() if not ok]
        if bad:
            raise ConfigError(f"invalid symmetry tolerance {', '.join(f'{k}={getattr(self, k)!r}' for k in bad)}: need "
                              "ratio >= 1, slack >= 0, 0 < min_angle_deg < 180, mesh_distance > 0, 0 <= mesh_share < 1")

    def same(self, distance: float, reference: float) -> bool:
        return bool(distance <= self.ratio * reference + self.slack)

    def coincide(self, share: float) -> bool:
        return bool(share <= self.mesh_share)


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))


# ------------------------------------------------------------------------------------------- surfaces
@dataclass
class Surface:
    """Points drawn area-uniformly on every part's meshes at rest (object frame, m).

    Attributes:
        points: (N, 3) float64. labels: (N,) int64 part index. links: part -> one link of the part (for its motion).
    """

    points: np.ndarray
    labels: np.ndarray
    spec: ArticulationSpec = field(repr=False)

    def posed(self, state: np.ndarray, T: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) the points at joint ``state`` (object frame), then moved by ``T (4, 4)`` when given."""
        motion = part_motions(self.spec, state)
        if T is not None:
            motion = np.asarray(T, dtype=np.float64) @ motion
        out = np.empty_like(self.points)
        for p in range(len(motion)):
            m = self.labels == p
            out[m] = transform_points(motion[p], self.points[m])
        return out


def part_motions(spec: ArticulationSpec, state: np.ndarray) -> np.ndarray:
    """(P, 4, 4) rigid motion of each part from the rest state to joint ``state`` (object frame)."""
    poses = spec.link_poses(np.asarray(state, dtype=np.float64))
    out = np.tile(np.eye(4), (spec.num_parts, 1, 1))
    for ln, p in spec.part_of_link.items():
        if p >= 0:
            out[p] = poses[ln] @ invert_transform(spec.rest_link_poses[ln])
    return out


def sample_surface(spec: ArticulationSpec, count: int, rng: np.random.Generator) -> Surface:
    """``count`` points drawn area-uniformly over all parts' meshes at rest (see :class:`Surface`).

    Raises:
        ConfigError: ``count`` < 16.
    """
    if count < 16:
        raise ConfigError(f"a surface sampling needs at least 16 points, got {count}")
    meshes = [load_part_mesh(spec, p) for p in range(spec.num_parts)]
    areas = np.array([m.area for m in meshes], dtype=np.float64)
    n = np.maximum(1, np.round(count * areas / areas.sum()).astype(int))
    pts, lab = [], []
    for p, (m, k) in enumerate(zip(meshes, n)):
        x, _ = trimesh.sample.sample_surface(m, int(k), seed=int(rng.integers(2**31)))
        pts.append(np.asarray(x, dtype=np.float64))
        lab.append(np.full(len(x), p, dtype=np.int64))
    return Surface(np.concatenate(pts), np.concatenate(lab), spec)


# ---------------------------------------------------------------------------------------------- ICP
def icp(src: np.ndarray, dst_tree: cKDTree, dst: np.ndarray, T0: np.ndarray, iters: int = 25,
        tol: float = 1e-7) -> np.ndarray:
    """Rigid point-to-point ICP: the (4, 4) transform ``T`` from ``T0`` that brings ``src (N, 3)`` onto
    ``dst (M, 3)`` (nearest neighbours in ``dst_tree``, Umeyama's least squares, Besl and McKay, 1992)."""
    T = np.asarray(T0, dtype=np.float64).copy()
    prev = np.inf
    for _ in range(iters):
        moved = transform_points(T, src)
        d, j = dst_tree.query(moved)
        T = umeyama(src, dst[j])[0]
        err = float(d.mean())
        if prev - err < tol:
            break
        prev = err
    return T


def _about(R: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(4, 4) rotation ``R`` about the point ``c``."""
    return as_transform(R, c - R @ c)


def _mean_dist(a: np.ndarray, tree_b: cKDTree) -> float:
    return float(tree_b.query(a)[0].mean())


def _share_far(a: np.ndarray, tree_b: cKDTree, far: float) -> float:
    """Share of the points ``a`` farther than ``far`` from the points in ``tree_b``."""
    return float((tree_b.query(a, distance_upper_bound=far)[0] > far).mean())


# ---------------------------------------------------------------------------------------- self-maps
def declared_rotation(sym: Symmetry, part_pose: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation of the rigid map that moves an object posed by ``part_pose (P, 4, 4)`` onto its twin
    (:func:`scapo.sim.assets.symmetry.twin`): the twin puts rest part 0 where the asset's part ``q`` (``parts[q] ==
    0``) is, turned by ``S^-1``, so the map is ``R_q R_S^T R_0^T``. For a symmetry that keeps the base part it is
    ``R_0 R_S^T R_0^T`` (the declared rotation seen in the pose's frame); for one that exchanges it (the laptop's)
    it depends on the joint state."""
    q = int(np.argsort(np.asarray(sym.parts))[0])
    P = np.asarray(part_pose, dtype=np.float64)
    return P[q, :3, :3] @ np.asarray(sym.rotation, dtype=np.float64).T @ P[0, :3, :3].T



@dataclass(frozen=True)
class SelfMap:
    """A rigid map of the posed object onto itself (object frame at the sampled state).

    Attributes:
        T: (4, 4) the map. angle_deg: its rotation angle. distance: the share of either surface that does not
        coincide after the map (:class:`Tolerance`). reference: that of an independent resampling. parts: (P,) the
        part each part
        lands on (majority of its points' nearest neighbours). declared: the name of the declared symmetry it is
        (its rotation within ``min_angle_deg``), or "".
    """

    T: np.ndarray
    angle_deg: float
    distance: float
    reference: float
    parts: tuple[int, ...]
    declared: str = ""


def object_self_maps(surface: Surface, state: np.ndarray, rng: np.random.Generator, tol: Tolerance = Tolerance(),
                     declared: tuple[Symmetry, ...] = (), iters: int = 30, icp_points: int = 1500) -> list[SelfMap]:
    """The cube-group rotations about the posed box centre that ICP refines into self-maps (measurement 1).

    Args:
        surface: :func:`sample_surface` of the instance. state: (J,) joint state from rest.
        declared: the category's symmetries; a map whose rotation is within ``min_angle_deg`` of one of them is
            labelled ``declared`` (a declared symmetry that exchanges joints maps state q onto its permutation,
            so at a sampled state it is found only approximately, or not at all).

    Returns:
        The distinct self-maps (rotations more than 10 deg apart), best first.
    """
    diag = surface.spec.bbox_diag
    X = surface.posed(state)
    half = rng.permutation(len(X))
    A, B = X[half[: len(X) // 2]], X[half[len(X) // 2:]]
    tree_a, tree_b = cKDTree(A), cKDTree(B)
    reference = max(_share_far(A, tree_b, tol.mesh_distance * diag), _share_far(B, tree_a, tol.mesh_distance * diag))
    c = 0.5 * (X.min(0) + X.max(0))
    found: list[SelfMap] = []
    src = A[rng.choice(len(A), min(len(A), icp_points), replace=False)]
    declared_R = [declared_rotation(s, part_motions(surface.spec, state)) for s in declared]
    for R in rotation_group("O")[1:]:
        T = icp(src, tree_b, B, _about(R, c), iters)
        ang = _angle_deg(T)
        if ang <= tol.min_angle_deg:
            continue
        moved = transform_points(T, A)
        far = tol.mesh_distance * diag
        dist = max(_share_far(moved, tree_b, far), _share_far(B, cKDTree(moved), far))
        if not tol.coincide(dist):
            continue
        if any(_angle_deg(T[:3, :3] @ f.T[:3, :3].T) < 10.0 for f in found):
            continue
        la = surface.labels[half[: len(X) // 2]]
        lb = surface.labels[half[len(X) // 2:]]
        land = lb[tree_b.query(moved)[1]]
        parts = tuple(int(np.bincount(land[la == p], minlength=1).argmax()) if np.any(la == p) else p
                      for p in range(surface.spec.num_parts))
        name = ""
        for k, D in enumerate(declared_R):
            if _angle_deg(T[:3, :3] @ D.T) < tol.min_angle_deg:
                name = f"declared {k}"
        found.append(SelfMap(T, ang, dist, reference, parts, name))
    return sorted(found, key=lambda f: f.distance)


@dataclass(frozen=True)
class DeclaredCheck:
    """How a declared symmetry holds at one state (measurement 2); lengths in bbox diagonals.

    Attributes:
        distance: two-sided mean surface distance after the declared map (part p compared with part ``parts[p]``).
        refined: the same after a rigid ICP refinement of the map. reference: an independent resampling's.
        offset: how far the refinement moved the surface (mean point displacement): the error of the twin ground
            truth's part positions. angle_deg: the refinement's rotation.
        holds: the declared map fits within the symmetry's stated slack, or its refinement does while turning by less
            than ``min_angle_deg`` (an approximate symmetry: the twin's rotations are right, its positions off by
            ``offset``).
    """

    distance: float
    refined: float
    reference: float
    offset: float
    angle_deg: float
    holds: bool


def declared_symmetry_error(surface: Surface, sym: Symmetry, rng: np.random.Generator,
                            tol: Tolerance = Tolerance()) -> DeclaredCheck:
    """Whether a declared symmetry holds (measurement 2).

    The twin ground truth (:func:`scapo.sim.assets.symmetry.twin`) poses part ``parts[p]`` by part p's pose times
    ``S^-1``; it describes the same observation at every joint state exactly when ``S`` maps each rest part p onto
    rest part ``parts[p]`` (and the joints onto each other). So the rest surface moved by ``S`` (its rotation about
    the object-frame origin, the rest bbox centre, or about its joint's rest pivot) is compared with the rest
    surface, part p with part ``parts[p]``; then the map is refined by rigid ICP. The symmetry's own ``slack``
    replaces the tolerance's.
    """
    diag = surface.spec.bbox_diag
    j = sym.pivot_joint
    center = None if j is None else np.asarray(surface.spec.gt_joints[j].pivot_obj, dtype=np.float64)
    rest = np.zeros(surface.spec.num_joints)
    X = surface.posed(rest, sym.transform(center))
    Y = surface.posed(rest)
    half = rng.permutation(len(X))
    ia, ib = half[: len(X) // 2], half[len(X) // 2:]
    lab = surface.labels

    def part_distance(Xa: np.ndarray) -> tuple[float, float]:
        dists, refs = [], []
        for p in range(surface.spec.num_parts):
            q = sym.parts[p]
            a, b, b_same = Xa[lab[ia] == p], Y[ib][lab[ib] == q], Y[ia][lab[ia] == q]
            if len(a) == 0 or len(b) == 0:
                continue
            ta, tb = cKDTree(a), cKDTree(b)
            dists.append(0.5 * (_mean_dist(a, tb) + _mean_dist(b, ta)))
            refs.append(0.5 * (_mean_dist(b_same, tb) + _mean_dist(b, cKDTree(b_same))))
        return float(np.mean(dists)) / diag, float(np.mean(refs)) / diag

    d, ref = part_distance(X[ia])
    T = icp(X[ia], cKDTree(Y[ib]), Y[ib], np.eye(4), 30)
    moved = transform_points(T, X[ia])
    d_ref, _ = part_distance(moved)
    offset = float(np.linalg.norm(moved - X[ia], axis=1).mean()) / diag
    ang = _angle_deg(T)
    own = Tolerance(tol.ratio, sym.slack, tol.min_angle_deg)
    holds = own.same(d, ref) or (own.same(d_ref, ref) and ang < tol.min_angle_deg)
    return DeclaredCheck(d, d_ref, ref, offset, ang, bool(holds))


@dataclass(frozen=True)
class PartSymmetry:
    """A rotation symmetry of one rigid part: ``kind`` "continuous" (every tested turn holds) or "discrete"
    (the half turn only), about ``axis (3,)`` through ``center (3,)`` (object frame at rest)."""

    part: int
    kind: str
    axis: tuple[float, float, float]
    center: tuple[float, float, float]
    distance: float
    reference: float


def part_symmetries(surface: Surface, rng: np.random.Generator, tol: Tolerance = Tolerance(),
                    angles_deg=(45.0, 90.0, 135.0, 180.0)) -> list[PartSymmetry]:
    """Rotation symmetries of each part about its principal axes through its area centroid (rest, object
    frame), by the mesh criterion of :class:`Tolerance` (distances in the instance's bbox diagonals)."""
    from scapo.ops.rigid import rotation_about_axis

    diag = surface.spec.bbox_diag
    out = []
    for p in range(surface.spec.num_parts):
        X = surface.points[surface.labels == p]
        if len(X) < 32:
            continue
        c = X.mean(0)
        _, vecs = np.linalg.eigh(np.cov((X - c).T))
        half = rng.permutation(len(X))
        A, B = X[half[: len(X) // 2]], X[half[len(X) // 2:]]
        tree_a, tree_b = cKDTree(A), cKDTree(B)
        far = tol.mesh_distance * diag
        ref = max(_share_far(A, tree_b, far), _share_far(B, tree_a, far))
        for k in range(3):
            axis = vecs[:, k]
            holds = []
            worst = 0.0
            for a in angles_deg:
                moved = transform_points(_about(rotation_about_axis(axis, np.radians(a)), c), A)
                d = max(_share_far(moved, tree_b, far), _share_far(B, cKDTree(moved), far))
                holds.append(tol.coincide(d))
                if a == 180.0:
                    worst = d
            if all(holds):
                out.append(PartSymmetry(p, "continuous", tuple(map(float, axis)), tuple(map(float, c)), worst, ref))
            elif holds[-1]:
                out.append(PartSymmetry(p, "discrete", tuple(map(float, axis)), tuple(map(float, c)), worst, ref))
    return out


# -------------------------------------------------------------------------------------------- views
def visible(points_cam: np.ndarray, K: np.ndarray, points_per_cell: int = 16, depth_slack: float = 0.01
            ) -> np.ndarray:
    """(N,) bool: the points of a dense surface sampling a pinhole camera sees (OpenCV frame, ``K (3, 3)``).

    The image is cut into square cells over the points' projected extent, about ``points_per_cell`` points per
    cell (so that a surface facing the camera leaves no empty cell for a farther one to show through); in each
    cell the points within ``depth_slack`` (m) of the nearest one are kept (a z-buffer with a tolerance for the
    surface's slope inside a cell). Points behind the camera are not visible."""
    bins = max(16, len(points_cam) // points_per_cell)
    z = points_cam[:, 2]
    ok = z > 1e-6
    uv = (points_cam[:, :2] / np.where(ok, z, 1.0)[:, None]) * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
    lo, hi = uv[ok].min(0), uv[ok].max(0)
    cell = max(float(np.sqrt(np.prod(np.maximum(hi - lo, 1.0)) / bins)), 1.0)
    ij = np.floor((uv - lo) / cell).astype(np.int64)
    key = ij[:, 0] * (int((hi[1] - lo[1]) / cell) + 2) + ij[:, 1]
    key = np.where(ok, key, -1)
    zmin = np.full(key.max() + 2, np.inf)
    np.minimum.at(zmin, key[ok], z[ok])
    return ok & (z <= zmin[np.maximum(key, 0)] + depth_slack)


@dataclass(frozen=True)
class ViewAmbiguity:
    """What one view leaves open (measurement 3); distances in bbox diagonals.

    Attributes:
        truth_one_sided / truth_two_sided: the truth's distances (observed -> full surface; observed <-> visible
            surface). best_one_sided / best_two_sided: the best map more than ``min_angle_deg`` from the truth.
        undeclared_one_sided / undeclared_two_sided: an undeclared map fits as well as the truth (by each criterion).
        declared: a declared symmetry fits as well as the truth (by the one-sided criterion).
        angle_deg: the rotation angle of the best undeclared map (one-sided).
    """

    truth_one_sided: float
    truth_two_sided: float
    best_one_sided: float
    best_two_sided: float
    undeclared_one_sided: bool
    undeclared_two_sided: bool
    declared: bool
    angle_deg: float


def view_ambiguity(sample: dict, surface: Surface, rng: np.random.Generator, tol: Tolerance = Tolerance(),
                   declared: tuple[Symmetry, ...] = (), icp_points: int = 256, iters: int = 25,
                   visible_iters: int = 8, visible_starts: int = 4, visible_points: int = 30_000) -> ViewAmbiguity:
    """Measurement 3 on one rendered sample (SPEC section 5 fields: ``points``, ``part_label``, ``part_pose``,
    ``joint_state``, ``T_cam_obj``, ``K``, ``bbox_diag``) against the instance's ``surface``.

    The model is the surface posed by the sample's ``part_pose`` (camera frame). The one-sided search starts from
    the 23 non-identity cube-group rotations (``iters`` ICP steps on ``icp_points`` observed points); the visible
    criterion refines the ``visible_starts`` best distinct end points (``visible_iters`` steps) on a subsample of
    ``visible_points`` model points. Raises ConfigError when the sample has fewer than 16 object points."""
    pts = np.asarray(sample["points"], dtype=np.float64)
    obs = pts[np.asarray(sample["part_label"]) >= 0]
    if len(obs) < 16:
        raise ConfigError(f"a view needs at least 16 object points to measure its ambiguity, got {len(obs)}")
    diag = float(sample["bbox_diag"])
    pose = np.asarray(sample["part_pose"], dtype=np.float64)
    Y = np.empty_like(surface.points)
    for p in range(len(pose)):
        m = surface.labels == p
        Y[m] = transform_points(pose[p], surface.points[m])
    K = np.asarray(sample["K"], dtype=np.float64)
    tree_y = cKDTree(Y)
    tree_obs = cKDTree(obs)
    sub = obs[rng.choice(len(obs), min(icp_points, len(obs)), replace=False)]
    truth1 = _mean_dist(obs, tree_y) / diag
    Yv = Y[rng.choice(len(Y), min(len(Y), visible_points), replace=False)]  # the visible criterion's model
    vis = Yv[visible(Yv, K)]
    truth2 = 0.5 * (_mean_dist(obs, cKDTree(vis)) + _mean_dist(vis, tree_obs)) / diag
    R_co = np.asarray(sample["T_cam_obj"], dtype=np.float64)[:3, :3]
    decl_cam = [declared_rotation(s, pose) for s in declared]
    c = 0.5 * (Y.min(0) + Y.max(0))
    best1, best2, ang_best = np.inf, np.inf, 0.0
    und1 = und2 = dec = False
    ends: list[np.ndarray] = []
    for G in rotation_group("O")[1:]:
        Rg = R_co @ G @ R_co.T
        # the object moved by M = about(Rg, c); ICP moves the observation by A = M^-1 onto the true surface
        A = icp(sub, tree_y, Y, invert_transform(_about(Rg, c)), iters)
        M = invert_transform(A)
        ang = _angle_deg(M)
        if ang <= tol.min_angle_deg:
            continue
        d1 = _mean_dist(transform_points(A, obs), tree_y) / diag
        is_decl = any(_angle_deg(M[:3, :3] @ D.T) < tol.min_angle_deg for D in decl_cam)
        if is_decl:
            dec = dec or tol.same(d1, truth1)
            continue
        if d1 < best1:
            best1, ang_best = d1, ang
        und1 = und1 or tol.same(d1, truth1)
        if any(_angle_deg(M[:3, :3] @ E[:3, :3].T) < 10.0 and np.linalg.norm(M[:3, 3] - E[:3, 3]) < 0.05 * diag
               for _, E in ends):
            continue
        ends.append((d1, M))
    ends.sort(key=lambda e: e[0])
    for _, M in ends[:visible_starts]:  # the visible-surface criterion, refined from the best distinct end points
        for _ in range(visible_iters):
            Ym = transform_points(M, Yv)
            V = Ym[visible(Ym, K)]
            tv = cKDTree(V)
            _, j = tv.query(obs)
            _, i = tree_obs.query(V)
            M_inv = invert_transform(M)
            src = np.concatenate([transform_points(M_inv, V[j]), transform_points(M_inv, V)])
            dst = np.concatenate([obs, obs[i]])
            M = umeyama(src, dst)[0]
        if _angle_deg(M) <= tol.min_angle_deg:
            continue
        Ym = transform_points(M, Yv)
        V = Ym[visible(Ym, K)]
        d2 = 0.5 * (_mean_dist(obs, cKDTree(V)) + _mean_dist(V, tree_obs)) / diag
        if any(_angle_deg(M[:3, :3] @ D.T) < tol.min_angle_deg for D in decl_cam):
            continue
        best2 = min(best2, d2)
        und2 = und2 or tol.same(d2, truth2)
    return ViewAmbiguity(truth1, truth2, float(best1), float(best2), und1, und2, dec, ang_best)


# ------------------------------------------------------------------------------------------- report
@dataclass
class SymmetryReport:
    """``scapo assets symmetry``'s result for one category (see the module docstring).

    Attributes:
        category, instances, views, seed: what was measured. declared: the declared symmetries (JSON form).
        self_maps: per instance and sampled state, the undeclared self-maps found (angle, distance, parts).
        declared_errors: per instance, the :class:`DeclaredCheck` of each declared symmetry.
        declared_hold: every declared symmetry held on every instance.
        part_symmetries: the part symmetries found (per instance).
        views_measured: rendered views measured. ambiguous_one_sided / ambiguous_two_sided: share of views that an
        undeclared map explains as well as the truth (each criterion). ambiguous_declared: share a declared one does.
        seconds: wall time.
    """

    category: str
    instances: int
    views: int
    seed: int
    declared: list = field(default_factory=list)
    self_maps: list = field(default_factory=list)
    declared_errors: list = field(default_factory=list)
    declared_hold: bool = True
    part_symmetries: list = field(default_factory=list)
    views_measured: int = 0
    ambiguous_one_sided: float = float("nan")
    ambiguous_two_sided: float = float("nan")
    ambiguous_declared: float = float("nan")
    per_view: list = field(default_factory=list)
    seconds: float = 0.0

    def to_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        """Human-readable summary."""
        out = [f"{self.category}: {self.instances} instances, seed {self.seed}"]
        out.append(f"  declared symmetries: {len(self.declared) or 'none'}"
                   + ("" if not self.declared else f" (hold on the meshes: {'yes' if self.declared_hold else 'NO'})"))
        for k, d in enumerate(self.declared):
            errs = [e["errors"][k] for e in self.declared_errors if len(e["errors"]) > k]
            out.append(f"    {k}: rotation {np.round(np.asarray(d['rotation']), 3).tolist()} about "
                       f"{d.get('center', 'origin')}, parts {d['parts']}, joints {d['joints']}, stated slack "
                       f"{d.get('slack', 0.004)}")
            if errs:
                out.append(f"       on the meshes: distance max {max(e['distance'] for e in errs):.4f}, refined max "
                           f"{max(e['refined'] for e in errs):.4f} (resampling "
                           f"{max(e['reference'] for e in errs):.4f});"
                           f" twin position error (refinement's offset) max {max(e['offset'] for e in errs):.4f}, "
                           f"turn max {max(e['angle_deg'] for e in errs):.1f} deg; holds on "
                           f"{sum(e['holds'] for e in errs)} of {len(errs)} instances")
            if d.get("note"):
                out.append(f"       {d['note']}")
        n_states = len(self.self_maps)
        with_map = sum(1 for s in self.self_maps if s["maps"])
        out.append(f"  undeclared self-maps of the posed meshes: {with_map} of {n_states} instance states")
        for s in self.self_maps:
            for m in s["maps"]:
                out.append(f"    instance {s['instance']} state {np.round(s['state'], 2).tolist()}: turn "
                           f"{m['angle_deg']:.0f} deg, {100 * m['distance']:.1f} % of the surface off (resampling "
                           f"{100 * m['reference']:.1f} %), parts -> {m['parts']}")
        out.append(f"  part symmetries: {len(self.part_symmetries) or 'none'}")
        for ps in self.part_symmetries:
            out.append(f"    instance {ps['instance']} part {ps['part']}: {ps['kind']} about "
                       f"{np.round(ps['axis'], 2).tolist()}")
        if self.views_measured:
            out.append(f"  views ambiguous under undeclared maps ({self.views_measured} views): "
                       f"{100 * self.ambiguous_one_sided:.1f} % (full surface, one-sided), "
                       f"{100 * self.ambiguous_two_sided:.1f} % (visible surface, two-sided)")
            if self.declared:
                out.append(f"  views a declared symmetry explains: {100 * self.ambiguous_declared:.1f} %")
        out.append(f"  ({self.seconds:.0f} s)")
        return out


def declared_symmetries(category: str) -> tuple[Symmetry, ...]:
    """The declared symmetries of a procedural category (none: an empty tuple)."""
    s = SYMMETRIES.get(category)
    return () if s is None else (s,)


def measure_meshes(category: str, instances: int = 4, states: int = 3, seed: int = 5, spacing: float = 0.012,
                   tol: Tolerance = Tolerance(), cache_dir=None, report: SymmetryReport | None = None,
                   progress=None, icp_points: int = 1500) -> SymmetryReport:
    """Measurements 1 and 2 on procedural instances ``0 .. instances-1`` of ``category`` (built with ``seed``),
    each at ``states`` joint states drawn uniformly in its limits (the first is the rest state); surfaces sampled at
    ``spacing`` bbox diagonals (:func:`surface_count`; the resampling reference, and so the tolerance, shrink with
    it: a sparse sampling hides features smaller than its spacing). ``icp_points``: the points of one half-sampling
    that each self-map's ICP moves (:func:`object_self_maps`; whether a map coincides is judged on all points).

    Raises:
        UnknownNameError: an unknown category. ConfigError: instances or states < 1, icp_points < 3.
    """
    import time

    from scapo.sim.assets import build_instance, parse_urdf

    if instances < 1 or states < 1:
        raise ConfigError(f"instances and states must be >= 1, got {instances} and {states}")
    if icp_points < 3:
        raise ConfigError(f"icp_points must be >= 3 (a rigid fit needs three points), got {icp_points}")
    t0 = time.time()
    rep = report or SymmetryReport(category, instances, 0, seed)
    decl = declared_symmetries(category)
    rep.declared = [s.to_dict() for s in decl]
    rng = np.random.default_rng([seed, 29])
    for i in range(instances):
        spec = parse_urdf(build_instance(category, i, seed, cache_dir).urdf, category=category)
        surf = sample_surface(spec, surface_count(spec, spacing), rng)
        lim = spec.joint_limit
        for k in range(states):
            q = np.zeros(spec.num_joints) if k == 0 else rng.uniform(lim[:, 0], lim[:, 1])
            maps = [m for m in object_self_maps(surf, q, rng, tol, decl, icp_points=icp_points)
                    if not m.declared]
            rep.self_maps.append({"instance": i, "state": q.tolist(), "maps": [
                {"angle_deg": m.angle_deg, "distance": m.distance, "reference": m.reference, "parts": list(m.parts),
                 "rotation": m.T[:3, :3].tolist()} for m in maps]})

        errs = []
        for s in decl:
            chk = declared_symmetry_error(surf, s, rng, tol)
            errs.append(asdict(chk))
            rep.declared_hold = rep.declared_hold and chk.holds
        rep.declared_errors.append({"instance": i, "errors": errs})
        for ps in part_symmetries(surf, rng, tol):
            rep.part_symmetries.append({"instance": i, **asdict(ps)})
        if progress is not None:
            progress(1)
    rep.seconds += time.time() - t0
    return rep


def surface_count(spec: ArticulationSpec, spacing: float = 0.005, cap: int = 250_000) -> int:
    """Surface points for a mean spacing of ``spacing`` rest bbox diagonals over all part meshes (at most ``cap``):
    the model's own sampling then adds about ``spacing / 2`` to every distance, whatever the object's size."""
    area = sum(load_part_mesh(spec, p).area for p in range(spec.num_parts))
    return int(min(cap, max(1000, area / (spacing * spec.bbox_diag) ** 2)))


def measure_views(category: str, instances: int = 10, views: int = 10, seed: int = 5, points: int = 1024,
                  random_rotation: bool = False, tol: Tolerance = Tolerance(), spacing: float = 0.005,
                  data_dir=None, cache_dir=None, report: SymmetryReport | None = None, progress=None
                  ) -> SymmetryReport:
    """Measurement 3: render ``instances x views`` samples of ``category`` (a dataset in ``data_dir``, by default
    ``$SCAPO_CACHE/symmetry/<category>-...``; reused when present) and measure each view's ambiguity against the
    instance's surface sampled at ``spacing`` bbox diagonals (:func:`surface_count`).

    Raises:
        UnknownNameError: an unknown category. RenderError: no Vulkan device (see ``scapo doctor``).
    """
    import os
    import time
    from pathlib import Path

    from scapo.data.config import make_config
    from scapo.data.dataset import load
    from scapo.data.generate import generate, instance_asset_path, load_instance

    t0 = time.time()
    rep = report or SymmetryReport(category, instances, views, seed)
    rep.views = views
    cfg = make_config(category, instances, views, seed, num_points=points, test_fraction=0.0, val_fraction=0.0,
                      random_rotation=random_rotation)
    if data_dir is None:
        root = Path(os.environ.get("SCAPO_CACHE") or Path.home() / ".cache" / "scapo") / "symmetry"
        data_dir = root / f"{category}-i{instances}-v{views}-s{seed}-n{points}{'-rot' if random_rotation else ''}"
    generate(cfg, Path(data_dir), workers=1, progress=False, cache_dir=cache_dir)
    ds = load(data_dir, "train")
    decl = declared_symmetries(category)
    rep.declared = [s.to_dict() for s in decl]
    rng = np.random.default_rng([seed, 30])
    surfaces: dict[int, Surface] = {}
    rows = []
    for k in range(len(ds)):
        s = ds[k]
        inst = int(s["instance_id"])
        if inst not in surfaces:
            spec = load_instance(cfg, instance_asset_path(cfg, Path(data_dir), inst, cache_dir))
            surfaces[inst] = sample_surface(spec, surface_count(spec, spacing), rng)
        s = {key: (v.numpy() if hasattr(v, "numpy") else v) for key, v in s.items()}
        a = view_ambiguity(s, surfaces[inst], rng, tol, decl)
        rows.append({"instance": inst, "view": int(s["view_id"]), **asdict(a)})
        if progress is not None:
            progress(1)
    rep.per_view = rows
    rep.views_measured = len(rows)
    rep.ambiguous_one_sided = float(np.mean([r["undeclared_one_sided"] for r in rows]))
    rep.ambiguous_two_sided = float(np.mean([r["undeclared_two_sided"] for r in rows]))
    rep.ambiguous_declared = float(np.mean([r["declared"] for r in rows]))
    rep.seconds += time.time() - t0
    return rep
