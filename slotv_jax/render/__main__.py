"""``python -m slotv_jax.render``: see :mod:`slotv_jax.render.cli`."""

from slotv_jax.render.cli import main

raise SystemExit(main())
