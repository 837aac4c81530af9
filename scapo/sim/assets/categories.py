"""Procedural generators of the nine benchmark categories (SPEC section 4).

Each generator takes a :class:`ParamSampler` (ranges and styles from
``scapo/sim_assets/categories/<name>.toml``) and returns an :class:`ArticulatedDesign` in the object
frame at rest: +z up, front facing -x. Positive joint states open the object (screen back,
door out, drawer out, temples open, handles up, blades apart, lid up). The design is centred on
its bounding box afterwards by :func:`scapo.sim.assets.design.finalize`.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from scapo.registry import Registry
from scapo.sim.assets.design import ArticulatedDesign, JointDesign, PartDesign
from scapo.sim.assets.meshes import (
    box,
    box_between,
    cylinder,
    ellipse_path,
    hollow_box,
    hull,
    torus,
    tube,
)
from scapo.sim.assets.templates import ParamSampler

Generator = Callable[[ParamSampler], ArticulatedDesign]

#: Registry of category generators; ``CATEGORIES.get(name)`` raises listing the known names.
CATEGORIES: Registry[Generator] = Registry("category")

Y = (0.0, 1.0, 0.0)
Z = (0.0, 0.0, 1.0)


def _assemble(ps: ParamSampler, parts: dict[str, list], joints: dict[str, tuple], scales: dict | None = None):
    """Build the design from part meshes and ``joints[name] = (axis, origin)``; limits from the template."""
    tpl = ps.template
    if set(parts) != set(tpl.parts):
        raise ValueError(f"{tpl.name}: generator parts {sorted(parts)} != template parts {sorted(tpl.parts)}")
    jd = []
    for jt in tpl.joints:
        axis, origin = joints[jt.name]
        lo, hi = jt.range
        if jt.range_scale:
            s = (scales or {})[jt.range_scale]
            lo, hi = round(lo * s, 6), round(hi * s, 6)
        jd.append(JointDesign(jt.name, jt.type, jt.parent, jt.child, tuple(axis), tuple(origin), (lo, hi)))
    unused = ps.unused()
    if unused:
        raise ValueError(f"{tpl.name}: template entries never used by the generator: {unused}")
    return ArticulatedDesign(
        tpl.name, [PartDesign(n, parts[n]) for n in tpl.parts], jd, dict(sorted(ps.values.items()))
    )


@CATEGORIES.register("laptop")
def laptop(ps: ParamSampler) -> ArticulatedDesign:
    """Base slab with keyboard deck; screen hinged at the rear edge (rest: 90 deg opening)."""
    W, D = ps.u("width"), ps.u("depth")
    tb, ts = ps.u("base_thickness"), ps.u("screen_thickness")
    H, Ws = ps.u("screen_height_ratio") * D, ps.u("screen_width_ratio") * W
    inset, hh = ps.u("hinge_inset"), ps.u("hinge_height")
    dw, dd = ps.u("deck_width_ratio"), ps.u("deck_depth_ratio")
    hinge, deck, bezel = ps.choice("hinge"), ps.choice("deck"), ps.choice("bezel")
    pivot = np.array([D / 2 - inset, 0.0, tb + hh])
    base = [box((D, W, tb), (0, 0, tb / 2))]
    if deck != "flat":
        kd = dd * D
        base.append(box((kd, dw * W, 0.0015), (D / 2 - inset - 0.02 - kd / 2, 0, tb + 0.00075)))
    if deck == "keyboard_touchpad":
        tp = 0.3 * D
        base.append(box((0.45 * tp, tp * 1.4, 0.001), (-D / 2 + 0.02 + 0.225 * tp, 0, tb + 0.0005)))
    if hinge == "barrel":
        base.append(cylinder(max(ts, 0.006) * 0.75, 0.7 * W, pivot, axis="y"))
    screen = [box((ts, Ws, H), pivot + (0, 0, H / 2))]
    if bezel == "panel":
        screen.append(box((0.001, 0.92 * Ws, 0.84 * H), pivot + (-ts / 2 - 0.0005, 0, 0.53 * H)))
    return _assemble(ps, {"base": base, "screen": screen}, {"hinge": (Y, pivot)})


@CATEGORIES.register("safe")
def safe(ps: ParamSampler) -> ArticulatedDesign:
    """Thick-walled box; front door on a vertical hinge at its -y edge."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, td, g, ho = ps.u("wall"), ps.u("door_thickness"), ps.u("door_gap"), ps.u("hinge_offset")
    dial_r, hl = ps.u("dial_radius"), ps.u("handle_length")
    handle, panel, feet = ps.choice("handle"), ps.choice("panel"), ps.choice("feet")
    body = hollow_box((D, W, H), wt, "-x", (0, 0, H / 2))
    if feet == "feet":
        for sx in (-1, 1):
            for sy in (-1, 1):
                body.append(box((0.04, 0.04, 0.02), (sx * (D / 2 - 0.03), sy * (W / 2 - 0.03), -0.01)))
    xf = -D / 2 - td  # front face of the door
    pivot = np.array([-D / 2 - td / 2, -W / 2 + g - ho, H / 2])
    for zc in (0.2 * H, 0.8 * H):
        body.append(cylinder(0.008, 0.06, (pivot[0], pivot[1], zc), axis="z"))
    door = [box_between((xf, -W / 2 + g, g), (-D / 2, W / 2 - g, H - g))]
    ys = W / 2 - g - 0.25 * W  # features on the free side
    if panel in ("dial", "dial_keypad"):
        door.append(cylinder(dial_r, 0.015, (xf - 0.0075, ys * 0.3, 0.62 * H), axis="x"))
    if panel in ("keypad", "dial_keypad"):
        door.append(box((0.008, 0.07, 0.09), (xf - 0.004, ys * 0.3, 0.35 * H)))
    hz = 0.5 * H
    if handle == "lever":
        door.append(cylinder(0.008, 0.03, (xf - 0.015, ys, hz), axis="x"))
        door.append(box((0.014, hl, 0.02), (xf - 0.035, ys - hl / 2 + 0.01, hz)))
    elif handle == "wheel":
        door.append(cylinder(0.01, 0.04, (xf - 0.02, ys, hz), axis="x"))
        door.append(torus(hl / 2, 0.006, (xf - 0.04, ys, hz), axis="x"))
        for a in (0.0, np.pi / 3, 2 * np.pi / 3):
            c, s = np.cos(a) * hl / 2, np.sin(a) * hl / 2
            door.append(box((0.008, max(abs(2 * c), 0.008), max(abs(2 * s), 0.008)), (xf - 0.04, ys, hz)))
    else:
        for dz in (-hl / 2 + 0.01, hl / 2 - 0.01):
            door.append(cylinder(0.007, 0.03, (xf - 0.015, ys, hz + dz), axis="x"))
        door.append(cylinder(0.01, hl, (xf - 0.03, ys, hz), axis="z"))
    return _assemble(ps, {"body": body, "door": door}, {"door_hinge": (Z, pivot)})


