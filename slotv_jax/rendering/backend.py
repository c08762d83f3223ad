"""What to say when no OpenGL context can be opened (standard library only: this module
must load even where importing MuJoCo's OpenGL backend fails)."""

from __future__ import annotations

import os


class RenderBackendError(RuntimeError):
    """No OpenGL context could be opened for offscreen rendering."""


def backend_message(err: BaseException) -> str:
    """What to do when MuJoCo cannot open (or even load) an OpenGL backend."""
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
