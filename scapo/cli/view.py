"""``scapo view``, ``preview``, ``demo``: looking at samples, predictions and twins, and the demo (each command's
parser beside its handler)."""

from __future__ import annotations

from pathlib import Path

from scapo.cli.common import add_cache
from scapo.errors import ConfigError


def cmd_view(args) -> int:
    from scapo.bench.viewer import Viewer

    v = Viewer(args.data, args.pred or (), args.twin, split=args.split, host=args.host, port=args.port)
    print(f"scapo view: open {v.url} in a browser (Ctrl-C stops)", flush=True)
    v.serve_forever()
    return 0


def cmd_preview(args) -> int:
    from scapo.bench.viz import render_dataset_samples
    from scapo.files import check_output_owned_file
    from scapo.sim.preview import save_preview

    if args.count < 1:
        raise ConfigError(f"--count must be >= 1, got {args.count}")
    check_output_owned_file(args.out, "scapo preview", "preview image", "preview.png")
    samples, titles, names = render_dataset_samples(args.data, args.split, args.count, args.cache)
    path = save_preview(samples, args.out, titles, names)
    print(f"wrote {path}")
    return 0




def cmd_demo(args) -> int:
    from scapo.bench.demo import run_demo

    run_demo(args.out, instances=args.instances, views=args.views, seed=args.seed, cache_dir=args.cache,
             preset=args.preset)
    return 0


def add_parsers(sub) -> None:
    """Add this group's commands to the ``scapo`` parser's sub-parsers ``sub``."""
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
    add_cache(sp)
    sp.set_defaults(func=cmd_preview)

    sp = sub.add_parser("demo", help="build assets, render, run ICP and SCAPO, evaluate, write a table and figures")
    sp.add_argument("--out", type=Path, default=Path("demo_out"))
    sp.add_argument("--preset", default="demo", help="SCAPO training preset (demo: a few minutes)")
    sp.add_argument("--instances", type=int, default=24)
    sp.add_argument("--views", type=int, default=12)
    sp.add_argument("--seed", type=int, default=0)
    add_cache(sp)
    sp.set_defaults(func=cmd_demo)
