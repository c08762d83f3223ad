"""The four hand-crafted legibility labelers (observer models) of SPEC §4.

Each labeler maps one trajectory to a probability vector over the goal slots::

    y = labeler(xyz (T, 3), goals (8, 3), goal_mask (8,), ...)  # (8,)

with ``y >= 0``, ``sum(y[goal_mask]) == 1`` and ``y[~goal_mask] == 0`` exactly. They
are pure JAX functions: batch them with ``jax.vmap``, compile them with ``jax.jit``
and differentiate them with ``jax.grad``. Nothing here is jitted except the bulk
labeller :func:`label_all` and the command line.

Notation (SPEC §4): ``S = xyz[0]``, ``p_i = xyz[i]``, ``d_k(i) = ‖p_i − g_k‖`` (m), and
softmax is taken over the real goals only (log-sum-exp form, padded slots at −∞).

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

import argparse
import collections
import functools
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from slotv_jax import validation
from slotv_jax.fileio import atomic_write
from slotv_jax.scene import Camera, project
from slotv_jax.scene import camera as scene_camera
from slotv_jax.validation import G_MAX

__all__ = [
    "DEFAULT_BETAS",
    "DEPTH_EPS",
    "LABELERS",
    "LABELER_NAMES",
    "depth_ok",
    "dragan",
    "effdist",
    "fastapp",
    "label_all",
    "main",
    "nikolaidis",
]

LABELER_NAMES = ("dragan", "nikolaidis", "effdist", "fastapp")
DEFAULT_BETAS = {"dragan": 5.0, "nikolaidis": 7.5, "effdist": 5.0, "fastapp": 5.0}
DEPTH_EPS = 1e-6  # a point or goal with camera depth <= this is invalid (SPEC §4.2)
DEFAULT_CHUNK = 1024  # trajectories per compiled call in label_all (fastest on a 2-core CPU)

# ----------------------------------------------------------------- time weights


class TimeWeights(NamedTuple):
    """Per-point weights that turn the integrals of SPEC §4 into dot products."""

    dragan: np.ndarray | Array  # (..., T): trapezoid weight × (1 − τ), summing to 1
    effdist: np.ndarray | Array  # (..., T): time-average weights, summing to 1
    fastapp: np.ndarray | Array  # (..., T): s_k = β Σ_i fastapp_i d_k(i)


def _weights_from_tau(tau, xp) -> TimeWeights:
    """Weights for normalised times ``tau (..., T)`` (0 = start, 1 = end), with ``xp`` np or jnp."""
    T = tau.shape[-1]
    h = xp.diff(tau, axis=-1)  # (..., T−1) interval lengths
    zero = xp.zeros_like(tau[..., :1])
    one_minus = 1.0 - tau

    # Dragan: trapezoid rule for ∫ P(t)(1 − t) dt / ∫ (1 − t) dt. The trapezoid weight
    # of point i is half of each adjacent interval; the same weights integrate the
    # denominator, so the labels sum to 1 over the real goals.
    trap = (xp.concatenate([zero, h], axis=-1) + xp.concatenate([h, zero], axis=-1)) / 2
    c = trap * one_minus
    c = c / xp.sum(c, axis=-1, keepdims=True)

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
    """Weights for t_i = i/(T−1), computed in float64 and cast (SPEC §4 exactly)."""
    tw = _weights_from_tau(np.arange(T, dtype=np.float64) / (T - 1), np)
    w = np.full(T, 1.0 / T)  # EffDist: (1/T) Σ_i, exactly as SPEC §4.3 writes it
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
# Batched cores: every array may carry leading batch dimensions ``...``. Points are
# laid out coordinate-major, ``pts (..., D, T)``, and distances ``(..., G, T)``: the
# time axis is the contiguous one everywhere, so that the loops over points are
# vectorised with unit-stride loads, the softmax over goals is an elementwise
# reduction over at most 8 rows, and the time integrals reduce the contiguous axis.


def _distances(pts: Float[Array, "... D T"], goals: Float[Array, "... G D"]) -> Array:
    """``d[..., k, i] = ‖pts[..., :, i] − goals_k‖`` with a finite gradient at 0.

    Summed coordinate by coordinate: XLA then emits one vectorised loop over (G, T)
    instead of a reduction over an axis of size D.
    """
    sq = 0.0
    for j in range(pts.shape[-2]):
        sq = sq + (goals[..., :, j, None] - pts[..., None, j, :]) ** 2
    # max(·, tiny) keeps the gradient finite when a point sits exactly on a goal
    # (e.g. a trajectory ending at its target); it changes d only below 1e-19 m.
    return jnp.sqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny))


_INTEGRATE_SLICES = 4


def _integrate(f: Float[Array, "... G T"], w: Float[Array, "... T"]) -> Float[Array, "... G"]:
    """``Σ_i w_i f[..., :, i]``, with weights ``w (T,)`` shared or ``(..., T)`` per row.

    Shared weights: the time axis is cut into ``_INTEGRATE_SLICES`` consecutive slices
    whose weighted terms are added elementwise, and one contraction with ones sums
    what is left. XLA fuses the computation of ``f`` into the elementwise part, and
    the array that reaches the contraction is a quarter of ``f``, which on a CPU stays
    in cache. Weights per row: one batched contraction.
    """
    if w.ndim > 1:
        return jnp.einsum("...gt,...t->...g", f, w)
    T = f.shape[-1]
    n = T // min(_INTEGRATE_SLICES, T)
    parts = [f[..., i : i + n] * w[i : i + n] for i in range(0, T - n + 1, n)]
    if T % n:  # the last T mod n points, padded to a slice
        rest = f[..., T - T % n :] * w[T - T % n :]
        parts.append(jnp.pad(rest, [(0, 0)] * (rest.ndim - 1) + [(0, n - T % n)]))
    acc = parts[0]
    for part in parts[1:]:
        acc = acc + part
    return jnp.einsum("...gt,t->...g", acc, jnp.ones(n, acc.dtype))


def _slots(x: Array, axis: int) -> list[Array]:
    """The slices of ``x`` along ``axis`` (at most 8 goal slots), for elementwise folds."""
    return [jax.lax.index_in_dim(x, k, axis, keepdims=True) for k in range(x.shape[axis])]


def _masked_softmax(s: Array, mask: Array, axis: int) -> Array:
    """Softmax over ``axis`` restricted to ``mask``; exact zeros elsewhere (log-sum-exp form).

    The max and the sum over the (at most 8) slots are elementwise folds, which XLA
    fuses into one loop (a reduction over a short axis is much slower on a CPU).
    """
    s = jnp.where(mask, s, -jnp.inf)
    e = jnp.exp(s - functools.reduce(jnp.maximum, _slots(s, axis)))
    return e / functools.reduce(jnp.add, _slots(e, axis))


def _dragan_core(d: Array, d0: Array, mask: Array, beta, c: Array) -> Array:
    """SPEC §4.1 from distances ``d (..., G, T)``, start distances ``d0 (..., G, 1)`` and
    integration weights ``c (..., T)``.

    ``y_k = Σ_i c_i P_k(i)`` with ``P_k(i) = e_k(i) / Z(i)``, ``e = exp(logits − max)`` and
    ``Z = Σ_k e_k``. The max and the sum over goals are elementwise folds over the slots.
    """
    logits = jnp.where(mask[..., :, None], beta * (d0 - d), -jnp.inf)  # β(‖S − g_k‖ − d_k(i))
    e = jnp.exp(logits - functools.reduce(jnp.maximum, _slots(logits, -2)))  # 0 on padding
    return _normalised_integral(e, c)


def _normalised_integral(e: Float[Array, "... G T"], c: Float[Array, "... T"]) -> Array:
    """``Σ_i c_i e_k(i) / Z(i)`` with ``Z = Σ_k e_k`` (a fold over the goal slots)."""
    return _integrate(e / functools.reduce(jnp.add, _slots(e, -2)), c)


# Bound on |logit| under which exp needs no max shift in float32: exp(±64) and a sum of
# eight such terms stay far from overflow (exp(88.7)) and from subnormals (exp(-87.3)).
_EXP_BOUND = 64.0


def _dragan_referenced(d: Array, d0: Array, mask: Array, beta, c: Array) -> Array:
    """:func:`_dragan_core` with the logits shifted by those of goal slot 0, not by their max.

    Softmax is shift-invariant, so the labels are the same. By the triangle inequality
    ``|d_k(i) − d_0(i)| <= ‖g_k − g_0‖``, so every shifted logit lies in
    ``±2β ‖g_k − g_0‖``: bounded by the goals alone (see :func:`_goal_spread`), whatever
    the trajectory. Within ``_EXP_BOUND`` the exponentials need no max over the goals,
    which saves a pass over the (goal, point) array. Slot 0 may be padding (its label
    is still 0); only its position enters.
    """
    logits = beta * ((d0 - d0[..., :1, :]) + (d[..., :1, :] - d))
    e = jnp.exp(jnp.where(mask[..., :, None], logits, -jnp.inf))  # exactly 0 on padding
    return _normalised_integral(e, c)


def _goal_spread(goals: Float[Array, "... G D"], mask: Array) -> Array:
    """``max ‖g_k − g_0‖`` over the real goals k and all leading dimensions (a scalar)."""
    sq = sum((goals[..., :, j] - goals[..., :1, j]) ** 2 for j in range(goals.shape[-1]))
    return jnp.sqrt(jnp.max(jnp.where(mask, sq, 0.0)))


def _dragan_chunk(d: Array, d0: Array, mask: Array, beta, c: Array, goals: Array) -> Array:
    """:func:`_dragan_core` for a batch of trajectories, with goal positions ``goals``
    (in the space of ``d``).

    Takes :func:`_dragan_referenced` when ``2β max ‖g_k − g_0‖ <= _EXP_BOUND`` over the
    whole batch (one branch runs, chosen on the device), the max-shifted form otherwise
    (large β or far-flung goals).
    """
    fits = 2.0 * beta * _goal_spread(goals, mask) <= _EXP_BOUND
    return jax.lax.cond(fits, _dragan_referenced, _dragan_core, d, d0, mask, beta, c)


def _effdist_core(d: Array, mask: Array, beta, w: Array) -> Array:
    """SPEC §4.3 [reconstruction] from distances ``d (..., G, T)``."""
    return _masked_softmax(-beta * _integrate(d, w), mask, axis=-1)


def _fastapp_core(d: Array, mask: Array, beta, a: Array) -> Array:
    """SPEC §4.4 [reconstruction] from distances ``d (..., G, T)``."""
    return _masked_softmax(beta * _integrate(d, a), mask, axis=-1)


def _image(pts: Float[Array, "... 3 T"], pos, rot, eps) -> tuple[Array, Array]:
    """:func:`slotv_jax.scene.project` of coordinate-major points, with the division
    guarded where depth <= eps.

    Returns the image points ``(..., 2, T)`` and ``ok = depth > eps`` ``(..., T)``;
    where not ok, (u, v) is the finite ``(p_c.x, p_c.y)`` so that neither values nor
    gradients become NaN. The rotation ``p_c = Rᵀ (p − c)`` is written out per
    coordinate (3×3 is too small for a matrix kernel to pay off).
    """
    rel = [pts[..., k, :] - pos[k] for k in range(3)]
    pc = [sum(rel[k] * rot[k, j] for k in range(3)) for j in range(3)]
    depth = -pc[2]
    ok = depth > eps
    inv = 1.0 / jnp.where(ok, depth, 1.0)
    return jnp.stack([pc[0] * inv, pc[1] * inv], axis=-2), ok


def _nikolaidis_parts(pts, goals, mask, pos, rot, beta, c, eps=DEPTH_EPS, chunk=False):
    """SPEC §4.2 labels, the per-trajectory depth-validity of the points and of the real
    goals, and the image-plane Dragan labels before invalid depths make them uniform.

    ``pts (..., 3, T)``; ``chunk=True`` labels the image points with
    :func:`_dragan_chunk` (bulk labelling).
    """
    uv, ok_p = _image(pts, pos, rot, eps)
    if chunk:
        # Store the image points once: otherwise XLA recomputes the projection inside
        # the distance loop, once per goal (10% of the bulk kernel's time).
        uv = jax.lax.optimization_barrier(uv)
    uv_g, ok_g = _image(jnp.swapaxes(goals, -1, -2), pos, rot, eps)
    uv_g = jnp.swapaxes(uv_g, -1, -2)  # (..., G, 2)
    d, d0 = _distances(uv, uv_g), _distances(uv[..., :1], uv_g)
    if chunk:
        y = _dragan_chunk(d, d0, mask, beta, c, uv_g)
    else:
        y = _dragan_core(d, d0, mask, beta, c)
    # Count the points behind the camera with a contraction (faster than a reduction).
    behind = jnp.where(ok_p, 0.0, 1.0).astype(uv.dtype)
    ok_p = behind @ jnp.ones(behind.shape[-1], behind.dtype) == 0
    ok_g = ~functools.reduce(jnp.logical_or, _slots(~ok_g & mask, -1))[..., 0]
    uniform = mask / jnp.sum(mask, axis=-1, keepdims=True)
    return jnp.where((ok_p & ok_g)[..., None], y, uniform.astype(y.dtype)), ok_p, ok_g, y


def _nikolaidis_core(pts, goals, mask, pos, rot, beta, c, eps=DEPTH_EPS) -> Array:
    """SPEC §4.2: Dragan legibility of the image-plane points; uniform if any depth is invalid."""
    return _nikolaidis_parts(pts, goals, mask, pos, rot, beta, c, eps)[0]


# ------------------------------------------------------------ public labelers


def _prepare(xyz, goals, goal_mask, beta, t, beta_name="beta"):
    """Boundary checks shared by the four labelers; returns the points coordinate-major
    ``(3, T)``, the goals, the mask and the time weights."""
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
    return jnp.swapaxes(xyz, -1, -2), goals, mask, _time_weights(t, T, xyz.dtype)


def _check_times(name: str, t, shape) -> None:
    validation.check_array(name, t, shape)
    if validation.is_concrete(t) and not np.all(np.diff(np.asarray(t, np.float64), axis=-1) > 0):
        raise ValueError(f"{name}: expected strictly increasing time stamps")


def dragan(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = 5.0,
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """Dragan legibility (SPEC §4.1; Dragan & Srinivasa, RSS 2013, "Generating Legible Motion").

    Per point, the probability of each goal given the motion so far::

        P_k(i) = softmax_k( β (‖S − g_k‖ − ‖p_i − g_k‖) )        (real goals only)
        y_k    = ∫₀¹ P_k(t)(1 − t) dt / ∫₀¹ (1 − t) dt            (trapezoid rule)

    The cost-so-far term of the paper cancels across goals. Equals the first author's
    numpy ``legibility(...)[-1]`` with ``beta = velocity / 2``.

    Args:
      xyz: trajectory points (m), ``xyz[0]`` the start S; T >= 2.
      goals: goal positions (m); padded slots are ignored.
      goal_mask: True for real goals (at least one).
      beta: inverse temperature (1/m), > 0. SPEC default 5.
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
    pts, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    d0 = _distances(pts[..., :1], goals)
    return _dragan_core(_distances(pts, goals), d0, mask, beta, tw.dragan)


