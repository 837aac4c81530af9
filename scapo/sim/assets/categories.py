"""Procedural generators of the nine benchmark categories (SPEC section 4).

Each generator takes a :class:`ParamSampler` (ranges and styles from
``sim_assets/categories/<name>.toml``) and returns an :class:`ArticulatedDesign` in the object
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
    """Base (thick, tapering to the front, on rubber feet, keyboard deck) and a thin lid hinged at the rear
    edge (rest: 90 deg opening). The lid is shorter than the base is deep and its display sits a step below
    a raised bezel; the hinge is a full-width barrel, two knuckles or flush, and the base may reach behind it."""
    W, D = ps.u("width"), ps.u("depth")
    tb, ts = ps.u("base_thickness"), ps.u("screen_thickness")
    wedge = ps.u("front_thickness_ratio")
    H, Ws = ps.u("screen_height_ratio") * D, ps.u("screen_width_ratio") * W
    inset, hh = ps.u("hinge_inset"), ps.u("hinge_height")
    dw, dd = ps.u("deck_width_ratio"), ps.u("deck_depth_ratio")
    fh, step = ps.u("foot_height"), ps.u("bezel_step")
    hinge, deck, bezel = ps.choice("hinge"), ps.choice("deck"), ps.choice("bezel")
    pivot = np.array([D / 2 - inset, 0.0, fh + tb + hh])
    tf = wedge * tb  # front thickness; the top face slopes up to the rear
    base = [hull(np.array([(x, y, z) for y in (-W / 2, W / 2) for x, z in
                           ((-D / 2, fh), (D / 2, fh), (-D / 2, fh + tf), (D / 2, fh + tb))]))]
    for sx in (-1, 1):  # rubber feet
        base.append(box((0.05 if sx > 0 else 0.02, 0.8 * W if sx > 0 else 0.02, fh), (sx * (D / 2 - 0.03), 0, fh / 2)))
    for sy in (-1, 1):
        base.append(box((0.02, 0.02, fh), (-(D / 2 - 0.03), sy * (W / 2 - 0.04), fh / 2)))

    def top(x):  # height of the base's top face at x
        return fh + tf + (tb - tf) * (x + D / 2) / D

    if deck != "flat":
        kd = dd * D
        xk = D / 2 - inset - 0.02 - kd / 2
        base.append(box((kd, dw * W, 0.0015), (xk, 0, top(xk) + 0.00075)))
    if deck == "keyboard_touchpad":
        tp = 0.3 * D
        xt = -D / 2 + 0.02 + 0.225 * tp
        base.append(box((0.45 * tp, tp * 1.4, 0.001), (xt, 0, top(xt) + 0.0005)))
    r = max(ts, 0.006) * 0.9
    if hinge == "barrel":
        base.append(cylinder(r, 0.7 * W, pivot, axis="y"))
    elif hinge == "knuckles":
        for sy in (-1, 1):
            base.append(cylinder(r * 1.2, 0.035, (pivot[0], sy * 0.36 * W, pivot[2]), axis="y"))
    screen = [box((ts, Ws, H), pivot + (0, 0, H / 2))]
    if bezel == "step":  # display panel a step behind the raised bezel: the bezel frame stands proud
        b = 0.012
        for zc, hz in ((H - b / 2, b), (0.035 / 2, 0.035)):
            screen.append(box((step, Ws, hz), pivot + (-ts / 2 - step / 2, 0, zc)))
        for sy in (-1, 1):
            screen.append(box((step, b, H), pivot + (-ts / 2 - step / 2, sy * (Ws / 2 - b / 2), H / 2)))
    else:  # flat glass panel edge to edge
        screen.append(box((0.001, 0.96 * Ws, 0.9 * H), pivot + (-ts / 2 - 0.0005, 0, 0.52 * H)))
    return _assemble(ps, {"base": base, "screen": screen}, {"hinge": (Y, pivot)})


@CATEGORIES.register("safe")
def safe(ps: ParamSampler) -> ArticulatedDesign:
    """Thick-walled box; a front door smaller than the front, proud of the body's frame, on a vertical hinge at
    its -y edge; handle and dial or keypad on the door, hinge barrels outside, feet or a plinth."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, td, ho = ps.u("wall"), ps.u("door_thickness"), ps.u("hinge_offset")
    g = ps.u("frame_ratio") * wt  # the body's front frame left visible around the door, on each side
    dial_r, hl, so = ps.u("dial_radius"), ps.u("handle_length"), ps.u("handle_standoff")
    hr, hlen, fh = ps.u("hinge_radius"), ps.u("hinge_length"), ps.u("foot_height")
    kdp = ps.u("keypad_depth")
    handle, panel, feet = ps.choice("handle"), ps.choice("panel"), ps.choice("feet")
    hl = min(hl, 0.45 * (W - 2 * g), 0.45 * (H - 2 * g))  # small safes get smaller handles
    body = hollow_box((D, W, H), wt, "-x", (0, 0, H / 2))
    if feet == "feet":
        for sx in (-1, 1):
            for sy in (-1, 1):
                body.append(box((0.05, 0.05, fh), (sx * (D / 2 - 0.04), sy * (W / 2 - 0.04), -fh / 2)))
    else:  # a plinth set back from the front
        body.append(box_between((-D / 2 + 0.04, -W / 2 + 0.02, -fh), (D / 2 - 0.02, W / 2 - 0.02, 0.0)))
    xf = -D / 2 - td  # front face of the door
    pivot = np.array([-D / 2 - td / 2, -W / 2 + g - ho, H / 2])
    for zc in (0.2 * H, 0.8 * H):  # external hinge barrels on the body, leaves reaching the door
        body.append(cylinder(hr, hlen, (pivot[0], pivot[1] - hr * 0.5, zc), axis="z"))
    door = [box_between((xf, -W / 2 + g, g), (-D / 2, W / 2 - g, H - g))]
    ys = W / 2 - g - 0.25 * W  # features on the free side
    # the lock's controls sit in the door's upper half: a dial on its escutcheon ring, an electronic keypad in a
    # raised housing (both on the hinge side of the handle when the safe has both)
    if panel in ("dial", "dial_keypad"):
        yd = ys * 0.3 if panel == "dial" else -0.2 * W
        door.append(cylinder(1.5 * dial_r, 0.006, (xf - 0.003, yd, 0.68 * H), axis="x", sections=32))
        door.append(cylinder(dial_r, 0.02, (xf - 0.01, yd, 0.68 * H), axis="x"))
    if panel in ("keypad", "dial_keypad"):
        kw, kz = float(np.clip(0.22 * W, 0.07, 0.14)), float(np.clip(0.25 * H, 0.09, 0.16))
        yk = ys * 0.3 if panel == "keypad" else 0.05 * W
        door.append(box((kdp, kw, kz), (xf - kdp / 2, yk, 0.68 * H)))
    hz = 0.5 * H
    if handle == "lever":
        door.append(cylinder(0.008, so, (xf - so / 2, ys, hz), axis="x"))
        door.append(box((0.014, hl, 0.02), (xf - so - 0.007, ys - hl / 2 + 0.01, hz)))
    elif handle == "wheel":
        door.append(cylinder(0.01, so, (xf - so / 2, ys, hz), axis="x"))
        door.append(torus(hl / 2, 0.006, (xf - so, ys, hz), axis="x"))
        for a in (0.0, np.pi / 3, 2 * np.pi / 3):
            c, s = np.cos(a) * hl / 2, np.sin(a) * hl / 2
            door.append(box((0.008, max(abs(2 * c), 0.008), max(abs(2 * s), 0.008)), (xf - so, ys, hz)))
    else:
        for dz in (-hl / 2 + 0.01, hl / 2 - 0.01):
            door.append(cylinder(0.007, so, (xf - so / 2, ys, hz + dz), axis="x"))
        door.append(cylinder(0.01, hl, (xf - so, ys, hz), axis="z"))
    return _assemble(ps, {"body": body, "door": door}, {"door_hinge": (Z, pivot)})


