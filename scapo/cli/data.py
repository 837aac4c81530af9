"""``scapo doctor``, ``list``, ``assets``, ``generate``, ``convert``: the renderer, the categories and methods, the
articulated assets, and datasets (each command's parser beside its handler)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from scapo.cli.common import add_cache
from scapo.errors import ConfigError


def cmd_doctor(args) -> int:
    from scapo.sim.doctor import diagnose

    ok, lines = diagnose()
    print("\n".join(lines))
    print("OK: SAPIEN renders." if ok else "NOT OK: see above.")
    return 0 if ok else 1


def cmd_list(args) -> int:
    from scapo.methods import METHODS
    from scapo.sim.assets import list_categories, load_template

    print("categories:")
    for c in list_categories():
        t = load_template(c)
        print(f"  {c:11s} parts={','.join(t.parts)}  joints={','.join(j.type for j in t.joints)}")
    print("methods (supervision: P pose, S segmentation, J joint; - none):")
    for name in METHODS:
        e = METHODS.get(name)
        how = f"trained (presets: {', '.join(e.presets)})" if e.trained else "fitted at predict time"
        how += ", takes --refine" if e.refinable else ""
        print(f"  {name:9s} {e.marks()}  {e.display:28s} {how}; {e.summary}")
    return 0


def cmd_assets_build(args) -> int:
    from scapo.sim.assets import build_category, parse_urdf

    recs = build_category(args.category, args.instances, args.seed, args.cache, progress=not args.no_progress)
    for r in recs:
        spec = parse_urdf(r.urdf)
        print(f"{r.category} #{r.instance_id}: {r.urdf}  bbox_diag={r.bbox_diag:.3f} m  parts={len(spec.part_names)} "
              f"joints={len(spec.gt_joints)}")
    return 0


def cmd_assets_symmetry(args) -> int:
    from scapo.data.symmetry_measure import Tolerance, measure_meshes, measure_views
    from scapo.files import check_output_owned_file, output_mark, write_json

    for name in ("instances", "views", "states"):
        if getattr(args, name) < (0 if name == "views" else 1):
            raise ConfigError(f"--{name} must be >= {0 if name == 'views' else 1}, got {getattr(args, name)}")
    if args.json is not None:
        check_output_owned_file(args.json, "scapo assets symmetry", "symmetry report", "symmetry.json")
    tol = Tolerance(args.ratio, args.slack, args.min_angle)
    rep = measure_meshes(args.category, min(args.instances, args.mesh_instances), args.states, args.seed,
                         tol=tol, cache_dir=args.cache)
    if args.views:
        rep = measure_views(args.category, args.instances, args.views, args.seed, random_rotation=args.random_rotation,
                            tol=tol, cache_dir=args.cache, report=rep)
    rep.instances = args.instances
    print("\n".join(rep.lines()))
    if args.json is not None:
        from dataclasses import asdict

        from scapo.provenance import provenance

        write_json(args.json, {**output_mark("scapo assets symmetry"), **rep.to_dict(), "tolerance": asdict(tol),
                               "provenance": provenance(command="scapo assets symmetry", seed=args.seed)})
        print(f"wrote {args.json}")
    return 0


def cmd_assets_check(args) -> int:
    from scapo.sim.assets import load_partnet_mobility, parse_urdf

    path = Path(args.path)
    if path.is_dir() and (path / "model.urdf").is_file() and not (path / "mobility.urdf").is_file():
        category = json.loads((path / "asset.json").read_text()).get("category") if (path / "asset.json").is_file() \
            else None  # a procedural asset folder (scapo assets build): its model.urdf
        spec = parse_urdf(path / "model.urdf", category=category)
    elif path.is_dir():
        spec = load_partnet_mobility(path)
    else:
        spec = parse_urdf(path)
    print(f"{spec.urdf}: category={spec.category} parts={list(spec.part_names)} bbox_diag={spec.bbox_diag:.3f} m")
    for j in spec.gt_joints:
        kind = "revolute" if j.type == 0 else "prismatic"
        print(f"  joint {j.name}: {kind} parts {j.parent_part}->{j.child_part} axis={j.axis_obj.round(3).tolist()} "
              f"pivot={j.pivot_obj.round(3).tolist()} range={j.limit.round(3).tolist()}")
    return 0


def cmd_generate(args) -> int:
    from scapo.data import generate, make_config

    objects = _object_sources(args)
    if not objects:
        if args.category is None or args.instances is None:
            raise ConfigError("give --category and --instances (a procedural category), or --object PATH / --objects "
                              "DIR (existing objects)")
        if args.parts or args.scale != "1" or args.object_options:
            raise ConfigError("--parts, --scale and --object-options apply to existing objects (--object/--objects)")
    view = {}
    for name in ("azimuth", "elevation", "distance"):
        val = getattr(args, name)
        if val is not None:
            view[name if name == "distance" else f"{name}_deg"] = _range(val, f"--{name}")
    cfg = make_config(args.category, args.instances or 0, args.views, args.seed, num_points=args.points,
                      sensor=args.sensor, random_rotation=args.random_rotation, width=args.width,
                      viewpoints=args.viewpoints, euler_deg=None if args.euler is None else _euler(args.euler),
                      train_views=_train_views(args.train_views),
                      height=args.height, test_fraction=args.test_fraction, val_fraction=args.val_fraction,
                      min_part_fraction=args.min_part_fraction,
                      shard_size=args.shard_size, cropped=args.cropped,
                      symmetric_labels=args.symmetric_labels, objects=objects, parts=args.parts or (),
                      scale=args.scale, view=view or None, backend=args.backend, complete=args.complete,
                      state=args.state, one_shape=args.one_shape, parts_alone=args.parts_alone)
    rep = generate(cfg, args.out, workers=args.workers, progress=not args.no_progress, cache_dir=args.cache,
                   executor=args.executor, ray_address=args.ray_address, num_envs=args.num_envs)
    print(f"{rep.out}: {rep.samples} samples ({rep.rendered} rendered now, {rep.skipped_shards} shards already "
          f"done); {sum(rep.rejections.values())} rejected views {dict(rep.rejections)}; "
          f"{rep.samples_per_second:.1f} samples/s")
    if rep.rejected_shards:
        print(f"re-rendered {len(rep.rejected_shards)} shard(s) that failed verification; the old files are in "
              f"{rep.out / 'rejected'}")
    if rep.test_samples == 0:
        print(f"scapo generate: warning: the test split is empty ({args.instances} instances, --test-fraction "
              f"{args.test_fraction}); methods cannot be evaluated on this dataset", file=sys.stderr)
    return 0


def _euler(text: str) -> tuple[tuple[float, float], ...]:
    """``--euler LO,HI`` (every axis) or ``LO,HI:LO,HI:LO,HI`` (x:y:z), degrees -> three ranges."""
    parts = text.split(":")
    if len(parts) not in (1, 3):
        raise ConfigError(f"--euler {text!r}: give one range for every axis (e.g. --euler=-22.5,22.5) or three, x:y:z "
                          "(e.g. --euler=-90,90:-90,90:-30,30)")
    ranges = [_range(t, "--euler") for t in parts]
    for lo, hi in ranges:
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo < -180 or hi > 180:
            raise ConfigError(f"--euler {text!r}: angles must be finite degrees within [-180, 180]")
    return tuple(ranges * 3 if len(ranges) == 1 else ranges)


def _train_views(n: int | None) -> int:
    if n is None:
        return 0
    if n < 1:
        raise ConfigError(f"--train-views must be >= 1 (views of each training instance), got {n}")
    return n


def _range(text: str, flag: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(f"{flag} {text!r}: give a range as two numbers, e.g. {flag} -60,60") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ConfigError(f"{flag} {text!r}: both ends must be finite numbers, e.g. {flag} -60,60")
    if not lo <= hi:
        raise ConfigError(f"{flag} {text!r}: the lower end exceeds the upper one")
    return lo, hi


def _object_sources(args) -> list:
    """--object / --objects / --object-options -> ObjectSource list (per-object parts and view overrides)."""
    from scapo.sim.assets.objects import ObjectSource, list_objects, parse_parts, view_overrides

    paths = [str(Path(p).resolve()) for p in (args.object or [])]
    if args.objects is not None:
        paths += list_objects(args.objects)
    for p in paths:
        if not Path(p).exists():
            raise ConfigError(f"--object {p}: no such file or folder")
    options = {}
    if args.object_options:
        from scapo.files import read_json

        options = read_json(Path(args.object_options), "object options", ConfigError,
                            'write a JSON object {"<object name>": {"parts": "door=link_1", "view": {...}}}')
        if not isinstance(options, dict):
            raise ConfigError(f"--object-options {args.object_options}: expected a JSON object keyed by object name")
    out, used = [], set()
    for p in paths:
        src = ObjectSource(p)
        opt = options.get(src.name) or options.get(p) or {}
        if not isinstance(opt, dict):
            raise ConfigError(f"--object-options: the entry of {src.name!r} must be a JSON object with \"parts\" "
                              "and / or \"view\"")
        unknown = sorted(set(opt) - {"parts", "view"})
        if unknown:
            raise ConfigError(f"--object-options: unknown key(s) {unknown} for {src.name!r}; known: parts, view")
        if opt:
            used.add(src.name if src.name in options else p)
            parts = opt.get("parts", "")
            parts = parse_parts(parts) if isinstance(parts, str) else tuple(sorted(parts.items()))
            src = ObjectSource(p, tuple(sorted(parts)), view_overrides(opt.get("view")))
        out.append(src)
    unused = sorted(set(options) - used)
    if unused:
        raise ConfigError(f"--object-options names objects that are not in this dataset: {unused}; object names are "
                          f"{sorted(ObjectSource(p).name for p in paths)[:8]}")
    return out


def cmd_convert_opalign(args) -> int:
    from scapo.data.opalign_real import convert_opalign_real

    try:
        h, w = (int(x) for x in args.image_size.lower().split("x"))
        jt = [int(x) for x in args.joint_types.split(",")] if args.joint_types else None
        jp = [[int(y) for y in x.split("-")] for x in args.joint_parts.split(",")] if args.joint_parts else None
    except ValueError:
        raise ConfigError("--image-size is HxW (e.g. 480x640), --joint-types e.g. 0,1, --joint-parts e.g. 0-1,0-2") \
            from None
    if (jt is None) != (jp is None) or (jt is not None and len(jt) != len(jp)):
        raise ConfigError("give --joint-types and --joint-parts together, one entry per joint")
    card = convert_opalign_real(args.root, args.category, args.out, num_points=args.points, seed=args.seed,
                                val_fraction=args.val_fraction, joint_type=jt, joint_parts=jp, image_size=(h, w))
    n = {k: v["samples"] for k, v in card["splits"].items()}
    print(f"{args.out}: {sum(n.values())} samples {n}; skipped frames {card['skipped_frames'] or 'none'}")
    return 0


def add_parsers(sub) -> None:
    """Add this group's commands to the ``scapo`` parser's sub-parsers ``sub``."""
    sp = sub.add_parser("doctor", help="report which Vulkan device SAPIEN renders on")
    sp.set_defaults(func=cmd_doctor)
    sp = sub.add_parser("list", help="list categories and methods")
    sp.set_defaults(func=cmd_list)

    sp = sub.add_parser("assets", help="build or check articulated assets")
    asub = sp.add_subparsers(dest="assets_command", required=True)
    b = asub.add_parser("build", help="build procedural instances (URDF + meshes) into the cache")
    b.add_argument("--category", required=True)
    b.add_argument("--instances", type=int, default=4)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--no-progress", action="store_true")
    add_cache(b)
    b.set_defaults(func=cmd_assets_build)
    m = asub.add_parser("symmetry", help="measure a category's symmetries: self-maps of the posed meshes, whether "
                        "the declared ones hold, and the share of single views another pose explains as well")
    m.add_argument("--category", required=True)
    m.add_argument("--instances", type=int, default=10, help="instances whose views are measured (default 10)")
    m.add_argument("--views", type=int, default=10, help="views per instance (default 10; 0: meshes only)")
    m.add_argument("--mesh-instances", type=int, default=4, help="instances whose meshes are measured (default 4)")
    m.add_argument("--states", type=int, default=3, help="joint states per instance for the meshes (rest first)")
    m.add_argument("--seed", type=int, default=5, help="seed of the instances and views (default 5)")
    m.add_argument("--random-rotation", action="store_true", help="views of objects under uniform SO(3) rotations")
    m.add_argument("--ratio", type=float, default=1.25, help="a pose explains as well: distance <= ratio x truth's ...")
    m.add_argument("--slack", type=float, default=0.004, help="... + slack (bbox diagonals)")
    m.add_argument("--min-angle", type=float, default=30.0, help="only poses this far (deg) from the truth count")
    m.add_argument("--json", type=Path, default=None, help="also write the full report (per view) as JSON")
    add_cache(m)
    m.set_defaults(func=cmd_assets_symmetry)
    c = asub.add_parser("check", help="parse and validate a URDF file or a PartNet-Mobility folder")
    c.add_argument("path")
    c.set_defaults(func=cmd_assets_check)

    sp = sub.add_parser("generate", help="render a dataset of partial point clouds with ground truth")
    sp.add_argument("--category", help="procedural category (or, with --object/--objects, the dataset's label)")
    sp.add_argument("--instances", type=int, help="procedural instances (object datasets: one per object)")
    sp.add_argument("--object", action="append", metavar="PATH",
                    help="an existing object: URDF file or PartNet-Mobility folder (also ManiSkill's copy); repeat")
    sp.add_argument("--objects", type=Path, metavar="DIR", help="every object folder / .urdf file in DIR")
    sp.add_argument("--parts", help="part map of an object dataset: slots SLOT[=PATTERN],... (PATTERN matches a part's "
                    "semantic label, link or joint names; default the slot name); other movable parts are fixed at "
                    "rest and merged into their parent. Default: every movable part")
    sp.add_argument("--scale", default="1", help="object datasets: length factor (e.g. 0.01) or fit:D to scale each "
                    "object to a rest bounding-box diagonal of D metres")
    sp.add_argument("--object-options", type=Path, metavar="FILE", help='JSON {"<object name>": {"parts": '
                    '"door=link_1", "view": {"azimuth_deg": [110, 250]}}} with per-object overrides')
    sp.add_argument("--azimuth", help="viewpoint azimuth range in degrees, e.g. -70,70 (0: in front, on -x)")
    sp.add_argument("--elevation", help="viewpoint elevation range in degrees, e.g. 10,60")
    sp.add_argument("--distance", help="camera distance range in rest bbox diagonals, e.g. 1.4,2.4")
    sp.add_argument("--views", type=int, required=True)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", type=Path, required=True)
    sp.add_argument("--workers", type=int, default=1, help="worker processes (Ray: actors), one SAPIEN scene each")
    sp.add_argument("--executor", default="local", choices=["local", "ray"],
                    help="local processes, or Ray actors (pip install 'scapo[ray]'); same output either way")
    sp.add_argument("--ray-address", default=None, help="--executor ray: address of a running Ray cluster (e.g. auto, "
                    "ray://head:10001); default: a local Ray instance")
    sp.add_argument("--points", type=int, default=1024, help="points per sample (FPS)")
    sp.add_argument("--sensor", default="clean", help="clean (exact object points) | realistic (depth noise, flying "
                    "pixels, detector-style mask with nearby background labelled -1, support plane; see "
                    "scapo.sim.sensor)")
    sp.add_argument("--cropped", default="reject", choices=["reject", "flag", "keep"],
                    help="views whose object touches the image border: reject them (default), flag them (kept, with "
                    "a 'cropped' column in the manifest), or keep them (as the Table 1 datasets do)")
    sp.add_argument("--symmetric-labels", default="view", choices=["view", "asset"],
                    help="categories whose symmetry exchanges parts (basket): label those parts by view (the handle "
                    "on the camera's side is handle_a) or keep the asset's labels")
    sp.add_argument("--viewpoints", default=None, choices=["upright", "paper", "sphere"],
                    help="upright (default): the category's azimuth/elevation/distance ranges (the [view] table of "
                    "its template; --azimuth etc.); paper: EAP's synthetic views, which the SCAPO paper follows: "
                    "the object turned about its bbox centre in front of a level front camera by Euler angles "
                    "(x, y, z; R = Rz Ry Rx) uniform in the category's [paper_view] ranges (+-22.5 deg for laptop "
                    "and safe, EAP's HOI4D loader; [-90, 90] for eyeglasses, oven, washer, its Shape2Motion "
                    "loader) or --euler; sphere: the object under a uniform SO(3) rotation (whole sphere, harder "
                    "than the paper; = --random-rotation). Views where a part keeps too few points are redrawn "
                    "(--min-part-fraction)")
    sp.add_argument("--euler", default=None, metavar="LO,HI[:LO,HI:LO,HI]",
                    help="--viewpoints paper: the object's Euler angle ranges in degrees, one for every axis or x:y:z "
                    "(default: the category's [paper_view]; needed for --object datasets); write a range that starts "
                    "with a minus sign with '=', e.g. --euler=-22.5,22.5")
    sp.add_argument("--random-rotation", action="store_true", help="uniform SO(3) object rotation (= --viewpoints "
                    "sphere)")
    sp.add_argument("--train-views", type=int, default=None, help="views of each training instance (default: "
                    "--views); val and test instances keep --views. EAP renders ~100 views per training instance")
    sp.add_argument("--complete", action="store_true", help="points sampled on the whole posed mesh (area-weighted, "
                    "then farthest-point sampled) instead of a rendered depth view: complete clouds, EAP's complete-"
                    "shape setting; the viewpoint still sets the frame the points are given in")
    sp.add_argument("--parts-alone", action="store_true", help="every part rendered in a scene of its own (the "
                    "others hidden, same camera and state) and the points pooled: no part hides another, EAP's "
                    "data regime (one part per scene in its MotionDatasetPartial.py); the card records it")
    sp.add_argument("--state", choices=("sampled", "rest"), default="sampled", help="joint states drawn within the "
                    "limits (default) or every sample at the rest state")
    sp.add_argument("--one-shape", action="store_true", help="every instance is instance 0's object (one shape "
                    "seen in many views and states; procedural categories)")
    sp.add_argument("--width", type=int, default=None)
    sp.add_argument("--height", type=int, default=None)
    sp.add_argument("--test-fraction", type=float, default=0.1, help="fraction of instances in the test split")
    sp.add_argument("--val-fraction", type=float, default=0.1, help="fraction of instances in the validation split "
                    "(where choices are made; 0: none)")
    sp.add_argument("--min-part-fraction", type=float, default=0.05)
    sp.add_argument("--shard-size", type=int, default=64)
    sp.add_argument("--no-progress", action="store_true")
    add_cache(sp)
    sp.add_argument("--backend", default="sapien", choices=["sapien", "maniskill"],
                    help="renderer: sapien (default) or maniskill (ManiSkill3's parallel sub-scenes; its datasets "
                    "equal SAPIEN's to float rounding, with a config of their own)")
    sp.add_argument("--num-envs", type=int, default=1, help="--backend maniskill: views rendered at once (GPU; the CPU "
                    "simulation takes 1)")
    sp.set_defaults(func=cmd_generate)

    sp = sub.add_parser("convert", help="convert another dataset format into a scapo dataset")
    csub = sp.add_subparsers(dest="convert_command", required=True)
    c = csub.add_parser("opalign-real", help="OP-Align's real-world RGB-D frames (<root>/{train,test}/*/*/input_2/"
                        "*.npz) of one category")
    c.add_argument("--root", type=Path, required=True, help="the category folder, e.g. dataset/laptop_output")
    c.add_argument("--category", required=True, help="basket, drawer, laptop, scissors, suitcase (or give the joints)")
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--points", type=int, default=1024)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--val-fraction", type=float, default=0.1, help="of the training instances")
    c.add_argument("--image-size", default="480x640", help="HxW of the organised frames")
    c.add_argument("--joint-types", help="another category: joint types, e.g. 0,1 (0 revolute, 1 prismatic)")
    c.add_argument("--joint-parts", help="another category: parent-child parts per joint, e.g. 0-1,0-2")
    c.set_defaults(func=cmd_convert_opalign)
