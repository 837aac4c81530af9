"""Network building blocks of SCAPO shared by its losses and its model (and usable by other methods):
vector-neuron layers (:mod:`~scapo.nn.vn`), the SE(3)-equivariant auto-encoder
(:mod:`~scapo.nn.encoder`) and Gaussian-bone blend skinning (:mod:`~scapo.nn.skinning`).

This stage sits below :mod:`scapo.losses` and :mod:`scapo.models`, so the losses never import the model.
"""
