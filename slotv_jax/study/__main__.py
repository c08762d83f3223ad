"""``python -m slotv_jax.study``: see :mod:`slotv_jax.study.cli`."""

import sys

from slotv_jax.study.cli import main

sys.exit(main())
