"""Category templates: parameter ranges, styles, joint ranges and view ranges, kept as data.

Each category has one TOML file in ``sim_assets/categories/<name>.toml`` (see that folder).
The templates ship inside the package (package data), so a wheel install or a remote worker (Ray) finds
them where it imports scapo from; ``$SCAPO_SIM_ASSETS`` points to another folder of templates instead.
"""

from __future__ import annotations

import hashlib
import math
import os
import tomllib
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from scapo.errors import ConfigError


def sim_assets_dir() -> Path:
    """Directory holding the category templates: ``$SCAPO_SIM_ASSETS`` when set, else the repository's top-level
    ``sim_assets/`` (a checkout or an editable install), else the installed package data ``scapo/sim_assets/`` (a
    wheel: ``setup.py`` maps the folder there).

    Raises:
        ConfigError: the folder has no ``categories/`` (a ``$SCAPO_SIM_ASSETS`` pointing elsewhere, or an
            installation made without the package data).
    """
    env = os.environ.get("SCAPO_SIM_ASSETS")
    here = Path(__file__).resolve().parents[2]  # the installed (or checked-out) scapo package
    options = [Path(env)] if env else [here.parent / "sim_assets", here / "sim_assets"]
    for c in options:
        if (c / "categories").is_dir():
            return c
    c = options[-1]
    raise ConfigError(
        f"cannot find the category templates in {c / 'categories'}; "
        + ("set SCAPO_SIM_ASSETS to a folder holding categories/*.toml" if env else
           "reinstall scapo ('pip install .'): its package data (scapo/sim_assets, from the repository's "
           "sim_assets/) is missing")
    )


@dataclass(frozen=True)
class JointTemplate:
    """Sampled state range of one joint, relative to the rest state.

    Attributes:
        name: joint name in the URDF. type: "revolute" or "prismatic".
        parent, child: part names.
        range: (lo, hi) in radians (revolute) or as given (prismatic, see ``range_scale``).
        range_scale: for prismatic joints, the design parameter (e.g. "drawer_depth") the range
            is a fraction of; empty when the range is in metres.
    """

    name: str
    type: str
    parent: str
    child: str
    range: tuple[float, float]
    range_scale: str = ""


@dataclass(frozen=True)
class ViewTemplate:
    """Viewpoint ranges (degrees; distance as a multiple of the rest-state bbox diagonal)."""

    azimuth_deg: tuple[float, float] = (-70.0, 70.0)
    elevation_deg: tuple[float, float] = (10.0, 60.0)
    distance: tuple[float, float] = (1.4, 2.4)
    roll_deg: tuple[float, float] = (-5.0, 5.0)


@dataclass(frozen=True)
class PaperViewTemplate:
    """The ``[paper_view]`` table of a category: the ranges of the object's Euler angles about x, y and z
    (degrees; ``R = Rz Ry Rx``, :class:`~scapo.sim.render.ViewConfig`'s ``paper`` setting) and where they come from
    (``source``: the paper or code file the ranges are read from)."""

    euler_deg: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    source: str = ""


#: Tables of a category TOML that set only viewpoints and were added after the assets were first built: they are
#: left out of the template digest (the asset cache key), so that adding them keeps every instance's digest and the
#: datasets rendered from those instances.
VIEW_ONLY_TABLES = ("paper_view",)


def asset_digest_text(text: str) -> str:
    """The TOML text the template digest is taken over: ``text`` without the :data:`VIEW_ONLY_TABLES` (each from its
    ``[name]`` header to the next header or the end) and the blank lines just before them."""
    lines = text.splitlines(keepends=True)
    out: list[str] = []
    skip = False
    for line in lines:
        head = line.strip()
        if head.startswith("["):
            skip = head.split("#")[0].strip() in {f"[{t}]" for t in VIEW_ONLY_TABLES}
            if skip:
                while out and not out[-1].strip():
                    out.pop()
        if not skip:
            out.append(line)
    return "".join(out)


def _paper_view(raw: dict, path) -> PaperViewTemplate | None:
    t = raw.get("paper_view")
    if t is None:
        return None
    where = f"{path}: paper_view"
    if not isinstance(t, dict):
        raise ConfigError(f"{where} must be a table")
    unknown = set(t) - {"euler_deg", "source"}
    if unknown:
        raise ConfigError(f"{where}: unknown fields {sorted(unknown)} (known: euler_deg, source)")
    eul = t.get("euler_deg")
    if not (isinstance(eul, list) and len(eul) == 3):
        raise ConfigError(f"{where}.euler_deg must be three [lo, hi] ranges (x, y, z; degrees), got {eul!r}")
    ranges = tuple(_pair(r, f"{where}.euler_deg[{i}]") for i, r in enumerate(eul))
    if any(lo < -180.0 or hi > 180.0 for lo, hi in ranges):
        raise ConfigError(f"{where}.euler_deg: angles must lie in [-180, 180] degrees, got {eul!r}")
    source = t.get("source", "")
    if not isinstance(source, str):
        raise ConfigError(f"{where}.source must be a string")
    return PaperViewTemplate(ranges, source)


