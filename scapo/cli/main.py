"""The ``scapo`` console script: one entry point, one sub-command per job.

Run ``scapo <command> --help`` for the options of each command. Heavy modules are imported
inside the commands so that ``scapo --help`` is instant.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
from pathlib import Path

from scapo.errors import ConfigError, ScapoError
from scapo.provenance import git_commit


def _ints(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x.strip()]


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def _names(text: str) -> list[str]:
    return [x.strip() for x in text.split(",") if x.strip()]


# ------------------------------------------------------------------------------ commands
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
    from scapo.data.symmetry import Tolerance, measure_meshes, measure_views
    from scapo.files import check_output_file, write_json

    for name in ("instances", "views", "states"):
        if getattr(args, name) < (0 if name == "views" else 1):
            raise ConfigError(f"--{name} must be >= {0 if name == 'views' else 1}, got {getattr(args, name)}")
    if args.json is not None:
        check_output_file(args.json, "symmetry report", example="symmetry.json")
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

        write_json(args.json, {**rep.to_dict(), "tolerance": asdict(tol),
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
                      state=args.state, one_shape=args.one_shape)
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


def cmd_export(args) -> int:
    from scapo.twin import export_twin

    if (args.pred is None) == (args.run is None):
        raise ConfigError("give --pred FILE (predictions of the dataset) or --run RUN (a trained run, which predicts "
                          "the sample's split first)")
    preds = args.pred if args.run is None else _run_predictions(args.run, args.data)
    rep = export_twin(args.data, preds, args.sample, args.out, split=args.split)
    print(f"wrote {rep.urdf} ({len(rep.parts)} links: {', '.join(rep.parts)}; "
          + ", ".join(f"{j['name']} {j['type']} {j['parent']}->{j['child']}" for j in rep.joints) + ")")
    return 0


def _run_predictions(run, data):
    """Predictions of a trained run on ``data`` (kept in memory; nothing is written)."""
    from scapo.methods import method_of_run, run_method

    return run_method(method_of_run(run), data, None, run=run)


def cmd_view(args) -> int:
    from scapo.viewer import Viewer

    v = Viewer(args.data, args.pred or (), args.twin, split=args.split, host=args.host, port=args.port)
    print(f"scapo view: open {v.url} in a browser (Ctrl-C stops)", flush=True)
    v.serve_forever()
    return 0


def cmd_preview(args) -> int:
    from scapo.files import check_output_file
    from scapo.sim.preview import save_preview
    from scapo.viz import render_dataset_samples

    if args.count < 1:
        raise ConfigError(f"--count must be >= 1, got {args.count}")
    check_output_file(args.out, "preview image", "preview.png")
    samples, titles, names = render_dataset_samples(args.data, args.split, args.count, args.cache)
    path = save_preview(samples, args.out, titles, names)
    print(f"wrote {path}")
    return 0


def cmd_train(args) -> int:
    from scapo.config import parse_assignments, read_config
    from scapo.methods import train_method

    # the preset (the run's own on resume), --config / --set and the seed are resolved once, by the engine
    values = {**(read_config(args.config) if args.config else {}), **parse_assignments(args.set)}
    ck = train_method(args.method, args.data, args.out, args.preset, progress=not args.no_progress,
                      device=args.device, seed=args.seed, overrides=values or None)
    if os.environ.get("RANK", "0") == "0":  # under torchrun, rank 0 speaks for the run
        print(f"trained: {ck} (loss curves in {Path(args.out) / 'losses.png'})")
    return 0


def cmd_predict(args) -> int:
    from scapo.methods import method_of_run, run_method

    opts = {}
    for kv in args.option or []:
        k, eq, v = kv.partition("=")
        if not eq or not k.strip():
            raise ConfigError(f"--option {kv!r} is not of the form key=value")
        opts[k.strip()] = v  # converted to the option's type by the method's options dataclass
    method = args.method
    if args.run is not None:
        trained_for = method_of_run(args.run)
        if method not in (None, trained_for):
            raise ScapoError(f"--run {args.run} is a run of method {trained_for!r}, not {method!r}")
        method = trained_for
        opts["run"] = args.run
    if args.device:
        opts["device"] = args.device
    if method is None:
        raise ScapoError("give --method NAME (see 'scapo list') or --run RUN (a folder written by 'scapo train')")
    if args.refine:
        from scapo.methods import METHODS
        from scapo.methods.learned import refinable_methods

        if not METHODS.get(method).refinable:
            raise ConfigError(f"method {method!r} has no canonical shape or template for the test-time refinement; "
                              f"--refine applies to: {', '.join(refinable_methods())}")
        opts["refine"] = True
    preds = run_method(method, args.data, args.out, **opts)
    print(f"wrote {args.out}: {len(preds)} predictions of {preds.method} "
          f"({preds.info.get('ms_per_cloud_test', float('nan')):.1f} ms per test cloud)")
    return 0


def cmd_evaluate(args) -> int:
    from scapo.eval import evaluate
    from scapo.eval.protocols import get_protocol
    from scapo.eval.tables import write_table1
    from scapo.files import atomic_write_text, check_output_dir
    from scapo.methods import describe
    from scapo.provenance import provenance

    protocol = get_protocol(args.protocol).name  # an unknown name is refused before any work
    if args.twin_limit < 0:
        raise ConfigError(f"--twin-limit must be >= 0 (0: every sample), got {args.twin_limit}")
    same = _duplicates(args.pred)
    if same:
        raise ConfigError(f"--pred {same[0]} and {same[1]} are the same predictions; give each file once (several "
                          "files of one method are its training seeds)")
    if args.out:
        from scapo.files import check_own_files

        check_output_dir(args.out, "table folder")
        check_own_files([Path(args.out) / f"{args.name}.{k}" for k in ("csv", "md", "tex")],
                        Path(args.out) / f"{args.name}.json", "table file",
                        "choose another --out folder or --name")
    results = [evaluate(args.data, p, protocol=protocol, split=args.split) for p in args.pred]
    _print_summary(results, protocol)
    if args.out:
        from scapo.data import load
        from scapo.data.config import viewpoints_of

        prov = provenance(dataset_hash=results[0].info["dataset_hash"], dataset=str(args.data),
                          predictions=[str(p) for p in args.pred], protocol=protocol, split=args.split,
                          methods=_method_provenance(results),
                          data={"viewpoints": viewpoints_of(load(args.data, args.split).card)})
        paths = write_table1(results, args.out, prov, name=args.name, describe=describe)
        for res in results:
            seed = f"_s{res.info['seed']}" if res.info.get("seed") is not None else ""
            atomic_write_text(Path(args.out) / f"{args.name}_{res.method}_{res.category}{seed}_per_sample.csv",
                              res.per_sample.to_csv(index=False))
        print("wrote " + ", ".join(str(p) for p in paths))
    if args.twin:
        _evaluate_twins(args, results)
    return 0


def _evaluate_twins(args, results) -> None:
    """``scapo evaluate --twin``: every method's twins scored by render and compare (:func:`scapo.twin.twin_table`)."""
    from scapo.methods import describe
    from scapo.twin import twin_table

    names = [(describe(res.method) or (res.method,))[0] for res in results]
    print(twin_table(args.data, args.pred, [r.method for r in results], names, split=args.split,
                     limit=args.twin_limit, out=args.out, name=args.name))
    if args.out:
        print(f"wrote {Path(args.out) / (args.name + '_twin.md')}")


