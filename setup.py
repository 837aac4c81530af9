"""Packaging shim: everything else is in pyproject.toml. The category templates are kept in the top-level
``sim_assets/`` folder of the repository and installed as the package data ``scapo/sim_assets/``."""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["scapo", "scapo.*"]), "scapo.sim_assets"],
      package_dir={"scapo.sim_assets": "sim_assets"})
