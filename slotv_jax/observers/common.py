"""Maths shared by the observers: the hand-crafted labelers, the parametric archetypes, the
SLOT-V / T-REX networks and the planner use these, and no copy of them.

- Goal-padding masks: :func:`mask_logits` (padded slots at −∞), :func:`masked_softmax`
  (exact zeros there) and :func:`masked_log` (log y, −∞ there, finite gradients).
- Time weights of samples at normalised times τ ∈ [0, 1] (0 = start, 1 = end):
  :func:`trapezoid` (the trapezoid rule's weight of each sample) and
  :func:`time_weights` / :func:`log_time_weights`, ``u_i ∝ [trap_i] · (1 − τ_i)^α``: at
  α = 1 with the trapezoid rule these are :ref:`concepts-dragan`'s integration weights (Dragan &
  Srinivasa's f(t) = T − t); α = 0 gives the plain mean.
- What a participant who stopped the motion at normalised time τ saw: :func:`seen_points`
  (its first L points), and the prefix's own times and weights for a traced L,
  :func:`prefix_times` and :func:`prefix_time_weights` (every observer family scores a
  motion seen up to a stop time: :mod:`slotv_jax.observers.prefix`).
- Dragan's legibility, :func:`dragan_kernel` (:ref:`concepts-dragan`, with a start weight, in linear
  form for the labelers or in log space for the archetypes), on :func:`distances` and the
  fused time integrals :func:`integrals`; :func:`pairwise_distances` for arrays of points.

The camera projection of :ref:`concepts-cameras` belongs to the world's cameras:
:func:`slotv_jax.world.scene.camera_coords` and :func:`slotv_jax.world.scene.image_coords`.

The time weights take NumPy times (computed in float64, as constants) or JAX arrays
(traced), and a fixed exponent (a Python number: the weights in linear form) or a traced
one (a softmax over log weights, so that α can be learned); 1 − τ is floored at the
dtype's smallest normal number, so that log weights stay finite at τ = 1.

>>> import numpy as np
>>> tau = uniform_times(3)
>>> [round(float(u), 3) for u in time_weights(tau, 1.0)]
[0.667, 0.333, 0.0]
>>> [round(float(u), 3) for u in time_weights(tau, 1.0, trapezoid_rule=True)]
[0.5, 0.5, 0.0]
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

__all__ = [
    "TAU_RTOL",
    "distances",
    "dragan_kernel",
    "dragan_log_labels",
    "integrals",
    "log_time_weights",
    "mask_logits",
    "masked_log",
    "masked_softmax",
    "masked_time_weights",
    "pairwise_distances",
    "prefix_time_weights",
    "prefix_times",
    "seen_only",
    "seen_points",
    "sums",
    "time_weights",
    "trapezoid",
    "uniform_times",
]

# ------------------------------------------------------------------------- masks


def mask_logits(scores: Float[Array, "... G"], goal_mask: Bool[Array, "... G"]) -> Array:
    """Padded goal slots get −∞: softmax then gives them exactly 0.

    >>> mask_logits(jnp.array([1.0, 2.0]), jnp.array([True, False])).tolist()
    [1.0, -inf]
    """
    return jnp.where(goal_mask, scores, -jnp.inf)


def masked_softmax(s: Float[Array, "... G"], goal_mask: Bool[Array, "... G"]) -> Array:
    """Softmax over the real goals, ``exp(s_k − max s) / Σ_l exp(s_l − max s)``; exact
    zeros on padded slots."""
    s = mask_logits(s, goal_mask)
    e = jnp.exp(s - jnp.max(s, axis=-1, keepdims=True))
    return e / jnp.sum(e, axis=-1, keepdims=True)


def masked_log(y: Float[Array, "... G"], goal_mask: Bool[Array, "... G"]) -> Array:
    """``log y`` on real goals, −∞ on padded slots. A padded slot's exact 0 never enters
    the log, whose gradient there would be 0/0."""
    mask = jnp.asarray(goal_mask).astype(bool)
    return mask_logits(jnp.log(jnp.where(mask, y, 1.0)), mask)


# ------------------------------------------------------------------ time weights


def uniform_times(T: int) -> np.ndarray:
    """``τ_i = i / (T − 1)``, float64."""
    return np.arange(T, dtype=np.float64) / (T - 1)


def trapezoid(tau, xp=jnp):
    """Trapezoid-rule weights of samples at times ``tau (..., T)``: half of each adjacent
    interval, so that ``Σ_i w_i f(τ_i)`` approximates ``∫ f dτ``."""
    h = xp.diff(tau, axis=-1)
    zero = xp.zeros_like(tau[..., :1])
    return (xp.concatenate([zero, h], axis=-1) + xp.concatenate([h, zero], axis=-1)) / 2


def _log_weights(tau, alpha, trapezoid_rule: bool, dtype):
    """Unnormalised ``α log max(1 − τ, ε) [+ log trap]``; NumPy times give float64
    constants cast to ``dtype`` (ε: its smallest normal number)."""
    if isinstance(tau, np.ndarray):
        dtype = dtype or jnp.float32
        eps = np.finfo(np.dtype(dtype)).tiny
        lom = jnp.asarray(np.log(np.maximum(1.0 - tau, eps)), dtype)
        lt = jnp.asarray(np.log(trapezoid(tau, np)), dtype) if trapezoid_rule else None
    else:
        tau = tau if dtype is None else tau.astype(dtype)
        lom = jnp.log(jnp.maximum(1.0 - tau, jnp.finfo(tau.dtype).tiny))
        lt = jnp.log(trapezoid(tau)) if trapezoid_rule else None
    return alpha * lom if lt is None else lt + alpha * lom


def time_weights(tau, alpha=1.0, *, trapezoid_rule: bool = False, dtype=None):
    """Normalised weights ``u_i ∝ [trap_i] · max(1 − τ_i, ε)^α`` of samples at ``tau (..., T)``,
    ε the smallest normal number of ``dtype`` (default: ``tau``'s).

    A Python ``alpha``: computed in linear form in ``tau``'s library (NumPy: float64, then
    cast to ``dtype`` if given). A traced or array ``alpha``: ``softmax(α log max(1 − τ,
    ε) [+ log trap])`` in ``dtype`` (default float32 for NumPy times).
    """
    if isinstance(alpha, int | float):
        xp = np if isinstance(tau, np.ndarray) else jnp
        one_minus = xp.maximum(1.0 - tau, np.finfo(np.dtype(dtype or tau.dtype)).tiny)
        w = one_minus if alpha == 1 else one_minus**alpha
        if trapezoid_rule:
            w = trapezoid(tau, xp) * w
        w = w / xp.sum(w, axis=-1, keepdims=True)
        return w if dtype is None else jnp.asarray(w, dtype)
    return jax.nn.softmax(_log_weights(tau, alpha, trapezoid_rule, dtype), axis=-1)


def log_time_weights(tau, alpha=1.0, *, trapezoid_rule: bool = False, dtype=None) -> Array:
    """``log u_i`` of :func:`time_weights` in log space (any ``alpha``; ε-floored)."""
    log_w = _log_weights(tau, alpha, trapezoid_rule, dtype)
    return log_w - jax.nn.logsumexp(log_w, axis=-1, keepdims=True)


# -------------------------------------------------------------------- stop times

#: A stop time τ within this fraction of the motion's duration of a point's time t_i counts
#: as reaching t_i (the study format's rule, :meth:`slotv_jax.answers.format.Study.seen`):
#: τ = 0.3 on 11 points shows t_3 although 3/10 rounds to just above 0.3.
TAU_RTOL = 1e-9


def seen_points(taus: Sequence[float], n_points: int) -> Int[np.ndarray, " K"]:
    """Points a participant saw who watched ``n_points`` uniformly timed points,
    t_i = i/(n − 1), up to each stop time τ of ``taus`` (normalised, 0 < τ ≤ 1)::

        L(τ) = max(2, #{i : t_i ≤ τ + TAU_RTOL})

    as :meth:`slotv_jax.answers.format.Study.seen` counts them (τ = 1: the whole motion).
    Returns ``(len(taus),)`` int32. Raises ValueError for τ outside (0, 1] or n < 2.

    >>> seen_points([0.3, 0.45, 1.0], 11).tolist()
    [4, 5, 11]
    """
    taus = np.asarray(taus, np.float64)
    if taus.ndim != 1 or taus.size == 0 or not np.all((taus > 0) & (taus <= 1)):
        raise ValueError(f"taus: expected normalised stop times in (0, 1], got {taus.tolist()}")
    if isinstance(n_points, bool) or not isinstance(n_points, int | np.integer) or n_points < 2:
        raise ValueError(f"n_points: expected an integer T >= 2, got {n_points!r}")
    t = np.arange(n_points, dtype=np.float64) / (n_points - 1.0)
    seen = (t[None, :] <= taus[:, None] + TAU_RTOL).sum(-1)
    return np.maximum(seen, 2).astype(np.int32)


def seen_only(xyz: Float[Array, "... T D"], seen: Int[Array, "..."]) -> Float[Array, "... T D"]:
    """The points of a motion seen up to its first ``seen`` (traced), the others replaced by
    the first point (always seen): fixed shapes, finite values, and, weighted 0 by the
    prefix weights, no gradient for the unseen points."""
    vis = jnp.arange(xyz.shape[-2]) < jnp.asarray(seen)[..., None]
    return jnp.where(vis[..., None], xyz, xyz[..., :1, :])


def prefix_times(n_points: int, seen, dtype=jnp.float32) -> Float[Array, "... T"]:
    """The prefix's own normalised times for its first ``seen`` = L points (L traced, any
    batch shape ``...``; the times are ``(..., T)``):
    τ_i = i/(L − 1) for i < L, and 1 for the points after it (which the prefix weights
    exclude), so that an observer of ``xyz[:L]`` at τ_i = i/(L − 1) can be computed on the
    fixed shape ``(T,)``.

    >>> prefix_times(5, 3).tolist()
    [0.0, 0.5, 1.0, 1.0, 1.0]
    """
    i = jnp.arange(n_points, dtype=dtype)
    return jnp.minimum(i / (jnp.asarray(seen, dtype)[..., None] - 1), 1.0)


def masked_time_weights(
    tau: Float[Array, "... T"],
    valid: Bool[Array, "... T"],
    alpha=1.0,
    *,
    trapezoid_rule: bool = False,
    log: bool = False,
    dtype=None,
) -> Float[Array, "... T"]:
    """:func:`time_weights` of the ``valid`` samples only, ``u_i ∝ [trap_i] · max(1 − τ_i,
    ε)^α`` normalised over them, 0 on the others (``log``: :func:`log_time_weights`, −∞ on
    the others). A Python ``alpha`` takes the linear form, a traced one the log form."""
    if log or not isinstance(alpha, int | float):
        lw = jnp.where(valid, _log_weights(tau, alpha, trapezoid_rule, dtype), -jnp.inf)
        return jax.nn.log_softmax(lw, axis=-1) if log else jax.nn.softmax(lw, axis=-1)
    w = jnp.where(valid, time_weights(tau, alpha, trapezoid_rule=trapezoid_rule, dtype=dtype), 0)
    return w / jnp.sum(w, axis=-1, keepdims=True)


def prefix_time_weights(
    n_points: int, seen, alpha=1.0, *, trapezoid_rule: bool = False, log: bool = False,
    dtype=jnp.float32,
) -> Float[Array, "... T"]:  # fmt: skip
    """The time weights ``(..., T)`` of the first ``seen`` = L points (L traced, shape
    ``...``) at their own times
    τ_i = i/(L − 1) (:func:`prefix_times`), 0 (``log``: −∞) for the points after them: on
    i < L exactly ``time_weights(uniform_times(L), alpha, ...)``, up to rounding.

    >>> [round(float(u), 3) for u in prefix_time_weights(5, 3, 1.0)]
    [0.667, 0.333, 0.0, 0.0, 0.0]
    """
    valid = jnp.arange(n_points) < jnp.asarray(seen)[..., None]
    tau = prefix_times(n_points, seen, dtype)
    return masked_time_weights(
        tau, valid, alpha, trapezoid_rule=trapezoid_rule, log=log, dtype=dtype
    )


# ------------------------------------------------------------------- Dragan kernel


def pairwise_distances(
    a: Float[Array, "... T D"], b: Float[Array, "... G D"], metric=None
) -> Float[Array, "... T G"]:
    """``d[..., i, k] = sqrt(Σ_j m_j (a_ij − b_kj)²)`` (m_j = 1 without ``metric``), with a
    finite gradient where a point sits on a goal (``max(·, tiny)`` under the root)."""
    diff = a[..., :, None, :] - b[..., None, :, :]
    sq = diff * diff if metric is None else diff * diff * metric
    sq = jnp.sum(sq, axis=-1)
    return jnp.sqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny))


# The Dragan kernel labels one trajectory. Points are passed coordinate by coordinate,
# ``pts[j]`` of shape ``(T,)``, and the goal slots are a loop over the rows of ``goals``:
# every per-goal quantity is a list of arrays over the points, and sums or maxima over the
# goals are elementwise folds of that list. Under ``jax.vmap`` these are ``(N, T)`` arrays
# of one shape, and the time integrals of all goals are one reduction (:func:`integrals`),
# so XLA compiles a batch of labels into a single loop over the points that computes each
# distance and exponential once and stores no ``(N, 8, T)`` array.


def distances(
    pts: Sequence[Float[Array, " T"]], g: Float[Array, " D"], scale: Array | None = None
) -> Float[Array, " T"]:
    """``‖p_i − g‖`` for points given by their coordinates ``pts[j] (T,)``; with a
    ``scale (T,)`` > 0, ``‖p_i − s_i g‖ / s_i = ‖p_i / s_i − g‖`` (the homogeneous
    image-plane distance of :func:`slotv_jax.observers.labelers.nikolaidis`).

    ``max(·, tiny)`` keeps the gradient finite when a point sits exactly on the goal
    (a trajectory ending at its target); it changes the distance only below 1e-19 m.
    """
    if scale is None:
        sq = sum((g[j] - p) ** 2 for j, p in enumerate(pts))
        return jnp.sqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny))
    sq = sum((p - scale * g[j]) ** 2 for j, p in enumerate(pts))
    return jnp.sqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny)) / scale


def sums(fs: Sequence[Array]) -> tuple[Array, ...]:
    """``Σ_i f(i)`` over the last axis for each ``f`` in ``fs``, as one variadic reduction.

    One reduction, not one per array: XLA fuses the computation of every ``f`` into
    it, so what they share (a point, Dragan's normaliser) is computed once per point
    and nothing of size ``(G, T)`` is stored.
    """
    zero = jnp.zeros((), fs[0].dtype)
    return tuple(
        jax.lax.reduce(
            tuple(fs),
            (zero,) * len(fs),
            lambda a, b: tuple(x + y for x, y in zip(a, b, strict=True)),
            (fs[0].ndim - 1,),
        )
    )


def integrals(fs: Sequence[Array], w: Float[Array, " T"]) -> Float[Array, " G"]:
    """``[Σ_i w_i f_k(i) for f_k in fs]``, as one reduction (:func:`sums`)."""
    return jnp.stack(sums([f * w for f in fs]), axis=-1)


def dragan_kernel(
    pts: Sequence[Float[Array, " T"]],
    goals: Float[Array, "G D"],
    mask: Bool[Array, " G"],
    beta,
    weights: Float[Array, " T"],
    *,
    start_weight=None,
    scale: Array | None = None,
    invalid: Array | None = None,
    log: bool = False,
) -> Float[Array, " G"]:
    """Dragan legibility (:ref:`concepts-dragan`; Dragan & Srinivasa, RSS 2013) of one trajectory,
    the one definition that the labelers, the archetypes and (through them) the planner use::

        P_k(i) = softmax_k( β (w₀ ‖S − g_k‖ − ‖p_i − g_k‖) )     (real goals only)
        y_k    = Σ_i c_i P_k(i)

    for points ``pts[j] (T,)`` (``S`` = the first), goals ``(G, D)``, integration weights
    ``c = weights`` (:ref:`concepts-dragan`: the trapezoid rule times ``1 − t``;
    :func:`time_weights`) and ``w₀ = start_weight`` (None: 1, Dragan's own).

    ``log=False`` (the labelers): ``y``, with ``P_k(i) = e_k(i) / Σ_l e_l(i)``,
    ``e = exp(logits − max_k logits)``, exactly 0 on padded slots, every integral in one
    fused reduction (fast on many trajectories). ``scale (T,)``: distances as in
    :func:`distances` (nikolaidis). ``invalid (T,)``: where any is True the label is
    uniform over the real goals; it is counted in the same loop as the integrals.

    ``log=True`` (the archetypes, whose fitted β may be large): ``log y``, from
    ``weights = log c`` by a log-softmax over goals and a log-sum-exp over time, so that
    small probabilities neither underflow nor take the gradient with them. Padded slots get
    finite, meaningless values (their positions enter the formula but not the
    normalisation): callers mask them. ``scale`` and ``invalid`` are for ``log=False``.
    """
    start = [p[:1] for p in pts]
    start_scale = None if scale is None else scale[:1]
    d_start = [distances(start, g, start_scale) for g in goals]
    if start_weight is not None:
        d_start = [start_weight * d for d in d_start]
    z = [beta * (d0 - distances(pts, g, scale)) for d0, g in zip(d_start, goals, strict=True)]
    logits = [mask_logits(zk, mask[k]) for k, zk in enumerate(z)]  # β(w₀‖S − g_k‖ − d_k(i))
    top = functools.reduce(jnp.maximum, logits)
    e = [jnp.exp(logit - top) for logit in logits]
    norm = functools.reduce(jnp.add, e)
    if log:
        if scale is not None or invalid is not None:
            raise ValueError("dragan_kernel: scale and invalid are for log=False")
        log_p = jnp.stack(z, axis=-1) - (top + jnp.log(norm))[:, None]  # (T, G)
        return jax.nn.logsumexp(log_p + weights[:, None], axis=0)
    w = weights / norm
    if invalid is None:
        return integrals(e, w)
    # 0 · w, not 0: lax.reduce cannot differentiate an operand without a tangent; and
    # a NaN weight of a valid point (overflow) then keeps the labels NaN, not uniform.
    *ys, n_invalid = sums([f * w for f in e] + [jnp.where(invalid, 1.0, 0.0 * w)])
    uniform = (mask / jnp.sum(mask, axis=-1, keepdims=True)).astype(w.dtype)
    return jnp.where(n_invalid > 0, uniform, jnp.stack(ys, axis=-1))


def dragan_log_labels(
    pts: Float[Array, "... T D"],
    goals: Float[Array, "... G D"],
    mask: Bool[Array, "... G"],
    beta,
    *,
    alpha=1.0,
    start_weight=None,
    metric=None,
    seen: Int[Array, "..."] | None = None,
) -> Float[Array, "... G"]:
    """log y_k of :func:`dragan_kernel` for arrays of trajectories, generalised as the
    learnable archetypes need::

        P_k(i) = softmax_k( β (w₀ ‖S − g_k‖_M − ‖p_i − g_k‖_M) )   (real goals only)
        y_k    = Σ_i c_i P_k(i),   c_i ∝ trap_i · (1 − t_i)^α,   Σ_i c_i = 1

    at t_i = i/(T − 1), with ``‖x‖_M² = Σ_j m_j x_j²`` (``metric``: the weights ``m``;
    None: Euclidean), computed as the kernel's Euclidean distance of ``√m ⊙ x``; the
    batch axes ``...`` broadcast (``jnp.vectorize``). With α = 1, w₀ = 1 and no metric
    this is ``log labelers.dragan`` at the same β (tested against one float64 reference).

    ``seen`` (``...``, traced; None: every point): score only each trajectory's first L
    points, at their own times t_i = i/(L − 1) (:func:`prefix_time_weights`): the value for
    ``pts[..., :L, :]``, with no gradient for the points after them.
    """
    if metric is not None:
        root = jnp.sqrt(jnp.asarray(metric))
        pts, goals = pts * root, goals * root
    T, dtype = pts.shape[-2], jnp.result_type(pts.dtype, goals.dtype)
    if seen is None:
        log_c = log_time_weights(uniform_times(T), alpha, trapezoid_rule=True, dtype=dtype)

        def one(p, g, m):
            return dragan_kernel(tuple(p.T), g, m, beta, log_c, start_weight=start_weight,
                                 log=True)  # fmt: skip

        return jnp.vectorize(one, signature="(t,d),(g,d),(g)->(g)")(pts, goals, mask)

    def one_prefix(p, g, m, L):
        log_c = prefix_time_weights(T, L, alpha, trapezoid_rule=True, log=True, dtype=dtype)
        p = seen_only(p, L)
        return dragan_kernel(tuple(p.T), g, m, beta, log_c, start_weight=start_weight, log=True)

    return jnp.vectorize(one_prefix, signature="(t,d),(g,d),(g),()->(g)")(pts, goals, mask, seen)
