"""Parametric observers: analytic observer models with a few interpretable, learned parameters.

The SLOT-V paper (Wallkötter et al. 2022, §VI) names the opacity of a neural observer as a
limitation and suggests keeping the supervised training but learning "an explicit analytic
model for which we only learn certain parameter values". This module holds three such
archetypes. Each maps one trajectory and the 8 goal slots to masked logits, exactly like
:class:`slotv_jax.observers.models.SlotV`::

    logits = observer(xyz (..., T, 3), goals (..., 8, 3), goal_mask (..., 8))  # (..., 8)

so training (SLOT-V's cross-entropy of :ref:`concepts-slotv`), evaluation, checkpoints,
:func:`slotv_jax.load_observer` and planners take them unchanged. They are selected by
``TrainConfig.model`` (``python -m slotv_jax.train --model {dragan,viewpoint,mixture}``):

- :class:`LearnableDragan` — Dragan legibility (:ref:`concepts-dragan`) with a learned temperature
  β, time weighting (1 − t)^α, weight w₀ of the start-to-goal term and a diagonal metric on
  world coordinates. At β = 5, α = 1, w₀ = 1 and the Euclidean metric its logits are
  ``log labelers.dragan``.
- :class:`LearnableViewpoint` — Dragan legibility in the image plane of a camera whose
  pose (yaw, pitch and distance about the workspace centre :data:`CENTER`) and β are
  learned (:ref:`concepts-cameras`). At the ``observer`` camera's pose (:func:`camera_pose`) and β =
  7.5 its logits are ``log labelers.nikolaidis``.
- :class:`DistanceApproachMixture` — β_E · E + β_F · F: an EffDist-like term E (minus the
  time-weighted mean distance, :ref:`concepts-effdist`) and a FastApp-like term F (the time-weighted
  mean approach speed, :ref:`concepts-fastapp`), each with its temperature and time weighting. Both
  terms are in metres (time is normalised to [0, 1]), so the share β_E / (β_E + β_F) says
  which one the observer follows.

Parameters live on unconstrained scales and are mapped to their meaningful ranges:
temperatures and distances through ``exp`` (a scale parameter: Adam's steps become
relative changes; β spans 5 to 30 in the datasets), exponents through ``softplus``
(α ≥ 0), metric weights through a softmax (positive, trace 3: the overall scale is β's),
the camera pitch through ``tanh`` (``|pitch|`` ≤ 90°) and the camera distance as
``DISTANCE_MIN + exp(·)`` (the camera stays outside the workspace). Each archetype's
:meth:`describe` prints the fitted values with units, in words; :meth:`parameters` returns
them as a dict (stored in checkpoints' ``meta``).

Time. The trajectory's points are at t_i = i/(T − 1). The weights (1 − t_i)^α are
evaluated as ``max(1 − t_i, ε)^α`` with ε the smallest normal float: exact at α = 0
(weight 1 everywhere, e.g. EffDist's plain mean) and, in float32, for α ≥ 1 (the last
point's weight ε^α underflows against the others), and smooth in α between, so that
gradients never meet 0^α · log 0.

>>> import jax.numpy as jnp
>>> from slotv_jax import labelers
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
>>> mask = jnp.arange(8) < 2
>>> logits = LearnableDragan()(xyz, g, mask)
>>> y = labelers.dragan(xyz, g, mask, beta=5.0)  # LearnableDragan starts at β = 5
>>> bool(jnp.allclose(jnp.exp(logits[:2]), y[:2], atol=1e-6))
True
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import common
from slotv_jax.observers.labelers import DEPTH_EPS
from slotv_jax.world.scene import Camera, image_coords
from slotv_jax.world.scene import camera as scene_camera

__all__ = [
    "CENTER",
    "DISTANCE_MIN",
    "LearnableDragan",
    "LearnableViewpoint",
    "camera_frame",
    "camera_pose",
    "start_pose",
    "time_weights",
]

#: The workspace centre (m): the point the observer cameras look at (:ref:`concepts-cameras`).
CENTER = (0.45, 0.0, 0.15)
#: The learned camera stays at least this far from :data:`CENTER` (m): every point of the
#: :ref:`concepts-trajectories` workspace (via box, cubes, the home TCP) lies within 0.6 m of it, so
# every point
#: stays at least 0.2 m in front of the camera, whatever its yaw and pitch.
DISTANCE_MIN = 0.8


# ------------------------------------------------------------------ parameter maps


def _param(x: float) -> nnx.Param:
    """A learned scalar, in the default float dtype (float64 under ``jax_enable_x64``)."""
    return nnx.Param(jnp.asarray(x, jnp.result_type(float)))


def _log(x: float) -> float:
    """Inverse of exp for an initial value (0 maps to −∞: the parameter then stays 0)."""
    return math.log(x) if x > 0 else -math.inf


def _inv_softplus(x: float) -> float:
    """Inverse of softplus for an initial value (0 maps to −∞: the parameter then stays 0)."""
    return x + math.log(-math.expm1(-x)) if x > 0 else -math.inf


def _check(name: str, value, lo: float = 0.0, *, strict: bool = True) -> float:
    v = float(value)
    ok = math.isfinite(v) and (v > lo if strict else v >= lo)
    if not ok:
        raise ValueError(
            f"{name}: expected a finite number {'>' if strict else '>='} {lo}, got {value!r}"
        )
    return v


def _value(p) -> Array:
    return p[...]


# ------------------------------------------------------------------ shared pieces


def time_weights(alpha: Float[Array, ""] | float, T: int, dtype=jnp.float32) -> Float[Array, " T"]:
    """Normalised time weights u_i = (1 − t_i)^α / Σ_j (1 − t_j)^α at t_i = i/(T − 1):
    :func:`slotv_jax.observers.common.time_weights` at uniform times.

    The weighting of Dragan & Srinivasa's legibility integral (RSS 2013, f(t) = T − t at
    α = 1; the labels of :ref:`concepts-dragan`): early points count more. α = 0 gives the plain
    mean.

    >>> [round(float(u), 3) for u in time_weights(1.0, 3)]
    [0.667, 0.333, 0.0]
    """
    return common.time_weights(common.uniform_times(T), alpha, dtype=dtype)


class _Archetype(nnx.Module):
    """Shared interface: ``scores`` (finite, 0 on padded slots), masked ``__call__``, the
    same of a motion seen up to a stop time (``prefix_scores``, ``prefix``),
    ``parameters`` and ``describe``. A subclass defines ``_scores(xyz, goals, goal_mask,
    seen)`` (``seen`` None: the whole motion)."""

    name = ""

    def __call__(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"],
    ) -> Float[Array, "... G"]:
        """Masked logits: softmax over the real goals is the observer's P(goal | trajectory)."""
        return common.mask_logits(self.scores(xyz, goals, goal_mask), goal_mask)

    def scores(
        self, xyz: Float[Array, "... T 3"], goals: Float[Array, "... G 3"], goal_mask, **_
    ) -> Float[Array, "... G"]:
        """The scores of the whole motion on real goals, 0 on padded slots (finite)."""
        return self._scores(xyz, goals, goal_mask, None)

    def prefix_scores(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"],
        seen: Int[Array, "..."],
        **_,
    ) -> Float[Array, "... G"]:
        """The scores of the motion seen up to its first ``seen`` = L points (L traced):
        the archetype's formula applied to ``xyz[..., :L, :]`` at the prefix's own times
        t_i = i/(L − 1), on the fixed shape of ``xyz`` (points ≥ L get no gradient)."""
        return self._scores(xyz, goals, goal_mask, jnp.asarray(seen))

    def prefix(
        self,
        xyz: Float[Array, "... T 3"],
        goals: Float[Array, "... G 3"],
        goal_mask: Bool[Array, "... G"],
        seen: Int[Array, "..."],
    ) -> Float[Array, "... G"]:
        """Masked logits of the motion seen up to its first ``seen`` points."""
        return common.mask_logits(self.prefix_scores(xyz, goals, goal_mask, seen), goal_mask)

    def _scalar_parameters(self) -> dict[str, float]:
        out = {}
        for k, v in self._constrained().items():
            a = np.asarray(v, np.float64)
            if a.ndim == 0:
                out[k] = float(a)
            elif a.ndim == 1 and a.shape[0] == 3 and k == "metric":
                out.update({f"metric_{c}": float(x) for c, x in zip("xyz", a, strict=True)})
            else:
                raise ValueError(
                    f"{type(self).__name__}: parameter {k!r} has shape {a.shape}; describe one "
                    "trained model (select a trial of a batched result first)"
                )
        return out


