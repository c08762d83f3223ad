"""slotv_jax: SLOT-V observer models of legible robot motion, in JAX.

Importing the package applies two XLA CPU settings before JAX starts (see
:mod:`slotv_jax.core.xla`); :data:`XLA_CONFIG` says what was applied.

:func:`load_observer` (SPEC §9) is :func:`slotv_jax.training.checkpoint.load_observer`, imported
on first use (PEP 562). The package's only eager import is :mod:`slotv_jax.core.xla`, for
two reasons measured on the 2-core CPU: ``import slotv_jax`` takes 0.25 s instead of
2.9 s (checkpoint pulls in JAX, Flax, MJX and Orbax), and ``python -m slotv_jax.train``
or ``python -m slotv_jax.labelers`` would otherwise find their own module already
imported by the package and warn (runpy's RuntimeWarning) before running it twice.
"""

from slotv_jax.core import __version__
from slotv_jax.core.xla import XLA_CONFIG, XlaConfig

__all__ = ["XLA_CONFIG", "XlaConfig", "__version__", "load_observer"]


def __getattr__(name: str):
    if name == "load_observer":
        from slotv_jax.training.checkpoint import load_observer  # lazy: see the module docstring

        return load_observer
    raise AttributeError(f"module 'slotv_jax' has no attribute {name!r}")
