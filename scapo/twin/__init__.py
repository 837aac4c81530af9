"""From one view to a digital twin: an articulated model (URDF) exported from one prediction."""

from scapo.twin.export import TwinReport, export_twin

__all__ = ["TwinReport", "export_twin"]
