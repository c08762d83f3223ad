"""``python -m slotv_jax.labelers``: see :mod:`slotv_jax.labelers.cli`."""

import sys

from slotv_jax.labelers.cli import main

sys.exit(main())
