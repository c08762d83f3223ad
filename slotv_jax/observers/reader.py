"""The motion reader: a learned observer of what a person watching a video can read.

SLOT-V's network sees one thing of each point, its position relative to a goal, p_i − g_k,
and averages one value of it over the motion. People watching a clip read more: where the
hand is heading and how fast it closes on a goal, whether its path, carried on, runs into
a goal, how it looks *in the picture* (depth is hard to see in a video), and they weigh
the moments they saw unevenly (the first impression, the last, or all; Hogarth & Einhorn
1992). :class:`MotionReader` learns each of these from answers, within SLOT-V's training
loop, loss and goal padding::

    f_ik  = the reading features of point i and goal k (below), in the world and in the
            study camera's image
    s_ik  = MLP(f_ik)                                  (a scalar per point and goal)
    w_i   = softmax_{i < L}( Σ_b a_b φ_b(u_i) ),  u_i = i / (L − 1)
    score_k = (1 − ρ) Σ_i w_i s_ik + ρ log Σ_i w_i softmax_k(s_ik)

for the first L points seen (the stop time's prefix, ``seen`` traced): the weighting w of
the seen points is learned through B = :data:`N_BASIS` Gaussian bumps φ_b over the
prefix's own time (a uniform mean at a = 0), and the share ρ = sigmoid(r) mixes the two
ways of combining the moments: adding evidence (log-linear, as SLOT-V) or remembering a
belief from one moment (a mixture of per-moment beliefs, as the population model's
people).

The features of point i (p_i; S = p_0 the start) and goal g_k, each in two views, the
world (metres / :data:`WORLD_SCALE`) and the image plane of the camera (normalised image
coordinates / :data:`IMAGE_SCALE`, :ref:`concepts-cameras`):

====================  ========================================================================
``distance``          ‖p_i − g_k‖
``progress``          ‖S − g_k‖ − ‖p_i − g_k‖ (Dragan's cost-to-go difference)
``heading``           cos(v_i, g_k − p_i), v_i = p_i − p_{i−w}: where the hand moves now
``approach``          (‖p_{i−w} − g_k‖ − ‖p_i − g_k‖) / Δt: how fast it closes on g_k
``overall``           cos(p_i − S, g_k − S): where it has gone since the start
``miss``              the distance from g_k to the ray p_i + s v_i, s ≥ 0 (extrapolation)
====================  ========================================================================

plus ``nearest``, ‖p_i − g_k‖ − min_j ‖p_i − g_j‖ in each view (is g_k the nearest goal).
The lag w is :data:`LAG` of the motion (5 of 100 points; fewer at the first points), Δt
its time; norms are damped, ‖x‖_ε = sqrt(‖x‖² + ε²) with ε = :data:`EPS`, so every
feature and gradient stays finite, also at rest. Every feature of point i reads only
points ≤ i, so the prefix's scores are the motion cut at L.

The camera is the study's (the lab films the clips; it knows where its camera stood:
``TrainConfig.camera``, a camera of the scene or a camera file). It is stored with the
parameters (so one compiled program serves studies filmed from different cameras) and is
never learned: the forward pass stops its gradient, so every update leaves it unchanged.

Reference: Wallkötter et al. 2022 (SLOT-V, the loss and the integral over the motion);
Dragan & Srinivasa 2013 (progress); Baker et al. 2009 and Hogarth & Einhorn 1992 (what a
reading of a motion can weigh).

>>> import jax.numpy as jnp
>>> m = MotionReader((16, 16), rngs=0)
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
>>> mask = jnp.arange(8) < 2
>>> m(xyz, g, mask).shape, bool(jnp.isinf(m(xyz, g, mask)[2]))
((8,), True)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import common
from slotv_jax.observers.parametric import _Archetype
from slotv_jax.world import scene

__all__ = [
    "EPS",
    "FEATURES",
    "IMAGE_SCALE",
    "LAG",
    "N_BASIS",
    "WORLD_SCALE",
    "MotionReader",
    "lag_points",
    "reading_features",
    "seen_weights",
    "with_camera",
]

#: The per-view reading features, in the order of :func:`reading_features`'s last axis
#: (the world's first, then the image's).
VIEW_FEATURES = ("distance", "progress", "heading", "approach", "overall", "miss", "nearest")
FEATURES = tuple(f"{v}_{f}" for v in ("world", "image") for f in VIEW_FEATURES)
WORLD_SCALE = 0.3  # m: the world view's lengths are divided by it (the goals lie ~0.3 m apart)
IMAGE_SCALE = 0.3  # the image view's (normalised image coordinates: ~0.6 across the tables)
EPS = 1e-3  # damping of the norms (m, or image units): 1 mm, far below any motion's step
LAG = 0.05  # the heading's look-back, as a share of the motion (5 of 100 points)
N_BASIS = 6  # Gaussian bumps of the learned weighting of the seen points
DEPTH_EPS = 1e-6  # points closer to the camera plane than this (m) read as at depth 1
ACTIVATIONS = {"relu": jax.nn.relu, "softplus": jax.nn.softplus}
_List = getattr(nnx, "List", list)  # flax < 0.12 keeps sub-modules in plain lists


def lag_points(n_points: int) -> int:
    """w = max(1, round(LAG · (T − 1))): the points the heading looks back."""
    return max(1, round(LAG * (n_points - 1)))


def _norm(x: Array) -> Array:
    return jnp.sqrt(jnp.sum(x * x, axis=-1) + EPS * EPS)


def _view_features(
    p: Float[Array, "... T D"], g: Float[Array, "... G D"], goal_mask, scale: float
) -> Float[Array, "... T G 7"]:
    """The seven features of :data:`VIEW_FEATURES` in one view (D = 3 or 2)."""
    n = p.shape[-2]
    w = lag_points(n)
    i = np.arange(n)
    j = np.maximum(i - w, 0)
    dt = np.maximum(i - j, 1).astype(np.float32) / max(n - 1, 1)  # time between j and i
    # differences of the raw points, then scaled: a point less itself is exactly 0
    start = p[..., :1, :]  # (..., 1, D)
    d = (g[..., None, :, :] - p[..., :, None, :]) / scale  # (..., T, G, D): to the goal
    dist = _norm(d)
    to_goal = (g[..., None, :, :] - start[..., None, :]) / scale  # (..., 1, G, D)
    dist_start = _norm(to_goal)  # (..., 1, G)
    v = (p - p[..., j, :]) / scale  # (..., T, D): the recent motion
    v_n = _norm(v)[..., None]
    heading = jnp.sum(v[..., None, :] * d, -1) / (v_n * dist)
    # a difference of two norms as (|a|² − |b|²) / (|a| + |b|) = (a − b)·(a + b) / (|a| + |b|)
    # (the damping cancels in the numerator): no cancellation, exactly 0 where nothing moved
    before = jnp.take(d, j, axis=-3)  # (..., T, G, D): to the goal, w points earlier
    approach = jnp.sum(v[..., None, :] * (before + d), -1) / (jnp.take(dist, j, axis=-2) + dist)
    approach = approach / dt[:, None]
    moved = (p - start) / scale  # (..., T, D)
    progress = jnp.sum(moved[..., None, :] * (to_goal + d), -1) / (dist_start + dist)
    overall = jnp.sum(moved[..., None, :] * to_goal, -1) / (_norm(moved)[..., None] * dist_start)
    u = (v / v_n)[..., None, :]  # the heading's unit vector (damped)
    ahead = jnp.maximum(jnp.sum(d * u, -1, keepdims=True), 0.0)
    miss = _norm(d - ahead * u)
    nearest = dist - jnp.min(jnp.where(goal_mask[..., None, :], dist, jnp.inf), -1, keepdims=True)
    return jnp.stack([dist, progress, heading, approach, overall, miss, nearest], axis=-1)


def reading_features(
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    goal_mask: Bool[Array, "... G"],
    cam_pos: Float[Array, " 3"],
    cam_rot: Float[Array, "3 3"],
) -> Float[Array, "... T G 14"]:
    """The reader's features of every point and goal (the module docstring's table), the
    world view's seven then the image view's (:data:`FEATURES`); the image view projects
    points and goals through the camera at ``cam_pos`` with world-from-camera rotation
    ``cam_rot`` (:func:`slotv_jax.world.scene.image_coords`). Causal: the features of
    point i read points ≤ i only."""
    world = _view_features(xyz, goals, goal_mask, WORLD_SCALE)

    def image(points):
        (u, v), _ = scene.image_coords(points, cam_pos, cam_rot, DEPTH_EPS)
        return jnp.stack([u, v], -1)

    img = _view_features(image(xyz), image(goals), goal_mask, IMAGE_SCALE)
    return jnp.concatenate([world, img], axis=-1)


def _basis(u: Float[Array, "... T"]) -> Float[Array, "... T B"]:
    c = np.linspace(0.0, 1.0, N_BASIS)
    s = 1.0 / (N_BASIS - 1)
    return jnp.exp(-0.5 * ((u[..., None] - c) / s) ** 2)


def seen_weights(
    a: Float[Array, " B"], n_points: int, seen: Int[Array, "..."]
) -> Float[Array, "... T"]:
    """w_i = softmax over the seen points i < L of Σ_b a_b φ_b(u_i), u_i = i/(L − 1) (the
    prefix's own times, :func:`slotv_jax.observers.common.prefix_times`); 0 after L.

    >>> [round(float(x), 3) for x in seen_weights(jnp.zeros(N_BASIS), 4, 2)]
    [0.5, 0.5, 0.0, 0.0]
    """
    u = common.prefix_times(n_points, seen)
    logit = _basis(u) @ a
    valid = jnp.arange(n_points) < jnp.asarray(seen)[..., None]
    return jax.nn.softmax(jnp.where(valid, logit, -jnp.inf), axis=-1)


class MotionReader(_Archetype):
    """The motion reader (module docstring): a small MLP over reading features, a learned
    weighting of the seen points and a learned way of combining them.

    ``hidden`` are the MLP's widths (``TrainConfig.hidden``), ``activation`` its
    nonlinearity; ``camera`` the study's camera (a camera name or a camera file,
    :func:`slotv_jax.world.scene.camera`). Parameters: the MLP's weights, the weighting's
    coefficients a (:data:`N_BASIS`, 0 at the start: the plain mean), the mixing share's
    logit r (ρ = sigmoid(r), 0.5 at the start) and the camera (fixed).
    """

    name = "reader"

    def __init__(
        self,
        hidden: Sequence[int] = (64, 64),
        *,
        activation: str = "relu",
        camera: str = "observer",
        rngs: nnx.Rngs | jax.Array | int = 0,
    ):
        hidden = tuple(int(h) for h in hidden)
        if not hidden or min(hidden) < 1:
            raise ValueError(f"hidden: expected positive widths, got {hidden}")
        if activation not in ACTIVATIONS:
            raise ValueError(
                f"activation: expected one of {tuple(ACTIVATIONS)}, got {activation!r}"
            )
        if not isinstance(rngs, nnx.Rngs):
            rngs = nnx.Rngs(rngs)
        cam = scene.camera(camera)
        self.activation = activation
        widths = (len(FEATURES), *hidden)
        self.layers = _List([nnx.Linear(a, b, rngs=rngs) for a, b in itertools.pairwise(widths)])
        # No output bias: a constant added to every goal's score changes no probability.
        self.readout = nnx.Linear(hidden[-1], 1, use_bias=False, rngs=rngs)
        self.time_coef = nnx.Param(jnp.zeros((N_BASIS,), jnp.float32))
        self.mix_logit = nnx.Param(jnp.zeros((), jnp.float32))
        self.camera_pos = nnx.Param(jnp.asarray(cam.pos, jnp.float32))
        self.camera_rot = nnx.Param(jnp.asarray(cam.rot, jnp.float32))

    def point_scores(
        self, xyz: Float[Array, "... T 3"], goals: Float[Array, "... G 3"], goal_mask
    ) -> Float[Array, "... T G"]:
        """s_ik = MLP(f_ik) of every point and goal."""
        pos = jax.lax.stop_gradient(self.camera_pos[...])
        rot = jax.lax.stop_gradient(self.camera_rot[...])
        h = reading_features(xyz, goals, goal_mask, pos, rot)
        act = ACTIVATIONS[self.activation]
        for layer in self.layers:
            h = act(layer(h))
        return self.readout(h)[..., 0]

    def _scores(self, xyz, goals, goal_mask, seen) -> Float[Array, "... G"]:
        n = xyz.shape[-2]
        seen = jnp.full(xyz.shape[:-2], n, jnp.int32) if seen is None else seen
        goal_mask = jnp.asarray(goal_mask, bool)
        s = self.point_scores(common.seen_only(xyz, seen), goals, goal_mask)  # (..., T, G)
        w = seen_weights(self.time_coef[...], n, seen)  # (..., T)
        rho = jax.nn.sigmoid(self.mix_logit[...])
        linear = jnp.sum(w[..., None] * s, axis=-2)
        beliefs = common.masked_softmax(s, goal_mask[..., None, :])
        mixture = jnp.log(jnp.maximum(jnp.sum(w[..., None] * beliefs, axis=-2), 1e-30))
        return jnp.where(goal_mask, (1.0 - rho) * linear + rho * mixture, 0.0)

    def parameters(self) -> dict[str, float]:
        """What can be read of the fitted reader: ``first_weight`` and ``last_weight``, the
        weight of the first and last fifth of a whole motion's points (0.2 each for the
        plain mean), ``mixture_share`` ρ, and the camera's position ``camera_x/y/z``."""
        a = np.asarray(self.time_coef[...], np.float64)
        if a.ndim != 1:
            raise ValueError(
                "MotionReader: describe one trained model (select a trial of a batched result)"
            )
        w = np.asarray(seen_weights(jnp.asarray(a, jnp.float32), 100, 100), np.float64)
        pos = np.asarray(self.camera_pos[...], np.float64)
        return {
            "first_weight": float(w[:20].sum()),
            "last_weight": float(w[80:].sum()),
            "mixture_share": float(1.0 / (1.0 + math.exp(-float(self.mix_logit[...])))),
            **{f"camera_{c}": float(x) for c, x in zip("xyz", pos, strict=True)},
        }

    def describe(self) -> str:
        """The readable parts of the fitted reader, in words."""
        p = self.parameters()
        return "\n".join(
            [
                "Motion reader (concepts: the motion reader):",
                f"  weight of the first fifth of the motion seen {p['first_weight']:.2f}, of "
                f"the last fifth {p['last_weight']:.2f} (0.20 each: every moment alike);",
                f"  share of remembered beliefs ρ = {p['mixture_share']:.2f} (0: the moments' "
                "evidence adds up; 1: the guess follows one moment's belief);",
                f"  the study's camera at ({p['camera_x']:.2f}, {p['camera_y']:.2f}, "
                f"{p['camera_z']:.2f}) m (given, not learned).",
            ]
        )


def with_camera(params, camera: scene.Camera):
    """A reader's parameters (an ``nnx`` state, any leading axes) with the study's camera
    set to ``camera``'s pose: a study filmed from another camera, the same weights."""
    params = jax.tree.map(lambda x: x, params)  # a copy: the caller's state stays as it was
    shape = jnp.shape(params["camera_pos"][...])[:-1]
    params["camera_pos"] = params["camera_pos"].replace(
        jnp.broadcast_to(jnp.asarray(camera.pos, jnp.float32), (*shape, 3))
    )
    params["camera_rot"] = params["camera_rot"].replace(
        jnp.broadcast_to(jnp.asarray(camera.rot, jnp.float32), (*shape, 3, 3))
    )
    return params
