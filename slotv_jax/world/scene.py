"""Scenes (:ref:`concepts-cameras`) and the observer cameras of the scene model
(:ref:`concepts-cameras`).

A scene is pure arrays: ``goals (8, 3)`` and ``goal_mask (8,)``, the first
``n_goals`` slots real and the rest padding. Cubes are 0.05 m boxes resting on
the goal table (centre z = 0.025), drawn uniformly in x ∈ [0.30, 0.70],
y ∈ [−0.45, 0.45] with at least 0.10 m between centres (rejection sampling).
The goal of a cube is its centre.

>>> import jax
>>> s = sample_scene(jax.random.key(0), 3)
>>> s.goals.shape, int(s.goal_mask.sum())
((8, 3), 3)
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation
from slotv_jax.core.validation import G_MAX
from slotv_jax.robot.kinematics import SCENE_XML, mj_model


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Where cubes may stand."""

    x_range: tuple[float, float] = (0.30, 0.70)  # cube centre x (m)
    y_range: tuple[float, float] = (-0.45, 0.45)  # cube centre y (m)
    cube_z: float = 0.025  # cube centre height (m): half of the 0.05 m cube
    min_spacing: float = 0.10  # minimum distance between cube centres (m)

    def __post_init__(self):
        for f in ("x_range", "y_range"):
            lo, hi = getattr(self, f)
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                raise ValueError(f"SceneConfig.{f}: expected (lo, hi) with lo < hi, got {(lo, hi)}")
        validation.check_positive("SceneConfig.min_spacing", self.min_spacing)
        if not np.isfinite(self.cube_z):
            raise ValueError(f"SceneConfig.cube_z: expected a finite height, got {self.cube_z}")


@struct.dataclass
class Scene:
    """One environment: up to G_MAX goals, the first ``n_goals`` real."""

    goals: Float[Array, "8 3"]  # goal (cube centre) positions, world frame (m); padding is 0
    goal_mask: Bool[Array, "8"]  # True for real goals
    n_goals: Int[Array, ""]  # number of real goals, 1..8


def sample_scene(key: jax.Array, n_goals, cfg: SceneConfig = SceneConfig()) -> Scene:
    """Draw ``n_goals`` cube centres by rejection sampling (pure; deterministic in ``key``).

    ``n_goals`` may be traced (1..8). Each slot draws candidates until one lies at
    least ``cfg.min_spacing`` from every earlier real cube.
    """
    lo = jnp.array([cfg.x_range[0], cfg.y_range[0]])
    hi = jnp.array([cfg.x_range[1], cfg.y_range[1]])
    real = jnp.arange(G_MAX) < n_goals

    def place(i, carry):
        xy, key = carry

        def far_enough(c):
            d = jnp.linalg.norm(xy - c[None], axis=-1)
            return jnp.all((d >= cfg.min_spacing) | (jnp.arange(G_MAX) >= i))

        def draw(state):
            k, _ = state
            k, sub = jax.random.split(k)
            return k, jax.random.uniform(sub, (2,), minval=lo, maxval=hi)

        key, c = draw((key, jnp.zeros(2)))
        key, c = jax.lax.while_loop(lambda s: ~far_enough(s[1]), draw, (key, c))
        return xy.at[i].set(c), key

    xy, _ = jax.lax.fori_loop(0, G_MAX, place, (jnp.zeros((G_MAX, 2)), key))
    goals = jnp.concatenate([xy, jnp.full((G_MAX, 1), cfg.cube_z)], axis=-1)
    goals = jnp.where(real[:, None], goals, 0.0)
    return Scene(goals=goals, goal_mask=real, n_goals=jnp.asarray(n_goals, jnp.int32))


def sample_goal_count(key: jax.Array, counts, n_counts=None) -> Int[Array, ""]:
    """Uniform draw from a set of goal counts, e.g. ``(2, 3, 5, 6)``: from the first
    ``n_counts`` entries of ``counts`` if given (an array padded to a fixed length, so
    that sets of different sizes share one compiled function; the same draws)."""
    n = len(counts) if n_counts is None else n_counts
    return jnp.asarray(counts, jnp.int32)[jax.random.randint(key, (), 0, n)]