def _duplicates(paths) -> tuple[str, str] | None:
    """Two of ``paths`` naming the same file or files with identical content, or None."""
    import hashlib

    seen = {}
    for p in paths:
        try:
            key = hashlib.sha256(Path(p).read_bytes()).hexdigest()
        except OSError:
            continue  # a missing file is the evaluator's error to name
        if key in seen:
            return seen[key], str(p)
        seen[key] = str(p)
    return None


def _method_provenance(results) -> dict:
    """Per method: preset, training seeds, runs, datasets trained on, and test-time settings."""
    out: dict = {}
    for r in results:
        m = out.setdefault(r.method, {})
        for k in ("preset", "trained_on", "refine_steps", "refine_margin"):
            if k in r.info:
                m[k] = r.info[k]
        for k, key in (("run", "runs"), ("seed", "seeds")):
            if r.info.get(k) is not None:
                m.setdefault(key, []).append(r.info[k])
    return out


def _print_summary(results, protocol: str = "scapo") -> None:
    """Print Table 1 in the paper's layout (our rows and the paper's), then the medians and rates."""
    from scapo.eval.tables import table1_markdown
    from scapo.methods import describe

    print(table1_markdown(results, protocol, describe=describe))


def cmd_bench_choose(args) -> int:
    """``scapo bench choose``: pick an option value on the val split, averaged over seeds."""
    import glob

    from scapo.bench import choose_on_val
    from scapo.files import check_output_file, write_json
    from scapo.provenance import provenance

    if not args.data or not args.candidate:
        raise ConfigError("bench choose needs --data DIR and one --candidate VALUE=GLOB per value")
    if args.out:
        check_output_file(args.out, "choice file", "choice.json")
    several = len(args.data) > 1
    candidates = {}
    for spec in args.candidate:
        value, eq, pattern = spec.partition("=")
        if not eq:
            raise ConfigError(f"--candidate {spec!r} is not of the form VALUE=GLOB (e.g. 0.3='work/pred_*_m0.3.npz')")
        if several and "{data}" not in pattern:
            raise ConfigError(f"--candidate {value}: with several --data, write the dataset's place in the GLOB as "
                              f"{{data}} (e.g. {value}='{{data}}/predictions_*.npz'), got {pattern!r}")
        lists = []
        for d in args.data:
            p = pattern.replace("{data}", str(d))
            files = sorted(glob.glob(p))
            if not files:
                raise ConfigError(f"--candidate {value}: no file matches {p!r}")
            lists.append([Path(f) for f in files])
        candidates[value] = lists if several else lists[0]
    chosen, rows = choose_on_val(args.data if several else args.data[0], candidates, args.criterion,
                                 args.protocol or "scapo")
    print(f"{'value':>8s} {'score':>9s} {'val S':>7s} {'val D':>7s} {'val R':>7s}  files")
    for r in rows:
        for p in r.get("per_dataset", ()):
            print(f"{'':>8s} {p['score']:9.3f} {p['val_S']:7.2f} {p['val_D']:7.2f} {p['val_R']:7.2f}  "
                  f"{len(p['files'])}  {p['dataset']}")
        print(f"{r['value']:>8s} {r['score']:9.3f} {r['val_S']:7.2f} {r['val_D']:7.2f} {r['val_R']:7.2f}  "
              f"{len(r['files'])}{'  (mean over datasets)' if several else ''}")
    if args.out:
        write_json(args.out, {"chosen": chosen, "criterion": args.criterion, "split": "val",
                              "protocol": args.protocol or "scapo", "candidates": rows,
                              "provenance": provenance(dataset=", ".join(str(d) for d in args.data))})
    print(json.dumps({"chosen": chosen}))
    return 0


