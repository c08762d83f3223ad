"""See the motion: the Panda in its scene, rendered by MuJoCo, as frames, video and stills.

Two steps, as in mujoco_playground: :func:`motion_frames` renders the frames of one
motion (a joint path, cut at normalised time τ, goals labelled) as a uint8 array, and
:func:`write_video` / :func:`write_png` / :func:`contact_sheet` turn frames into files.
:func:`compare_frames` puts several motions of one scene side by side or overlays them.
This is the library; its public face is :mod:`slotv_jax.render` (the same names, and the
command ``python -m slotv_jax.render``, which renders a dataset trajectory, a labelers
``.npz``, a study file or a planning run's plans: :mod:`slotv_jax.render.cli`).

Rendering needs an OpenGL context: ``MUJOCO_GL=egl`` on a headless machine (a GPU's EGL,
or Mesa's software EGL on a CPU), chosen before MuJoCo is first imported. If it is unset
on a Linux machine without a display and MuJoCo is not imported yet, ``import slotv_jax``
sets it to ``egl``, or to ``disable`` where no EGL library loads; then
:func:`check_backend` (called by every renderer) refuses in one line that says what to
install. Only what writes pictures imports this package (the render
command, stimulus sets, the planning figures); the rest of ``slotv_jax`` never needs OpenGL.

>>> from slotv_jax import rendering
>>> frames = rendering.motion_frames(q, goals, goal_mask, tau=0.6)  # doctest: +SKIP
>>> rendering.write_video("clip.mp4", frames, fps=30)  # doctest: +SKIP
"""

import sys

from slotv_jax.rendering.backend import RenderBackendError, backend_message, check_backend

try:  # importing mujoco loads the OpenGL backend that MUJOCO_GL names
    import mujoco  # noqa: F401
except ImportError:
    raise
except Exception as e:  # PyOpenGL fails so when the backend's library is missing
    if sys.argv and sys.argv[0] == "-m":  # `python -m ...` is locating its module: a command
        print(f"error: {backend_message(e)}", file=sys.stderr)
        raise SystemExit(2) from None
    raise RenderBackendError(backend_message(e)) from e

from slotv_jax.rendering.camera import CAMERAS, FreeCamera, pixels
from slotv_jax.rendering.compare import LAYOUTS, compare_frames
from slotv_jax.rendering.frames import (
    MotionRenderer,
    frame_times,
    goal_labels,
    joints_from_tcp,
    motion_frames,
    still,
)
from slotv_jax.rendering.writers import (
    contact_sheet,
    grid,
    read_video,
    write_png,
    write_video,
)

__all__ = [
    "CAMERAS",
    "LAYOUTS",
    "FreeCamera",
    "MotionRenderer",
    "RenderBackendError",
    "check_backend",
    "compare_frames",
    "contact_sheet",
    "frame_times",
    "goal_labels",
    "grid",
    "joints_from_tcp",
    "motion_frames",
    "pixels",
    "read_video",
    "still",
    "write_png",
    "write_video",
]
