"""slotv_jax: SLOT-V observer models of legible robot motion, in JAX.

Importing the package applies one XLA CPU setting before JAX starts (see
:mod:`slotv_jax._xla`); :data:`XLA_CONFIG` says what was applied.
"""

from slotv_jax._xla import XLA_CONFIG, XlaConfig

__version__ = "0.1.0"
__all__ = ["XLA_CONFIG", "XlaConfig", "__version__", "load_observer"]


def __getattr__(name: str):
    if name == "load_observer":
        from slotv_jax.checkpoint import load_observer

        return load_observer
    raise AttributeError(f"module 'slotv_jax' has no attribute {name!r}")
