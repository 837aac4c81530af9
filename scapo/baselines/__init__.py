"""Methods that predict part poses and joints: the method registry and the baselines.

``METHODS.get(name)(**options)`` builds a method; ``list_methods()`` enumerates them.
Baselines are re-implementations of an approach, named "-style" in tables where they follow a
published method, and never passed off as the original code.
"""

from scapo.baselines import icp  # noqa: F401  (registers "icp")
from scapo.baselines.base import METHODS, Method, list_methods, run_method
from scapo.models import predict as _scapo_predict  # noqa: F401  (registers "scapo")

__all__ = ["METHODS", "Method", "list_methods", "run_method"]
