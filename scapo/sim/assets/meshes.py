"""Watertight mesh primitives for the procedural generators (built on trimesh).

All functions return :class:`trimesh.Trimesh` in metres with outward-facing triangles (the
renderer culls back faces, so winding matters). Axes are given as "x", "y" or "z".
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

_AXES = {"x": np.array([1.0, 0.0, 0.0]), "y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}


def _align_z_to(axis: str) -> np.ndarray:
    """4x4 rotation taking +z to the named axis."""
    if axis == "z":
        return np.eye(4)
    if axis == "x":
        return trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    if axis == "y":
        return trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
    raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")


def box(extents: Sequence[float], center: Sequence[float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Axis-aligned box with full side lengths ``extents`` (3,) centred at ``center``."""
    m = trimesh.creation.box(extents=np.asarray(extents, dtype=np.float64))
    m.apply_translation(center)
    return m


def box_between(lo: Sequence[float], hi: Sequence[float]) -> trimesh.Trimesh:
    """Axis-aligned box spanning the corners ``lo`` and ``hi``."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return box(np.abs(hi - lo), (lo + hi) / 2)


def cylinder(
    radius: float, length: float, center: Sequence[float], axis: str = "z", sections: int = 24
) -> trimesh.Trimesh:
    """Closed cylinder of ``radius`` and ``length`` along ``axis`` centred at ``center``."""
    m = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    m.apply_transform(_align_z_to(axis))
    m.apply_translation(center)
    return m


def torus(
    major: float,
    minor: float,
    center: Sequence[float],
    axis: str = "z",
    scale: Sequence[float] = (1.0, 1.0, 1.0),
    sections: tuple[int, int] = (32, 10),
) -> trimesh.Trimesh:
    """Ring with centre-line radius ``major`` and tube radius ``minor`` around ``axis``.

    ``scale`` stretches the ring (before orienting it) to make ovals.
    """
    m = trimesh.creation.torus(major_radius=major, minor_radius=minor,
                               major_sections=sections[0], minor_sections=sections[1])
    m.apply_scale(np.asarray(scale, dtype=np.float64))
    m.apply_transform(_align_z_to(axis))
    m.apply_translation(center)
    return m


def hull(points: np.ndarray) -> trimesh.Trimesh:
    """Convex hull of ``points (M, 3)`` (wedges, tapered blades, slanted walls)."""
    return trimesh.Trimesh(vertices=np.asarray(points, dtype=np.float64)).convex_hull


def tube(
    path: np.ndarray, radius: float, sections: int = 10, closed: bool = False,
    profile: np.ndarray | None = None, normal0: Sequence[float] | None = None,
) -> trimesh.Trimesh:
    """Tube of ``radius`` swept along the polyline ``path (M, 3)``.

    Frames are propagated along the path (parallel transport), so the tube does not twist.
    Open tubes get flat end caps; ``closed=True`` joins the last ring to the first (loops).
    ``profile (K, 2)`` replaces the circular cross-section (coordinates along the frame's normal
    and binormal, metres, counter-clockwise); ``normal0`` fixes the first frame's normal.

    Raises:
        ValueError: for fewer than 2 path points or repeated consecutive points.
    """
    path = np.asarray(path, dtype=np.float64)
    if path.ndim != 2 or path.shape[1] != 3 or len(path) < 2:
        raise ValueError(f"tube path must be (M>=2, 3), got {path.shape}")
    seg = np.diff(path, axis=0)
    if closed:
        seg = np.vstack([seg, path[:1] - path[-1:]])
    if np.any(np.linalg.norm(seg, axis=1) < 1e-9):
        raise ValueError("tube path has repeated consecutive points")
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    if closed:
        tangents = seg + np.roll(seg, 1, axis=0)
    else:
        tangents = np.vstack([seg[:1], seg[:-1] + seg[1:], seg[-1:]])
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    if normal0 is not None:
        n = np.asarray(normal0, dtype=np.float64)
    else:
        ref = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        n = np.cross(tangents[0], ref)
    n = n - tangents[0] * (n @ tangents[0])
    n /= np.linalg.norm(n)
    if profile is None:
        angles = 2 * np.pi * np.arange(sections) / sections
        profile = radius * np.stack([np.cos(angles), np.sin(angles)], 1)
    profile = np.asarray(profile, dtype=np.float64)
    sections = len(profile)
    rings = []
    for t in tangents:
        n = n - t * (n @ t)
        n /= np.linalg.norm(n)
        b = np.cross(t, n)
        rings.append(profile[:, :1] * n + profile[:, 1:] * b)
    M = len(path)
    verts = (path[:, None, :] + np.asarray(rings)).reshape(-1, 3)
    faces = []
    k = np.arange(sections)
    k1 = (k + 1) % sections
    n_links = M if closed else M - 1
    for i in range(n_links):
        j = (i + 1) % M
        a, b_, c, d = i * sections + k, i * sections + k1, j * sections + k1, j * sections + k
        faces.append(np.stack([a, b_, c], 1))
        faces.append(np.stack([a, c, d], 1))
    if not closed:
        c0, c1 = len(verts), len(verts) + 1
        verts = np.vstack([verts, path[0], path[-1]])
        faces.append(np.stack([np.full(sections, c0), k1, k], 1))
        last = (M - 1) * sections
        faces.append(np.stack([np.full(sections, c1), last + k, last + k1], 1))
    m = trimesh.Trimesh(vertices=verts, faces=np.vstack(faces), process=True)
    trimesh.repair.fix_normals(m)
    return m


def ellipse_path(
    center: Sequence[float], radii: tuple[float, float], plane: str = "yz", count: int = 40,
    squareness: float = 0.0,
) -> np.ndarray:
    """Closed loop of ``count`` points (no repeated end) around ``center`` in ``plane``.

    ``squareness`` in [0, 1) morphs the ellipse towards a rounded rectangle (superellipse).
    """
    u = 2 * np.pi * np.arange(count) / count
    p = 2.0 / (1.0 - squareness) if squareness > 0 else 2.0
    c, s = np.cos(u), np.sin(u)
    a = np.sign(c) * np.abs(c) ** (2.0 / p) * radii[0]
    b = np.sign(s) * np.abs(s) ** (2.0 / p) * radii[1]
    out = np.zeros((count, 3))
    i, j = ("xyz".index(plane[0]), "xyz".index(plane[1]))
    out[:, i], out[:, j] = a, b
    return out + np.asarray(center, dtype=np.float64)


def hollow_box(
    extents: Sequence[float], wall: float, open_face: str, center: Sequence[float] = (0.0, 0.0, 0.0)
) -> list[trimesh.Trimesh]:
    """Five wall slabs of a box with outer ``extents`` whose ``open_face`` ("-x", "+z", ...) is missing."""
    ex = np.asarray(extents, dtype=np.float64)
    c = np.asarray(center, dtype=np.float64)
    lo, hi = c - ex / 2, c + ex / 2
    walls = []
    for ax in range(3):
        for sign, name in ((-1, "-"), (1, "+")):
            if open_face == f"{name}{'xyz'[ax]}":
                continue
            wlo, whi = lo.copy(), hi.copy()
            if sign < 0:
                whi[ax] = lo[ax] + wall
            else:
                wlo[ax] = hi[ax] - wall
            walls.append(box_between(wlo, whi))
    if len(walls) != 5:
        raise ValueError(f"open_face must be one of -x,+x,-y,+y,-z,+z, got {open_face!r}")
    return walls


def merge(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate meshes into one (no boolean union; overlapping solids are fine for rendering)."""
    if not meshes:
        raise ValueError("merge needs at least one mesh")
    return trimesh.util.concatenate(list(meshes))


def to_obj_bytes(mesh: trimesh.Trimesh) -> bytes:
    """Deterministic Wavefront OBJ bytes (trimesh's exporter; 6 decimals, i.e. 1 um; no normals)."""
    text = trimesh.exchange.obj.export_obj(
        mesh, include_normals=False, include_color=False, include_texture=False, digits=6,
        header="scapo procedural mesh",
    )
    return text.replace("-0.000000", "0.000000").encode()
