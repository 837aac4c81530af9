"""Simulation: procedural articulated assets (:mod:`scapo.sim.assets`) and SAPIEN rendering
(:mod:`scapo.sim.render`)."""
