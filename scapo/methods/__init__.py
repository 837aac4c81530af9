"""Methods that predict part poses and joints, in one neutral registry (one module per method).

``METHODS.get(name)`` is a :class:`~scapo.methods.registry.MethodEntry` (factory, options dataclass,
display name, supervision marks, alignment need, trainer); :func:`run_method` fits or loads a method
and writes its predictions; :func:`load` loads a trained run of any method for prediction.
Re-implementations of other papers' methods are named "-style" in tables
and say in their module docstring what differs from the original.
"""

from scapo.methods import eap, icp, npcs, op_align, scapo  # noqa: F401  (each module registers its method)
from scapo.methods.registry import (
    METHODS,
    Method,
    MethodEntry,
    describe,
    list_methods,
    load_run,
    method_of_run,
    options_class,
    register_method,
    run_method,
    train_method,
    validate_options,
)

load = load_run  # scapo.methods.load(run): a trained run of any method, ready to predict

__all__ = ["METHODS", "Method", "MethodEntry", "describe", "list_methods", "load", "load_run", "method_of_run",
           "options_class", "register_method", "run_method", "train_method", "validate_options"]
