"""How much of each part the other parts hide in one viewpoint setting: what ``scapo generate --parts-alone`` (EAP's
data regime, every part rendered in a scene of its own) changes.

For every drawn view (instances 0..I-1 of the procedural category, V views each, the generator's joint-state and
viewpoint draws), the pixels of each part in the whole-object picture are counted against its pixels when rendered
alone from the same camera at the same state; the share it loses is what the other parts hide. Views are not
rejected here (the generator would redraw those in which a part keeps too few points). Usage:
``.venv/bin/python bench/diagnostics/occlusion_share.py [--viewpoints paper] [--instances 20] [--views 4] CATEGORY
[CATEGORY ...]``; prints Markdown.
"""

import argparse

import numpy as np

from scapo.data.config import make_config
from scapo.sim.assets import build_instance, parse_urdf
from scapo.sim.render import Renderer, _draw_state, _part_map, sample_camera_pose


def hidden_shares(renderer: Renderer, category: str, instances: int, views: int, viewpoints: str, seed: int = 1
                  ) -> tuple[tuple[str, ...], np.ndarray]:
    """``(part names, (instances * views, P) float64)``: per view, the share of each part's own visible pixels that
    the other parts hide (0: none; 1: all)."""
    cfg = make_config(category, instances, views, seed, viewpoints=viewpoints)
    rows, names = [], ()
    for i in range(instances):
        spec = parse_urdf(build_instance(category, i, seed=seed).urdf)
        names = spec.part_names
        view = cfg.view_for(i)
        for v in range(views):
            rng = np.random.default_rng((i, v))
            state = _draw_state(spec, cfg.render, rng)
            T = sample_camera_pose(view, spec.bbox_diag, rng)
            renderer.submit(spec, state, T, rng)
            f = renderer.fetch()
            pm = _part_map(f.seg.astype(np.int64), f.lut)
            scene = np.array([np.count_nonzero(pm == p) for p in range(spec.num_parts)])
            renderer.submit(spec, state, T, rng, parts_alone=True)
            f = renderer.fetch()
            alone = np.array([np.count_nonzero(_part_map(f.seg[p].astype(np.int64), f.lut) == p)
                              for p in range(spec.num_parts)])
            rows.append(1.0 - scene / np.maximum(alone, 1))
    return tuple(names), np.array(rows)


if __name__ == "__main__":
    from scapo.provenance import provenance

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("categories", nargs="+")
    ap.add_argument("--viewpoints", default="paper", choices=["paper", "sphere", "upright"])
    ap.add_argument("--instances", type=int, default=20)
    ap.add_argument("--views", type=int, default=4)
    a = ap.parse_args()
    r = Renderer()
    print(f"Viewpoints {a.viewpoints}, {a.instances} instances x {a.views} views (data seed 1) per category.\n")
    print("| category | parts | mean share hidden by the other parts | views where a part loses > 25 % |\n"
          "|:--|:--|:--|--:|")
    for cat in a.categories:
        names, h = hidden_shares(r, cat, a.instances, a.views, a.viewpoints)
        shares = ", ".join(f"{n} {100 * s:.1f} %" for n, s in zip(names, h.mean(0)))
        print(f"| {cat} | {len(names)} | {shares} | {100 * np.mean(h.max(1) > 0.25):.1f} |")
    p = provenance()
    print("\nProvenance: " + ", ".join(f"{k}={p[k]}" for k in ("commit", "time") if k in p))
