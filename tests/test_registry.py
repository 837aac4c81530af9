import pytest

from scapo.errors import UnknownNameError
from scapo.registry import Registry


def test_unknown_name_lists_known_names():
    reg = Registry("widget")
    reg.add("a", 1)
    reg.register("b")(2)
    assert reg.get("b") == 2 and reg.names() == ["a", "b"] and "a" in reg
    with pytest.raises(UnknownNameError, match="unknown widget 'c'; known: a, b"):
        reg.get("c")
    with pytest.raises(ValueError, match="twice"):
        reg.add("a", 3)


def test_category_and_method_registries_fail_loudly():
    from scapo.methods import METHODS
    from scapo.sim.assets import CATEGORIES

    with pytest.raises(UnknownNameError, match="laptop"):
        CATEGORIES.get("lapptop")
    with pytest.raises(UnknownNameError, match="icp"):
        METHODS.get("nope")
