"""Observers of a motion seen up to a stop time: the hand-crafted labelers on a prefix.

A participant of a legibility study who watched a motion until the stop time τ saw its
first L = :func:`slotv_jax.observers.common.seen_points` points and guessed from them.
Every observer family of slotv_jax scores such a prefix with a traced L on the motion's
fixed shape ``(T, 3)`` (points ≥ L are ignored and get no gradient):

- the SLOT-V / T-REX networks: :meth:`slotv_jax.observers.models.SlotV.prefix_scores`, the
  mean (SLOT-V) or sum (T-REX) of the network over the seen points, what training on
  answers optimises (:func:`slotv_jax.answers.fitting.prefix_scores`);
- the archetypes (:mod:`slotv_jax.observers.parametric`): their formula applied to
  ``xyz[:L]`` at the prefix's own times t_i = i/(L − 1) (``prefix_scores`` of each);
- the hand-crafted labelers: :func:`prefix_labels` below, the labeler applied to
  ``xyz[:L]`` at t_i = i/(L − 1), exactly what slicing computes
  (:func:`slotv_jax.answers.crossval.labeler_probs`).

For the labelers this is the :ref:`concepts-stop-times` formula of the prefix as a motion of its
own::

    dragan:     y_k = Σ_{i<L} c_i P_k(i),  c_i ∝ trap_i (1 − t_i),  t_i = i/(L − 1)
    effdist:    y = softmax(−β (1/L) Σ_{i<L} d_k(i))
    fastapp:    y = softmax(β Σ_{1≤i<L} w_i (d_k(i−1) − d_k(i)) / Σ_{1≤i<L} w_i Δt),
                w_i = 1 − t_i  (L = 2: β (d_k(0) − d_k(1)) / Δt)
    nikolaidis: dragan's of the image-plane points

computed by the labelers' own kernels with weights that are 0 on the points ≥ L, which
are replaced by the first point (:func:`slotv_jax.observers.common.seen_only`).

>>> import jax.numpy as jnp
>>> from slotv_jax.observers import labelers
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.0]).at[1].set([0.5, -0.2, 0.0])
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.4]), g[0], 20)
>>> m = jnp.arange(8) < 2
>>> y = prefix_labels("dragan", xyz, g, m, jnp.int32(7), beta=20.0)
>>> bool(jnp.allclose(y, labelers.dragan(xyz[:7], g, m, beta=20.0), atol=1e-6))
True
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import common
from slotv_jax.observers.labelers import (
    LABELER_NAMES,
    _as_camera,
    _effdist_core,
    _fastapp_core,
    _nikolaidis_core,
    _weights_from_tau,
)
from slotv_jax.world.scene import Camera

__all__ = ["prefix_labels", "prefix_weights"]


def prefix_weights(name: str, n_points: int, seen, dtype=jnp.float32) -> Float[Array, " T"]:
    """The per-point weights of labeler ``name``'s kernel for the first ``seen`` = L points of
    ``n_points`` (L traced), at the prefix's times t_i = i/(L − 1): on i < L the weights
    the labeler computes for ``xyz[:L]`` (up to rounding), 0 after them.

    >>> [round(float(w), 3) for w in prefix_weights("effdist", 4, 2)]
    [0.5, 0.5, 0.0, 0.0]
    """
    L = jnp.asarray(seen)
    valid = jnp.arange(n_points) < L
    if name == "effdist":  # exactly 1/L, as :ref:`concepts-effdist` writes the uniform mean
        return jnp.where(valid, 1.0 / L.astype(dtype), 0.0).astype(dtype)
    tau = common.prefix_times(n_points, L, dtype)
    if name in ("dragan", "nikolaidis"):
        return common.masked_time_weights(tau, valid, 1.0, trapezoid_rule=True, dtype=dtype)
    if name != "fastapp":
        raise ValueError(f"name: expected one of {LABELER_NAMES}, got {name!r}")
    # The times after L repeat t = 1, so their intervals and their weights w_i = 1 − t_i are
    # 0: the labeler's summation-by-parts weights of the prefix, except L = 2, where its
    # ratio is 0/0 and the labeler uses the one approach speed, (d(0) − d(1)) / Δt, Δt = 1.
    two = jnp.where(jnp.arange(n_points) == 0, 1.0, jnp.where(jnp.arange(n_points) == 1, -1.0, 0.0))
    safe = jnp.where(L > 2, tau, jnp.minimum(jnp.arange(n_points, dtype=dtype) / 2, 1.0))
    a = _weights_from_tau(safe, jnp).fastapp
    return jnp.where(L > 2, a, two.astype(dtype))


def prefix_labels(
    name: str,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""],
    *,
    beta,
    camera: Camera | str | None = None,
) -> Float[Array, " 8"]:
    """Labeler ``name``'s goal distribution y (8,) for the motion seen up to its first
    ``seen`` = L points (2 ≤ L ≤ T, traced): ``labeler(xyz[:L], goals, goal_mask, beta=β)``
    with its uniform times t_i = i/(L − 1) (module docstring), on the fixed shape of
    ``xyz``. Pure (jit/vmap over ``seen`` too), differentiable w.r.t. ``xyz`` (the points
    ≥ L get no gradient) and β. ``camera`` (nikolaidis only): a Camera or its name.
    No value checks: callers check at their boundary.
    """
    if name not in LABELER_NAMES:
        raise ValueError(f"name: expected one of {LABELER_NAMES}, got {name!r}")
    xyz = jnp.asarray(xyz)
    if not jnp.issubdtype(xyz.dtype, jnp.floating):
        xyz = xyz.astype(jnp.result_type(float))
    goals = jnp.asarray(goals, xyz.dtype)
    mask = jnp.asarray(goal_mask).astype(bool)
    T, dtype = xyz.shape[0], xyz.dtype
    w = prefix_weights(name, T, seen, dtype)
    p = common.seen_only(xyz, seen)
    pts = (p[:, 0], p[:, 1], p[:, 2])
    if name == "dragan":
        return common.dragan_kernel(pts, goals, mask, beta, w)
    if name == "effdist":
        return _effdist_core(pts, goals, mask, beta, w)
    if name == "fastapp":
        return _fastapp_core(pts, goals, mask, beta, w)
    cam = _as_camera("observer" if camera is None else camera)
    return _nikolaidis_core(p, goals, mask, cam.pos.astype(dtype), cam.rot.astype(dtype), beta, w)
