"""The ``scapo`` console script (:mod:`scapo.cli.main`) and its command groups."""