def cmd_bench_ladder(args) -> int:
    """``scapo bench ladder``: the canonical-frame diagnosis ladder (:mod:`scapo.bench.ladder`)."""
    from scapo.bench.ladder import LADDER_METHODS, RUNGS, run_ladder

    if len(args.data) or args.categories:
        raise ConfigError("bench ladder makes its own datasets: give --category (one), not --data or --categories")
    rungs = args.rungs if args.rungs is not None else list(RUNGS)
    methods = args.methods if args.methods is not None else list(LADDER_METHODS)
    cmd = "scapo bench ladder " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "scapo bench ladder"
    paths = run_ladder(args.category, methods, rungs, args.seeds, work=args.work / "ladder",
                       out=args.out or Path("results/canonical_ladder"),
                       budget_minutes=5.0 if args.budget_minutes is None else args.budget_minutes,
                       instances=args.instances or 60, views=args.views or 8,
                       train_views=16 if args.train_views is None else args.train_views, data_seed=args.seed,
                       preset=args.preset, workers=max(args.workers), command=cmd, dry_run=args.dry_run,
                       data_only=args.data_only, variants=args.variant, finished_only=args.finished_only)
    for p in paths:
        print(f"wrote {p}")
    return 0


def cmd_bench_compute(args) -> int:
    """``scapo bench compute``: accuracy against training compute (:mod:`scapo.bench.compute`)."""
    from scapo.bench.compute import COMPUTE_BUDGETS, run_compute_curve
    from scapo.bench.ladder import LADDER_METHODS

    if len(args.data) or args.categories:
        raise ConfigError("bench compute uses the ladder's datasets: give --category (one), not --data or "
                          "--categories")
    rungs = args.rungs if args.rungs is not None else ["paper"]
    if len(rungs) != 1:
        raise ConfigError(f"bench compute: give one rung (--rungs paper), got {','.join(rungs)}")
    cmd = "scapo bench compute " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "scapo bench compute"
    paths = run_compute_curve(args.category, args.methods if args.methods is not None else list(LADDER_METHODS),
                              args.budgets if args.budgets is not None else list(COMPUTE_BUDGETS), args.seeds,
                              work=args.work / "ladder", out=args.out or Path("results"), rung=rungs[0],
                              instances=args.instances or 60, views=args.views or 8,
                              train_views=16 if args.train_views is None else args.train_views, data_seed=args.seed,
                              preset=args.preset, workers=max(args.workers), command=cmd, dry_run=args.dry_run,
                              data_only=args.data_only, finished_only=args.finished_only)
    for p in paths:
        print(f"wrote {p}")
    return 0


