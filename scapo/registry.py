"""Name -> object registries that fail loudly (one each for categories, methods and presets)."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from typing import Generic, NamedTuple, TypeVar

from scapo.errors import UnknownNameError

T = TypeVar("T")


class Registry(Generic[T]):
    """A mapping from names to registered objects.

    Args:
        kind: what the entries are ("category", "method", "preset"); used in error messages.

    Raises:
        UnknownNameError: from :meth:`get` for a name that was never registered; the message
            lists every known name.
        ValueError: from :meth:`register` when a name is registered twice.
    """

    def __init__(self, kind: str):
        self.kind = kind
        self._entries: dict[str, T] = {}

    def register(self, name: str) -> Callable[[T], T]:
        """Decorator registering ``obj`` under ``name``; returns ``obj`` unchanged."""

        def deco(obj: T) -> T:
            self.add(name, obj)
            return obj

        return deco

    def add(self, name: str, obj: T) -> None:
        """Register ``obj`` under ``name`` (error if the name is taken)."""
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is registered twice")
        self._entries[name] = obj

    def get(self, name: str) -> T:
        """Return the entry called ``name`` or raise :class:`UnknownNameError` listing known names."""
        try:
            return self._entries[name]
        except KeyError:
            known = ", ".join(sorted(self._entries)) or "(none)"
            raise UnknownNameError(f"unknown {self.kind} {name!r}; known: {known}") from None

    def remove(self, name: str) -> T:
        """Unregister ``name`` and return its entry (e.g. a method a test registered for itself).

        Raises:
            UnknownNameError: ``name`` is not registered."""
        entry = self.get(name)
        del self._entries[name]
        return entry

    def names(self) -> list[str]:
        """Registered names in registration order."""
        return list(self._entries)

    def __getitem__(self, name: str) -> T:
        """``registry[name]`` is :meth:`get` (UnknownNameError, a KeyError, for an unknown name)."""
        return self.get(name)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)


#: the supervision settings a preset name or a predictions label can name (the paper's Table 2: S, J, SJ)
SUPERVISIONS = ("S", "J", "SJ")


class PresetName(NamedTuple):
    """A preset name taken apart: ``"cpu/sj/no-shape_var"`` -> base ``cpu``, mods ``("sj", "no-shape_var")``.

    Attributes:
        base: the registered preset. mods: the parts after it, in order.
        supervision: ``"S"``, ``"J"`` or ``"SJ"`` when a part names a supervised setting, else None.
        disabled: the ``TERM`` of every ``no-TERM`` part. rest: the parts that are none of these.
        schedule: the training schedule a part ``epochs-A`` (``epochs-A-B``: stage 1 and stage 2 of a two-stage
            method) or ``iterations-N`` sets (:func:`apply_schedule`), as ``{"epochs": (A, ...)}`` /
            ``{"iterations": (N,)}``; empty without one. ``scapo bench table1 --budget-minutes`` names its cells'
            presets so (the epochs that fill the budget), so the table says the schedule each row trained with.
    """

    base: str
    mods: tuple[str, ...]
    supervision: str | None
    disabled: tuple[str, ...]
    rest: tuple[str, ...]
    schedule: dict = {}


def parse_preset(name: str) -> PresetName:
    """Take a preset name ``BASE[/MOD...]`` apart (the one parser of the preset syntax; each method decides
    which parts it accepts). A part ``sj``, ``s`` or ``j`` names the semi-supervised setting, ``no-TERM``
    switches something off, ``epochs-N[-M]`` or ``iterations-N`` sets the schedule.

    Raises:
        UnknownNameError: a part that starts as a schedule and is not one (``epochs-abc``)."""
    base, *mods = str(name).split("/")
    sup = [m.upper() for m in mods if m.upper() in SUPERVISIONS]
    off = tuple(m[3:] for m in mods if m.startswith("no-"))
    schedule, rest = {}, []
    for m in mods:
        if m.upper() in SUPERVISIONS or m.startswith("no-"):
            continue
        hit = _SCHEDULE.fullmatch(m)
        if hit:
            schedule[hit.group(1)] = tuple(int(v) for v in hit.group(2).split("-"))
        elif m.startswith(("epochs-", "iterations-")):
            raise UnknownNameError(f"unknown preset {name!r}: {m!r} is not a schedule; write epochs-N (one stage), "
                                   "epochs-N-M (two stages) or iterations-N with N, M whole numbers")
        else:
            rest.append(m)
    return PresetName(base, tuple(mods), sup[-1] if sup else None, off, tuple(rest), schedule)


_SCHEDULE = re.compile(r"(epochs|iterations)-([0-9]{1,7}(?:-[0-9]{1,7})?)")


def schedule_fields(preset) -> tuple[str, ...]:
    """The preset fields that hold a trained method's epochs, one per training stage in the engine's order:
    ``("stage1_epochs", "stage2_epochs")`` (SCAPO), ``("stage0_epochs", "epochs")`` (a learned baseline with a
    whole-object stage trained first, EAP-style), ``("epochs",)`` (one stage)."""
    if hasattr(preset, "stage2_epochs"):
        return ("stage1_epochs", "stage2_epochs")
    if hasattr(preset, "stage0_epochs"):
        return ("stage0_epochs", "epochs")
    return ("epochs",)


def schedule_part(values: dict) -> str:
    """The preset-name part (:func:`parse_preset`) that sets a schedule: ``{"stage1_epochs": 15, "stage2_epochs":
    13}`` -> ``"epochs-15-13"``, ``{"epochs": 47}`` -> ``"epochs-47"``, ``{"iterations": 400}`` ->
    ``"iterations-400"`` (the keys :func:`scapo.bench.perf.training_budget` gives)."""
    if "stage1_epochs" in values:
        return f"epochs-{int(values['stage1_epochs'])}-{int(values['stage2_epochs'])}"
    if "stage0_epochs" in values:
        return f"epochs-{int(values['stage0_epochs'])}-{int(values['epochs'])}"
    if "iterations" in values and "epochs" not in values:
        return f"iterations-{int(values['iterations'])}"
    return f"epochs-{int(values['epochs'])}"


def apply_schedule(preset, parsed: PresetName, name: str):
    """``preset`` (a frozen dataclass) with the schedule of ``parsed`` (:attr:`PresetName.schedule`): ``epochs-A``
    sets ``epochs`` (a one-stage preset), ``epochs-A-B`` the two stages' fields of :func:`schedule_fields` (a
    two-stage one),
    ``iterations-N`` ``iterations``; ``name`` (the full preset name) becomes its ``name``.

    Raises:
        UnknownNameError: a schedule the preset has no fields for, or a value < 1."""
    import dataclasses

    from scapo.errors import UnknownNameError

    fields = {}
    for key, vals in parsed.schedule.items():
        if min(vals) < 1:
            raise UnknownNameError(f"preset {name!r}: {key}-{'-'.join(map(str, vals))} must count at least 1")
        if key == "iterations" and len(vals) == 1 and hasattr(preset, "iterations"):
            fields["iterations"] = vals[0]
        elif key == "epochs" and len(vals) == len(schedule_fields(preset)):
            fields.update(zip(schedule_fields(preset), vals))
        else:
            two = len(schedule_fields(preset)) == 2
            raise UnknownNameError(f"preset {name!r}: '{key}-{'-'.join(map(str, vals))}' does not fit this method's "
                                   f"schedule; it takes " + ("epochs-STAGE1-STAGE2" if two else "epochs-N")
                                   + (" or iterations-N" if hasattr(preset, "iterations") else ""))
    return dataclasses.replace(preset, name=str(name), **fields) if fields else preset


def split_supervision_label(label: str) -> tuple[str, str] | None:
    """``"scapo-sj"`` -> ``("scapo", "SJ")``: a predictions label with a supervision suffix (a run trained with
    those labels, named by :func:`parse_preset`'s ``supervision``); None for a label without one."""
    base, _, suffix = str(label).rpartition("-")
    if base and suffix.upper() in SUPERVISIONS:
        return base, suffix.upper()
    return None
