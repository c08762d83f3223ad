"""slotv_jax: SLOT-V observer models of legible robot motion, in JAX.

Importing the package applies two XLA CPU settings before JAX starts (see
:mod:`slotv_jax.core.xla`); :data:`XLA_CONFIG` says what was applied. On Linux without a
display it also sets ``MUJOCO_GL=egl`` unless set (MuJoCo reads it once, at its import).

:func:`load_observer` (SPEC §9) is :func:`slotv_jax.training.checkpoint.load_observer`, imported
on first use (PEP 562). The package's only eager import is :mod:`slotv_jax.core.xla`, for
two reasons measured on the 2-core CPU: ``import slotv_jax`` takes 0.25 s instead of
2.9 s (checkpoint pulls in JAX, Flax, MJX and Orbax), and ``python -m slotv_jax.train``
or ``python -m slotv_jax.labelers`` would otherwise find their own module already
imported by the package and warn (runpy's RuntimeWarning) before running it twice.
"""

import os
import sys

# MuJoCo picks its OpenGL backend from MUJOCO_GL when it is first imported, and many
# modules import it (kinematics, data) long before anything renders: on a Linux machine
# without a display, EGL (a GPU's, or Mesa's software one) unless the user chose.
if (
    sys.platform.startswith("linux")
    and "mujoco" not in sys.modules
    and not os.environ.get("DISPLAY")
    and not os.environ.get("WAYLAND_DISPLAY")
):
    os.environ.setdefault("MUJOCO_GL", "egl")

from slotv_jax.core import __version__
from slotv_jax.core.xla import XLA_CONFIG, XlaConfig

__all__ = ["XLA_CONFIG", "XlaConfig", "__version__", "load_observer"]


def __getattr__(name: str):
    if name == "load_observer":
        from slotv_jax.training.checkpoint import load_observer  # lazy: see the module docstring

        return load_observer
    raise AttributeError(f"module 'slotv_jax' has no attribute {name!r}")