@CATEGORIES.register("oven")
def oven(ps: ParamSampler) -> ArticulatedDesign:
    """Body with a front cavity, control panel and knobs; drop-down door hinged at its bottom edge."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, td, zb = ps.u("wall"), ps.u("door_thickness"), ps.u("door_bottom")
    Hd = ps.u("door_height_ratio") * (H - zb)
    so, kr = ps.u("handle_standoff"), ps.u("knob_radius")
    nk, handle, window = int(ps.choice("knobs")), ps.choice("handle"), ps.choice("window")
    body = hollow_box((D, W, Hd), wt, "-x", (0, 0, zb + Hd / 2))
    ztop = zb + Hd
    body.append(box((D, W, H - ztop), (0, 0, (ztop + H) / 2)))
    if zb > 0.002:
        body.append(box((D - 0.03, W, zb), (0.015, 0, zb / 2)))
    zk = (ztop + H) / 2
    for y in np.linspace(-0.35 * W, 0.35 * W, nk):
        body.append(cylinder(kr, 0.02, (-D / 2 - 0.01, y, zk), axis="x"))
    xf = -D / 2 - td
    door = [box_between((xf, -W / 2 + 0.004, zb), (-D / 2, W / 2 - 0.004, ztop - 0.003))]
    if window == "window":
        door.append(box((0.002, 0.6 * W, 0.42 * Hd), (xf - 0.001, 0, zb + 0.5 * Hd)))
    hz = ztop - 0.06
    if handle == "bar":
        for y in (-0.35 * W, 0.35 * W):
            door.append(cylinder(0.007, so, (xf - so / 2, y, hz), axis="x"))
        door.append(cylinder(0.011, 0.8 * W, (xf - so, 0, hz), axis="y"))
    else:
        door.append(box((so, 0.8 * W, 0.02), (xf - so / 2, 0, ztop - 0.013)))
    pivot = np.array([-D / 2 - td / 2, 0.0, zb])
    return _assemble(ps, {"body": body, "door": door}, {"door_hinge": ((0.0, -1.0, 0.0), pivot)})


@CATEGORIES.register("washer")
def washer(ps: ParamSampler) -> ArticulatedDesign:
    """Front loader: body with slanted control panel; round door hinged on a vertical line."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    R = ps.u("door_radius_ratio") * W
    td, zc = ps.u("door_thickness"), ps.u("door_height_ratio") * H
    hg, ph, kr = ps.u("hinge_gap"), ps.u("panel_height"), ps.u("knob_radius")
    rim, porthole, knob = ps.choice("rim"), ps.choice("porthole"), ps.choice("knob")
    zp = H - ph
    body = [box((D, W, zp), (0, 0, zp / 2))]
    corners = np.array([[sx, sy, sz] for sx in (-D / 2, D / 2) for sy in (-W / 2, W / 2) for sz in (zp, H)])
    corners[(corners[:, 0] < 0) & (corners[:, 2] > zp), 0] += 0.04  # slanted control panel
    body.append(hull(corners))
    if knob == "knob":
        body.append(cylinder(kr, 0.025, (-D / 2 + 0.01, 0.3 * W, zp + 0.45 * ph), axis="x"))
        body.append(box((0.01, 0.18 * W, 0.4 * ph), (-D / 2 + 0.015, -0.15 * W, zp + 0.5 * ph)))
    ring_t = 0.012
    if porthole == "ring":
        body.append(torus(1.06 * R, ring_t, (-D / 2, 0, zc), axis="x"))
    x0 = -D / 2 - (ring_t + 0.002 if porthole == "ring" else 0.002)  # back face of the door
    door = [cylinder(R, td, (x0 - td / 2, 0, zc), axis="x", sections=40)]
    if rim == "ring":
        door.append(torus(0.92 * R, 0.35 * td, (x0 - td, 0, zc), axis="x", sections=(40, 10)))
    door.append(box((0.03, 0.06, 0.12 * R + 0.03), (x0 - td - 0.01, 0.85 * R, zc)))
    pivot = np.array([x0 - td / 2, -R - hg, zc])
    door.append(box_between((x0 - td * 0.8, -R - hg - 0.01, zc - 0.05), (x0 - td * 0.2, -R + 0.02, zc + 0.05)))
    return _assemble(ps, {"body": body, "door": door}, {"door_hinge": (Z, pivot)})