def check_scene(scene: Scene, cfg: SceneConfig = SceneConfig(), *, batched: bool = False) -> None:
    """Raise ValueError if a concrete scene (or batch of scenes) breaks :ref:`concepts-scenes`."""
    b = (None,) if batched else ()
    validation.check_goals("goals", scene.goals, scene.goal_mask, batch_shape=b)
    g = np.asarray(scene.goals, np.float64).reshape(-1, G_MAX, 3)
    m = np.asarray(scene.goal_mask, bool).reshape(-1, G_MAX)
    if np.any(m[:, 1:] & ~m[:, :-1]):
        raise ValueError("goal_mask: expected the real goals in the first slots")
    n = np.asarray(scene.n_goals).reshape(-1)
    if np.any(n != m.sum(-1)):
        raise ValueError("n_goals: expected the number of True entries of goal_mask")
    d = np.linalg.norm(g[:, :, None, :2] - g[:, None, :, :2], axis=-1)
    pair = m[:, :, None] & m[:, None, :] & ~np.eye(G_MAX, dtype=bool)
    if np.any(pair & (d < cfg.min_spacing - 1e-6)):
        raise ValueError(f"goals: cube spacing below {cfg.min_spacing} m")


# ---------------------------------------------------------------------- cameras


@struct.dataclass
class Camera:
    """A pinhole observer camera (MuJoCo convention: looks along its −z, x right, y up)."""

    pos: Float[Array, "3"]  # camera centre, world frame (m)
    rot: Float[Array, "3 3"]  # world-from-camera rotation; columns are the camera x, y, z axes
    fovy: Float[Array, ""]  # vertical field of view (degrees)
    resolution: Int[Array, "2"]  # image width, height (pixels)


@functools.cache
def camera_poses() -> tuple[Float[np.ndarray, "ncam 3"], Float[np.ndarray, "ncam 3 3"]]:
    """Every camera of the scene model posed by MuJoCo C (``mj_kinematics`` then
    ``mj_camlight``, float64, read-only: computed once): positions ``(ncam, 3)`` and
    world-from-camera rotations ``(ncam, 3, 3)``, in the model's camera order.
    Microseconds, and nothing to compile: posing them with ``mjx.kinematics`` +
    ``mjx.camlight`` cost every process about 4 s of tracing and compilation on a quiet 2-core
    CPU, 7-13 s on a loaded one (``python -m slotv_jax.benchmarks.startup``); the tests check
    these poses against MJX's."""
    m = mj_model(SCENE_XML)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    mujoco.mj_camlight(m, d)
    pos, rot = d.cam_xpos.copy(), d.cam_xmat.reshape(-1, 3, 3).copy()
    pos.setflags(write=False)
    rot.setflags(write=False)
    return pos, rot


CAMERAS = ("observer", "observer_angle", "observer_side")  # the named cameras of scene.xml
CAMERA_SUFFIX = ".json"  # a camera that is not a name of the scene is a camera file
#: A camera file's rotation is orthonormal to this (the largest entry of abs(RᵀR − I); six
#: decimals typed by hand).
ROTATION_TOL = 1e-4
DEFAULT_RESOLUTION = (1280, 720)  # a camera file's image size when it names none (the scene's)


def is_camera_file(camera: str) -> bool:
    """True if ``camera`` names a camera file (a path ending in ``.json``), not a camera of
    the scene model."""
    return isinstance(camera, str) and camera.lower().endswith(CAMERA_SUFFIX)


def camera_label(camera: str) -> str:
    """The short name of a camera in ids, tables and file names: the scene camera's name, or
    a camera file's stem (``lab/cam_left.json`` → ``cam_left``)."""
    return os.path.splitext(os.path.basename(camera))[0] if is_camera_file(camera) else camera


def _vector(d: dict, key: str, where: str, n: int = 3) -> np.ndarray:
    v = d[key]
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: field {key!r}: expected {n} finite numbers, got {v!r}")
    return a


