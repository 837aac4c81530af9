"""scapo: simulation-based data, baselines and benchmark for category-level articulated pose estimation.

The package follows the SCAPO paper (Zhang and Lee, CVPR 2026). Sub-packages are named after
pipeline stages:

- :mod:`scapo.sim`       procedural articulated assets (URDF + meshes) and SAPIEN rendering
- :mod:`scapo.data`      dataset generation, storage and loading
- :mod:`scapo.baselines` methods that predict part poses and joints (ICP, ...)
- :mod:`scapo.eval`      metrics, part matching, canonical-frame alignment, tables
- :mod:`scapo.cli`       the ``scapo`` console script

Conventions (hold everywhere): metres and radians; 4x4 homogeneous transforms with
column vectors ``p' = R p + t``; camera frame is OpenCV (x right, y down, z forward).
"""

__version__ = "0.1.0"
