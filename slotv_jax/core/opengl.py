"""Which OpenGL backend MuJoCo loads, chosen before MuJoCo is first imported.

MuJoCo reads ``MUJOCO_GL`` once, when it is imported, and imports that backend's Python
module then (``mujoco.rendering.classic.gl_context``): ``egl`` imports PyOpenGL's EGL
bindings, unset (on Linux) imports GLFW, ``disable`` imports none. Many modules import
MuJoCo (kinematics, data) long before anything renders, so :func:`choose_mujoco_gl`
decides when ``slotv_jax`` is imported, on a Linux machine without a display whose user
has not set ``MUJOCO_GL``:

- an EGL library loads (a GPU's, or Mesa's software one): ``MUJOCO_GL=egl``;
- none does (a plain CUDA container, say): ``MUJOCO_GL=disable``. With ``egl`` MuJoCo's
  import would fail inside PyOpenGL (``AttributeError: 'NoneType' object has no attribute
  'eglQueryString'``) and take every command with it, training and labelling too, which
  need no OpenGL; left unset, the import would load GLFW, whose Python package starts a
  Python process per copy of its library to read the version, and could not draw without
  a display either. With ``disable`` everything but rendering works, and rendering says
  in one line what is missing (:mod:`slotv_jax.rendering.backend`).

The standard library only: this runs inside ``import slotv_jax``, which stays cheap.

>>> choose_mujoco_gl({"MUJOCO_GL": "osmesa"})  # the user's choice is kept
'osmesa'
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import MutableMapping

# The names PyOpenGL's EGL platform tries (OpenGL.platform.ctypesloader: libEGL.so, then
# libEGL.so.9 ... libEGL.so.0), libEGL.so.1 (libglvnd's, the usual one) first.
EGL_NAMES = ("libEGL.so.1", "libEGL.so", *(f"libEGL.so.{i}" for i in range(9, -1, -1) if i != 1))
DISABLED = "disable"  # the MUJOCO_GL value with which MuJoCo imports no OpenGL backend
EGL_BACKENDS = ("", "egl", DISABLED)  # MUJOCO_GL values (lower case) that render through EGL


def headless(environ: MutableMapping[str, str] = os.environ) -> bool:
    """True on Linux without an X or Wayland display (where only EGL or OSMesa can draw)."""
    return (
        sys.platform.startswith("linux")
        and not environ.get("DISPLAY")
        and not environ.get("WAYLAND_DISPLAY")
    )


def egl_library() -> str | None:
    """The name under which this machine's EGL library loads (as PyOpenGL would load it),
    or None when there is none."""
    for name in EGL_NAMES:
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return name
    return None


def choose_mujoco_gl(environ: MutableMapping[str, str] = os.environ) -> str | None:
    """Set ``MUJOCO_GL`` in ``environ`` when MuJoCo is not imported yet, the machine is
    headless and the user has not chosen: ``egl`` where an EGL library loads, ``disable``
    where none does (see the module docstring). Returns the value then in force."""
    if "MUJOCO_GL" not in environ and "mujoco" not in sys.modules and headless(environ):
        environ["MUJOCO_GL"] = "egl" if egl_library() is not None else DISABLED
    return environ.get("MUJOCO_GL")
