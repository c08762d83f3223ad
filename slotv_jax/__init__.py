"""slotv_jax: SLOT-V observer models of legible robot motion, in JAX.

Importing the package applies two XLA CPU settings before JAX starts (see
:mod:`slotv_jax.core.xla`); :data:`XLA_CONFIG` says what was applied. On Linux without a
display it also sets ``MUJOCO_GL`` unless set (MuJoCo reads it once, at its import): ``egl``
where an EGL library loads, else ``disable``, so that MuJoCo loads without OpenGL and only
rendering fails, in one line (:mod:`slotv_jax.core.opengl`).

:func:`load_observer` (:ref:`concepts-observers`) is
:func:`slotv_jax.training.checkpoint.load_observer`, imported on first use (PEP 562);
``dir(slotv_jax)`` lists it with the other public names,
:data:`__all__`. The package's only eager imports are :mod:`slotv_jax.core.opengl`
and :mod:`slotv_jax.core.xla`, for two reasons measured on the 2-core CPU: ``import
slotv_jax`` takes 0.25 s instead of 2.9 s (checkpoint pulls in JAX, Flax, MJX and Orbax),
and ``python -m slotv_jax.train`` or ``python -m slotv_jax.labelers`` would otherwise
find their own module already imported by the package and warn (runpy's RuntimeWarning)
before running it twice.
"""

from slotv_jax.core import __version__, opengl
from slotv_jax.core.xla import XLA_CONFIG

# MuJoCo picks its OpenGL backend from MUJOCO_GL when it is first imported, and many
# modules import it (kinematics, data) long before anything renders: on a Linux machine
# without a display, EGL if this machine has it, else none (see slotv_jax.core.opengl).
opengl.choose_mujoco_gl()

__all__ = ["XLA_CONFIG", "__version__", "load_observer"]


def __getattr__(name: str):
    if name == "load_observer":
        from slotv_jax.training.checkpoint import load_observer  # lazy: see the module docstring

        return load_observer
    raise AttributeError(f"module 'slotv_jax' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The public names, ``load_observer`` among them before its first use (completion and
    ``help()`` read ``dir``), and none of the layers' modules the package imports itself."""
    return sorted(__all__)
