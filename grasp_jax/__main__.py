"""``python -m grasp_jax``: the ``grasp-jax`` command line (see :mod:`grasp_jax.cli`)."""

import sys

from .cli import main

sys.exit(main())