@CATEGORIES.register("eyeglasses")
def eyeglasses(ps: ParamSampler) -> ArticulatedDesign:
    """Front frame (rims, bridge, end pieces); temples fold about vertical hinges (rest: folded)."""
    lw, lh, br = ps.u("lens_width"), ps.u("lens_height"), ps.u("bridge")
    rr, ep, tl = ps.u("rim_radius"), ps.u("end_piece_length"), ps.u("temple_length")
    th, tw = ps.u("temple_height"), ps.u("temple_width")
    lens, tip, shape = ps.choice("lens"), ps.choice("temple_tip"), ps.choice("rim_shape")
    radii = {"oval": (lw / 2, lh / 2), "round": (lw / 2, min(lh, lw) / 2 * 1.05), "rect": (lw / 2, lh / 2)}[shape]
    square = 0.6 if shape == "rect" else 0.0
    frame = []
    for sy in (-1, 1):
        c = (0.0, sy * (br / 2 + lw / 2), 0.0)
        loop = ellipse_path(c, radii, plane="yz", count=48, squareness=square)
        frame.append(tube(loop, rr, sections=8, closed=True))
        if lens == "lens":
            pts = ellipse_path(c, (radii[0] * 0.98, radii[1] * 0.98), plane="yz", count=48, squareness=square)
            frame.append(hull(np.vstack([pts + (0.0008, 0, 0), pts - (0.0008, 0, 0)])))
    u = np.linspace(0, np.pi, 9)
    bridge = np.stack([np.zeros_like(u), -np.cos(u) * (br / 2 + rr), 0.25 * radii[1] + 0.004 * np.sin(u)], 1)
    frame.append(tube(bridge, rr, sections=8))
    yh = br / 2 + lw + rr  # hinge line, |y|
    zh = 0.2 * radii[1]
    for sy in (-1, 1):
        frame.append(box_between((-rr, sy * yh - 0.002, zh - th / 2), (ep, sy * yh + 0.0015, zh + th / 2)))
    temples = {}
    for name, sy, off in (("left_temple", 1, 1.5 * tw + 0.0008), ("right_temple", -1, 0.5 * tw + 0.0003)):
        # at rest the temple lies along -sy*y behind the frame; ``off`` stacks the two folded temples
        y0, y1 = sy * yh, sy * yh - sy * tl * (0.78 if tip == "bent" else 1.0)
        meshes = [box_between((ep + off - tw / 2, min(y0, y1), zh - th / 2),
                              (ep + off + tw / 2, max(y0, y1), zh + th / 2))]
        meshes.append(cylinder(0.0018, th * 1.1, (ep, sy * yh, zh), axis="z", sections=12))
        meshes.append(box_between((ep, sy * yh - 0.0015, zh - th / 2),
                                  (ep + off + tw / 2, sy * yh + 0.0015, zh + th / 2)))
        if tip == "bent":
            y2 = sy * yh - sy * tl
            drop = 0.22 * tl * np.sin(np.radians(30))
            pts = [(ep + off + dx, y, z + dz) for dx in (-tw / 2, tw / 2) for (y, z) in ((y1, zh), (y2, zh - drop))
                   for dz in (-th / 2, th / 2)]
            meshes.append(hull(np.array(pts)))
        temples[name] = meshes
    joints = {
        "left_hinge": (Z, (ep, yh, zh)),
        "right_hinge": ((0.0, 0.0, -1.0), (ep, -yh, zh)),
    }
    return _assemble(ps, {"frame": frame, **temples}, joints)


