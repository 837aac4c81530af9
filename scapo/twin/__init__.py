"""From one view to a digital twin: an articulated model (URDF) exported from one prediction."""

from scapo.twin.export import TwinReport, export_twin
from scapo.twin.score import TWIN_METRICS, score_twin, twin_table

__all__ = ["TWIN_METRICS", "TwinReport", "export_twin", "score_twin", "twin_table"]