def camera_from_dict(d: dict, where: str = "camera") -> Camera:
    """The camera of a camera file's JSON object (:ref:`concepts-camera-files`), checked
    field by field (ValueError naming ``where`` and the field); NumPy fields.

    ``position`` (m) and either ``look_at`` (a point, with ``up``, default +z) or
    ``rotation`` (world-from-camera, columns the camera's x right, y up, z backwards: it
    looks along −z, MuJoCo's convention), ``fovy`` (vertical field of view, degrees, in
    (0, 180)) and optionally ``resolution`` ``[width, height]`` (pixels; its aspect
    bounds the horizontal field of view). With ``look_at`` the rotation is

        z = (c − a)/‖c − a‖,  x = (u × z)/‖u × z‖,  y = z × x

    for the camera centre c, the point looked at a and the up vector u.

    >>> cam = camera_from_dict({"position": [1.6, 0, 0.8], "look_at": [0.45, 0, 0.15],
    ...                         "fovy": 40})
    >>> np.allclose(cam.rot, camera("observer").rot, atol=1e-6)
    True
    """
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a JSON object of the camera's fields, got {d!r}")
    known = ("position", "look_at", "up", "rotation", "fovy", "resolution", "note")
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ValueError(f"{where}: field {unknown[0]!r}: unknown; expected some of {list(known)}")
    for k in ("position", "fovy"):
        if k not in d:
            raise ValueError(f"{where}: field {k!r}: missing")
    if ("look_at" in d) == ("rotation" in d):
        raise ValueError(f"{where}: expected exactly one of the fields 'look_at' and 'rotation'")
    pos = _vector(d, "position", where)
    if "rotation" in d:
        if "up" in d:
            raise ValueError(f"{where}: field 'up': only with 'look_at' (a rotation has its own)")
        try:
            rot = np.asarray(d["rotation"], np.float64)
        except (TypeError, ValueError):
            rot = np.zeros(0)
        if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
            raise ValueError(
                f"{where}: field 'rotation': expected a 3x3 matrix of finite numbers, "
                f"got {d['rotation']!r}"
            )
        err = float(np.abs(rot.T @ rot - np.eye(3)).max())
        if err > ROTATION_TOL or np.linalg.det(rot) < 0:
            raise ValueError(
                f"{where}: field 'rotation': expected an orthonormal, right-handed rotation "
                f"(max |RᵀR − I| ≤ {ROTATION_TOL:g}, det +1), got max |RᵀR − I| = {err:.3g}, "
                f"det {np.linalg.det(rot):.3g}"
            )
    else:
        at = _vector(d, "look_at", where)
        up = _vector(d, "up", where) if "up" in d else np.array([0.0, 0.0, 1.0])
        back = pos - at
        if np.linalg.norm(back) < 1e-6:
            raise ValueError(f"{where}: field 'look_at': expected a point away from 'position'")
        z = back / np.linalg.norm(back)
        x = np.cross(up, z)
        if np.linalg.norm(x) < 1e-6 * max(np.linalg.norm(up), 1e-300):
            raise ValueError(f"{where}: field 'up': expected a direction not along the view")
        x /= np.linalg.norm(x)
        rot = np.stack([x, np.cross(z, x), z], axis=1)
    fovy = d["fovy"]
    if isinstance(fovy, bool) or not isinstance(fovy, int | float) or not 0 < fovy < 180:
        raise ValueError(f"{where}: field 'fovy': expected degrees in (0, 180), got {fovy!r}")
    res = d.get("resolution", list(DEFAULT_RESOLUTION))
    if (
        not isinstance(res, list | tuple)
        or len(res) != 2
        or not all(isinstance(r, int) and not isinstance(r, bool) and r >= 1 for r in res)
    ):
        raise ValueError(
            f"{where}: field 'resolution': expected [width, height] in pixels, got {res!r}"
        )
    return Camera(pos=pos, rot=rot, fovy=np.float64(fovy), resolution=np.asarray(res, np.int32))


def _file_key(path: str) -> tuple:
    """What a camera file's cache entries are keyed by: its path, and its size and time of
    change (a rewritten file is read again)."""
    try:
        st = os.stat(path)
    except OSError:
        return (path, None)
    return (path, os.path.abspath(path), st.st_mtime_ns, st.st_size)


def read_camera_file(path: str) -> Camera:
    """A camera file's camera, checked (:func:`camera_from_dict`), with NumPy float64 fields
    as the file gives them; read again when the file changes (:func:`camera` is its float32
    JAX form, for traced code)."""
    return _camera_file_at(_file_key(path))


@functools.cache
def _camera_file_at(key: tuple) -> Camera:
    path = key[0]
    if not os.path.isfile(path):
        raise ValueError(
            f"camera: no camera file {path!r} (a JSON file; or one of {list(CAMERAS)})"
        )
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"camera {path}: expected a JSON camera file ({e})") from None
    return camera_from_dict(d, f"camera {path}")


def check_camera(name: str) -> None:
    """ValueError unless ``name`` is a camera of the scene model or a readable, valid camera
    file (:ref:`concepts-camera-files`); poses nothing, compiles nothing."""
    if not isinstance(name, str):
        raise ValueError(f"camera: expected a camera name or a camera file's path, got {name!r}")
    if is_camera_file(name):
        read_camera_file(name)
        return
    m = mj_model(SCENE_XML)
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name) < 0:
        names = [m.camera(i).name for i in range(m.ncam)]
        raise ValueError(
            f"camera: no camera named {name!r} in {SCENE_XML.name}; have {names} "
            f"(or a camera file, *{CAMERA_SUFFIX})"
        )


@functools.cache
def _camera_cached(name: str, key: tuple = ()) -> Camera:
    check_camera(name)
    if is_camera_file(name):
        c = read_camera_file(name)
        pos, rot, fovy, res = c.pos, c.rot, c.fovy, c.resolution
    else:
        m = mj_model(SCENE_XML)
        cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name)
        pos, rot = (a[cam] for a in camera_poses())
        fovy, res = m.cam_fovy[cam], m.cam_resolution[cam]
    with jax.ensure_compile_time_eval():
        return Camera(
            pos=jnp.asarray(pos, jnp.float32),
            rot=jnp.asarray(rot, jnp.float32),
            fovy=jnp.asarray(fovy, jnp.float32),
            resolution=jnp.asarray(res, jnp.int32),
        )