@CATEGORIES.register("oven")
def oven(ps: ParamSampler) -> ArticulatedDesign:
    """Body with a front cavity, control panel and knobs; drop-down door hinged at its bottom edge."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, td, zb = ps.u("wall"), ps.u("door_thickness"), ps.u("door_bottom")
    Hd = ps.u("door_height_ratio") * (H - zb)
    so, kr, kd = ps.u("handle_standoff"), ps.u("knob_radius"), ps.u("knob_depth")
    fh, bg = ps.u("foot_height"), ps.u("backguard_height")
    nk, handle, window = int(ps.choice("knobs")), ps.choice("handle"), ps.choice("window")
    kind = ps.choice("kind")
    body = hollow_box((D, W, Hd), wt, "-x", (0, 0, zb + Hd / 2))
    ztop = zb + Hd
    body.append(box((D, W, H - ztop), (0, 0, (ztop + H) / 2)))
    if zb > 0.002:
        body.append(box((D - 0.03, W, zb), (0.015, 0, zb / 2)))
    for sx in (-1, 1):  # levelling feet
        for sy in (-1, 1):
            body.append(cylinder(0.015, fh, (sx * (D / 2 - 0.05), sy * (W / 2 - 0.05), -fh / 2), axis="z", sections=12))
    if kind == "range":  # freestanding range: backguard at the rear, burner grates on the cooktop
        body.append(box((0.03, W, bg), (D / 2 - 0.015, 0, H + bg / 2)))
        for sy in (-1, 1):
            for xg in (-0.22 * D, 0.12 * D):
                body.append(box((0.3 * D, 0.4 * W, 0.02), (xg, sy * 0.24 * W, H + 0.01)))
    else:  # counter-top / built-in oven: a vent grille along the top's rear half
        body.append(box((0.35 * D, 0.8 * W, 0.012), (0.25 * D, 0, H + 0.006)))
    zk = (ztop + H) / 2
    for y in np.linspace(-0.35 * W, 0.35 * W, nk):
        body.append(cylinder(kr, kd, (-D / 2 - kd / 2, y, zk), axis="x"))
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
    """Front loader: body with a slanted control panel at the top and a recessed kick panel at the bottom; a
    large round door below the middle, hinged on a vertical line at its -y side."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    R = ps.u("door_radius_ratio") * W
    td, zc = ps.u("door_thickness"), ps.u("door_height_ratio") * H
    hg, ph, kr = ps.u("hinge_gap"), ps.u("panel_height"), ps.u("knob_radius")
    kh, kd = ps.u("kick_height"), ps.u("kick_depth")
    rim, porthole, knob = ps.choice("rim"), ps.choice("porthole"), ps.choice("knob")
    zp = H - ph
    ring_t = 0.012
    # the door (with its ring) fits between the kick panel and the control panel, 2 cm clear of each
    R = min(R, (zp - kh - 0.04) / 2 / 1.06 - ring_t)
    zc = float(np.clip(zc, kh + 0.02 + 1.06 * R + ring_t, zp - 0.02 - 1.06 * R - ring_t))
    body = [box((D, W, zp - kh), (0, 0, (kh + zp) / 2))]
    body.append(box((D - kd, W, kh), (kd / 2, 0, kh / 2)))  # the kick panel, set back from the front
    corners = np.array([[sx, sy, sz] for sx in (-D / 2, D / 2) for sy in (-W / 2, W / 2) for sz in (zp, H)])
    corners[(corners[:, 0] < 0) & (corners[:, 2] > zp), 0] += 0.04  # slanted control panel
    body.append(hull(corners))
    if knob == "knob":
        body.append(cylinder(kr, 0.025, (-D / 2 + 0.01, 0.3 * W, zp + 0.45 * ph), axis="x"))
        body.append(box((0.01, 0.18 * W, 0.4 * ph), (-D / 2 + 0.015, -0.15 * W, zp + 0.5 * ph)))
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
    """Front frame (rims, bridge, nose pads, end pieces); temples fold about vertical hinges (rest: folded).

    Real frames are not symmetric top to bottom: the lenses are wider above than below (``lens_taper``), the
    bridge and the hinges sit above the lens centres, and the nose pads below the bridge behind the rims."""
    lw, lh, br = ps.u("lens_width"), ps.u("lens_height"), ps.u("bridge")
    rr, ep, tl = ps.u("rim_radius"), ps.u("end_piece_length"), ps.u("temple_length")
    th, tw = ps.u("temple_height"), ps.u("temple_width")
    bhr, hhr, taper = ps.u("bridge_height_ratio"), ps.u("hinge_height_ratio"), ps.u("lens_taper")
    lens, tip, shape = ps.choice("lens"), ps.choice("temple_tip"), ps.choice("rim_shape")
    pads = ps.choice("nose_pads")
    radii = {"oval": (lw / 2, lh / 2), "round": (lw / 2, min(lh, lw) / 2 * 1.05), "rect": (lw / 2, lh / 2)}[shape]
    square = 0.6 if shape == "rect" else 0.0
    bh, zh = bhr * radii[1], hhr * radii[1]

    def rim_loop(sy: float, shrink: float = 1.0) -> np.ndarray:
        c = np.array([0.0, sy * (br / 2 + lw / 2), 0.0])
        pts = ellipse_path(c, (radii[0] * shrink, radii[1] * shrink), plane="yz", count=48, squareness=square)
        pts[:, 1] = c[1] + (pts[:, 1] - c[1]) * (1.0 + taper * pts[:, 2] / radii[1])  # wider above than below
        return pts

    right = rim_loop(1.0)

    def edge_at(z: float, inner: bool) -> float:  # |y| of the right rim's inner or outer edge at height z
        side = right[right[:, 1] < br / 2 + lw / 2] if inner else right[right[:, 1] > br / 2 + lw / 2]
        return float(side[np.argmin(np.abs(side[:, 2] - z)), 1])

    frame = []
    for sy in (-1, 1):
        frame.append(tube(right if sy > 0 else rim_loop(sy), rr, sections=8, closed=True))
        if lens == "lens":
            pts = rim_loop(sy, 0.98)
            frame.append(hull(np.vstack([pts + (0.0008, 0, 0), pts - (0.0008, 0, 0)])))
    yi = edge_at(bh, inner=True)
    u = np.linspace(0, np.pi, 9)
    bridge = np.stack([np.zeros_like(u), -np.cos(u) * yi, bh + 0.004 * np.sin(u)], 1)
    frame.append(tube(bridge, rr, sections=8))
    yp = edge_at(-0.15 * radii[1], inner=True)
    for sy in (-1, 1):  # nose pads below the bridge, behind the rims
        if pads == "pads":  # metal frames: a pad on a wire arm from the rim
            frame.append(box_between((rr, sy * yp - 0.0008, -0.1 * radii[1] - 0.0008),
                                     (rr + 0.006, sy * yp + 0.0008, -0.1 * radii[1] + 0.0008)))
            frame.append(box((0.0015, 0.007, 0.013), (rr + 0.006, sy * (yp - 0.002), -0.25 * radii[1])))
        else:  # plastic frames: a moulded pad along the lower inner rim
            frame.append(box_between((0.0, sy * yp - 0.003, -0.45 * radii[1]),
                                     (rr + 0.004, sy * yp + 0.003, 0.05 * radii[1])))
    yo = edge_at(zh, inner=False)
    yh = max(br / 2 + lw, yo) + rr  # hinge line, |y|
    for sy in (-1, 1):
        lo, hi = sorted((sy * (yo - 0.002), sy * (yh + 0.0015)))
        frame.append(box_between((-rr, lo, zh - th / 2), (ep, hi, zh + th / 2)))
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
    """Cabinet carcass open at the front and one drawer sliding out along -x; the top is flush at the back, an open
    shelf may sit under the drawer, and the unit stands on a toe kick, legs or a plinth."""
    W, D, H = ps.u("width"), ps.u("depth"), ps.u("height")
    wt, tf, g = ps.u("wall"), ps.u("front_thickness"), ps.u("gap")
    ddr, thr, hwr = ps.u("drawer_depth_ratio"), ps.u("tray_height_ratio"), ps.u("handle_width_ratio")
    kh, kd, ov, hs = ps.u("base_height"), ps.u("kick_depth"), ps.u("top_overhang"), ps.u("shelf_height")
    br, hp = ps.u("back_recess"), ps.u("handle_projection")
    front, handle, base, lower = ps.choice("front"), ps.choice("handle"), ps.choice("base"), ps.choice("lower")
    cabinet = hollow_box((D, W, H), wt, "-x", (0, 0, H / 2))
    # the top overhangs the front and the sides and is flush at the back (against a wall)
    cabinet.append(box((D + ov + br, W + 2 * ov, wt), (-(ov - br) / 2, 0, H + wt / 2)))
    z0 = 0.0
    if lower == "shelf":  # an open compartment under the drawer (a nightstand's shelf)
        cabinet += hollow_box((D, W, hs), wt, "-x", (0, 0, -hs / 2))
        z0 = -hs
    # the back panel sits in a groove: the carcass's sides, top and bottom reach ``br`` past it
    zb, zt = z0, H
    x0, x1 = D / 2, D / 2 + br
    for lo, hi in (((x0, -W / 2, zb), (x1, -W / 2 + wt, zt)), ((x0, W / 2 - wt, zb), (x1, W / 2, zt)),
                   ((x0, -W / 2, zb), (x1, W / 2, zb + wt)), ((x0, -W / 2, zt - wt), (x1, W / 2, zt))):
        if br >= 0.002:  # else the back panel is nailed flush to the carcass
            cabinet.append(box_between(lo, hi))
    # what it stands on: a toe kick set back from the front, four legs, or a plinth set back all round
    if base == "toe_kick":
        cabinet.append(box_between((-D / 2 + kd, -W / 2 + 0.01, z0 - kh), (D / 2, W / 2 - 0.01, z0)))
    elif base == "legs":
        for sx in (-1, 1):
            for sy in (-1, 1):
                cabinet.append(cylinder(0.015, kh, (sx * (D / 2 - 0.03), sy * (W / 2 - 0.03), z0 - kh / 2), axis="z"))
    else:
        cabinet.append(box_between((-D / 2 + kd, -W / 2 + kd, z0 - kh), (D / 2 - 0.01, W / 2 - kd, z0)))
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
            drawer_parts.append(cylinder(0.005, hp, (x_front - hp / 2, y, zc), axis="x", sections=12))
        drawer_parts.append(cylinder(0.007, hw, (x_front - hp, 0, zc), axis="y", sections=16))
    elif handle == "knob":
        drawer_parts.append(cylinder(0.006, hp, (x_front - hp / 2, 0, zc), axis="x", sections=12))
        drawer_parts.append(cylinder(0.015, 0.012, (x_front - hp + 0.006, 0, zc), axis="x", sections=20))
    else:
        drawer_parts.append(box((hp, hwr * W, 0.012), (x_front - hp / 2, 0, hi[2] - 0.006)))
    parts = {"cabinet": cabinet, "drawer": drawer_parts}
    return _assemble(ps, parts, {"slide": ((-1.0, 0.0, 0.0), (x_front, 0.0, zc))}, {"drawer_depth": Dd})


