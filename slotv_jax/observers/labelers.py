"""The four hand-crafted legibility labelers (observer models) of :ref:`concepts-labelers`.

Each labeler maps one trajectory to a probability vector over the goal slots::

    y = labeler(xyz (T, 3), goals (8, 3), goal_mask (8,), ...)  # (8,)

with ``y >= 0``, ``sum(y[goal_mask]) == 1`` and ``y[~goal_mask] == 0`` exactly. They
are pure JAX functions: batch them with ``jax.vmap``, compile them with ``jax.jit``
and differentiate them with ``jax.grad``. ``jax.jit(jax.vmap(dragan))`` is the fast
way to label many trajectories (see the note above the cores); :func:`label_all` is
that, chunk by chunk, with validation. Nothing else here is jitted.

Notation (:ref:`concepts-labelers`): ``S = xyz[0]``, ``p_i = xyz[i]``, ``d_k(i) = ‖p_i − g_k‖`` (m),
and softmax is taken over the real goals only (log-sum-exp form, padded slots at −∞).

Time. Trajectories are sampled at normalised times ``t_i = i / (T − 1)`` unless
time stamps ``t (T,)`` are given. Given time stamps must be finite and strictly
increasing; they are normalised to ``τ = (t − t₀) / (t_{T−1} − t₀)`` ∈ [0, 1]. Without
``t`` every labeler computes exactly the SPEC formula.

Validation. The public functions check their arguments at the boundary and raise
``ValueError`` naming the argument: shapes (always), and NaN/inf, an empty goal
mask, two real goals at one position, β ≤ 0, non-increasing ``t`` and points behind
the camera (only on concrete values, so the same functions work under
``jit``/``vmap``/``grad``).

>>> import jax.numpy as jnp
>>> goals = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.0]).at[1].set([0.5, -0.2, 0.0])
>>> mask = jnp.arange(8) < 2
>>> xyz = jnp.linspace(jnp.array([0.0, 0.0, 0.3]), jnp.array([0.5, 0.2, 0.0]), 100)
>>> y = dragan(xyz, goals, mask)
>>> bool(y[0] > y[1]), float(y[2:].sum())
(True, 0.0)

Command line (label user trajectories from an ``.npz`` holding ``xyz (N, T, 3)``,
``goals`` and ``goal_mask`` (per trajectory or shared) and optional ``t``)::

    python -m slotv_jax.labelers --in trajs.npz --out labels.npz
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from slotv_jax.core import validation
from slotv_jax.core.defaults import DEFAULT_BETAS, LABELER_NAMES
from slotv_jax.observers.common import (
    distances,
    dragan_kernel,
    integrals,
    masked_softmax,
    time_weights,
)
from slotv_jax.world.scene import Camera, camera_coords, project
from slotv_jax.world.scene import camera as scene_camera
from slotv_jax.world.scene import image_coords as _image  # the guarded projection

__all__ = [
    "DEFAULT_BETAS",
    "DEPTH_EPS",
    "LABELERS",
    "LABELER_NAMES",
    "depth_ok",
    "dragan",
    "effdist",
    "fastapp",
    "nikolaidis",
]

DEPTH_EPS = 1e-6  # a point or goal with camera depth <= this is invalid (:ref:`concepts-cameras`)
# label_all's default chunk: this many trajectory labels per compiled call, i.e. 16,384
# trajectories for one labeler and 4,096 for all four (measured fastest on the 2-core
# CPU: experiments/BENCHMARKS.md; larger chunks of all four spill out of the caches).
CHUNK_LABELS = 16384

# ----------------------------------------------------------------- time weights


class TimeWeights(NamedTuple):
    """Per-point weights that turn the integrals of :ref:`concepts-labelers` into dot products."""

    dragan: np.ndarray | Array  # (..., T): trapezoid weight × (1 − τ), summing to 1
    effdist: np.ndarray | Array  # (..., T): time-average weights, summing to 1
    fastapp: np.ndarray | Array  # (..., T): s_k = β Σ_i fastapp_i d_k(i)


def _weights_from_tau(tau, xp) -> TimeWeights:
    """Weights for normalised times ``tau (..., T)`` (0 = start, 1 = end), with ``xp`` np or jnp."""
    T = tau.shape[-1]
    h = xp.diff(tau, axis=-1)  # (..., T−1) interval lengths
    zero = xp.zeros_like(tau[..., :1])
    one_minus = 1.0 - tau

    # Dragan: trapezoid rule for ∫ P(t)(1 − t) dt / ∫ (1 − t) dt, c_i ∝ trap_i (1 − τ_i):
    # the same weights integrate the denominator, so the labels sum to 1 over the real
    # goals (observers.common, shared with the archetypes and the networks' time weights).
    c = time_weights(tau, 1.0, trapezoid_rule=True)

    # EffDist: each sample stands for the time around it, the two end samples
    # mirroring their single neighbour interval; for uniform τ every weight is 1/T.
    cell = (
        xp.concatenate([h[..., :1], h], axis=-1) + xp.concatenate([h, h[..., -1:]], axis=-1)
    ) / 2
    w = cell / xp.sum(cell, axis=-1, keepdims=True)

    # FastApp: Σ_{i≥1} w_i (d(i−1) − d(i)) / Σ_{i≥1} w_i Δt_i with w_i = 1 − τ_i, written
    # as one weight per point (summation by parts). With T = 2 the only weight is
    # w_1 = 0 and the ratio is 0/0; its limit, the one approach speed, is used.
    if T == 2:
        a = xp.concatenate([1.0 / h, -1.0 / h], axis=-1)
    else:
        wr = one_minus[..., 1:]  # w_i for i = 1..T−1
        a = xp.concatenate([wr, zero], axis=-1) - xp.concatenate([zero, wr], axis=-1)
        a = a / xp.sum(wr * h, axis=-1, keepdims=True)
    return TimeWeights(c, w, a)


def _uniform_weights(T: int, dtype) -> TimeWeights:
    """Weights for t_i = i/(T−1), computed in float64 and cast (:ref:`concepts-labelers`
    exactly)."""
    tw = _weights_from_tau(np.arange(T, dtype=np.float64) / (T - 1), np)
    w = np.full(T, 1.0 / T)  # EffDist: (1/T) Σ_i, exactly as :ref:`concepts-effdist` writes it
    return TimeWeights(*(jnp.asarray(x, dtype) for x in (tw.dragan, w, tw.fastapp)))


def _normalise_times(t, xp):
    return (t - t[..., :1]) / (t[..., -1:] - t[..., :1])


def _time_weights(t, T: int, dtype) -> TimeWeights:
    if t is None:
        return _uniform_weights(T, dtype)
    if validation.is_concrete(t):
        # Normalise in float64 first: large clock offsets (e.g. Unix time) would
        # otherwise lose all resolution in float32.
        t = _normalise_times(np.asarray(t, np.float64), np)
    t = jnp.asarray(t, dtype)
    return _weights_from_tau(_normalise_times(t, jnp), jnp)


# ------------------------------------------------------------------- cores
# Each core labels one trajectory, its points coordinate by coordinate (``pts[j] (T,)``),
# on the fused kernels of :mod:`slotv_jax.observers.common`.


def _effdist_core(pts: Sequence[Array], goals: Array, mask: Array, beta, w: Array) -> Array:
    """:ref:`concepts-effdist` [reconstruction]: ``softmax(−β Σ_i w_i d_k(i))``."""
    return masked_softmax(-beta * integrals([distances(pts, g) for g in goals], w), mask)


def _fastapp_core(pts: Sequence[Array], goals: Array, mask: Array, beta, a: Array) -> Array:
    """:ref:`concepts-fastapp` [reconstruction]: ``softmax(β Σ_i a_i d_k(i))`` (summation by
    parts)."""
    return masked_softmax(beta * integrals([distances(pts, g) for g in goals], a), mask)


def _in_front(pts: Float[Array, "*n K 3"], pos, rot, mask=None, eps=DEPTH_EPS) -> Array:
    """Whether every one of the K points (with ``mask (*n, K)``: every real one) lies at
    camera depth > eps, ``(*n,)``."""
    _, ok = _image(pts, pos, rot, eps)
    return jnp.all(ok if mask is None else ok | ~mask, axis=-1)


def _nikolaidis_core(xyz, goals, mask, pos, rot, beta, c, eps=DEPTH_EPS) -> Array:
    """:ref:`concepts-cameras`: Dragan legibility of the image-plane points; uniform over the real
    goals if a point or real goal is at depth <= eps.

    The points are not divided by their depth ``z = −p_c.z``: the image-plane distance
    is taken in homogeneous form, ``‖(p_c.x, p_c.y) / z − (u_k, v_k)‖ = ‖p_c − z r_k‖ / z``
    with the goal's ray ``r_k = (u_k, v_k, −1)`` (the third coordinate of ``p_c − z r_k``
    is exactly 0). The points stay 3-vectors, so under ``vmap`` the projection fuses
    into the one loop of :func:`~slotv_jax.observers.common.dragan_kernel`, with no
    ``(N, T)`` image arrays stored, and that loop compiles like Dragan's 3-D one (measured
    1.5× faster than dividing first). The depth check is counted in the same loop (10 %
    faster than a separate pass over the points). See experiments/BENCHMARKS.md.

    A non-finite point is not a depth problem: its depth is NaN, neither valid nor
    invalid, and the labels are NaN as with the other labelers (so that
    :func:`label_all` finds it from the labels, without a pass over the points).
    """
    pc = camera_coords(xyz, pos, rot)
    depth = -pc[2]
    behind = depth <= eps  # False for a NaN depth
    (u, v), ok_g = _image(goals, pos, rot, eps)
    rays = jnp.stack([u, v, -jnp.ones_like(u)], axis=-1)
    goal_behind = ~jnp.all(ok_g | ~mask, axis=-1)
    scale = jnp.where(behind, 1.0, depth)
    return dragan_kernel(pc, rays, mask, beta, c, scale=scale, invalid=behind | goal_behind)


# ------------------------------------------------------------ public labelers


def _prepare(xyz, goals, goal_mask, beta, t, beta_name="beta"):
    """Boundary checks shared by the four labelers; returns the points ``(T, 3)``, the
    goals, the mask and the time weights."""
    validation.check_array("xyz", xyz, (None, 3))
    T = int(np.shape(xyz)[0])
    if T < 2:
        raise ValueError(f"xyz: expected at least 2 trajectory points (T >= 2), got T = {T}")
    validation.check_goals("goals", goals, goal_mask)
    validation.check_positive(beta_name, beta)
    if t is not None:
        _check_times("t", t, (T,))
    xyz = jnp.asarray(xyz)
    if not jnp.issubdtype(xyz.dtype, jnp.floating):
        xyz = xyz.astype(jnp.result_type(float))
    goals = jnp.asarray(goals, xyz.dtype)
    mask = jnp.asarray(goal_mask).astype(bool)
    return xyz, goals, mask, _time_weights(t, T, xyz.dtype)


def _coords(xyz: Float[Array, "T 3"]) -> tuple[Array, Array, Array]:
    return xyz[:, 0], xyz[:, 1], xyz[:, 2]


def _finite(y: Array) -> Array:
    """The labels, after checking that concrete ones are finite (valid finite input can
    still overflow float32: distances beyond about 1e19 m)."""
    validation.check_finite_result(
        "xyz",
        y,
        "the labels overflow: xyz or goals hold coordinates too large for the "
        f"distances to fit in {y.dtype} (|x| must stay well below 1e19 m in float32)",
    )
    return y


def _check_times(name: str, t, shape) -> None:
    validation.check_array(name, t, shape)
    if validation.is_concrete(t) and not np.all(np.diff(np.asarray(t, np.float64), axis=-1) > 0):
        raise ValueError(f"{name}: expected strictly increasing time stamps")


def dragan(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = DEFAULT_BETAS["dragan"],
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """Dragan legibility (:ref:`concepts-dragan`; Dragan & Srinivasa, RSS 2013, "Generating Legible
    Motion").

    Per point, the probability of each goal given the motion so far::

        P_k(i) = softmax_k( β (‖S − g_k‖ − ‖p_i − g_k‖) )        (real goals only)
        y_k    = ∫₀¹ P_k(t)(1 − t) dt / ∫₀¹ (1 − t) dt            (trapezoid rule)

    The cost-so-far term of the paper cancels across goals. Equals the first author's
    numpy ``legibility(...)[-1]`` with ``beta = velocity / 2``.

    Args:
      xyz: trajectory points (m), ``xyz[0]`` the start S; T >= 2.
      goals: goal positions (m); padded slots are ignored.
      goal_mask: True for real goals (at least one).
      beta: inverse temperature (1/m), > 0. Default: :data:`DEFAULT_BETAS` (20, the
        datasets' temperature).
      t: optional strictly increasing time stamps (any unit; normalised to [0, 1]).
        Default: uniform ``i / (T − 1)``.

    Returns:
      ``y (8,)``: probabilities over the real goals, exactly 0 on padded slots.

    Example: a straight line to goal 0 between two goals mirrored in y:

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([1.0, 0.5, 0.0]).at[1].set([1.0, -0.5, 0.0])
    >>> xyz = jnp.linspace(jnp.zeros(3), g[0], 50)
    >>> y = dragan(xyz, g, jnp.arange(8) < 2)
    >>> bool(y[0] > 0.5), round(float(y[0] + y[1]), 6)
    (True, 1.0)
    """
    xyz, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    return _finite(dragan_kernel(_coords(xyz), goals, mask, beta, tw.dragan))


def effdist(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = DEFAULT_BETAS["effdist"],
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """EffDist, the "effective distance" observer (:ref:`concepts-effdist`) **[reconstruction]**.

    The goal the motion stays closest to, on average over time::

        s_k = −β (1/T) Σ_i ‖p_i − g_k‖,     y = softmax(s)  (real goals only)

    This is a reconstruction: the source definition (Zhao et al., ICRA 2020, as used in
    Wallkötter et al. 2022, arXiv 2201.05765) could not be read. It is isolated in
    :func:`_effdist_core` so it can be replaced without touching anything else.

    Args:
      xyz, goals, goal_mask: as in :func:`dragan`.
      beta: inverse temperature (1/m), > 0. Default: :data:`DEFAULT_BETAS` (20, the
        datasets' temperature).
      t: optional time stamps. The mean becomes a time average: each point is weighted
        by the time around it (half of each neighbouring interval; the two end points
        count their one interval in full). Uniform stamps give exactly 1/T.

    Example: a path that stays at goal 0 gets most of the mass:

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.4, 0.0, 0.0]).at[1].set([0.4, 0.4, 0.0])
    >>> y = effdist(jnp.tile(g[0], (10, 1)), g, jnp.arange(8) < 2, beta=5.0)
    >>> round(float(y[0]), 4)  # softmax(0, −5·0.4) = 1 / (1 + e^−2)
    0.8808
    """
    xyz, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    return _finite(_effdist_core(_coords(xyz), goals, mask, beta, tw.effdist))


def fastapp(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = DEFAULT_BETAS["fastapp"],
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """FastApp, the "fast approach" observer (:ref:`concepts-fastapp`) **[reconstruction]**.

    The goal the motion approaches most, early. With ``a_k(i) = d_k(i−1) − d_k(i)`` (m)
    and ``w_i = 1 − t_i`` for i = 1..T−1::

        s_k = β Σ_i w_i a_k(i) / Σ_i w_i Δt_i,    y = softmax(s)  (real goals only)

    i.e. β times the (1 − t)-weighted mean approach speed (m per unit time); β has
    units of time/m. ``Δt_i = t_i − t_{i−1}`` (1/(T−1) by default). For T = 2 the only
    weight is 0 and the ratio is 0/0; its limit, ``s_k = β a_k(1) / Δt``, is used.

    This is a reconstruction: the source definition (Zhao et al., ICRA 2020, as used in
    Wallkötter et al. 2022, arXiv 2201.05765) could not be read. It is isolated in
    :func:`_fastapp_core` so it can be replaced without touching anything else.

    Example: T = 2 from the origin straight to goal 0 at 0.5 m; goal 1 is 0.5 m away
    too but sideways (its distance grows to √0.5 m):

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.0, 0.0]).at[1].set([0.0, 0.5, 0.0])
    >>> y = fastapp(jnp.stack([jnp.zeros(3), g[0]]), g, jnp.arange(8) < 2, beta=1.0)
    >>> round(float(y[0]), 4)  # softmax(0.5, 0.5 − √0.5)
    0.6698
    """
    xyz, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    return _finite(_fastapp_core(_coords(xyz), goals, mask, beta, tw.fastapp))


def _as_camera(cam) -> Camera:
    if isinstance(cam, str):
        return scene_camera(cam)
    if not isinstance(cam, Camera):
        raise ValueError(
            f"camera: expected a slotv_jax.scene.Camera or a camera name, got {type(cam)}"
        )
    validation.check_array("camera.pos", cam.pos, (3,))
    validation.check_array("camera.rot", cam.rot, (3, 3))
    return cam


def _check_depth(xyz, goals, goal_mask, cam: Camera, eps: float = DEPTH_EPS) -> None:
    """Raise if a concrete point or real goal is at depth <= eps (behind the camera)."""
    if not all(validation.is_concrete(x) for x in (xyz, goals, goal_mask, cam.pos, cam.rot)):
        return
    c = Camera(
        pos=np.asarray(cam.pos, np.float64),
        rot=np.asarray(cam.rot, np.float64),
        fovy=cam.fovy,
        resolution=cam.resolution,
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        _, dp = project(np.asarray(xyz, np.float64), c)
        _, dg = project(np.asarray(goals, np.float64), c)
    bad_p = np.flatnonzero(~(dp > eps))
    if bad_p.size:
        raise ValueError(
            f"xyz: {bad_p.size} point(s) at camera depth <= {eps} m (on or behind the camera "
            f"plane), first at index {bad_p[0]}; every point must be in front of the camera"
        )
    bad_g = np.flatnonzero(np.asarray(goal_mask, bool) & ~(dg > eps))
    if bad_g.size:
        raise ValueError(
            f"goals: real goal slot(s) {bad_g.tolist()} at camera depth <= {eps} m "
            "(on or behind the camera plane)"
        )


def depth_ok(
    xyz: Float[Array, "T 3"], goals: Float[Array, "8 3"], goal_mask: Bool[Array, " 8"], camera
) -> Bool[Array, ""]:
    """True if every point and real goal lies in front of ``camera`` (depth > 1e-6 m).

    The traced counterpart of :func:`nikolaidis`'s eager depth check, for use under
    ``jit``/``vmap`` where it cannot raise.
    """
    cam = _as_camera(camera)
    mask = jnp.asarray(goal_mask).astype(bool)
    return _in_front(jnp.asarray(xyz), cam.pos, cam.rot) & _in_front(
        jnp.asarray(goals), cam.pos, cam.rot, mask
    )


def nikolaidis(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    camera: Camera | str,
    *,
    beta: float = DEFAULT_BETAS["nikolaidis"],
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """Viewpoint-based (Nikolaidis) legibility: Dragan legibility in the image plane
    (:ref:`concepts-cameras`).

    Points and goals are projected into ``camera`` (MuJoCo convention: it looks along
    its −z axis, x right, y up)::

        p_c = R_camᵀ (p − c_cam),   (u, v) = (p_c.x, p_c.y) / (−p_c.z)

    and :func:`dragan` is applied to the 2-D points (u, v are normalised image
    coordinates, tan of the view angle, so β is per unit of image plane at depth 1).
    Reference: Nikolaidis, Dragan & Srinivasa, "Viewpoint-Based Legibility
    Optimization", HRI 2016.

    Depth rule: a point or real goal with depth ``−p_c.z <= 1e-6`` m is invalid.
    On concrete inputs this raises ``ValueError``. Under ``jit``/``vmap``/``grad`` it
    cannot raise; the label is then the uniform distribution over the real goals (an
    observer who cannot see the motion has no preference), finite with finite
    gradients, never NaN. Use :func:`depth_ok` to detect that case in traced code.

    Args:
      xyz, goals, goal_mask, t: as in :func:`dragan`.
      camera: a :class:`slotv_jax.scene.Camera` (e.g. ``scene.camera("observer")``) or
        a camera name of the scene model.
      beta: inverse temperature (per unit image plane), > 0. Default:
        :data:`DEFAULT_BETAS` (30, the datasets' temperature).

    Example:

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
    >>> y = nikolaidis(xyz, g, jnp.arange(8) < 2, "observer")
    >>> bool(y[0] > y[1])
    True
    """
    cam = _as_camera(camera)
    xyz, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    _check_depth(xyz, goals, mask, cam)
    dt = xyz.dtype
    y = _nikolaidis_core(xyz, goals, mask, cam.pos.astype(dt), cam.rot.astype(dt), beta, tw.dragan)
    return _finite(y)


LABELERS: dict[str, Callable[..., Array]] = {
    "dragan": dragan,
    "nikolaidis": nikolaidis,
    "effdist": effdist,
    "fastapp": fastapp,
}
