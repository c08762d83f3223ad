"""``python -m slotv_jax.data``: see :mod:`slotv_jax.data.cli`."""

import sys

from slotv_jax.data.cli import main

sys.exit(main())
