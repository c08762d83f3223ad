"""What to say when no OpenGL context can be opened (the standard library only: this module
must load even where importing MuJoCo's OpenGL backend fails).

On a Linux machine without a display MuJoCo draws through EGL. Where no EGL library loads,
``import slotv_jax`` has set ``MUJOCO_GL=disable`` (:mod:`slotv_jax.core.opengl`) so that
everything but rendering works; :func:`check_backend` then refuses to render in one line
that names the missing library and how to install it.
"""

from __future__ import annotations

import os

from slotv_jax.core import opengl


class RenderBackendError(RuntimeError):
    """No OpenGL context could be opened for offscreen rendering."""


def egl_missing() -> bool:
    """True where rendering needs EGL (Linux, no display, ``MUJOCO_GL`` unset, ``egl`` or
    ``disable``) and no EGL library loads."""
    gl = os.environ.get("MUJOCO_GL", "").strip().lower()
    return opengl.headless() and gl in opengl.EGL_BACKENDS and opengl.egl_library() is None


def egl_missing_message() -> str:
    """The one line that says EGL is missing and how to get it."""
    return (
        "cannot render: this machine has no display and no EGL library (libEGL.so.1), "
        "through which MuJoCo draws offscreen; on Debian/Ubuntu install it with "
        "`apt-get install libegl1 libgl1-mesa-dri` (Mesa's software EGL), or on a CUDA "
        "machine the NVIDIA driver's EGL libraries (libegl1 and, in a container, "
        "NVIDIA_DRIVER_CAPABILITIES including graphics); or render through OSMesa "
        "(MUJOCO_GL=osmesa, `apt-get install libosmesa6`)"
    )


def check_backend() -> None:
    """Raise :class:`RenderBackendError` (one line) where rendering cannot work for want of
    an EGL library: before a renderer is opened, or any work that ends in one starts."""
    if egl_missing():
        raise RenderBackendError(egl_missing_message())


def backend_message(err: BaseException) -> str:
    """What to do when MuJoCo cannot open (or even load) an OpenGL backend."""
    if egl_missing():
        return egl_missing_message()
    gl = os.environ.get("MUJOCO_GL", "")
    text = str(err).strip()
    first = text.splitlines()[0] if text else ""
    return (
        f"cannot open an OpenGL context for rendering (MUJOCO_GL={gl or 'unset'}: "
        f"{type(err).__name__}: {first}). Set MUJOCO_GL before Python imports mujoco: "
        "MUJOCO_GL=egl on a headless machine (a GPU's EGL, or Mesa's software EGL), "
        "MUJOCO_GL=osmesa for Mesa's OSMesa, or glfw with a display; on Debian/Ubuntu "
        "install EGL with `apt-get install libegl1 libgl1-mesa-dri` or OSMesa with "
        "`apt-get install libosmesa6`"
    )