# ------------------------------------------------------------------ learnable Dragan


class LearnableDragan(_Archetype):
    """Dragan legibility with learned temperature, time weighting, start term and metric.

    For a trajectory p_0..p_{T−1} (S = p_0) at t_i = i/(T − 1) and real goals g_k::

        ‖x‖_M   = sqrt(m_x x² + m_y y² + m_z z²),         m_j > 0, Σ_j m_j = 3
        P_k(i)  = softmax_k( β (w₀ ‖S − g_k‖_M − ‖p_i − g_k‖_M) )
        s_k     = log Σ_i c_i P_k(i),    c_i ∝ trap_i (1 − t_i)^α,  Σ_i c_i = 1

    Parameters (all learned): β > 0 (1/m, ``exp``), α ≥ 0 (``softplus``), w₀ ≥ 0
    (``softplus``), metric weights m (softmax × 3; trace 3 so that β alone sets the
    scale). The defaults (β = 5, α = 1, w₀ = 1, m = 1) are :ref:`concepts-dragan`'s labeler at β =
    5: the logits are ``log labelers.dragan(xyz, goals, goal_mask, beta=5.0)``. w₀ = 0 is a
    nearest-goal observer (no memory of the start); α = 0 weighs the whole motion
    equally, large α only its beginning; a small m_z means the observer hardly sees height.

    Reference: Dragan & Srinivasa, "Generating Legible Motion", RSS 2013.

    >>> import jax.numpy as jnp
    >>> m = LearnableDragan(beta=20.0)
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.0]).at[1].set([0.5, -0.2, 0.0])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.4]), g[0], 100)
    >>> m(xyz, g, jnp.arange(8) < 2).shape
    (8,)
    """

    name = "dragan"

    def __init__(
        self,
        *,
        beta: float = 5.0,
        alpha: float = 1.0,
        start_weight: float = 1.0,
        metric: tuple[float, float, float] = (1.0, 1.0, 1.0),
    ):
        _check("beta", beta)
        _check("alpha", alpha, strict=False)
        _check("start_weight", start_weight, strict=False)
        m = np.asarray(metric, np.float64)
        if m.shape != (3,) or not np.all(np.isfinite(m)) or not np.all(m > 0):
            raise ValueError(f"metric: expected 3 finite weights > 0, got {metric!r}")
        m = 3.0 * m / m.sum()
        self.log_beta = _param(_log(beta))
        self.raw_alpha = _param(_inv_softplus(alpha))
        self.raw_start_weight = _param(_inv_softplus(start_weight))
        self.log_metric = nnx.Param(jnp.asarray(np.log(m), jnp.result_type(float)))

    def _constrained(self) -> dict[str, Array]:
        return {
            "beta": jnp.exp(_value(self.log_beta)),
            "alpha": jax.nn.softplus(_value(self.raw_alpha)),
            "start_weight": jax.nn.softplus(_value(self.raw_start_weight)),
            "metric": 3.0 * jax.nn.softmax(_value(self.log_metric), axis=-1),
        }

    def _scores(self, xyz, goals, goal_mask, seen) -> Float[Array, "... G"]:
        """s_k = log y_k on real goals, 0 on padded slots (finite everywhere)."""
        p = self._constrained()
        s = common.dragan_log_labels(
            xyz,
            goals,
            goal_mask,
            p["beta"],
            alpha=p["alpha"],
            start_weight=p["start_weight"],
            metric=p["metric"],
            seen=seen,
        )
        return jnp.where(goal_mask, s, 0.0)

    def parameters(self) -> dict[str, float]:
        """The fitted values: beta (1/m), alpha, start_weight, metric_x/y/z (trace 3)."""
        return self._scalar_parameters()

    def describe(self) -> str:
        """The fitted parameters with their units, in words."""
        p = self.parameters()
        return "\n".join(
            [
                "Learnable Dragan observer (concepts: Dragan with learned parameters):",
                f"  temperature β = {p['beta']:.3g} per metre: a goal 1/β = "
                f"{100 / p['beta']:.3g} cm closer makes it e times likelier at each moment;",
                f"  time weighting (1 − t)^α with α = {p['alpha']:.3g}: "
                + _alpha_words(p["alpha"]),
                f"  start-to-goal term weight w₀ = {p['start_weight']:.3g} "
                "(1: Dragan's progress from the start; 0: only the distance left matters);",
                f"  metric weights x {p['metric_x']:.3g}, y {p['metric_y']:.3g}, "
                f"z {p['metric_z']:.3g} (sum 3; 1, 1, 1 is Euclidean; a small weight is an "
                "axis the observer hardly sees).",
            ]
        )