def camera(name: str = "observer") -> Camera:
    """A camera of the scene model, posed by MuJoCo C (``mj_kinematics`` + ``mj_camlight``,
    every camera on first use), or a camera file's
    (:ref:`concepts-camera-files`: a path ending in ``.json``, read once).

    Names: ``observer`` (default), ``observer_angle``, ``observer_side``.
    """
    name = str(name)
    return _camera_cached(name, _file_key(name) if is_camera_file(name) else ())


def in_view(points: Float[np.ndarray, "*n 3"], cam: Camera) -> Bool[np.ndarray, "*n"]:
    """Which world points a camera sees: in front of it and inside its image,
    ``depth > 0``, ``|v| ≤ tan(fovy/2)`` and ``|u| ≤ (W/H) tan(fovy/2)`` (NumPy)."""
    x, y, z = camera_coords(np.asarray(points, np.float64), np.asarray(cam.pos, np.float64),
                            np.asarray(cam.rot, np.float64))  # fmt: skip
    depth = -z
    t = np.tan(np.deg2rad(float(cam.fovy)) / 2)
    w, h = (int(v) for v in np.asarray(cam.resolution))
    safe = np.where(depth > 0, depth, 1.0)
    return (depth > 0) & (np.abs(y / safe) <= t) & (np.abs(x / safe) <= t * w / h)


def check_sees_goals(
    camera_name: str, goals: Float[np.ndarray, "*b 8 3"], goal_mask: Bool[np.ndarray, "*b 8"]
) -> None:
    """ValueError naming the camera unless it sees at least one real goal of every scene
    (:func:`in_view`): a study filmed from it could show none of the answers' options."""
    cam = camera(camera_name)
    g = np.asarray(goals, np.float64).reshape(-1, G_MAX, 3)
    m = np.asarray(goal_mask, bool).reshape(-1, G_MAX)
    seen = in_view(g, cam) & m
    blind = np.flatnonzero(~seen.any(-1))
    if blind.size:
        raise ValueError(
            f"camera {camera_name}: sees none of the goals of {blind.size} of {len(m)} scenes "
            f"(the first: scene {int(blind[0])}); point it at the goal table"
        )


def camera_coords(points: Float[Array, "*n 3"], pos, rot) -> list[Array]:
    """The camera frame of :ref:`concepts-cameras`, ``p_c = Rᵀ (p − c)``, as its three coordinates,
    each ``(*n,)``, for a camera at ``pos (3,)`` with world-from-camera rotation ``rot (3, 3)``
    (MuJoCo's ``cam_xmat``: the camera looks along its −z axis, x right, y up).

    The one definition of the projection: :func:`project`, :func:`image_coords`, the
    labelers and the viewpoint archetype build on it. Written out (a 3×3 product is too
    small for a matrix kernel to pay off, and the sums fuse into the labelers' loops);
    NumPy and JAX arrays alike.
    """
    rel = [points[..., k] - pos[k] for k in range(3)]
    return [sum(rel[k] * rot[k, j] for k in range(3)) for j in range(3)]


def image_coords(
    points: Float[Array, "*n 3"], pos, rot, eps: float
) -> tuple[tuple[Array, Array], Bool[Array, "*n"]]:
    """:func:`project` for traced code: the image coordinates ``(u, v)``, each ``(*n,)``,
    and ``ok = depth > eps``; where not ok, (u, v) is the finite ``(p_c.x, p_c.y)``, so
    that neither values nor gradients become NaN."""
    pc = camera_coords(points, pos, rot)
    depth = -pc[2]
    ok = depth > eps
    safe = jnp.where(ok, depth, 1.0)
    return (pc[0] / safe, pc[1] / safe), ok


def project(
    points: Float[Array, "*n 3"], cam: Camera
) -> tuple[Float[Array, "*n 2"], Float[Array, "*n"]]:
    """Normalised image-plane coordinates and depth of world points (:ref:`concepts-cameras`).

    ``p_c = Rᵀ (p − c)`` (:func:`camera_coords`), ``(u, v) = (p_c.x, p_c.y) / (−p_c.z)``;
    depth is ``−p_c.z``. NumPy in (points and camera), NumPy out.
    """
    x, y, z = camera_coords(points, cam.pos, cam.rot)
    depth = -z
    xp = jnp if isinstance(depth, jax.Array) else np
    return xp.stack([x / depth, y / depth], axis=-1), depth
