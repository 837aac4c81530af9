"""Configuration of dataset generation (frozen; serialised into the dataset's ``config.json``)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from scapo.errors import ConfigError
from scapo.sim.assets.objects import ObjectSource
from scapo.sim.assets.templates import load_template
from scapo.sim.render import CameraConfig, RenderConfig, ViewConfig
from scapo.sim.sensor import SENSORS, SensorConfig

#: Version of the on-disk dataset layout (bump on incompatible changes).
FORMAT_VERSION = 1
#: Sensor fields added after datasets were first written (left out of a clean-sensor config at their defaults).
SENSOR_ADDED_FIELDS = ("max_range", "depth_margin", "flying", "ground")


#: seeds are 63-bit (numpy's and torch's generators take them as they are)
MAX_SEED = 2 ** 63
#: renderers a dataset can be generated with
BACKENDS = ("sapien", "maniskill")
#: the largest dataset one ``generate`` makes (its plan is held in memory before the first shard)
MAX_INSTANCES = 100_000
MAX_SAMPLES = 10_000_000

@dataclass(frozen=True)
class GenerateConfig:
    """What ``scapo generate`` renders.

    Instances ``0 .. instances-1`` of ``category`` are built with ``seed``; a fraction
    ``test_fraction`` of them (at least one when there are two or more) forms the test split, a
    fraction ``val_fraction`` of them (at least one when it is positive and the training split keeps
    one) the validation split, the rest the training split (all by instance, never by view); each
    instance is rendered from ``views`` sampled viewpoints and joint states (training instances from
    ``train_views`` when it is set: EAP renders a new view of a training instance each time it is loaded, about
    100 per instance, while val and test keep ``views``).
    """

    category: str
    """Procedural category name (see ``scapo.sim.assets.list_categories()``)."""
    instances: int
    """Number of object instances."""
    views: int
    """Samples (view + joint state) per instance."""
    seed: int = 0
    """Seed of the asset designs, the split and every sample."""
    test_fraction: float = 0.1
    """Fraction of instances in the test split (split by instance, never by view)."""
    render: RenderConfig = field(default_factory=RenderConfig)
    """Camera, point count, visibility threshold, shader, sensor model."""
    view: ViewConfig | None = None
    """Viewpoint ranges; None takes the category template's ranges."""
    shard_size: int = 64
    """Samples per shard file (the unit of atomic writes and of resuming)."""
    val_fraction: float = 0.1
    """Fraction of instances in the validation split, where every choice is made (0: no val split; the
    config of a dataset written before val splits existed reads as 0 and hashes as before)."""
    objects: tuple[ObjectSource, ...] = ()
    """Existing objects (URDF files, PartNet-Mobility folders) to render instead of procedural instances:
    instance i is object i, and ``category`` is only the dataset's label (see :mod:`scapo.sim.assets.objects`)."""
    parts: tuple[tuple[str, str], ...] = ()
    """Object datasets: the part slots ``(name, pattern)`` that define parts 1.. (empty: every movable part)."""
    scale: str = "1"
    """Object datasets: length factor, or ``fit:<rest bbox diagonal in metres>``."""
    train_views: int = 0
    """Samples per training instance (0: ``views``, as every dataset made before the field existed)."""
    one_shape: bool = False
    """Every instance is instance 0's object (one shape; the instances then differ only in their views and states):
    the one-instance rung of ``scapo bench ladder``. Procedural categories only."""
    backend: str = "sapien"
    """Renderer: "sapien" (one view at a time) or "maniskill" (ManiSkill3's parallel sub-scenes, the same draws and
    ground truth; points equal to float rounding: median 1e-5 m, 98 % within 1 mm, labels 98 % equal, as
    ``tests/test_maniskill.py`` checks), so the two give datasets of their own (the backend is part of the
    config; "sapien" is left out of it, as before the field existed)."""

    def __post_init__(self):
        from scapo.sim.assets.categories import CATEGORIES
        from scapo.sim.assets.objects import parse_scale

        if self.objects:
            if not self.category or not all(c.isalnum() or c in "_-." for c in self.category):
                raise ConfigError(f"the category label of an object dataset must be a non-empty name of letters, "
                                  f"digits, '_', '-' or '.', got {self.category!r}")
            if self.instances != len(self.objects):
                raise ConfigError(f"an object dataset has one instance per object: instances must be "
                                  f"{len(self.objects)}, got {self.instances}")
            parse_scale(self.scale)
        else:
            CATEGORIES.get(self.category)  # raises UnknownNameError listing the known categories
            if self.parts or self.scale != "1":
                raise ConfigError("--parts and --scale apply to datasets of existing objects (--object/--objects), "
                                  "not to procedural categories")
        if not 0 <= self.seed < MAX_SEED:
            raise ConfigError(f"seed must be >= 0 and < 2**63, got {self.seed}")
        if self.instances < 1 or self.views < 1:
            raise ConfigError(f"instances and views must be >= 1, got {self.instances} and {self.views}")
        if not isinstance(self.train_views, int) or isinstance(self.train_views, bool) or self.train_views < 0:
            raise ConfigError(f"train_views (--train-views) must be >= 1 (0: as --views), got {self.train_views!r}")
        if self.instances > MAX_INSTANCES or self.instances * max(self.views, self.train_views) > MAX_SAMPLES:
            raise ConfigError(f"{self.instances} instances x {max(self.views, self.train_views)} views is beyond what "
                              "one dataset holds here "
                              f"(at most {MAX_INSTANCES} instances and {MAX_SAMPLES} samples); generate several "
                              "datasets with different --seed")
        if not 0.0 <= self.test_fraction < 1.0:
            raise ConfigError(f"test_fraction must be in [0, 1), got {self.test_fraction}")
        if self.shard_size < 1:
            raise ConfigError(f"shard_size must be >= 1, got {self.shard_size}")
        if not 0.0 <= self.val_fraction < 1.0 or self.val_fraction + self.test_fraction >= 1.0:
            raise ConfigError(f"val_fraction must be in [0, 1) with val_fraction + test_fraction < 1, got "
                              f"{self.val_fraction} and {self.test_fraction}")
        if self.backend not in BACKENDS:
            raise ConfigError(f"unknown backend {self.backend!r}; known: {', '.join(BACKENDS)}")
        if self.backend != "sapien" and self.render.complete:
            raise ConfigError("--complete samples mesh surfaces without rendering: use the default backend (sapien)")
        if self.backend != "sapien" and self.render.parts_alone:
            raise ConfigError("--parts-alone renders each part in a scene of its own with the SAPIEN backend: leave "
                              "out --backend maniskill")
        if self.one_shape and self.objects:
            raise ConfigError("--one-shape applies to procedural categories; for one object give --object once")

    @property
    def view_config(self) -> ViewConfig:
        """The effective viewpoint ranges (object datasets: :class:`ViewConfig`'s defaults unless given)."""
        if self.view is not None:
            return self.view
        return ViewConfig() if self.objects else ViewConfig.from_template(load_template(self.category).view)

    @property
    def views_train(self) -> int:
        """Samples per training instance (``train_views``, or ``views`` when it is 0)."""
        return self.train_views or self.views

    def view_for(self, instance_id: int) -> ViewConfig:
        """Viewpoint ranges of one instance: the dataset's, with an object's own overrides."""
        if self.objects and self.objects[instance_id].view:
            return self.view_config.with_fields(dict(self.objects[instance_id].view))
        return self.view_config

    @property
    def symmetry(self):
        """The :class:`~scapo.sim.assets.symmetry.Symmetry` of a procedural category that has one, else None
        (object datasets: None)."""
        from scapo.sim.assets.symmetry import SYMMETRIES

        return None if self.objects else SYMMETRIES.get(self.category)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["view"] = self.view_config.stored()  # as datasets written before the viewpoint settings stored it
        if not self.train_views or self.train_views == self.views:
            del d["train_views"]  # one number of views for every split: as before the field existed
        d["format_version"] = FORMAT_VERSION
        # fields added later are left out at the value that reproduces the datasets written before them, so those
        # datasets keep their config hash and resume
        if d["render"]["cropped"] == "keep":
            del d["render"]["cropped"]
        if not d["render"]["complete"]:  # rendered views, as before complete clouds existed
            del d["render"]["complete"]
        if d["render"]["state"] == "sampled":
            del d["render"]["state"]
        if not d["render"]["parts_alone"]:  # every part in the one scene, as before the regime existed
            del d["render"]["parts_alone"]
        if not self.one_shape:
            del d["one_shape"]
        if self.render.symmetric_labels == "asset" or self.symmetry is None or self.symmetry.front is None:
            # no effect (no symmetry, or one whose labels stay the asset's): as before the rule
            del d["render"]["symmetric_labels"]
        if d["render"]["sensor"]["kind"] == "clean":  # the clean sensor ignores them
            default = dataclasses.asdict(SensorConfig())
            for k in SENSOR_ADDED_FIELDS:
                if d["render"]["sensor"][k] == default[k]:
                    del d["render"]["sensor"][k]
        if not self.val_fraction:  # identical to a config written before val splits existed
            del d["val_fraction"]
        if self.backend == "sapien":  # as before the ManiSkill3 backend could write datasets
            del d["backend"]
        if self.objects:
            d["objects"] = [o.to_dict() for o in self.objects]
            d["parts"] = [list(p) for p in self.parts]
        else:  # a procedural dataset's config is as before object datasets existed
            for k in ("objects", "parts", "scale"):
                del d[k]
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, indent=1)

    @classmethod
    def from_dict(cls, d: dict) -> GenerateConfig:
        """Inverse of :meth:`to_dict`.

        Raises:
            ConfigError: another format version, or fields missing / unknown / of the wrong type.
        """
        d = dict(d)
        d.setdefault("val_fraction", 0.0)  # written before val splits existed
        fv = d.pop("format_version", FORMAT_VERSION)
        if fv != FORMAT_VERSION:
            raise ConfigError(f"dataset format version {fv} is not supported (this scapo reads {FORMAT_VERSION})")
        try:
            r = dict(d.pop("render"))
            render = RenderConfig(camera=CameraConfig(**r.pop("camera")), sensor=SensorConfig(**r.pop("sensor")),
                                  **r)
            v = d.pop("view")
            view = ViewConfig().with_fields({k: (tuple(tuple(r) if isinstance(r, list) else r for r in x)
                                                 if isinstance(x, list) else x) for k, x in v.items()}) if v else None
            objects = tuple(ObjectSource.from_dict(o) for o in d.pop("objects", []))
            parts = tuple(tuple(p) for p in d.pop("parts", []))
            return cls(render=render, view=view, objects=objects, parts=parts, **d)
        except (KeyError, TypeError, AttributeError) as e:
            raise ConfigError(f"not a scapo generate config ({type(e).__name__}: {e}); was it written by another "
                              "version of scapo?") from None