def _alpha_words(alpha: float) -> str:
    half = 1.0 - 0.5 ** (1.0 / alpha) if alpha > 0 else 1.0  # (1 − t)^α = 1/2
    if half > 0.99:
        return "nearly every moment of the motion counts the same;"
    return f"moments after t = {half:.2f} of the motion count less than half as much as its start;"


# ------------------------------------------------------------------ learnable viewpoint


def camera_frame(
    yaw, pitch, distance, center=CENTER
) -> tuple[Float[Array, " 3"], Float[Array, "3 3"]]:
    """Position and world-from-camera rotation of a camera looking at ``center``.

    The camera stands at c + r (cos φ cos ψ, cos φ sin ψ, sin φ) for yaw ψ (rad, about the
    vertical through ``center``, 0 on the +x side, facing the robot), pitch φ (rad, above
    the horizontal) and distance r (m). MuJoCo convention (:ref:`concepts-nikolaidis`): the columns
    of the rotation are the camera's x (right, horizontal), y (up) and z (backwards: from the
    centre to the camera) axes; it looks along −z.

    >>> pos, rot = camera_frame(0.0, 0.0, 2.0)
    >>> [round(float(v), 3) + 0.0 for v in pos], [round(float(v), 3) + 0.0 for v in rot[:, 0]]
    ([2.45, 0.0, 0.15], [0.0, 1.0, 0.0])
    """
    cy, sy, cp, sp = jnp.cos(yaw), jnp.sin(yaw), jnp.cos(pitch), jnp.sin(pitch)
    back = jnp.stack([cp * cy, cp * sy, sp])
    right = jnp.stack([-sy, cy, jnp.zeros_like(sy)])
    up = jnp.cross(back, right)
    pos = jnp.asarray(center, back.dtype) + distance * back
    return pos, jnp.stack([right, up, back], axis=-1)


