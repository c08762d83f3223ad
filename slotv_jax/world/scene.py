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

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation
from slotv_jax.core.validation import G_MAX
from slotv_jax.robot.kinematics import SCENE_XML, host_eval, mj_model, mjx


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
def _camera_poses() -> tuple[np.ndarray, np.ndarray]:
    """Every camera of the scene model posed by ``mjx.kinematics`` + ``mjx.camlight``:
    positions ``(ncam, 3)`` and rotations ``(ncam, 3, 3)``, in one compiled call (a second
    or two; several on a loaded CPU) for all of them."""

    def pose(mx):
        d = mjx.camlight(mx, mjx.kinematics(mx, mjx.make_data(mx)))
        return d.cam_xpos, d.cam_xmat.reshape(-1, 3, 3)

    return host_eval(pose, mj_model(SCENE_XML))


CAMERAS = ("observer", "observer_angle", "observer_side")  # the named cameras of scene.xml


def check_camera(name: str) -> int:
    """The index of the scene model's camera ``name`` (ValueError naming the cameras there
    for another name); poses nothing, compiles nothing."""
    m = mj_model(SCENE_XML)
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, str(name))
    if cam < 0:
        names = [m.camera(i).name for i in range(m.ncam)]
        raise ValueError(f"camera: no camera named {name!r} in {SCENE_XML.name}; have {names}")
    return cam


@functools.cache
def _camera_cached(name: str) -> Camera:
    cam = check_camera(name)
    m = mj_model(SCENE_XML)
    pos, rot = (a[cam] for a in _camera_poses())
    with jax.ensure_compile_time_eval():
        return Camera(
            pos=jnp.asarray(pos, jnp.float32),
            rot=jnp.asarray(rot, jnp.float32),
            fovy=jnp.asarray(m.cam_fovy[cam], jnp.float32),
            resolution=jnp.asarray(m.cam_resolution[cam], jnp.int32),
        )


def camera(name: str = "observer") -> Camera:
    """The named camera of the scene model, posed by ``mjx.kinematics`` + ``mjx.camlight``
    (every camera in one compiled call, on first use).

    Names: ``observer`` (default), ``observer_angle``, ``observer_side``.
    """
    return _camera_cached(str(name))


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
