"""``scapo train``, ``predict``, ``evaluate``, ``export``: a method's run, its predictions, their scores, and one
view's prediction as an articulated model (each command's parser beside its handler)."""

from __future__ import annotations

import os
from pathlib import Path

from scapo.errors import ConfigError, ScapoError


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
    for kv in args.option or []:  # --set FIELD=VALUE, as scapo train's (--option is its alias)
        k, eq, v = kv.partition("=")
        if not eq or not k.strip():
            raise ConfigError(f"--set {kv!r} is not of the form FIELD=VALUE")
        if k.strip() in ("run", "device"):
            raise ConfigError(f"--set {k.strip()}=... is given as --{k.strip()} {v} (a flag of its own)")
        if k.strip() in opts:  # the last once won without a word
            raise ConfigError(f"--set {k.strip()} is given twice ({opts[k.strip()]!r} and {v!r}); give it once")
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
    named = [_named_predictions(p) for p in args.pred]
    args.pred = [path for path, _ in named]
    same = _duplicates(args.pred)
    if same:
        raise ConfigError(f"--pred {same[0]} and {same[1]} are the same predictions; give each file once (several "
                          "files of one method are its training seeds)")
    if args.out:
        from scapo.files import check_name, check_own_files

        args.name = check_name(args.name)
        check_output_dir(args.out, "table folder")
        check_own_files([Path(args.out) / f"{args.name}.{k}" for k in ("csv", "md", "tex")],
                        Path(args.out) / f"{args.name}.json", "table file",
                        "choose another --out folder or --name")
    results = [evaluate(args.data, preds, protocol=protocol, split=args.split) for _, preds in named]
    _one_file_per_run(results, args.pred)
    if args.out:  # the rows' labels name the per-sample files: each must stay inside --out (checked before writing)
        for res, path in zip(results, args.pred):
            check_name(res.method, f"the method label of {path} (its predictions' 'method'; rename the row with "
                                   "--pred LABEL=FILE)")
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


def _one_file_per_run(results, paths) -> None:
    """Several predictions files of one method are its training seeds (mean ± std): refuse two of one run.

    Raises:
        ConfigError: two files of one method from the same run folder (or naming the same training seed of a run
            trained on the same data), naming both."""
    seen = {}
    for res, path in zip(results, paths):
        info = res.info or {}
        if info.get("run"):
            key = (res.method, str(Path(info["run"]).resolve()))
        elif info.get("seed") is not None and info.get("trained_on"):
            key = (res.method, f"seed {info['seed']} on {info['trained_on']}")
        else:
            continue  # a fitted method (ICP): one file is all it has
        if key in seen:
            raise ConfigError(f"--pred {seen[key]} and {path} are predictions of one run ({key[1]}) of {res.method}; "
                              "several files of one method count as its training seeds: give one file per seed")
        seen[key] = str(path)


def _named_predictions(spec: Path) -> tuple[Path, object]:
    """``scapo evaluate --pred``: ``FILE``, or ``LABEL=FILE`` (the file's predictions as the table row ``LABEL``, e.g.
    two variants of one method side by side with the paired bootstrap; a path that exists is always a file) ->
    ``(FILE, FILE or the relabelled Predictions)``.

    Raises:
        ConfigError: ``LABEL`` is not a plain name (letters, digits, '_', '-', '.', '+').
        PredictionError: the file cannot be read as predictions (:meth:`Predictions.load`)."""
    import dataclasses

    from scapo.eval.predictions import Predictions

    text = str(spec)
    label, sep, rest = text.partition("=")
    if spec.exists() or not sep or not rest:
        return spec, spec
    if not label or not all(c.isalnum() or c in "_-.+" for c in label):
        raise ConfigError(f"--pred {text!r}: write FILE or LABEL=FILE with LABEL a plain name (letters, digits, '_', "
                          "'-', '.', '+')")
    return Path(rest), dataclasses.replace(Predictions.load(rest), method=label)


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


def add_parsers(sub) -> None:
    """Add this group's commands to the ``scapo`` parser's sub-parsers ``sub``."""
    sp = sub.add_parser("export", help="export one view's prediction as an articulated model (URDF + meshes)")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--pred", type=Path, default=None, help="predictions file of the dataset (scapo predict)")
    sp.add_argument("--run", type=Path, default=None, help="or a trained run (predicts the dataset first)")
    sp.add_argument("--sample", type=int, required=True, help="index of the sample in --split")
    sp.add_argument("--split", default="test")
    sp.add_argument("--out", type=Path, required=True, help="the twin folder (mobility.urdf, meshes/, twin.json)")
    sp.set_defaults(func=cmd_export)

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
    sp.add_argument("--set", "--option", dest="option", action="append", metavar="FIELD=VALUE",
                    help="a prediction option of the method (repeat; the syntax of scapo train --set; --option is "
                    "its alias): the prediction steps (scapo.steps.StepOptions: hinge=true, base_slot=auto, ...) and "
                    "the method's own (scapo list; e.g. SCAPO's stage2_starts=off, refine_steps=0)")
    sp.add_argument("--refine", action="store_true", help="fit the method's own whole-object model (canonical shape "
                    "or template) to each view after its one-pass prediction (scapo.steps.refine); the "
                    "predictions are labelled METHOD+refine")
    sp.set_defaults(func=cmd_predict)

    sp = sub.add_parser("evaluate", help="score a predictions file on a dataset's test split")
    sp.add_argument("--data", type=Path, required=True)
    sp.add_argument("--pred", type=Path, required=True, nargs="+", action="extend",
                    help="one or more prediction files (one row per method in the table; several files of one "
                    "method are its training seeds); LABEL=FILE names the file's row LABEL (e.g. two variants of "
                    "one method)")
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