def cmd_bench(args) -> int:
    if args.what == "compute":
        return cmd_bench_compute(args)
    if args.what == "choose":
        return cmd_bench_choose(args)
    if args.what == "ladder":
        return cmd_bench_ladder(args)
    if args.what in ("table1", "table2", "table3"):
        return cmd_bench_table(args)
    if len(args.data) > 1:
        raise ConfigError(f"bench {args.what} takes one --data, got {len(args.data)}")
    args.data = args.data[0] if args.data else None
    instances, views = args.instances or 20, args.views or 30
    if min(args.workers) < 1 or instances < 1 or views < 1:
        raise ConfigError("--workers, --instances and --views must be >= 1")
    from scapo.files import check_output_dir

    if args.out:
        check_output_dir(args.out, "benchmark output folder")
    from scapo.perf import write_perf

    if (args.baseline or args.budget_minutes is not None) and args.target != "train":
        raise ConfigError("--baseline and --budget-minutes go with 'bench perf --what train'; leave them out for "
                          f"--what {args.target}")
    extra_prov: dict = {}
    if args.target == "growth":
        from scapo.perf import bench_growth

        rows = bench_growth(args.category, sizes=tuple(args.sizes), workers=args.workers[0], cache_dir=args.cache)
        name = f"growth_{args.category}"
    elif args.target == "maniskill":
        from scapo.perf import bench_maniskill

        rows = bench_maniskill(args.category, instances=args.instances or 4, views=args.views or 32,
                               cache_dir=args.cache)
        name = f"maniskill_{args.category}"
    elif args.target == "icp":
        from scapo.perf import bench_icp

        if args.data is None:
            raise ConfigError("bench perf --what icp needs --data DATASET (ICP's template comes from its training "
                              "split)")
        rows = bench_icp(args.data, limit=args.limit)
        name = f"icp_{Path(args.data).name}"
    elif args.target == "generate":
        from scapo.perf import bench_generate

        rows = bench_generate(args.category, instances, views, tuple(args.workers), args.seed, args.cache)
        name = f"generate_{args.category}"
    elif args.target == "train":
        from scapo.perf import bench_train

        if args.data is not None:  # real training steps on a dataset, through the engine
            from scapo.perf import bench_train_data

            rows = bench_train_data(args.data, [args.method] if args.method else None, args.preset,
                                    steps=args.steps)
            name = f"train_{args.preset}_{Path(args.data).name}" + (f"_{args.method}" if args.method else "")
        else:
            rows = bench_train([args.method] if args.method else None, args.preset, device=args.device)
            name = f"train_{args.preset}" + (f"_{args.method}" if args.method else "")
        if args.budget_minutes is not None:
            from scapo.perf import training_budget

            clouds = args.train_clouds or (rows[0].get("train_clouds") if rows else None) or 840
            rows = training_budget(rows, args.budget_minutes, clouds)
            extra_prov.update(budget_minutes=args.budget_minutes, train_clouds=clouds)
        if args.baseline:
            from scapo.perf import compare_train

            rows, extra_prov = compare_train(rows, args.baseline)
            name += "_vs_baseline"
    elif args.method is None:  # SCAPO's training and inference speed
        from scapo.perf import bench_method

        rows = bench_method("scapo", args.preset, device=args.device)
        name = f"model_{args.preset}"
    else:
        from scapo.perf import bench_method

        rows = bench_method(args.method, args.preset, device=args.device, data=args.data)
        name = f"model_{args.method}_{args.preset}"
    for r in rows:
        print(r)
    if args.out:
        paths = write_perf(rows, args.out, name, **extra_prov)
        print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_bench_table(args) -> int:
    """``scapo bench table1|table2|table3``: the paper's tables, resumable per cell (``--dry-run`` lists the
    cells)."""
    from scapo.bench import parse_category_seeds
    from scapo.bench.experiments import BenchOptions, run_table

    instances = BenchOptions.instances if args.instances is None else args.instances
    views = BenchOptions.views if args.views is None else args.views
    if min(args.workers) < 1 or instances < 1 or views < 1:
        raise ConfigError("--workers, --instances and --views must be >= 1")
    run_table(args.what, args.methods, args.categories, instances=instances, views=views, data_seed=args.seed,
              work_dir=args.work, out_dir=args.out or Path("results"), preset=args.preset, seeds=args.seeds,
              category_seeds=parse_category_seeds(args.category_seeds), protocol=args.protocol, name=args.name,
              workers=args.workers[0], cache_dir=args.cache, dry_run=args.dry_run, progress=not args.no_progress,
              device=args.device, finished_only=args.finished_only, recompute_dirty=args.recompute_dirty,
              allow_dirty=args.allow_dirty, allow_mixed_commits=args.allow_mixed_commits,
              sj=not args.no_sj, upright=args.upright, archive=args.archive, data_only=args.data_only,
              viewpoints=args.viewpoints, train_views=args.train_views)
    return 0


