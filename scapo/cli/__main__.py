"""``python -m scapo.cli ...`` (and ``torchrun --nproc_per_node N -m scapo.cli train ...``): the console script."""

import sys

from scapo.cli.main import console

sys.exit(console())