def camera_pose(cam: Camera, center=CENTER) -> tuple[float, float, float]:
    """(yaw, pitch, distance) of a camera about ``center`` (radians, radians, metres).

    Converts a MuJoCo camera pose (:ref:`concepts-cameras`; e.g. ``scene.camera("observer")``) to
    the parameters of :func:`camera_frame`, from the direction and length of
    ``cam.pos − center``. Raises ValueError unless the camera looks at ``center`` (its −z
    axis points there to 1e-4) — a roll about that axis does not matter: it rotates the
    image plane, which leaves image-plane distances, and so the labels, unchanged.

    >>> from slotv_jax import scene
    >>> [round(float(np.degrees(a)), 2) for a in camera_pose(scene.camera("observer"))[:2]]
    [0.0, 29.48]
    """
    yaw, pitch, r, back = _about(cam, center)
    rot = np.asarray(cam.rot, np.float64)
    if np.max(np.abs(rot[:, 2] - back)) > 1e-4:
        raise ValueError(
            f"camera: it does not look at the centre {center} (its z axis "
            f"{rot[:, 2].round(4).tolist()}, the direction from the centre "
            f"{back.round(4).tolist()})"
        )
    return yaw, pitch, r


def _about(cam: Camera, center) -> tuple[float, float, float, np.ndarray]:
    """Yaw, pitch (rad), distance (m) and unit direction of a camera's position about
    ``center`` (ValueError if it stands on it)."""
    pos = np.asarray(cam.pos, np.float64)
    off = pos - np.asarray(center, np.float64)
    r = float(np.linalg.norm(off))
    if not r > 0:
        raise ValueError(f"camera: its position {pos.tolist()} is the centre {center}")
    back = off / r
    return float(np.arctan2(back[1], back[0])), float(np.arcsin(np.clip(back[2], -1, 1))), r, back


