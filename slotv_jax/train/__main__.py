"""``python -m slotv_jax.train``: see :mod:`slotv_jax.train.cli`."""

import sys

from slotv_jax.train.cli import main

sys.exit(main())