@dataclass(frozen=True)
class CategoryTemplate:
    """Everything about a category that is data rather than code.

    Attributes:
        name: category name. parts: part names, base part first. description: one line.
        params: name -> (lo, hi) uniform ranges. styles: name -> tuple of choices.
        joints: joint templates in URDF order. view: default viewpoint ranges.
        digest: sha256 of the TOML file (part of the asset cache key).
    """

    name: str
    parts: tuple[str, ...]
    description: str
    params: dict[str, tuple[float, float]]
    styles: dict[str, tuple[str, ...]]
    joints: tuple[JointTemplate, ...]
    view: ViewTemplate
    digest: str = field(default="", compare=False)
    paper_view: PaperViewTemplate | None = None
    """The ``[paper_view]`` table: the paper's (EAP's) viewpoint ranges (``scapo generate --viewpoints paper``);
    None where the category has none."""


def _pair(value, where: str) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, int | float) for v in value)):
        raise ConfigError(f"{where}: expected a [lo, hi] pair of numbers, got {value!r}")
    lo, hi = float(value[0]), float(value[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise ConfigError(f"{where}: need finite lo <= hi, got {value!r}")
    return lo, hi


def parse_template(path: Path) -> CategoryTemplate:
    """Parse and validate one category TOML file.

    Raises:
        ConfigError: naming the file and the field for missing or malformed entries.
    """
    raw_bytes = Path(path).read_bytes()
    try:
        raw = tomllib.loads(raw_bytes.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: not valid TOML ({e})") from e
    try:
        cat = raw["category"]
        name, parts = cat["name"], tuple(cat["parts"])
    except KeyError as e:
        raise ConfigError(f"{path}: missing [category] field {e}") from None
    params = {k: _pair(v, f"{path}: params.{k}") for k, v in raw.get("params", {}).items()}
    styles = {}
    for k, v in raw.get("styles", {}).items():
        if not (isinstance(v, list) and v and all(isinstance(s, str) for s in v)):
            raise ConfigError(f"{path}: styles.{k} must be a non-empty list of strings")
        styles[k] = tuple(v)
    joints = []
    for jname, j in raw.get("joints", {}).items():
        where = f"{path}: joints.{jname}"
        jtype = j.get("type")
        if jtype not in ("revolute", "prismatic"):
            raise ConfigError(f"{where}.type must be 'revolute' or 'prismatic', got {jtype!r}")
        for key in ("parent", "child"):
            if j.get(key) not in parts:
                raise ConfigError(f"{where}.{key} must be one of the parts {parts}, got {j.get(key)!r}")
        if jtype == "revolute":
            lo, hi = _pair(j.get("range_deg"), f"{where}.range_deg")
            rng = (math.radians(lo), math.radians(hi))
            scale = ""
        else:
            rng = _pair(j.get("range"), f"{where}.range")
            scale = j.get("range_scale", "")
        joints.append(JointTemplate(jname, jtype, j["parent"], j["child"], rng, scale))
    v = raw.get("view", {})
    view = ViewTemplate(
        **{k: _pair(val, f"{path}: view.{k}") for k, val in v.items() if k in ViewTemplate.__dataclass_fields__}
    )
    unknown_view = set(v) - set(ViewTemplate.__dataclass_fields__)
    if unknown_view:
        raise ConfigError(f"{path}: unknown view fields {sorted(unknown_view)}")
    return CategoryTemplate(
        name=name,
        parts=parts,
        description=cat.get("description", ""),
        params=params,
        styles=styles,
        joints=tuple(joints),
        view=view,
        digest=hashlib.sha256(asset_digest_text(raw_bytes.decode()).encode()).hexdigest(),
        paper_view=_paper_view(raw, path),
    )


@cache
def load_template(category: str) -> CategoryTemplate:
    """The template of ``category`` from ``sim_assets/categories/<category>.toml``.

    Raises:
        ConfigError: if the file is missing or malformed.
    """
    path = sim_assets_dir() / "categories" / f"{category}.toml"
    if not path.is_file():
        raise ConfigError(f"no template for category {category!r} at {path}")
    tpl = parse_template(path)
    if tpl.name != category:
        raise ConfigError(f"{path}: [category].name is {tpl.name!r}, expected {category!r}")
    return tpl


class ParamSampler:
    """Draws design parameters of one instance from a template with a numpy Generator.

    Every draw is recorded in :attr:`values` (written to the instance's ``asset.json``).
    Asking for a name that the template does not define raises :class:`ConfigError`.
    """

    def __init__(self, template: CategoryTemplate, rng: np.random.Generator):
        self.template = template
        self.rng = rng
        self.values: dict[str, float | str] = {}

    def u(self, name: str) -> float:
        """Uniform draw of the continuous parameter ``name`` (rounded to 0.1 mm / 1e-4)."""
        try:
            lo, hi = self.template.params[name]
        except KeyError:
            raise ConfigError(f"category {self.template.name!r} defines no parameter {name!r}") from None
        value = round(float(self.rng.uniform(lo, hi)), 4)
        self.values[name] = value
        return value

    def choice(self, name: str) -> str:
        """Uniform draw among the styles called ``name``."""
        try:
            options = self.template.styles[name]
        except KeyError:
            raise ConfigError(f"category {self.template.name!r} defines no style {name!r}") from None
        value = options[int(self.rng.integers(len(options)))]
        self.values[name] = value
        return value

    def unused(self) -> list[str]:
        """Template parameters and styles that were never drawn (a generator bug if non-empty)."""
        return sorted((set(self.template.params) | set(self.template.styles)) - set(self.values))