def cmd_demo(args) -> int:
    from scapo.demo import run_demo

    run_demo(args.out, instances=args.instances, views=args.views, seed=args.seed, cache_dir=args.cache,
             preset=args.preset)
    return 0


# ------------------------------------------------------------------------------ parser
def _every_command_takes_no_progress(parser: argparse.ArgumentParser) -> None:
    """Give every (sub)command a ``--no-progress`` flag (commands without bars of their own accept it too)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                if any(isinstance(a, argparse._SubParsersAction) for a in sp._actions):
                    _every_command_takes_no_progress(sp)
                elif not any("--no-progress" in a.option_strings for a in sp._actions):
                    sp.add_argument("--no-progress", action="store_true", help="no progress bars")


@contextlib.contextmanager
def _scapo_warnings(command: str):
    """Inside the block, a :class:`~scapo.errors.ScapoWarning` prints as one line ``scapo COMMAND: warning: ...``
    (each message once); other warnings as Python shows them."""
    import warnings

    from scapo.errors import ScapoWarning

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, ScapoWarning):
            print(f"scapo {command}: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("default", ScapoWarning)
        warnings.showwarning = show
        yield


def _version_text() -> str:
    from scapo.provenance import git_commit, package_version

    return f"scapo {package_version()} ({git_commit()})"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scapo", description="Articulated-object data generation, baselines and "
                                "benchmark (SCAPO, CVPR 2026).")
    p.add_argument("--version", action="version", version=_version_text())
    sub = p.add_subparsers(dest="command", required=True)

    def common_cache(sp):
        sp.add_argument("--cache", type=Path, default=None, help="asset cache folder (default ~/.cache/scapo/assets "
                        "or $SCAPO_CACHE/assets)")

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
    common_cache(b)
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
    common_cache(m)
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
    common_cache(sp)
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

    sp = sub.add_parser("export", help="export one view's prediction as an articulated model (URDF + meshes)")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--pred", type=Path, default=None, help="predictions file of the dataset (scapo predict)")
    sp.add_argument("--run", type=Path, default=None, help="or a trained run (predicts the dataset first)")
    sp.add_argument("--sample", type=int, required=True, help="index of the sample in --split")
    sp.add_argument("--split", default="test")
    sp.add_argument("--out", type=Path, required=True, help="the twin folder (mobility.urdf, meshes/, twin.json)")
    sp.set_defaults(func=cmd_export)

    sp = sub.add_parser("view", help="interactive 3-D viewer in the browser (viser): samples, predictions, twins")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--pred", type=Path, nargs="*", default=[], action="extend",
                    help="predictions files to colour points by (repeat --pred or list several)")
    sp.add_argument("--twin", type=Path, default=None, help="a twin folder (scapo export) to show and articulate")
    sp.add_argument("--split", default="test")
    sp.add_argument("--host", default="127.0.0.1", help="listen address (0.0.0.0: reachable from other machines)")
    sp.add_argument("--port", type=int, default=8080)
    sp.set_defaults(func=cmd_view)

    sp = sub.add_parser("preview", help="PNG of dataset samples (re-rendered) with parts coloured and axes drawn")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--split", default="test", help="train, val, test or all (default test; each panel's title "
                    "names its sample's split)")
    sp.add_argument("--count", type=int, default=4)
    sp.add_argument("--out", type=Path, default=Path("preview.png"))
    common_cache(sp)
    sp.set_defaults(func=cmd_preview)

    sp = sub.add_parser("train", help="train a method (default SCAPO, both stages) on a dataset's training split")
    sp.add_argument("--method", default="scapo", help="a trained method (see 'scapo list'; default scapo)")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--preset", default=None, help="paper | cpu | test (scapo also demo; default: an existing run's "
                    "own preset, else cpu)")
    sp.add_argument("--out", type=Path, required=True, help="run folder (resumes from its checkpoint)")
    sp.add_argument("--device", default=None, help="cpu | cuda (default: the preset's, auto)")
    sp.add_argument("--seed", type=int, default=None, help="training seed (default: the preset's, 0); one run "
                    "folder per seed")
    sp.add_argument("--set", action="append", metavar="FIELD=VALUE", help="replace a preset field (repeat; dotted "
                    "for nested settings: --set stage1_epochs=40 --set losses.seg=2.0); recorded in run.json")
    sp.add_argument("--config", type=Path, default=None, help="a TOML (or YAML) file of preset fields to replace "
                    "(applied before --set)")
    sp.add_argument("--no-progress", action="store_true")
    sp.set_defaults(func=cmd_train)

    sp = sub.add_parser("predict", help="fit a method on the training split (or load a SCAPO run) and predict")
    sp.add_argument("--method", default=None, help="method name (see 'scapo list')")
    sp.add_argument("--run", type=Path, default=None, help="a run folder written by 'scapo train' (implies its "
                    "method)")
    sp.add_argument("--device", default=None)
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--out", type=Path, required=True)
    sp.add_argument("--option", action="append", help="method option key=value (repeatable)")
    sp.add_argument("--refine", action="store_true", help="fit the method's own whole-object model (canonical shape "
                    "or template) to each view after its one-pass prediction (scapo.methods.refine); the "
                    "predictions are labelled METHOD+refine")
    sp.set_defaults(func=cmd_predict)

    sp = sub.add_parser("evaluate", help="score a predictions file on a dataset's test split")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--pred", type=Path, required=True, nargs="+", action="extend",
                    help="one or more prediction files (one row per method in the table)")
    sp.add_argument("--protocol", default="scapo", help="evaluation protocol: scapo (the paper's; default), op-align, "
                    "eap (those papers' released evaluation code), scapo-per-category")
    sp.add_argument("--split", default="test", choices=["test", "val"],
                    help="test (reported results) or val (where choices are made)")
    sp.add_argument("--out", type=Path, default=None, help="write Table 1 files here")
    sp.add_argument("--name", default="table1")
    sp.add_argument("--twin", action="store_true", help="also export each sample's prediction as a URDF twin and "
                    "score it by render and compare (does it look and move like the object?)")
    sp.add_argument("--twin-limit", type=int, default=0, help="--twin: the first N samples only (0: all)")
    sp.set_defaults(func=cmd_evaluate)

    sp = sub.add_parser("bench", help="benchmarks: perf (throughput), table1 / table3 (the paper's tables, resumable "
                        "per cell), choose (an option value on the val split)")
    sp.add_argument("what", choices=["perf", "table1", "table2", "table3", "choose", "ladder", "compute"])
    sp.add_argument("--rungs", type=_names, default=None, help="ladder: rungs, easiest first (default one,complete,"
                    "paper,sphere: complete clouds of one shape at rest; of all instances and states; single views in "
                    "the paper's regime; from the whole sphere). Scored on val; --budget-minutes (default 5) core-"
                    "minutes of training per cell; --instances 60, --views 8, --train-views 16, --methods "
                    "scapo,op-align,eap,npcs by default; results in --out (default results/canonical_ladder)")
    sp.add_argument("--viewpoints", default=None, choices=["paper", "sphere", "upright"],
                    help="table1, table3: paper (default: EAP's views per source dataset, which the SCAPO paper "
                         "follows, see 'scapo generate --help'; datasets named ..._paper, --train-views views per "
                         "training instance), sphere (whole sphere: objects under uniform SO(3) rotations, harder than "
                         "the paper; the tables made before the paper's views existed; table named <table>_sphere) or "
                         "upright (the category's view ranges, the rotation diagnostic; datasets and cells in "
                         "WORK/upright/, table named <table>_upright). Table 2 is upright (real scans are natural "
                         "views)")
    sp.add_argument("--upright", action="store_true", help="table1, table3: --viewpoints upright")
    sp.add_argument("--train-views", type=int, default=None,
                    help="table1, table3: views per training instance (default: 64 with --viewpoints paper, chosen on "
                         "val (results/paper_regime/); --views otherwise)")
    sp.add_argument("--variant", action="append", default=[], metavar="METHOD:LABEL:KEY=VALUE[,KEY=VALUE]",
                    help="ladder: an extra row of METHOD with preset fields replaced (scapo train --set keys), same "
                    "budget, e.g. scapo:consensus:losses.consensus=1; repeatable")
    sp.add_argument("--no-sj", action="store_true", help="table2: leave out the semi-supervised (SJ) rows")
    sp.add_argument("--data", type=Path, action="append", default=[], help="choose: the dataset (its val split is "
                    "used); repeat to choose one value for several datasets (mean of their scores); perf --what "
                    "icp / --method: the dataset")
    sp.add_argument("--candidate", action="append", default=[], help="choose: VALUE=GLOB of that value's "
                    "predictions files (one per training seed; with several --data, {data} stands for each "
                    "dataset); repeat per value")
    sp.add_argument("--criterion", default="D+R", help="choose: what to minimise on val, averaged over seeds "
                    "(D+R, R, D, R_median, -S)")
    sp.add_argument("--protocol", default=None, help="choose, table1, table3: evaluation protocol (default scapo); "
                    "table2: default op-align, as the paper's Table 2")
    sp.add_argument("--limit", type=int, default=0, help="perf --what icp: time the first N test clouds (0: all)")
    sp.add_argument("--sizes", type=_ints, default=[100, 1000, 10000], help="perf --what growth: dataset sizes")
    sp.add_argument("--what", dest="target", choices=["generate", "model", "train", "icp", "maniskill", "growth"],
                    default="generate",
                    help="perf: generation throughput (generate), SCAPO's or a method's training/inference speed "
                    "(model), every trained method's training clouds/s per stage (train; --method for one), "
                    "ICP's two searches (icp, with --data), the ManiSkill3 backend against SAPIEN "
                    "(maniskill), generation and evaluation time against dataset size (growth)")
    sp.add_argument("--budget-minutes", type=float, default=None, help="perf --what train: the training budget per "
                    "cell in minutes (one torch thread); adds each preset's planned minutes and the epochs per stage "
                    "that fill the budget")
    sp.add_argument("--budgets", type=_floats, default=None, help="compute: training budgets in core-minutes per "
                    "cell (default 5,15,45,120); accuracy against training compute on one ladder rung (--rungs, "
                    "default paper), val split, --methods scapo,op-align,eap,npcs by default, one --seeds seed; "
                    "datasets and speeds shared with the ladder (WORK/ladder); writes OUT (default results)/"
                    "accuracy_vs_compute.{md,csv,json,png}")
    sp.add_argument("--train-clouds", type=int, default=None, help="perf --what train --budget-minutes: training "
                    "clouds of a cell (default: the --data training split, else 840: the tables' 150 instances x 8 "
                    "views, 105 training instances)")
    sp.add_argument("--steps", type=int, default=20, help="perf --what train --data: steps per epoch of the timed "
                    "two-epoch run (per stage)")
    sp.add_argument("--baseline", default=None, help="perf --what train: an earlier run's .json (e.g. at another "
                    "commit, same machine and threads): adds each stage's clouds/s before and the speed-up")
    sp.add_argument("--preset", default="cpu", help="preset of trained methods (perf --what model, table1, table3; a "
                    "method's per-category preset PRESET-CATEGORY is used where it has one)")
    sp.add_argument("--method", default=None, help="perf --what model: time this method's inference (default: "
                    "SCAPO training and inference; icp also needs --data)")
    sp.add_argument("--device", default=None, help="perf --what model, table1, table3: cpu | cuda")
    sp.add_argument("--category", default="laptop", help="perf: category")
    sp.add_argument("--categories", type=_names, default=None,
                    help="table1: default laptop,safe,eyeglasses,oven,washer; table3: default laptop,eyeglasses")
    sp.add_argument("--methods", type=_names, default=None, help="table1: default every registered method")
    sp.add_argument("--instances", type=int, default=None,
                    help="instances per category (tables: 150, a fifth of them test; perf: 20)")
    sp.add_argument("--views", type=int, default=None, help="views per instance (tables: 8; perf: 30)")
    sp.add_argument("--workers", type=_ints, default=[1, 2])
    sp.add_argument("--seed", type=int, default=0, help="seed of the data (assets, splits, views)")
    sp.add_argument("--seeds", type=_ints, default=[0], help="table1/3: training seeds of trained methods (e.g. 0,1,2)")
    sp.add_argument("--category-seeds", action="append", default=[], metavar="CAT=SEEDS",
                    help="table1/3: training seeds for one category instead of --seeds (e.g. safe=0); repeatable")
    sp.add_argument("--work", type=Path, default=Path("bench_work"), help="table1/3: datasets, runs, predictions, "
                    "cell records")
    sp.add_argument("--dry-run", action="store_true", help="table1/3: list the cells and which are done; compute "
                    "nothing")
    sp.add_argument("--finished-only", action="store_true", help="table1/2/3: train and predict nothing; write the "
                    "tables of the cells that are done or predicted (scored again when the evaluator changed "
                    "since; the others are listed in the provenance)")
    sp.add_argument("--data-only", action="store_true", help="table1/2/3: generate the datasets (with --archive: "
                    "made the archived dataset's bytes where they differ only by rounding, pinned in the archive "
                    "otherwise, their archived cells restored) and compute no cell")
    sp.add_argument("--recompute-dirty", action="store_true", help="table1/2/3: compute again, from scratch, the done "
                    "cells whose record names a -dirty commit (computed from uncommitted code; the old files are "
                    "moved to <dataset>/dirty/)")
    sp.add_argument("--allow-dirty", action="store_true", help="table1/2/3: compute or score cells from a checkout "
                    "with uncommitted changes (refused otherwise: their code could not be recovered)")
    sp.add_argument("--allow-mixed-commits", action="store_true", help="table1/2/3: write a table whose cells come "
                    "from several commits (refused otherwise, naming the cells of each commit)")
    sp.add_argument("--archive", type=Path, default=None, help="table1/2/3: keep every done cell's small files "
                    "(record, per-sample metrics, compressed predictions, run identity) in this folder, and restore "
                    "the cells archived there once their dataset is generated (a lost work folder then costs only "
                    "the datasets)")
    sp.add_argument("--name", default=None, help="table1/3: file name stem (table1_synthetic, table3_ablation)")
    sp.add_argument("--no-progress", action="store_true")
    sp.add_argument("--out", type=Path, default=None, help="write result files here (table1/3: default results/)")
    common_cache(sp)
    sp.set_defaults(func=cmd_bench)

    sp = sub.add_parser("demo", help="build assets, render, run ICP and SCAPO, evaluate, write a table and figures")
    sp.add_argument("--out", type=Path, default=Path("demo_out"))
    sp.add_argument("--preset", default="demo", help="SCAPO training preset (demo: a few minutes)")
    sp.add_argument("--instances", type=int, default=24)
    sp.add_argument("--views", type=int, default=12)
    sp.add_argument("--seed", type=int, default=0)
    common_cache(sp)
    sp.set_defaults(func=cmd_demo)
    _every_command_takes_no_progress(p)
    return p


#: What an interrupted command leaves behind, by command.
_INTERRUPTED = {
    "generate": "finished shards are kept; rerun the same command to resume",
    "train": "the last finished epoch is kept in the run's checkpoint.pt; rerun the same command to resume",
    "bench": "finished datasets, runs and predictions in the work folder are kept; rerun to resume",
    "demo": "what finished is kept in the output folder; rerun the same command to resume",
    "assets": "finished instances are kept in the asset cache",
}


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns its exit status (0 ok, 2 a user error, 3 a bug, 130 interrupted).

    Every error raised on purpose (:class:`~scapo.errors.ScapoError`) is printed as one line
    ``scapo <command>: error: <what is wrong and what to do>``; an operating-system error (disk full,
    permission) as one line naming the file. Anything else is a bug in scapo: one line says so
    (``SCAPO_DEBUG=1`` shows the traceback).
    """
    args = build_parser().parse_args(argv)
    git_commit()  # the commit of the code this process loads, recorded in provenance however long it runs
    env_before = os.environ.get("TQDM_DISABLE")
    if getattr(args, "no_progress", False):  # every tqdm bar, ours and the libraries', stays off
        os.environ["TQDM_DISABLE"] = "1"
    try:
        with _scapo_warnings(args.command):
            return int(args.func(args) or 0)
    except ScapoError as e:
        print(f"scapo {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        left = _INTERRUPTED.get(args.command, "nothing was written")
        print(f"scapo {args.command}: interrupted ({left})", file=sys.stderr)
        return 130
    except OSError as e:
        if os.environ.get("SCAPO_DEBUG"):
            raise
        where = f": {e.filename}" if e.filename else ""
        print(f"scapo {args.command}: error: {e.strerror or e}{where}", file=sys.stderr)
        return 2
    except Exception as e:  # noqa: BLE001 - the last line of defence: a bug, said as such, not a traceback
        if os.environ.get("SCAPO_DEBUG"):
            raise
        print(f"scapo {args.command}: internal error ({type(e).__name__}: {e}); this is a bug in scapo: please report "
              "it with the command line (SCAPO_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 3
    finally:
        if env_before is None:
            os.environ.pop("TQDM_DISABLE", None)
        else:
            os.environ["TQDM_DISABLE"] = env_before


if __name__ == "__main__":
    sys.exit(main())
