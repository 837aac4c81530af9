"""``scapo bench``: perf, the paper's tables, choices on val, the canonical-frame ladder and accuracy against
training compute (the parser beside its handlers)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from scapo.cli.common import add_cache, floats, ints, names
from scapo.errors import ConfigError


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
        if value in candidates:
            raise ConfigError(f"--candidate {value} is given twice; give each value once (all its files in one GLOB)")
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
    from scapo.bench.ladder import DEFAULT_RUNGS, LADDER_METHODS, run_ladder

    if len(args.data) or args.categories:
        raise ConfigError("bench ladder makes its own datasets: give --category (one), not --data or --categories")
    rungs = args.rungs if args.rungs is not None else list(DEFAULT_RUNGS)
    methods = args.methods if args.methods is not None else list(LADDER_METHODS)
    cmd = "scapo bench ladder " + " ".join(sys.argv[3:]) if len(sys.argv) > 3 else "scapo bench ladder"
    paths = run_ladder(args.category, methods, rungs, args.seeds, work=args.work / "ladder",
                       out=args.out or args.work / "results",
                       budget_minutes=5.0 if args.budget_minutes is None else args.budget_minutes,
                       instances=args.instances or 60, views=args.views or 8,
                       train_views=16 if args.train_views is None else args.train_views, data_seed=args.seed,
                       preset=args.preset, workers=max(args.workers), command=cmd, dry_run=args.dry_run,
                       data_only=args.data_only, variants=args.variant, finished_only=args.finished_only,
                       allow_mixed_commits=args.allow_mixed_commits,
                       device=args.device)
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
    train_views = args.train_views  # the tables' default with --from-table (64 per training instance in the paper's
    if train_views is None:  # viewpoints, else --views), the ladder's 16 otherwise
        train_views = (64 if rungs[0] == "paper" else args.views or 8) if args.from_table else 16
    paths = run_compute_curve(args.category, args.methods if args.methods is not None else list(LADDER_METHODS),
                              args.budgets if args.budgets is not None else list(COMPUTE_BUDGETS), args.seeds,
                              work=args.work if args.from_table else args.work / "ladder",
                              out=args.out or args.work / "results", rung=rungs[0],
                              instances=args.instances or (150 if args.from_table else 60), views=args.views or 8,
                              train_views=train_views,
                              data_seed=args.seed, preset=args.preset, workers=max(args.workers), command=cmd,
                              dry_run=args.dry_run, data_only=args.data_only, finished_only=args.finished_only,
                              allow_mixed_commits=args.allow_mixed_commits,
                              from_table=args.from_table)
    for p in paths:
        print(f"wrote {p}")
    return 0


def cmd_bench(args) -> int:
    from scapo.files import owner_of

    work = Path(args.work).resolve()
    for folder in (work, *work.parents):  # the bench writes datasets and runs of its own under --work
        owner = owner_of(folder) if folder.is_dir() else None
        if owner is not None:
            raise ConfigError(f"--work {args.work} is {'' if folder == work else 'inside '}the scapo {owner} folder "
                              f"{folder}, whose files the bench's datasets and runs could replace; give a folder "
                              "outside it")
    for flag in ("instances", "views", "train_views"):  # 0 once fell back to the default without a word
        value = getattr(args, flag, None)
        if value is not None and value < 1:
            raise ConfigError(f"--{flag.replace('_', '-')} must be >= 1, got {value}; leave it out for the default")
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
    from scapo.bench.perf import write_perf

    if (args.baseline or args.budget_minutes is not None) and args.target != "train":
        raise ConfigError("--baseline and --budget-minutes go with 'bench perf --what train'; leave them out for "
                          f"--what {args.target}")
    if args.iters is not None and (args.target != "train" or args.data is not None):
        raise ConfigError("--iters goes with 'bench perf --what train' without --data (timed steps on box clouds); "
                          "with --data the timed run is set by --steps")
    if args.steps is not None and args.steps < 1:
        raise ConfigError(f"--steps must be >= 1, got {args.steps}")
    if args.iters is not None and args.iters < 1:
        raise ConfigError(f"--iters must be >= 1, got {args.iters}")
    extra_prov: dict = {}
    if args.target == "growth":
        from scapo.bench.perf import bench_growth

        rows = bench_growth(args.category, sizes=tuple(args.sizes), workers=args.workers[0], cache_dir=args.cache)
        name = f"growth_{args.category}"
    elif args.target == "maniskill":
        from scapo.bench.perf import bench_maniskill

        rows = bench_maniskill(args.category, instances=args.instances or 4, views=args.views or 32,
                               cache_dir=args.cache)
        name = f"maniskill_{args.category}"
    elif args.target == "agreement":
        from scapo.bench.perf import bench_agreement

        if args.data is None or args.method is None:
            raise ConfigError("bench perf --what agreement needs --data DATASET and --method METHOD (the method's "
                              "first --steps training steps on that dataset, eager and compiled)")
        rows = bench_agreement(args.data, args.method, args.preset, steps=args.steps or 200)
        name = f"agreement_{args.method}_{args.preset}_{Path(args.data).name}"
    elif args.target == "icp":
        from scapo.bench.perf import bench_icp

        if args.data is None:
            raise ConfigError("bench perf --what icp needs --data DATASET (ICP's template comes from its training "
                              "split)")
        rows = bench_icp(args.data, limit=args.limit, split=args.split)
        name = f"icp_{Path(args.data).name}"
    elif args.target == "generate":
        from scapo.bench.perf import bench_generate

        rows = bench_generate(args.category, instances, views, tuple(args.workers), args.seed, args.cache)
        name = f"generate_{args.category}"
    elif args.target == "train":
        from scapo.bench.perf import bench_train

        if args.data is not None:  # real training steps on a dataset, through the engine
            from scapo.bench.perf import bench_train_data

            rows = bench_train_data(args.data, [args.method] if args.method else None, args.preset,
                                    steps=args.steps or 20)
            name = f"train_{args.preset}_{Path(args.data).name}" + (f"_{args.method}" if args.method else "")
        else:
            rows = bench_train([args.method] if args.method else None, args.preset, device=args.device,
                               iters=args.iters or 5)
            name = f"train_{args.preset}" + (f"_{args.method}" if args.method else "")
        if args.budget_minutes is not None:
            from scapo.bench.perf import training_budget

            clouds = args.train_clouds or (rows[0].get("train_clouds") if rows else None) or 840
            rows = training_budget(rows, args.budget_minutes, clouds)
            extra_prov.update(budget_minutes=args.budget_minutes, train_clouds=clouds)
        if args.baseline:
            from scapo.bench.perf import compare_train

            rows, extra_prov = compare_train(rows, args.baseline)
            name += "_vs_baseline"
    elif args.method is None:  # SCAPO's training and inference speed
        from scapo.bench.perf import bench_method

        rows = bench_method("scapo", args.preset, device=args.device)
        name = f"model_{args.preset}"
    else:
        from scapo.bench.perf import bench_method

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
              work_dir=args.work, out_dir=args.out or args.work / "results", preset=args.preset, seeds=args.seeds,
              category_seeds=parse_category_seeds(args.category_seeds), protocol=args.protocol, name=args.name,
              workers=args.workers[0], cache_dir=args.cache, dry_run=args.dry_run, progress=not args.no_progress,
              device=args.device, finished_only=args.finished_only, recompute_dirty=args.recompute_dirty,
              allow_dirty=args.allow_dirty, allow_mixed_commits=args.allow_mixed_commits,
              sj=not args.no_sj, upright=args.upright, archive=args.archive, data_only=args.data_only,
              archive_predictions=args.archive_predictions, viewpoints=args.viewpoints, train_views=args.train_views,
              parts_alone=args.parts_alone,
              budget_minutes=args.budget_minutes, refine_rows=not args.no_refine_rows, parts=args.part,
              option_rows=args.option_row)
    return 0


#: The subcommands of ``scapo bench`` and their one-line help.
COMMANDS = {
    "perf": "speed, as ratios against a reference measured in the same run (--what generate|model|train|agreement|icp|"
            "maniskill|growth)",
    "table1": "Table 1: every method on the paper's metrics, resumable per cell, three seeds, one clean commit",
    "table2": "Table 2: real-world style (realistic sensor), with the semi-supervised rows",
    "table3": "Table 3: SCAPO's ablations",
    "choose": "choose an option value on the val split (--candidate VALUE=GLOB ...)",
    "ladder": "the canonical-frame diagnosis ladder: where each method's frame breaks, at equal compute, on val",
    "compute": "accuracy against training compute (--budgets), on val",
}
_TABLES = ("table1", "table2", "table3")
#: The subcommands each option belongs to (by its destination); the others do not take it.
USES = {
    "rungs": ("ladder", "compute"), "viewpoints": _TABLES, "upright": _TABLES, "parts_alone": _TABLES,
    "train_views": (*_TABLES, "ladder", "compute"), "variant": ("ladder",), "part": _TABLES, "option_row": _TABLES,
    "no_sj": _TABLES, "data": ("choose", "perf"), "candidate": ("choose",), "criterion": ("choose",),
    "protocol": ("choose", *_TABLES), "limit": ("perf",), "split": ("perf",), "sizes": ("perf",), "target": ("perf",),
    "budget_minutes": ("perf", *_TABLES, "ladder"), "no_refine_rows": _TABLES, "budgets": ("compute",),
    "train_clouds": ("perf",), "iters": ("perf",), "steps": ("perf",), "baseline": ("perf",),
    "preset": ("perf", *_TABLES, "ladder", "compute"), "method": ("perf",), "device": ("perf", *_TABLES, "ladder"),
    "category": ("perf", "ladder", "compute"), "categories": _TABLES, "methods": (*_TABLES, "ladder", "compute"),
    "instances": ("perf", *_TABLES, "ladder", "compute"), "views": ("perf", *_TABLES, "ladder", "compute"),
    "workers": ("perf", *_TABLES, "ladder", "compute"), "seed": ("perf", *_TABLES, "ladder", "compute"),
    "seeds": (*_TABLES, "ladder", "compute"), "category_seeds": _TABLES, "from_table": ("compute",),
    "dry_run": (*_TABLES, "ladder", "compute"), "finished_only": (*_TABLES, "ladder", "compute"),
    "data_only": (*_TABLES, "ladder", "compute"), "recompute_dirty": _TABLES, "allow_dirty": _TABLES,
    "allow_mixed_commits": (*_TABLES, "ladder", "compute"), "archive": _TABLES, "archive_predictions": _TABLES,
    "name": _TABLES,
}


def add_parsers(sub) -> None:
    """Add ``scapo bench`` and its subcommands (:data:`COMMANDS`) to the ``scapo`` parser's sub-parsers ``sub``: each
    subcommand takes the options of :data:`USES` that name it (and ``--work``, ``--out``, ``--cache``,
    ``--no-progress``), with its own help; an option it does not take is a usage error."""
    sp = sub.add_parser("bench", help="benchmarks: " + ", ".join(COMMANDS) + " (scapo bench COMMAND --help)")
    bsub = sp.add_subparsers(dest="what", metavar="COMMAND", required=True)
    parsers = {w: bsub.add_parser(w, help=h, description=h) for w, h in COMMANDS.items()}
    options: list[tuple[tuple, dict]] = []

    def opt(*flags, **kwargs):
        options.append((flags, kwargs))

    opt("--rungs", type=names, default=None, help="ladder: rungs, easiest first (default one,complete,"
                    "paper,sphere: complete clouds of one shape at rest; of all instances and states; single views in "
                    "the paper's regime; from the whole sphere; 'aligned', asked for by name: complete clouds of all "
                    "instances and states with no rotation, the frame given). Scored on val; --budget-minutes "
                    "(default 5) core-minutes of training per cell; --instances 60, --views 8, --train-views 16, "
                    "--methods scapo,op-align,eap,npcs by default; results in --out (default WORK/results)")
    opt("--viewpoints", default=None, choices=["paper", "sphere", "upright"],
                    help="table1, table3: paper (default: EAP's views per source dataset, which the SCAPO paper "
                         "follows, see 'scapo generate --help'; datasets named ..._paper, --train-views views per "
                         "training instance), sphere (whole sphere: objects under uniform SO(3) rotations, harder than "
                         "the paper; the tables made before the paper's views existed; table named <table>_sphere) or "
                         "upright (the category's view ranges, the rotation diagnostic; datasets and cells in "
                         "WORK/upright/, table named <table>_upright). Table 2 is upright (real scans are natural "
                         "views)")
    opt("--upright", action="store_true", help="table1, table3: --viewpoints upright")
    opt("--parts-alone", action="store_true", help="table1, table3: every part rendered in a scene of its own "
        "(scapo generate --parts-alone: EAP's data regime, no part hides another); tables <name>_parts_alone")
    opt("--train-views", type=int, default=None,
                    help="table1, table3: views per training instance (default: 64 with --viewpoints paper, chosen on "
                         "val (results/paper_regime/); --views otherwise)")
    opt("--variant", action="append", default=[], metavar="METHOD:LABEL:KEY=VALUE[,KEY=VALUE]",
                    help="ladder: an extra row of METHOD with preset fields replaced (scapo train --set keys), same "
                    "budget, e.g. scapo:consensus:losses.consensus=1; preset=NAME trains another preset of METHOD "
                    "(its own measured speed), e.g. scapo:cpu-laptop:preset=cpu-laptop; repeatable")
    opt("--part", action="append", default=[], metavar="METHOD/PART",
                    help="table1: an extra row of trained METHOD with its preset's part PART (preset <preset>/PART, "
                    "e.g. scapo/principal), labelled METHOD-PART, same seeds and budget; repeatable")
    opt("--option-row", action="append", default=[], metavar="METHOD:LABEL:KEY=VALUE[,KEY=VALUE]",
                    help="table1: an extra row of trained METHOD's own runs predicted with these prediction options "
                    "(scapo predict --option keys, e.g. scapo:base-frame:base_frame=principal), labelled "
                    "METHOD-LABEL; no training; repeatable")
    opt("--no-sj", action="store_true", help="table2: leave out the semi-supervised (SJ) rows")
    opt("--data", type=Path, action="append", default=[], help="choose: the dataset (its val split is "
                    "used); repeat to choose one value for several datasets (mean of their scores); perf --what "
                    "icp / --method: the dataset")
    opt("--candidate", action="append", default=[], help="choose: VALUE=GLOB of that value's "
                    "predictions files (one per training seed; with several --data, {data} stands for each "
                    "dataset); repeat per value")
    opt("--criterion", default="D+R", help="choose: what to minimise on val, averaged over seeds "
                    "(D+R, R, D, R_median, -S)")
    opt("--protocol", default=None, help="choose, table1, table3: evaluation protocol (default scapo); "
                    "table2: default op-align, as the paper's Table 2")
    opt("--limit", type=int, default=0, help="perf --what icp: time the first N clouds of --split (0: all)")
    opt("--split", default="val", choices=["val", "test"],
        help="perf --what icp: the split whose clouds are timed and scored (default val, where a choice between the "
             "searches is made; test for a dataset without a val split)")
    opt("--sizes", type=ints, default=[100, 1000, 10000], help="perf --what growth: dataset sizes")
    opt("--what", dest="target", choices=["generate", "model", "train", "agreement", "icp",
                                                                "maniskill", "growth"],
                    default="generate",
                    help="perf: generation throughput (generate), SCAPO's or a method's training/inference speed "
                    "(model), every trained method's training clouds/s per stage (train; --method for one), a "
                    "method's first --steps (200) training losses eager and compiled (agreement, with --data), "
                    "ICP's two searches (icp, with --data), the ManiSkill3 backend against SAPIEN "
                    "(maniskill), generation and evaluation time against dataset size (growth)")
    opt("--budget-minutes", type=float, default=None, help="perf --what train: the training budget per "
                    "cell in minutes (one torch thread); adds each preset's planned minutes and the epochs per stage "
                    "that fill the budget. table1, table3: every trained cell trains for the epochs that fill this "
                    "many core-minutes (speeds measured once per dataset and method; run the cells one torch thread "
                    "per core); its preset is named PRESET/epochs-... . ladder: per trained cell (default 5)")
    opt("--no-refine-rows", action="store_true", help="table1, table2: one-pass rows only (no "
                    "METHOD+refine rows)")
    opt("--budgets", type=floats, default=None, help="compute: training budgets in core-minutes per "
                    "cell (default 5,15,45,120); accuracy against training compute on one ladder rung (--rungs, "
                    "default paper), val split, --methods scapo,op-align,eap,npcs by default, one --seeds seed; "
                    "datasets and speeds shared with the ladder (WORK/ladder); writes OUT (default results)/"
                    "accuracy_vs_compute.{md,csv,json,png}")
    opt("--train-clouds", type=int, default=None, help="perf --what train --budget-minutes: training "
                    "clouds of a cell (default: the --data training split, else 840: the tables' 150 instances x 8 "
                    "views, 105 training instances)")
    opt("--iters", type=int, default=None, help="perf --what train (without --data): timed optimiser "
                    "steps per method and stage after a warm-up, default 5; the median is reported (more: less noise)")
    opt("--steps", type=int, default=None, help="perf --what train --data: steps per epoch of the timed "
                    "two-epoch run (per stage; default 20); perf --what agreement: training steps compared (default "
                    "200)")
    opt("--baseline", default=None, help="perf --what train: an earlier run's .json (e.g. at another "
                    "commit, same machine and threads): adds each stage's clouds/s before and the speed-up")
    opt("--preset", default="cpu", help="preset of trained methods (perf --what model, table1, table3, "
                    "ladder, compute), the same for every category; a per-category preset is a labelled row "
                    "(ladder: --variant METHOD:LABEL:preset=NAME)")
    opt("--method", default=None, help="perf --what model: time this method's inference (default: "
                    "SCAPO training and inference; icp also needs --data)")
    opt("--device", default=None, help="perf --what model, table1, table3, ladder: cpu | cuda "
                    "(ladder: its budget is then minutes of that device)")
    opt("--category", default="laptop", help="perf: category")
    opt("--categories", type=names, default=None,
                    help="table1: default laptop,safe,eyeglasses,oven,washer; table3: default laptop,eyeglasses")
    opt("--methods", type=names, default=None, help="table1: default every registered method")
    opt("--instances", type=int, default=None,
                    help="instances per category (tables: 150, a fifth of them test; perf: 20)")
    opt("--views", type=int, default=None, help="views per instance (tables: 8; perf: 30)")
    opt("--workers", type=ints, default=[1, 2])
    opt("--seed", type=int, default=0, help="seed of the data (assets, splits, views)")
    opt("--seeds", type=ints, default=[0], help="table1/3: training seeds of trained methods (e.g. 0,1,2)")
    opt("--category-seeds", action="append", default=[], metavar="CAT=SEEDS",
                    help="table1/3: training seeds for one category instead of --seeds (e.g. safe=0); repeatable")
    opt("--work", type=Path, default=Path("bench_work"), help="table1/3: datasets, runs, predictions, "
                    "cell records")
    opt("--from-table", action="store_true",
                    help="compute: the curve of a table's own cells: --work is a 'bench table1 --budget-minutes' work "
                         "folder whose dataset (default --instances 150, --views 8, --train-views 64 in the paper's "
                         "viewpoints), measured speeds, presets and budget rule (one-time work charged) are used; a "
                         "cell at the table's own budget and seed starts from the table's finished run")
    opt("--dry-run", action="store_true", help="table1/3: list the cells and which are done; compute "
                    "nothing")
    opt("--finished-only", action="store_true", help="table1/2/3: train and predict nothing; write the "
                    "tables of the cells that are done or predicted (scored again when the evaluator changed "
                    "since; the others are listed in the provenance)")
    opt("--data-only", action="store_true", help="table1/2/3: generate the datasets (with --archive: "
                    "made the archived dataset's bytes where they differ only by rounding, pinned in the archive "
                    "otherwise, their archived cells restored) and compute no cell")
    opt("--recompute-dirty", action="store_true", help="table1/2/3: compute again, from scratch, the done "
                    "cells whose record names a -dirty commit (computed from uncommitted code; the old files are "
                    "moved to <dataset>/dirty/)")
    opt("--allow-dirty", action="store_true", help="table1/2/3: compute or score cells from a checkout "
                    "with uncommitted changes (refused otherwise: their code could not be recovered)")
    opt("--allow-mixed-commits", action="store_true", help="table1/2/3, ladder, compute: write a table whose cells "
                    "come from several commits (refused otherwise, naming the cells of each commit)")
    opt("--archive", type=Path, default=None, help="table1/2/3: keep every done cell's small files "
                    "(record with its predictions' sha256, per-sample metrics, run identity) in this folder, and "
                    "restore the cells archived there once their dataset is generated (a lost work folder then costs "
                    "only the datasets; a restored cell is tabled from its record and per-sample metrics)")
    opt("--archive-predictions", action="store_true", help="table1/2/3 --archive: also keep each "
                    "cell's predictions (xz; most of an archive's size), so that a restored cell can be scored again "
                    "by a changed evaluator or adopted by a dataset regenerated on another CPU kind")
    opt("--name", default=None, help="table1/3: file name stem (table1_synthetic, table3_ablation)")
    opt("--no-progress", action="store_true")
    opt("--out", type=Path, default=None, help="write result files here (table1/3, ladder, compute: "
                    "default WORK/results; the committed results/ only when named)")
    for what, parser in parsers.items():
        defaults = {}
        for flags, kwargs in options:
            dest = kwargs.get("dest") or next(f for f in flags if f.startswith("--"))[2:].replace("-", "_")
            if dest in USES and what not in USES[dest]:
                defaults[dest] = kwargs.get("default", False if kwargs.get("action") == "store_true" else None)
            else:
                parser.add_argument(*flags, **kwargs)
        add_cache(parser)
        parser.set_defaults(func=cmd_bench, **defaults)