def _arch(L: float, h: float, square: bool, count: int = 17) -> np.ndarray:
    """Handle centre-line in its pivot plane: ends at (0, +-L/2), apex at (-h, 0); columns (out, y)."""
    u = np.linspace(0, np.pi, count)
    p = 0.25 if square else 1.0  # exponent < 1 squares the arch
    out = -h * np.abs(np.sin(u)) ** p
    y = (L / 2) * np.sign(np.cos(u)) * np.abs(np.cos(u)) ** p
    return np.stack([out, y], 1)


@CATEGORIES.register("basket")
def basket(ps: ParamSampler) -> ArticulatedDesign:
    """Tapered open container; arched handles pivot on the front and back rim (rest: folded out)."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, taper = ps.u("wall"), ps.u("taper")
    L, hh, po = ps.u("handle_span_ratio") * W, ps.u("handle_height"), ps.u("pivot_offset")
    hw, ht = ps.u("handle_width"), ps.u("handle_thickness")
    style, rim = ps.choice("handle"), ps.choice("rim")
    bx, by = taper * D / 2, taper * W / 2
    body = [box((2 * bx, 2 * by, wt), (0, 0, wt / 2))]
    for ax in (0, 1):
        for s in (-1, 1):
            pts = []
            for z, (hx, hy) in ((0.0, (bx, by)), (H, (D / 2, W / 2))):
                for inner in (0.0, wt):
                    if ax == 0:
                        pts += [(s * (hx - inner), y, z) for y in (-hy, hy)]
                    else:
                        pts += [(x, s * (hy - inner), z) for x in (-hx, hx)]
            body.append(hull(np.array(pts)))
    if rim == "thick":
        loop = ellipse_path((0, 0, H), (D / 2 - wt / 2, W / 2 - wt / 2), plane="xy", count=48, squareness=0.85)
        body.append(tube(loop, 1.2 * wt, sections=8, closed=True))
    arch = _arch(L, hh, style == "square")
    parts, joints = {"body": body}, {}
    handles = (("handle_a", "handle_a_pivot", -1, Y), ("handle_b", "handle_b_pivot", 1, (0.0, -1.0, 0.0)))
    for name, jname, sx, axis in handles:
        xp = sx * (D / 2 + po)
        path = np.stack([xp - sx * arch[:, 0], arch[:, 1], np.full(len(arch), H)], 1)
        # flat strap: broad side (hw) across the arch plane, thickness (ht) within it
        strap = np.array([[-hw / 2, -ht / 2], [hw / 2, -ht / 2], [hw / 2, ht / 2], [-hw / 2, ht / 2]])
        meshes = [tube(path, 0.0, profile=strap, normal0=Z)]
        for sy in (-1, 1):
            meshes.append(cylinder(0.6 * hw, 0.012, (xp, sy * L / 2, H), axis="y", sections=16))
            body.append(box((0.02, 0.008, 0.03), (xp - sx * 0.004, sy * (L / 2 + 0.01), H - 0.01)))
        parts[name] = meshes
        joints[jname] = (axis, (xp, 0.0, H))
    return _assemble(ps, parts, joints)


@CATEGORIES.register("drawer")
def drawer(ps: ParamSampler) -> ArticulatedDesign:
    """Cabinet carcass open at the front and one drawer sliding out along -x."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, tf, g = ps.u("wall"), ps.u("front_thickness"), ps.u("gap")
    ddr, thr, hwr = ps.u("drawer_depth_ratio"), ps.u("tray_height_ratio"), ps.u("handle_width_ratio")
    front, handle, top = ps.choice("front"), ps.choice("handle"), ps.choice("top")
    cabinet = hollow_box((D, W, H), wt, "-x", (0, 0, H / 2))
    if top == "overhang":
        cabinet.append(box((D + 0.02, W + 0.03, wt), (-0.01, 0, H + wt / 2)))
    if front == "overlay":
        lo, hi = (-D / 2 - tf, -W / 2 + g, g), (-D / 2, W / 2 - g, H - g)
        x_back_of_front = -D / 2
    else:
        lo, hi = (-D / 2, -W / 2 + wt + g, wt + g), (-D / 2 + tf, W / 2 - wt - g, H - wt - g)
        x_back_of_front = -D / 2 + tf
    x_front = lo[0]
    drawer_parts = [box_between(lo, hi)]
    Dd = ddr * (D / 2 - wt - x_back_of_front)
    Wt, Ht = W - 2 * wt - 2 * g, thr * (H - 2 * wt - 2 * g)
    drawer_parts += hollow_box((Dd, Wt, Ht), 0.008, "+z", (x_back_of_front + Dd / 2, 0, wt + g + Ht / 2))
    zc = (lo[2] + hi[2]) / 2
    if handle == "bar":
        hw = hwr * W
        for y in (-hw / 2 + 0.01, hw / 2 - 0.01):
            drawer_parts.append(cylinder(0.005, 0.025, (x_front - 0.0125, y, zc), axis="x", sections=12))
        drawer_parts.append(cylinder(0.007, hw, (x_front - 0.025, 0, zc), axis="y", sections=16))
    elif handle == "knob":
        drawer_parts.append(cylinder(0.012, 0.025, (x_front - 0.0125, 0, zc), axis="x", sections=20))
    else:
        drawer_parts.append(box((0.02, hwr * W, 0.012), (x_front - 0.01, 0, hi[2] - 0.006)))
    parts = {"cabinet": cabinet, "drawer": drawer_parts}
    return _assemble(ps, parts, {"slide": ((-1.0, 0.0, 0.0), (x_front, 0.0, zc))}, {"drawer_depth": Dd})