def make_config(
    category: str, instances: int, views: int, seed: int = 0, *, num_points: int = 1024,
    sensor: str = "clean", random_rotation: bool = False, width: int | None = None, height: int | None = None,
    test_fraction: float = 0.1, min_part_fraction: float = 0.05, shard_size: int = 64, shader: str = "trivial",
    val_fraction: float = 0.1, cropped: str = "reject", objects=(), parts=(), scale: str = "1",
    view: dict | None = None, symmetric_labels: str = "view", backend: str = "sapien",
    viewpoints: str | None = None, euler_deg=None, train_views: int = 0, complete: bool = False,
    state: str = "sampled", one_shape: bool = False, parts_alone: bool = False,
) -> GenerateConfig:
    """Convenience constructor used by the CLI (named sensor, optional SO(3) rotation, image size).

    ``cropped``: what to do with views whose object touches the image border ("reject", "flag", or "keep" as
    the Table 1 datasets do; see :class:`~scapo.sim.render.RenderConfig`). ``symmetric_labels``: "view" (part
    labels of a symmetric category such as basket chosen by view) or "asset" (see
    :mod:`scapo.sim.assets.symmetry`). ``objects``: existing objects
    (paths, or :class:`~scapo.sim.assets.objects.ObjectSource`) instead of a procedural category; then
    ``category`` is the dataset's label (None: the first object's ``meta.json`` category, else "object"),
    ``instances`` is ignored, ``parts`` is the part map (``"door,drawer=*drawer*"`` or pairs) and ``scale``
    a factor or ``fit:<metres>``. ``view``: viewpoint ranges (:class:`~scapo.sim.render.ViewConfig` fields)
    replacing the category's. ``viewpoints``: "upright" (the category's azimuth/elevation ranges; the default),
    "sphere" (uniform SO(3); ``random_rotation=True`` is its older spelling) or "paper" (EAP's: the object turned in
    front of a level front camera by Euler angles in ``euler_deg``, three ``(lo, hi)`` ranges in degrees, default
    the category template's ``[paper_view]``; required for object datasets and categories without one).
    ``train_views``: samples per training instance (0: ``views``). ``complete``: points sampled on the whole posed
    mesh instead of a rendered view (:attr:`~scapo.sim.render.RenderConfig.complete`); ``state``: "sampled" or
    "rest" joint states; ``one_shape``: every instance is instance 0's object (:attr:`GenerateConfig.one_shape`);
    ``parts_alone``: every part rendered in a scene of its own, EAP's data regime
    (:attr:`~scapo.sim.render.RenderConfig.parts_alone`).

    Raises:
        ConfigError: an unknown sensor or viewpoint setting, bad sizes, fractions, part map or scale, Euler ranges
            given without ``viewpoints="paper"`` or missing for it.
        UnknownNameError: an unknown procedural category.
    """
    from scapo.sim.assets.objects import parse_parts, view_overrides

    if objects:
        objects = tuple(o if isinstance(o, ObjectSource) else ObjectSource(str(Path(o).resolve())) for o in objects)
        if category is None:
            from scapo.sim.assets.objects import find_urdf
            from scapo.sim.assets.urdf import read_meta_category

            label = read_meta_category(find_urdf(objects[0].path).parent) or "object"
            category = "".join(c if c.isalnum() or c in "_-." else "_" for c in label.lower())
        instances = len(objects)
        parts = parse_parts(parts) if isinstance(parts, str) else tuple(tuple(p) for p in parts)
    if sensor not in SENSORS:
        raise ConfigError(f"unknown sensor {sensor!r}; known sensors: {', '.join(SENSORS)}")
    cam = CameraConfig()
    cam = dataclasses.replace(cam, width=cam.width if width is None else width,
                              height=cam.height if height is None else height)
    render = RenderConfig(camera=cam, num_points=num_points, min_part_fraction=min_part_fraction,
                          shader=shader, sensor=SENSORS[sensor], cropped=cropped, symmetric_labels=symmetric_labels,
                          complete=bool(complete), state=state, parts_alone=bool(parts_alone))
    if not objects:
        from scapo.sim.assets.categories import CATEGORIES

        CATEGORIES.get(category)  # an unknown category is named before its template is looked for
    viewpoints = resolve_viewpoints(viewpoints, random_rotation)
    if viewpoints == "paper" and euler_deg is None:
        tpl = None if objects else load_template(category).paper_view
        if tpl is None:
            what = "object datasets" if objects else f"category {category!r}"
            raise ConfigError(f"--viewpoints paper needs the object's Euler ranges: {what} define none; give them "
                              "with --euler LO,HI (every axis) or LO,HI:LO,HI:LO,HI (x:y:z), degrees")
        euler_deg = tpl.euler_deg
    elif viewpoints != "paper" and euler_deg is not None:
        raise ConfigError("--euler sets the paper's viewpoints (the object's Euler ranges); give it with --viewpoints "
                          "paper")
    base = ViewConfig() if objects else (
        ViewConfig.from_template(load_template(category).view) if (view or viewpoints != "upright") else None)
    view_cfg = None
    if view:
        view_cfg = base.with_fields(dict(view_overrides(view)))
    if viewpoints != "upright":
        view_cfg = (view_cfg or base).with_fields(
            {"viewpoints": viewpoints,
             "object_euler_deg": tuple(tuple(r) for r in euler_deg) if viewpoints == "paper" else None})
    return GenerateConfig(category, instances, views, seed, test_fraction, render, view_cfg, shard_size, val_fraction,
                          tuple(objects), tuple(parts), str(scale), int(train_views or 0), bool(one_shape), backend)


