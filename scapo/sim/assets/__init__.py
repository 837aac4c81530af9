"""Articulated assets: procedural category generators, URDF writing, URDF / PartNet-Mobility loading.

Public API::

    list_categories()                                  -> ["laptop", "safe", ...]
    build_instance(category, instance_id, seed)        -> AssetRecord (cached on disk)
    build_category(category, instances, seed)          -> [AssetRecord, ...]
    parse_urdf(path) / load_partnet_mobility(folder)   -> ArticulationSpec
"""

from scapo.sim.assets.build import (
    GENERATOR_VERSION,
    AssetRecord,
    build_category,
    build_instance,
    default_cache_dir,
    design_instance,
    instance_dir,
    list_categories,
)
from scapo.sim.assets.categories import CATEGORIES
from scapo.sim.assets.templates import CategoryTemplate, load_template
from scapo.sim.assets.urdf import ArticulationSpec, GTJoint, load_part_mesh, load_partnet_mobility, parse_urdf

__all__ = [
    "GENERATOR_VERSION",
    "AssetRecord",
    "ArticulationSpec",
    "CATEGORIES",
    "CategoryTemplate",
    "GTJoint",
    "build_category",
    "build_instance",
    "default_cache_dir",
    "design_instance",
    "instance_dir",
    "list_categories",
    "load_part_mesh",
    "load_partnet_mobility",
    "load_template",
    "parse_urdf",
]
