"""Shared geometric operations, the lowest stage of scapo above the foundation modules.

``rigid`` (transforms, joint motions; numpy), ``align`` (Umeyama, Kabsch, RANSAC), ``groups``
(finite rotation groups, random rotations), ``sampling`` (farthest-point sampling) and ``chamfer``
(Chamfer variants; torch). Everything above (sim, data, eval, losses, models, methods) imports these;
they import nothing of scapo but :mod:`scapo.errors`. ``tests/test_layers.py`` enforces the direction.
"""
