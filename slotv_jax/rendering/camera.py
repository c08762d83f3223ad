"""Where the picture is taken from: a named camera of the scene or a free camera, and
the projection of world points to the pixels of a rendered frame.

A view is a camera name of ``franka_assets/scene.xml`` (:data:`CAMERAS`), a camera file
(a lab's own camera: pose and field of view, :ref:`concepts-camera-files`) or a
:class:`FreeCamera` (look-at point, distance, azimuth and elevation, MuJoCo's
``mjvCamera`` convention). Each becomes a :class:`slotv_jax.scene.Camera` (position,
world-from-camera rotation, vertical field of view; NumPy fields, posed by MuJoCo C, so
that nothing compiles) and are projected with
:func:`slotv_jax.scene.project`, the one projection of the project; a frame of
``W × H`` pixels then maps normalised image coordinates ``(u, v)`` to

    x = W / 2 + f u,   y = H / 2 − f v,   f = (H / 2) / tan(fovy / 2)

(pixels, x to the right and y down, pixel ``(i, j)`` covering ``[j, j+1) × [i, i+1)``).
MuJoCo draws perspective cameras with ``fovy`` as the vertical field of view at any
aspect ratio, so this holds for every frame size.

No OpenGL is needed here.

>>> pixels(np.array([[0.45, 0.0, 0.15]]), "observer", (640, 360))  # doctest: +SKIP
array([[320., 180.]])
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np
from jaxtyping import Float

from slotv_jax.robot import kinematics
from slotv_jax.world import scene
from slotv_jax.world.scene import CAMERAS  # the named cameras of scene.xml (re-exported)


@dataclasses.dataclass(frozen=True)
class FreeCamera:
    """A camera orbiting a point (MuJoCo's free ``mjvCamera``; angles in degrees).

    The camera looks along ``(cos e cos a, cos e sin a, sin e)`` (azimuth ``a``,
    elevation ``e``; a negative elevation looks down) and stands ``distance`` metres
    back from ``lookat`` along that direction; its vertical field of view is the
    model's ``visual/global/fovy`` (45°).
    """

    lookat: tuple[float, float, float] = (0.45, 0.0, 0.15)  # point looked at (m)
    distance: float = 1.6  # metres from the camera to ``lookat``
    azimuth: float = 180.0  # degrees about +z; 180 looks along −x (from the goal table's far side)
    elevation: float = -30.0  # degrees; negative looks down

    def __post_init__(self):
        la = np.asarray(self.lookat, np.float64)
        if la.shape != (3,) or not np.all(np.isfinite(la)):
            raise ValueError(f"FreeCamera.lookat: expected 3 finite numbers, got {self.lookat!r}")
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise ValueError(f"FreeCamera.distance: expected a number > 0, got {self.distance!r}")
        for f in ("azimuth", "elevation"):
            if not np.isfinite(getattr(self, f)):
                raise ValueError(f"FreeCamera.{f}: expected a finite angle in degrees")
        if not -90.0 < self.elevation < 90.0:
            raise ValueError(
                f"FreeCamera.elevation: expected degrees in (-90, 90), got {self.elevation!r}"
            )


View = str | FreeCamera


def check_view(camera) -> None:
    """Raise ValueError unless ``camera`` is a camera name of the scene, a valid camera file
    (:func:`slotv_jax.scene.check_camera`) or a FreeCamera."""
    if isinstance(camera, FreeCamera):
        return
    if scene.is_camera_file(camera):
        scene.check_camera(camera)
        return
    if not isinstance(camera, str) or camera not in CAMERAS:
        raise ValueError(
            f"camera: expected one of {list(CAMERAS)}, a camera file (*.json) or a FreeCamera, "
            f"got {camera!r}"
        )


@functools.cache
def scene_model() -> mujoco.MjModel:
    """The scene model (robot, tables, cubes, cameras) as MuJoCo compiles it."""
    return kinematics.mj_model(kinematics.SCENE_XML)


def free_camera_pose(cam: FreeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) and world-from-camera rotation (3, 3) of a free camera.

    MuJoCo's ``mjv_updateCamera``: forward ``d = (cos e cos a, cos e sin a, sin e)``,
    up ``(−sin e cos a, −sin e sin a, cos e)``, position ``lookat − distance · d``;
    the camera's axes are x = d × up, y = up, z = −d.
    """
    a, e = np.deg2rad(cam.azimuth), np.deg2rad(cam.elevation)
    fwd = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    up = np.array([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)])
    pos = np.asarray(cam.lookat, np.float64) - cam.distance * fwd
    return pos, np.stack([np.cross(fwd, up), up, -fwd], axis=1)


@functools.cache
def named_camera(name: str) -> scene.Camera:
    """A named camera of the scene posed by MuJoCo C (``mj_kinematics`` + ``mj_camlight``),
    with NumPy fields (float64): the pose of :func:`slotv_jax.scene.camera`, before its
    cast to float32."""
    if not isinstance(name, str) or name not in CAMERAS:
        raise ValueError(f"camera: expected one of {list(CAMERAS)}, got {name!r}")
    m = scene_model()
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name)
    pos, rot = (a[cam].copy() for a in scene.camera_poses())
    return scene.Camera(
        pos=pos, rot=rot, fovy=np.float64(m.cam_fovy[cam]), resolution=m.cam_resolution[cam].copy()
    )


def view_camera(camera: View) -> scene.Camera:
    """The pinhole camera of a view (NumPy fields): a named camera, a camera file or a free
    camera."""
    check_view(camera)
    if scene.is_camera_file(camera):
        return scene.read_camera_file(camera)
    if isinstance(camera, str):
        return named_camera(camera)
    pos, rot = free_camera_pose(camera)
    fovy = np.float64(scene_model().vis.global_.fovy)
    return scene.Camera(pos=pos, rot=rot, fovy=fovy, resolution=np.zeros(2, np.int32))


def pixels(
    points: Float[np.ndarray, "n 3"], camera: View, size: tuple[int, int]
) -> tuple[Float[np.ndarray, "n 2"], Float[np.ndarray, " n"]]:
    """Pixel coordinates ``(x, y)`` and depth (m) of world points in a ``size = (W, H)`` frame.

    Through :func:`slotv_jax.scene.project` (see the module docstring); points behind
    the camera have depth ≤ 0.
    """
    w, h = size
    cam = view_camera(camera)
    uv, depth = scene.project(np.asarray(points, np.float64), cam)  # NumPy in, NumPy out
    f = (h / 2) / np.tan(np.deg2rad(float(cam.fovy)) / 2)
    return np.stack([w / 2 + f * uv[:, 0], h / 2 - f * uv[:, 1]], axis=1), np.asarray(depth)