@CATEGORIES.register("scissors")
def scissors(ps: ParamSampler) -> ArticulatedDesign:
    """Two stacked blades crossing at the screw (rest: closed). Like offset-handle scissors, blade A carries the
    large oval finger loop (with a finger rest) and blade B the small thumb loop; the tips may differ
    (one pointed, one blunt)."""
    Lb, wb, t = ps.u("blade_length"), ps.u("blade_width"), ps.u("thickness")
    Lh, Rr, rt = ps.u("handle_length"), ps.u("ring_radius"), ps.u("ring_tube")
    ro, sr = ps.u("ring_offset"), ps.u("screw_radius")
    fl, fr = ps.u("finger_loop_ratio"), ps.u("finger_rest_length")
    tip, ring = ps.choice("tip"), ps.choice("ring")
    parts = {}
    for name, sy, z0 in (("blade_a", -1, 0.0), ("blade_b", 1, t + 0.0003)):
        zs = (z0, z0 + t)
        pointed = tip == "pointed" or (tip == "sharp_blunt" and name == "blade_a")
        tip_w = 0.0015 if pointed else 0.4 * wb
        outline = [(0.012, sy * wb / 2), (0.012, -sy * 0.3 * wb / 2), (-Lb, sy * (0.25 * wb + tip_w / 2)),
                   (-Lb, sy * (0.25 * wb - tip_w / 2))]
        blade = hull(np.array([(x, y, z) for x, y in outline for z in zs]))
        finger = name == "blade_a"
        # the finger loop is longer along the handle (x) by ``fl``; the thumb loop is round or slightly oval
        sx = fl if finger else (1.15 if ring == "oval" else 1.0)
        xc = Lh + (sx - 1.0) * Rr * 0.8 if finger else Lh
        rc = (xc, sy * (ro + 0.6 * Rr), z0 + t / 2)
        shank = [(0.008, sy * 0.004), (0.008, -sy * 0.003), (xc - 0.8 * sx * Rr, rc[1] - sy * 0.004 - sy * 0.4 * Rr),
                 (xc - 0.8 * sx * Rr, rc[1] + sy * 0.004 - sy * 0.4 * Rr)]
        meshes = [blade, hull(np.array([(x, y, z) for x, y in shank for z in zs]))]
        meshes.append(torus(Rr, max(rt, t / 2), rc, axis="z", scale=(sx, 1.0, 1.0), sections=(32, 8)))
        if finger:
            # finger rest (tang): a curved spur off the far side of the finger loop
            u = np.linspace(0.0, 1.0, 7)
            x0, y0 = xc + 0.5 * sx * Rr, rc[1] + sy * 0.85 * Rr
            path = np.stack([x0 + fr * u, y0 + sy * fr * (0.35 * u + 0.25 * u**2), np.full_like(u, rc[2])], 1)
            meshes.append(tube(path, max(rt, t / 2) * 0.9, sections=8))
            meshes.append(cylinder(sr, 2 * t + 0.002, (0, 0, t), axis="z", sections=16))
        parts[name] = meshes
    return _assemble(ps, parts, {"screw": (Z, (0.0, 0.0, 0.0))})


