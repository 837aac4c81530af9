"""scapo: simulation-based data, baselines and benchmark for category-level articulated pose estimation.

The package follows the SCAPO paper (Zhang and Lee, CVPR 2026). Sub-packages are named after
pipeline stages, listed bottom-up (a module imports only from its own stage or lower ones; checked
by ``tests/test_layers.py``):

- :mod:`scapo.ops`       shared geometry: rigid transforms, Umeyama/Kabsch, rotation groups, FPS, Chamfer
- :mod:`scapo.sim`       procedural articulated assets (URDF + meshes) and SAPIEN rendering
- :mod:`scapo.data`      dataset generation, storage and loading
- :mod:`scapo.eval`      metrics, part matching, canonical-frame alignment, tables
- :mod:`scapo.nn`        network building blocks: vector-neuron layers, SE(3) auto-encoder, skinning
- :mod:`scapo.losses`    SCAPO's losses
- :mod:`scapo.models`    the SCAPO network, its training and inference
- :mod:`scapo.methods`   the method registry: ICP, SCAPO, OP-Align-style, EAP-style, NPCS-style
- :mod:`scapo.bench`       experiments and reports: the tables, the ladder, perf, the demo, figures, the viewer
- :mod:`scapo.cli`       the ``scapo`` console script

Conventions (hold everywhere): metres and radians; 4x4 homogeneous transforms with
column vectors ``p' = R p + t``; camera frame is OpenCV (x right, y down, z forward).
"""

__version__ = "0.1.0"
