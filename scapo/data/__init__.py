"""Datasets: generation (:func:`generate`), storage, and loading (:func:`load`)."""

from scapo.data.config import GenerateConfig, make_config
from scapo.data.dataset import ArticulationDataset, load
from scapo.data.generate import GenerateReport, generate, plan, split_instances

__all__ = ["ArticulationDataset", "GenerateConfig", "GenerateReport", "generate", "load", "make_config", "plan",
           "split_instances"]