@CATEGORIES.register("suitcase")
def suitcase(ps: ParamSampler) -> ArticulatedDesign:
    """Hard-shell suitcase lying on its back: shell (the deeper back half) and lid hinged along the back long
    edge (+x); wheels at the bottom end (-y), the telescoping handle's grip and a carry handle at the top end
    (+y), a side carry handle and latches on the front (-x) edge (as a standing case: height along y)."""
    W, D = ps.u("width"), ps.u("depth")
    Hs, wt = ps.u("shell_height"), ps.u("wall")
    Hl = ps.u("lid_ratio") * Hs  # the front half is at most as deep as the back half
    ho, hw = ps.u("hinge_offset"), ps.u("handle_width")
    wr, tgw, tgo = ps.u("wheel_radius"), ps.u("trolley_width_ratio"), ps.u("trolley_standoff")
    tch, dvd, dome = ps.u("trolley_channel_height"), ps.u("divider_depth"), ps.u("front_dome")
    handle, wheels, latches = ps.choice("handle"), ps.choice("wheels"), int(ps.choice("latches"))
    lining = ps.choice("lining")
    shell = hollow_box((D, W, Hs), wt, "+z", (0, 0, Hs / 2))
    lid = hollow_box((D, W, Hl), wt, "-z", (0, 0, Hs + Hl / 2))
    # inside the back half: the telescoping handle's tube channel along the case's length (y), as wide as the grip;
    # outside, the tubes' two ridges along the back panel (the case rests on them)
    shell.append(box((tgw * D, W - 2 * wt, tch), (0, 0, wt + tch / 2)))
    for sx in (-1, 1):
        shell.append(box((0.035, W - 0.08, 0.015), (sx * (tgw * D / 2 - 0.0175), 0, -0.0075)))
    # the front panel bulges outwards (a shallow dome over the lid's outer face)
    zt = Hs + Hl
    rims = ((D / 2 - wt, W / 2 - wt, zt), (0.3 * D, 0.38 * W, zt + dome))
    lid.append(hull(np.array([(x, y, z) for (hx, hy, z) in rims for x in (-hx, hx) for y in (-hy, hy)])))
    # a zipped divider panel closes the front half a little below its rim (hard-shell cases pack the back half
    # open, under compression straps, and the front half behind a divider)
    lid.append(box((D - 2 * wt, W - 2 * wt, 0.004), (0, 0, Hs + dvd + 0.002)))
    if lining == "straps":  # compression straps across the back half, over the handle's channel
        for y in (-0.25 * W, 0.25 * W):
            shell.append(box((D - 2 * wt, 0.035, 0.004), (0, y, wt + tch + 0.002)))
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
    # bottom end (-y): spinner wheels at the four corners (two on each half), or two larger inline wheels on the
    # back half; each in a housing on the end face
    ye = -W / 2
    corners = [(sx * (D / 2 - 0.045), 0.03) for sx in (-1, 1)]
    if wheels == "spinner":
        corners += [(sx * (D / 2 - 0.045), Hs + Hl - 0.03) for sx in (-1, 1)]
    r = wr if wheels == "spinner" else 1.2 * wr
    hd = ps.u("wheel_housing")
    for x, z in corners:
        owner = shell if z < Hs else lid
        owner.append(box((0.06, hd, 0.055), (x, ye - hd / 2, z)))
        for dx in (-0.012, 0.012):  # the fork's two legs either side of the wheel
            owner.append(box((0.004, r + 0.01, 0.03), (x + dx, ye - hd - (r + 0.01) / 2, z)))
        owner.append(cylinder(r, 0.02, (x, ye - hd - r, z), axis="x", sections=20))
    # top end (+y): the telescoping handle's grip over two tube stubs on the back half, and a carry handle
    yt = W / 2
    gw = tgw * D
    for x in (-gw / 2 + 0.012, gw / 2 - 0.012):
        shell.append(box((0.024, tgo, 0.03), (x, yt + tgo / 2, 0.035)))
    shell.append(box((gw, 0.025, 0.035), (0, yt + tgo + 0.0125, 0.035)))
    for x in (-0.06, 0.06):
        lid.append(cylinder(0.006, 0.025, (x, yt + 0.0125, Hs + 0.5 * Hl), axis="y", sections=12))
    lid.append(cylinder(0.009, 0.14, (0, yt + 0.03, Hs + 0.5 * Hl), axis="x", sections=14))
    if latches:
        for y in (-0.3 * W, 0.3 * W):
            shell.append(box((0.012, 0.04, 0.035), (-D / 2 - 0.006, y, Hs - 0.0175)))
            lid.append(box((0.012, 0.04, 0.015), (-D / 2 - 0.006, y, Hs + 0.0075)))
    return _assemble(ps, {"shell": shell, "lid": lid}, {"hinge": (Y, pivot)})