@CATEGORIES.register("scissors")
def scissors(ps: ParamSampler) -> ArticulatedDesign:
    """Two stacked blades with finger rings, crossing at the screw (rest: closed)."""
    Lb, wb, t = ps.u("blade_length"), ps.u("blade_width"), ps.u("thickness")
    Lh, Rr, rt = ps.u("handle_length"), ps.u("ring_radius"), ps.u("ring_tube")
    ro, sr = ps.u("ring_offset"), ps.u("screw_radius")
    tip, ring = ps.choice("tip"), ps.choice("ring")
    tip_w = 0.0015 if tip == "pointed" else 0.4 * wb
    parts = {}
    for name, sy, z0 in (("blade_a", -1, 0.0), ("blade_b", 1, t + 0.0003)):
        zs = (z0, z0 + t)
        outline = [(0.012, sy * wb / 2), (0.012, -sy * 0.3 * wb / 2), (-Lb, sy * (0.25 * wb + tip_w / 2)),
                   (-Lb, sy * (0.25 * wb - tip_w / 2))]
        blade = hull(np.array([(x, y, z) for x, y in outline for z in zs]))
        rc = (Lh, sy * (ro + 0.6 * Rr), z0 + t / 2)
        shank = [(0.008, sy * 0.004), (0.008, -sy * 0.003), (Lh - 0.8 * Rr, rc[1] - sy * 0.004 - sy * 0.4 * Rr),
                 (Lh - 0.8 * Rr, rc[1] + sy * 0.004 - sy * 0.4 * Rr)]
        meshes = [blade, hull(np.array([(x, y, z) for x, y in shank for z in zs]))]
        meshes.append(torus(Rr, max(rt, t / 2), rc, axis="z", scale=(1.3 if ring == "oval" else 1.0, 1.0, 1.0),
                            sections=(32, 8)))
        if name == "blade_a":
            meshes.append(cylinder(sr, 2 * t + 0.002, (0, 0, t), axis="z", sections=16))
        parts[name] = meshes
    return _assemble(ps, parts, {"screw": (Z, (0.0, 0.0, 0.0))})