def start_pose(cam: Camera, center=CENTER) -> tuple[float, float, float]:
    """(yaw, pitch, distance) of a camera's *position* about ``center``: the viewpoint
    archetype's start for a study filmed by ``cam`` (a camera file's camera need not look at
    the centre; the archetype's camera does, and learns its pose from there), the distance
    at least :data:`DISTANCE_MIN` plus 1 cm.

    >>> from slotv_jax import scene
    >>> np.allclose(start_pose(scene.camera("observer")), camera_pose(scene.camera("observer")))
    True
    """
    yaw, pitch, r, _ = _about(cam, center)
    return yaw, float(np.clip(pitch, -1.55, 1.55)), max(r, DISTANCE_MIN + 0.01)


class LearnableViewpoint(_Archetype):
    """Dragan legibility in the image plane of a learned camera (:ref:`concepts-cameras`, learned
    pose).

    The camera stands at yaw ψ, pitch φ and distance r about :data:`CENTER`, looking at it
    (:func:`camera_frame`). Points and goals are projected as in :ref:`concepts-cameras`,
    p_c = Rᵀ (p − c), (u, v) = (p_c.x, p_c.y) / (−p_c.z), and :func:`LearnableDragan`'s
    formula with α = 1, w₀ = 1 and the Euclidean metric is applied to the (u, v) points
    with temperature β (per unit of image plane at depth 1).

    Parameters: ψ (rad, free), φ = 90° · tanh(·) (``|φ|`` ≤ 90°; the frame stays defined),
    r = DISTANCE_MIN + exp(·) (m), β = exp(·). Defaults: a start pose that is not the
    ``observer`` camera's (ψ = 45°, φ = 45°, r = 1.5 m; the observer stands at ψ = 0°,
    φ = 29.5°, r = 1.32 m) and β = 7.5. With the observer's pose and β = 7.5 the logits are
    ``log labelers.nikolaidis(xyz, goals, goal_mask, scene.camera("observer"), beta=7.5)``.

    Points or real goals at depth ≤ 1e-6 m (behind the learned camera) make the scores
    uniform over the real goals, as the labeler does; with :data:`DISTANCE_MIN` this
    cannot happen in the :ref:`concepts-trajectories` workspace.

    Reference: Nikolaidis, Dragan & Srinivasa, "Viewpoint-Based Legibility Optimization",
    HRI 2016.

    >>> from slotv_jax import scene
    >>> yaw, pitch, r = camera_pose(scene.camera("observer"))
    >>> m = LearnableViewpoint(yaw=yaw, pitch=pitch, distance=r, beta=7.5)
    >>> round(m.parameters()["distance"], 3)
    1.321
    """

    name = "viewpoint"

    def __init__(
        self,
        *,
        yaw: float = math.radians(45.0),
        pitch: float = math.radians(45.0),
        distance: float = 1.5,
        beta: float = 7.5,
        camera: str | None = None,
    ):
        if camera is not None:  # start where the study's camera stands (a name or a file)
            yaw, pitch, distance = start_pose(scene_camera(camera))
        _check("yaw", yaw, -math.inf)
        p = float(pitch)
        if not (math.isfinite(p) and abs(p) < math.pi / 2):
            raise ValueError(f"pitch: expected radians in (−π/2, π/2), got {pitch!r}")
        _check("distance", distance, DISTANCE_MIN)
        _check("beta", beta)
        self.yaw = _param(float(yaw))
        self.raw_pitch = _param(math.atanh(p / (math.pi / 2)))
        self.log_distance = _param(math.log(float(distance) - DISTANCE_MIN))
        self.log_beta = _param(_log(beta))

    def _constrained(self) -> dict[str, Array]:
        return {
            "yaw": _value(self.yaw),
            "pitch": (math.pi / 2) * jnp.tanh(_value(self.raw_pitch)),
            "distance": DISTANCE_MIN + jnp.exp(_value(self.log_distance)),
            "beta": jnp.exp(_value(self.log_beta)),
        }

    def camera(self) -> tuple[Float[Array, " 3"], Float[Array, "3 3"]]:
        """The learned camera's position and world-from-camera rotation."""
        p = self._constrained()
        return camera_frame(p["yaw"], p["pitch"], p["distance"])

    def _scores(self, xyz, goals, goal_mask, seen) -> Float[Array, "... G"]:
        """s_k = log y_k on real goals (0 for all if a seen point's or a real goal's depth is
        invalid), 0 on padding."""
        p = self._constrained()
        pos, rot = camera_frame(p["yaw"], p["pitch"], p["distance"])
        pos, rot = pos.astype(xyz.dtype), rot.astype(xyz.dtype)
        uv, ok_p = _image_points(xyz, pos, rot)
        uv_g, ok_g = _image_points(goals, pos, rot)
        s = common.dragan_log_labels(uv, uv_g, goal_mask, p["beta"], seen=seen)
        if seen is not None:  # the points after the seen ones do not count
            ok_p = ok_p | (jnp.arange(xyz.shape[-2]) >= seen[..., None])
        ok = jnp.all(ok_p, axis=-1) & jnp.all(ok_g | ~goal_mask, axis=-1)
        return jnp.where(goal_mask & ok[..., None], s, 0.0)

    def parameters(self) -> dict[str, float]:
        """The fitted values: yaw, pitch (rad), distance (m), beta (per unit image plane),
        and the camera position x/y/z (m)."""
        p = self._scalar_parameters()
        pos, _ = camera_frame(p["yaw"], p["pitch"], p["distance"])
        return {
            **p,
            **{f"camera_{c}": float(v) for c, v in zip("xyz", np.asarray(pos), strict=True)},
        }

    def describe(self) -> str:
        """The fitted parameters with their units, in words."""
        p = self.parameters()
        yaw = math.degrees(math.remainder(p["yaw"], 2 * math.pi))
        return "\n".join(
            [
                "Learnable viewpoint observer (Dragan legibility in a learned camera's image):",
                f"  camera yaw {yaw:.1f}° about the vertical through the workspace centre "
                f"{CENTER} m (0°: across the goal table, facing the robot; 90°: on its left, "
                "the +y side);",
                f"  camera pitch {math.degrees(p['pitch']):.1f}° above the horizontal, "
                f"distance {p['distance']:.3g} m from the centre (camera at "
                f"{p['camera_x']:.2f}, {p['camera_y']:.2f}, {p['camera_z']:.2f} m);",
                f"  temperature β = {p['beta']:.3g} per unit of image plane (at 1 m depth, "
                f"a goal {100 / p['beta']:.3g} cm closer across the view makes it e times "
                "likelier at each moment).",
            ]
        )


def _image_points(p: Float[Array, "... N 3"], pos, rot) -> tuple[Array, Array]:
    """Image-plane points (..., N, 2) and depth validity (..., N): :ref:`concepts-cameras`'s
    projection (:func:`slotv_jax.world.scene.image_coords`, guarded where the depth is ≤
    DEPTH_EPS)."""
    (u, v), ok = image_coords(p, pos, rot, DEPTH_EPS)
    return jnp.stack([u, v], axis=-1), ok
