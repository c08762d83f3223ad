"""``python -m slotv_jax.execution``: see :mod:`slotv_jax.execution.cli`."""

import sys

from slotv_jax.execution.cli import main

sys.exit(main())
