"""Maths shared by the observers: the hand-crafted labelers, the parametric archetypes, the
SLOT-V / T-REX networks and the planner use these, and no copy of them.

- Goal-padding masks: :func:`mask_logits` (padded slots at −∞), :func:`masked_softmax`
  (exact zeros there) and :func:`masked_log` (log y, −∞ there, finite gradients).
- Time weights of samples at normalised times τ ∈ [0, 1] (0 = start, 1 = end):
  :func:`trapezoid` (the trapezoid rule's weight of each sample) and
  :func:`time_weights` / :func:`log_time_weights`, ``u_i ∝ [trap_i] · (1 − τ_i)^α``: at
  α = 1 with the trapezoid rule these are SPEC §4.1's integration weights (Dragan &
  Srinivasa's f(t) = T − t); α = 0 gives the plain mean.
- Dragan's legibility in log space, :func:`dragan_log_labels` (SPEC §4.1, generalised by
  a time exponent, a start weight and a metric), on :func:`pairwise_distances`.

The camera projection of SPEC §4.2 belongs to the world's cameras:
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

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

__all__ = [
    "dragan_log_labels",
    "log_time_weights",
    "mask_logits",
    "masked_log",
    "masked_softmax",
    "pairwise_distances",
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


def dragan_log_labels(
    pts: Float[Array, "... T D"],
    goals: Float[Array, "... G D"],
    mask: Bool[Array, "... G"],
    beta,
    *,
    alpha=1.0,
    start_weight=1.0,
    metric=None,
) -> Float[Array, "... G"]:
    """log y_k of Dragan legibility (SPEC §4.1) in the space of ``pts``, generalised::

        P_k(i) = softmax_k( β (w₀ ‖S − g_k‖_M − ‖p_i − g_k‖_M) )   (real goals only)
        y_k    = Σ_i c_i P_k(i),   c_i ∝ trap_i · (1 − t_i)^α,   Σ_i c_i = 1

    at t_i = i/(T − 1), in log space (log-softmax, then a log-sum-exp over time), so that
    large β neither overflows nor loses the small probabilities. Padded slots get finite,
    meaningless values (their positions enter the formula but not the normalisation):
    callers mask them. With α = 1, w₀ = 1 and no metric this is ``log labelers.dragan``
    at the same β, whose fused form labels many trajectories fast (both are tested
    against one float64 reference and against each other).
    """
    d = pairwise_distances(pts, goals, metric)  # (..., T, G)
    z = beta * (start_weight * d[..., :1, :] - d)
    log_p = z - jax.nn.logsumexp(mask_logits(z, mask[..., None, :]), axis=-1, keepdims=True)
    log_c = log_time_weights(uniform_times(pts.shape[-2]), alpha, trapezoid_rule=True,
                             dtype=z.dtype)  # fmt: skip
    return jax.nn.logsumexp(log_p + log_c[:, None], axis=-2)