def effdist(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = 5.0,
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """EffDist, the "effective distance" observer (SPEC §4.3) **[reconstruction]**.

    The goal the motion stays closest to, on average over time::

        s_k = −β (1/T) Σ_i ‖p_i − g_k‖,     y = softmax(s)  (real goals only)

    This is a reconstruction: the source definition (Zhao et al., ICRA 2020, as used in
    Wallkötter et al. 2022, arXiv 2201.05765) could not be read. It is isolated in
    :func:`_effdist_core` so it can be replaced without touching anything else.

    Args:
      xyz, goals, goal_mask: as in :func:`dragan`.
      beta: inverse temperature (1/m), > 0. SPEC default 5.
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
    pts, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    return _effdist_core(_distances(pts, goals), mask, beta, tw.effdist)


def fastapp(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    *,
    beta: float = 5.0,
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """FastApp, the "fast approach" observer (SPEC §4.4) **[reconstruction]**.

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
    pts, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    return _fastapp_core(_distances(pts, goals), mask, beta, tw.fastapp)


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
    _, ok_p = _image(jnp.swapaxes(jnp.asarray(xyz), -1, -2), cam.pos, cam.rot, DEPTH_EPS)
    _, ok_g = _image(jnp.swapaxes(jnp.asarray(goals), -1, -2), cam.pos, cam.rot, DEPTH_EPS)
    return jnp.all(ok_p) & jnp.all(ok_g | ~mask)


def nikolaidis(
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    camera: Camera | str,
    *,
    beta: float = 7.5,
    t: Float[Array, " T"] | None = None,
) -> Float[Array, " 8"]:
    """Viewpoint-based (Nikolaidis) legibility: Dragan legibility in the image plane (SPEC §4.2).

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
      beta: inverse temperature (per unit image plane), > 0. SPEC default 7.5.

    Example:

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
    >>> y = nikolaidis(xyz, g, jnp.arange(8) < 2, "observer")
    >>> bool(y[0] > y[1])
    True
    """
    cam = _as_camera(camera)
    pts, goals, mask, tw = _prepare(xyz, goals, goal_mask, beta, t)
    _check_depth(xyz, goals, mask, cam)
    dt = pts.dtype
    return _nikolaidis_core(
        pts, goals, mask, cam.pos.astype(dt), cam.rot.astype(dt), beta, tw.dragan
    )


LABELERS: dict[str, Callable[..., Array]] = {
    "dragan": dragan,
    "nikolaidis": nikolaidis,
    "effdist": effdist,
    "fastapp": fastapp,
}

# ------------------------------------------------------------ bulk labelling

_IN_FLIGHT = 2  # chunks each label_all thread dispatches ahead of the one it waits on
_THREADS = 2  # label_all threads that dispatch chunks
_ALIGN = 64  # bytes: XLA:CPU reads host buffers aligned so in place, and copies others
_SLACK = _ALIGN // 4 - 1  # float32 values a view of xyz may start before its chunk
_TRACES = {"label_chunk": 0}  # traces of the bulk kernel (tests check it compiles once)


_FLAG_ERRORS = {  # bit i of the kernel's `bad` output, in this order
    "xyz_finite": "xyz: expected finite values; trajectory {i} holds NaN/inf (or "
    "coordinates so large that float32 distances overflow)",
    "goals_finite": "goals: expected finite values; trajectory {i} holds NaN/inf",
    "goals_distinct": "goals: two real goals share the same position (trajectory {i})",
    "xyz_depth": "xyz: trajectory {i} has point(s) at camera depth <= {eps} m "
    "(on or behind the camera plane)",
    "goals_depth": "goals: trajectory {i} has real goal(s) at camera depth <= {eps} m "
    "(on or behind the camera plane)",
}


def _label_chunk(xyz, offset, goals, mask, t, pos, rot, betas, names: tuple[str, ...], span: int):
    """Labels ``(C, len(names), 8)`` and a validity bitmask ``(C,)`` for one chunk.

    The one compiled kernel of :func:`label_all`. ``xyz`` is flat, ``(C·T·3 + _SLACK,)``:
    the chunk's ``(C, T, 3)`` trajectories in row-major order start ``offset``
    (``0 <= offset <= _SLACK``, an int32 scalar) values into it (see :func:`label_all`
    for why). ``betas`` is ``(len(names),)``. Only the first ``span`` goal slots are
    labelled (every real goal lies in them); the slots after it are padding and get exact
    zeros. The validity flags cover all eight slots.
    """
    _TRACES["label_chunk"] += 1
    C = goals.shape[0]
    T = (xyz.shape[0] - _SLACK) // (3 * C)
    rows = jax.lax.dynamic_slice_in_dim(xyz, offset, C * T * 3)
    # Coordinate-major, (C, 3, T); XLA fuses the transpose into the loops that read it.
    pts = jnp.swapaxes(rows.reshape(C, T, 3), -1, -2)
    tw = _time_weights(t, T, pts.dtype)
    beta = dict(zip(names, betas, strict=True))
    # Per-trajectory validity, so that label_all can reject bad input without an extra
    # pass over the data on the host. A sum is non-finite if any term is NaN/inf (or if
    # it overflows float32). The checks over goal slots are elementwise folds.
    g = [goals[..., k, j] for k in range(G_MAX) for j in range(3)]
    ok = {"goals_finite": jnp.isfinite(functools.reduce(jnp.add, g))}
    goals, mask = goals[..., :span, :], mask[..., :span]
    same = [
        mask[..., k]
        & mask[..., l]
        & (sum((g[3 * k + j] - g[3 * l + j]) ** 2 for j in range(3)) < 1e-18)
        for k in range(span)
        for l in range(k)
    ]
    ok["goals_distinct"] = ~functools.reduce(jnp.logical_or, same, jnp.zeros(mask.shape[:-1], bool))
    out = {}
    world = [n for n in ("dragan", "effdist", "fastapp") if n in names]
    if world:
        d = _distances(pts, goals)  # shared by the three world-space labelers
        if "dragan" in names:
            d0 = _distances(pts[..., :1], goals)
            out["dragan"] = _dragan_chunk(d, d0, mask, beta["dragan"], tw.dragan, goals)
        if "effdist" in names:
            out["effdist"] = _effdist_core(d, mask, beta["effdist"], tw.effdist)
        if "fastapp" in names:
            out["fastapp"] = _fastapp_core(d, mask, beta["fastapp"], tw.fastapp)
    if "nikolaidis" in names:
        out["nikolaidis"], ok["xyz_depth"], ok["goals_depth"], image = _nikolaidis_parts(
            pts, goals, mask, pos, rot, beta["nikolaidis"], tw.dragan, chunk=True
        )
    # A NaN/inf coordinate makes that point's distance to every goal NaN/inf, and every
    # label takes every point's distances into a sum (with a weight, maybe 0: 0·inf is
    # NaN too), so all its labels are NaN. With finite goals, finite labels therefore
    # mean finite points; this check costs nothing. It holds in the image plane too
    # (the image-plane Dragan labels, before an invalid depth makes them uniform): a
    # non-finite coordinate makes p_c.x and p_c.y NaN or ±inf (inf·0 is NaN, should a
    # rotation entry be 0), and so (u, v): they are p_c.x, p_c.y times 1/depth (0 for
    # an infinite depth, and inf·0 is NaN again) or times 1 where the depth is invalid.
    first = out[world[0]] if world else image
    ok["xyz_finite"] = jnp.isfinite(first[..., 0]) | ~ok["goals_finite"]
    bad = sum(
        jnp.where(ok[k], 0, 1 << bit).astype(jnp.int32)
        for bit, k in enumerate(_FLAG_ERRORS)
        if k in ok
    )
    y = jnp.stack([out[k] for k in names], axis=-2)
    return jnp.pad(y, [(0, 0)] * (y.ndim - 1) + [(0, G_MAX - span)]), bad


_label_chunk_jit = jax.jit(_label_chunk, static_argnames=("names", "span"))


def label_all(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    *,
    t: Float[np.ndarray, "*N T"] | None = None,
    chunk_size: int = DEFAULT_CHUNK,
    progress: bool = True,
    labelers: Sequence[str] = LABELER_NAMES,
    beta_dragan: float = DEFAULT_BETAS["dragan"],
    beta_nikolaidis: float = DEFAULT_BETAS["nikolaidis"],
    beta_effdist: float = DEFAULT_BETAS["effdist"],
    beta_fastapp: float = DEFAULT_BETAS["fastapp"],
    camera: Camera | str = "observer",
) -> dict[str, np.ndarray]:
    """Label many trajectories with the four labelers, in fixed-size compiled chunks.

    The trajectories go through one jitted kernel in chunks of ``chunk_size`` (the last
    chunk padded), so the kernel is compiled once per (chunk_size, T, labelers, number
    of goal slots up to the last real one) and memory stays bounded by a few chunks.
    A C-contiguous float32 ``xyz`` is read in place; any other is converted chunk by
    chunk into aligned buffers. Two threads dispatch chunks, which keeps both cores of
    a small machine busy. The distances to the goals are computed once and shared by
    dragan, effdist and fastapp. Labels are float32.

    Args:
      xyz: ``(N, T, 3)`` trajectories (m), T >= 2.
      goals: ``(N, 8, 3)`` goals per trajectory, or ``(8, 3)`` shared by all.
      goal_mask: ``(N, 8)`` or ``(8,)``, True for real goals (at least one each).
      t: optional time stamps, ``(T,)`` shared or ``(N, T)``, strictly increasing.
      chunk_size: trajectories per compiled call.
      progress: show a tqdm progress bar.
      labelers: which labels to compute (default all four).
      beta_*: inverse temperatures (SPEC §4 defaults). Changing them does not recompile.
      camera: the Nikolaidis camera, a :class:`~slotv_jax.scene.Camera` or a name.

    Returns:
      ``{name: (N, 8) float32}`` for each requested labeler.

    Raises:
      ValueError: naming the argument, for bad shapes, NaN/inf, an empty goal mask,
        β <= 0, non-increasing ``t``, or (nikolaidis) points or goals behind the camera.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> xyz = rng.uniform([0.3, -0.4, 0.1], [0.7, 0.4, 0.4], (10, 100, 3))
    >>> goals = np.zeros((8, 3))
    >>> goals[:3] = [[0.4, 0.3, 0.025], [0.5, 0.0, 0.025], [0.6, -0.3, 0.025]]
    >>> y = label_all(xyz, goals, np.arange(8) < 3, progress=False)
    >>> sorted(y), y["dragan"].shape
    (['dragan', 'effdist', 'fastapp', 'nikolaidis'], (10, 8))
    """
    from tqdm.auto import tqdm

    names = tuple(labelers)
    unknown = [n for n in names if n not in LABELERS]
    if unknown or not names:
        raise ValueError(f"labelers: expected a non-empty subset of {LABELER_NAMES}, got {names}")
    validation.check_shape("xyz", xyz, (None, None, 3))
    xyz = np.asarray(xyz)
    N, T = xyz.shape[:2]
    if T < 2:
        raise ValueError(f"xyz: expected at least 2 trajectory points (T >= 2), got T = {T}")
    goals = np.asarray(goals)
    goal_mask = np.asarray(goal_mask)
    if goals.ndim == 2:
        goals = np.broadcast_to(goals, (N, *goals.shape))
    if goal_mask.ndim == 1:
        goal_mask = np.broadcast_to(goal_mask, (N, *goal_mask.shape))
    validation.check_shape("goals", goals, (N, G_MAX, 3))
    validation.check_goal_mask("goal_mask", goal_mask, batch_shape=(N,))
    if t is not None:
        t = np.asarray(t)
        if t.ndim == 1:
            _check_times("t", t, (T,))
        else:
            _check_times("t", t, (N, T))
    betas = {
        "dragan": beta_dragan,
        "nikolaidis": beta_nikolaidis,
        "effdist": beta_effdist,
        "fastapp": beta_fastapp,
    }
    for n in names:
        validation.check_positive(f"beta_{n}", betas[n])
    chunk_size = int(chunk_size)
    if chunk_size < 1:
        raise ValueError(f"chunk_size: expected a positive integer, got {chunk_size}")
    cam = _as_camera(camera)
    # Put once on the device, not converted again by every call of the kernel.
    pos, rot = jnp.asarray(cam.pos, jnp.float32), jnp.asarray(cam.rot, jnp.float32)
    beta_arr = jnp.asarray([betas[n] for n in names], jnp.float32)
    if t is not None:  # normalised once, in float64 (see _time_weights)
        t = _normalise_times(np.asarray(t, np.float64), np).astype(np.float32)
        if t.ndim == 1:
            t = jnp.asarray(t)
    goal_mask = goal_mask.astype(bool, copy=False)

    out = {n: np.empty((N, G_MAX), np.float32) for n in names}
    if N == 0:
        return out
    C = min(chunk_size, N)
    # Goal slots after the last real one of every trajectory are not labelled (zeros).
    span = 1 + max(k for k in range(G_MAX) if goal_mask[:, k].any())
    # XLA on the CPU reads a host buffer in place if it starts on a 64-byte boundary and
    # copies it otherwise. A C-contiguous float32 xyz is therefore passed chunk by chunk
    # as flat views of C·T·3 + _SLACK values that start `offset` values before the chunk,
    # on such a boundary; the kernel skips them (a traced offset: one compilation for
    # every alignment). The trajectories are read where they lie, without a copy. The
    # chunks this cannot cover (the first if offset > 0, a short chunk, the last full
    # one if its view would run past the array, every chunk of an xyz of another dtype or
    # layout) are copied into aligned buffers, at offset 0.
    flat, offset = None, 0
    if xyz.dtype == np.float32 and xyz.flags.c_contiguous and xyz.ctypes.data % 4 == 0:
        flat, offset = xyz.reshape(-1), xyz.ctypes.data % _ALIGN // 4
    offsets = {o: jnp.asarray(o, jnp.int32) for o in {0, offset}}  # put on the device once
    view = C * T * 3 + _SLACK
    n_chunks = -(-N // C)
    first_bad: list = [n_chunks, None]  # the first chunk with a bad trajectory, its flags
    errors: list[BaseException] = []
    lock = threading.Lock()

    def run(chunks: Sequence[int], bar) -> None:
        """Label ``chunks`` in order, keeping _IN_FLIGHT of them dispatched ahead of the
        one waited on. A chunk's staging buffers were last read by the chunk
        _IN_FLIGHT + 1 before it, already collected. Stops past a bad chunk."""
        n_stages = min(len(chunks), _IN_FLIGHT + 1)
        stages = [_Stage(C, xyz, goals, goal_mask, t) for _ in range(n_stages)]
        pending = collections.deque()

        def collect() -> None:
            k, labels, bad = pending.popleft()
            start, stop = k * C, min(k * C + C, N)
            bad = np.asarray(bad)[: stop - start]
            labels = np.asarray(labels)
            for j, name in enumerate(names):
                out[name][start:stop] = labels[: stop - start, j]
            with lock:
                if bad.any() and k < first_bad[0]:
                    first_bad[:] = [k, bad]
                bar.update(stop - start)

        try:
            for i, k in enumerate(chunks):
                if k > first_bad[0] or errors:
                    break
                start, stop = k * C, min(k * C + C, N)
                a = start * T * 3 - offset  # where the view would start
                in_place = flat is not None and stop - start == C and 0 <= a <= flat.size - view
                x, g, m, tt = stages[i % n_stages].fill(start, stop, xyz=not in_place)
                x = flat[a : a + view] if in_place else x
                labels, bad = _label_chunk_jit(
                    x,
                    offsets[offset if in_place else 0],
                    g,
                    m,
                    t if tt is None else tt,
                    pos,
                    rot,
                    beta_arr,
                    names=names,
                    span=span,
                )
                pending.append((k, labels, bad))
                if len(pending) > _IN_FLIGHT:
                    collect()
            while pending:
                collect()
        except BaseException as e:  # re-raised by the calling thread
            with lock:
                errors.append(e)

    with tqdm(total=N, unit="traj", desc="labelling", disable=not progress) as bar:
        run([0], bar)  # compiles the kernel (once), in this thread
        # The other chunks in _THREADS threads, chunk k in thread k mod _THREADS: XLA runs
        # kernels called from different threads side by side, which keeps both cores of
        # a small machine busier than one stream of calls does.
        threads = [
            threading.Thread(target=run, args=(range(1 + i, n_chunks, _THREADS), bar))
            for i in range(_THREADS)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    if errors:
        raise errors[0]
    if first_bad[1] is not None:  # every chunk before it was labelled and checked
        k, bad = first_bad
        i = int(np.flatnonzero(bad)[0])
        bit = (int(bad[i]) & -int(bad[i])).bit_length() - 1  # lowest set bit
        raise ValueError(list(_FLAG_ERRORS.values())[bit].format(i=k * C + i, eps=DEPTH_EPS))
    return out


class _Stage:
    """Host buffers that one chunk of :func:`label_all` is copied into.

    The trajectories are stored flat, ``(C·T·3 + _SLACK,)`` as the kernel takes them,
    with the ``(C, T, 3)`` chunk at offset 0 and ``_SLACK`` unused values after it. The
    buffers are 64-byte aligned, so that on the CPU the jitted kernel reads them in
    place, without another copy: a buffer must not be refilled before the kernel that
    reads it has finished.
    """

    def __init__(self, C: int, xyz, goals, goal_mask, t):
        T = xyz.shape[1]
        per_row_t = t if t is not None and t.ndim == 2 else None
        x = _aligned_empty((C * T * 3 + _SLACK,), np.float32)
        # (source, buffer, the buffer's view in the source's row layout), xyz first
        self.parts = [(xyz, x, x[: C * T * 3].reshape(C, T, 3))]
        for a, shape, dt in [
            (goals, (C, G_MAX, 3), np.float32),
            (goal_mask, (C, G_MAX), bool),
            (per_row_t, (C, T), np.float32),
        ]:
            buf = None if a is None else _aligned_empty(shape, dt)
            self.parts.append((a, buf, buf))

    def fill(self, start: int, stop: int, xyz: bool = True) -> list:
        """Copy rows ``start:stop`` of every source (of all but ``xyz`` if it is False)
        into the buffers, repeating the last row to fill them; the buffers, None where
        there is no source or nothing was copied."""
        n = stop - start
        out = []
        for a, buf, rows in self.parts[0 if xyz else 1 :]:
            if a is not None:
                rows[:n] = a[start:stop]
                rows[n:] = rows[n - 1]
            out.append(buf)
        return out if xyz else [None, *out]


def _aligned_empty(shape: tuple[int, ...], dtype) -> np.ndarray:
    """``np.empty(shape, dtype)`` whose data starts on a ``_ALIGN``-byte boundary."""
    nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    raw = np.empty(nbytes + _ALIGN, np.uint8)
    offset = -raw.ctypes.data % _ALIGN
    return raw[offset : offset + nbytes].view(dtype).reshape(shape)


# ------------------------------------------------------------------ command line


def _savez(path, arrays: dict[str, np.ndarray]) -> None:
    atomic_write(path, lambda f: np.savez(f, **arrays))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m slotv_jax.labelers --in trajs.npz --out labels.npz``."""
    from slotv_jax import XLA_CONFIG

    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.labelers",
        description="Label trajectories with the four legibility labelers (SPEC §4). The input "
        ".npz holds xyz (N, T, 3), goals (N, 8, 3) or (8, 3), goal_mask (N, 8) or (8,), and "
        "optionally t (T,) or (N, T); the output .npz holds y_<labeler> (N, 8) float32 and the "
        "betas used.",
    )
    p.add_argument("--in", dest="inp", required=True, type=Path, help="input .npz")
    p.add_argument("--out", required=True, type=Path, help="output .npz (written atomically)")
    for n in LABELER_NAMES:
        p.add_argument(f"--beta-{n}", type=float, default=DEFAULT_BETAS[n], help=f"β of {n}")
    p.add_argument("--camera", default="observer", help="scene camera for nikolaidis")
    p.add_argument(
        "--labelers", default=",".join(LABELER_NAMES), help="comma-separated subset to compute"
    )
    p.add_argument("--chunk-size", type=int, default=DEFAULT_CHUNK)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    print(XLA_CONFIG.summary(), file=sys.stderr)

    names = tuple(s.strip() for s in args.labelers.split(",") if s.strip())
    try:
        with np.load(args.inp, allow_pickle=False) as f:
            files = list(f.files)
            data = {k: f[k] for k in ("xyz", "goals", "goal_mask", "t") if k in files}
    except (OSError, ValueError) as e:  # missing file, not an .npz, or object arrays
        p.error(f"{args.inp}: cannot read ({e})")
    missing = [k for k in ("xyz", "goals", "goal_mask") if k not in data]
    if missing:
        p.error(f"{args.inp}: missing array(s) {missing}; it holds {files}")
    betas = {n: getattr(args, f"beta_{n}") for n in LABELER_NAMES}
    try:
        y = label_all(
            data["xyz"],
            data["goals"],
            data["goal_mask"],
            t=data.get("t"),
            chunk_size=args.chunk_size,
            progress=not args.quiet,
            labelers=names,
            camera=args.camera,
            **{f"beta_{n}": b for n, b in betas.items()},
        )
    except ValueError as e:
        p.error(f"{args.inp}: {e}")
    arrays = {f"y_{n}": v for n, v in y.items()}
    arrays.update({f"beta_{n}": np.float64(betas[n]) for n in names})
    if "nikolaidis" in names:
        arrays["camera"] = np.asarray(args.camera)
    _savez(args.out, arrays)
    print(f"wrote {', '.join(arrays)} for {len(data['xyz'])} trajectories to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