@CATEGORIES.register("suitcase")
def suitcase(ps: ParamSampler) -> ArticulatedDesign:
    """Hard-shell suitcase lying flat: shell and lid hinged along the back (+x) edge."""
    W, D = ps.u("width"), ps.u("depth")
    Hs, Hl, wt = ps.u("shell_height"), ps.u("lid_height"), ps.u("wall")
    ho, hw = ps.u("hinge_offset"), ps.u("handle_width")
    handle, wheels, latches = ps.choice("handle"), ps.choice("wheels"), int(ps.choice("latches"))
    shell = hollow_box((D, W, Hs), wt, "+z", (0, 0, Hs / 2))
    lid = hollow_box((D, W, Hl), wt, "-z", (0, 0, Hs + Hl / 2))
    pivot = np.array([D / 2 + ho, 0.0, Hs])
    for y in (-0.3 * W, 0.3 * W):
        shell.append(cylinder(0.008, 0.08, (pivot[0], y, Hs), axis="y", sections=16))
        shell.append(box((ho + 0.006, 0.08, 0.01), (D / 2 + (ho + 0.006) / 2 - 0.003, y, Hs - 0.006)))
    zh = 0.55 * Hs
    if handle == "bar":
        for y in (-hw / 2, hw / 2):
            shell.append(cylinder(0.007, 0.03, (-D / 2 - 0.015, y, zh), axis="x", sections=12))
        shell.append(cylinder(0.011, hw + 0.02, (-D / 2 - 0.03, 0, zh), axis="y", sections=16))
    else:
        u = np.linspace(0, np.pi, 13)
        path = np.stack([-D / 2 - 0.035 * np.sin(u), -(hw / 2) * np.cos(u), np.full_like(u, zh)], 1)
        shell.append(tube(path, 0.009, sections=10))
    if wheels == "wheels":
        for y in (-(W / 2 - 0.05), W / 2 - 0.05):
            shell.append(cylinder(0.025, 0.02, (D / 2 - 0.04, y, -0.012), axis="y", sections=20))
    if latches:
        for y in (-0.3 * W, 0.3 * W):
            shell.append(box((0.012, 0.04, 0.035), (-D / 2 - 0.006, y, Hs - 0.0175)))
            lid.append(box((0.012, 0.04, 0.015), (-D / 2 - 0.006, y, Hs + 0.0075)))
    return _assemble(ps, {"shell": shell, "lid": lid}, {"hinge": (Y, pivot)})