def viewpoints_of(settings: dict) -> str:
    """The viewpoint setting ("upright", "paper", "sphere") of :func:`make_config` keywords (``viewpoints``, or the
    older ``random_rotation``), of a config's ``view`` dict (``object_euler_deg``, ``random_rotation``), or of a
    dataset card (its ``viewpoints``, else its config's view; "unknown" for a card without either, e.g. a converted
    dataset)."""
    if isinstance(settings.get("viewpoints"), str):
        return settings["viewpoints"]
    if "config" in settings:  # a dataset card written before the field existed
        view = (settings.get("config") or {}).get("view") or {}
        return viewpoints_of(view) if view else "unknown"
    if settings.get("object_euler_deg"):
        return "paper"
    return "sphere" if settings.get("random_rotation") else "upright"


def resolve_viewpoints(viewpoints: str | None, random_rotation: bool = False) -> str:
    """The viewpoint setting of ``--viewpoints`` and its older alias ``--random-rotation`` ("sphere").

    Raises:
        ConfigError: an unknown setting, or ``random_rotation`` with another one."""
    from scapo.sim.render import VIEWPOINTS

    if viewpoints is not None and viewpoints not in VIEWPOINTS:
        raise ConfigError(f"unknown viewpoints {viewpoints!r}; known: {', '.join(VIEWPOINTS)}")
    if random_rotation and viewpoints not in (None, "sphere"):
        raise ConfigError(f"--random-rotation is --viewpoints sphere; it contradicts --viewpoints {viewpoints}")
    return "sphere" if random_rotation else (viewpoints or "upright")


def dict_diff(old, new, prefix: str = "") -> list[str]:
    """Dotted names of the entries that differ between two nested dicts (configs, presets), e.g.
    ``["render.num_points", "views"]``; used by every "differs in ..." message."""
    if not (isinstance(old, dict) and isinstance(new, dict)):
        return [prefix.rstrip(".") or "(whole config)"] if old != new else []
    out = []
    for k in sorted(set(old) | set(new)):
        out += dict_diff(old.get(k), new.get(k), f"{prefix}{k}.")
    return out
