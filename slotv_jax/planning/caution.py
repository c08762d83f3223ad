"""Caution where answers are thin: plan for a lower confidence bound over an ensemble.

A planner that climbs one fitted observer goes where that fit is most sure, which is
often where no answer was ever asked and the fit is merely extrapolating; optimisation
against a fixed learned model overshoots as the pressure on it grows (Gao, Schulman &
Hilton, "Scaling Laws for Reward Model Overoptimization", ICML 2023), and planning for
what *every* plausible fit agrees on limits it (pessimism under an ensemble: Coste et al.,
"Reward Model Ensembles Help Mitigate Overoptimization", ICLR 2024).

:func:`lower_bound_observer` wraps M observers of one family, stacked along a leading
axis of their parameters (the fits of one study on resampled answers: the pick's
cross-validation folds and its fit on every answer, in the people loop). The planner
(:func:`slotv_jax.planning.legibility`) then maximises, at each stop time τ,

    B_τ(ξ) = mean_m ℓ_m − κ · sd_m ℓ_m,    ℓ_m = log P_m(target | ξ_{0:τ}),
    sd_m ℓ_m = √( Σ_m (ℓ_m − mean ℓ)² / (M − 1) )

(the sample standard deviation, computed as √(var + 10⁻¹²) so that its gradient stays
finite where the members agree), and the prefix legibility becomes the mean of B_τ over
the stop times; ``κ`` (``caution``) counts the standard deviations held back. κ = 0 plans
for the members' mean log-probability. Called as an observer (judged, evaluated, scored),
it is the members' log-linear pool with equal weights, ``logits = mean_m log softmax(z_m)``
(−∞ on padded slots): the bound is a property of the planning objective, not of what the
ensemble predicts.

>>> import jax, jax.numpy as jnp
>>> from slotv_jax import planning
>>> betas = jnp.array([5.0, 10.0, 20.0])
>>> members = jax.vmap(lambda b: planning.labeler_observer("effdist", beta=b))(betas)
>>> cautious = lower_bound_observer(members, 1.0)
>>> cautious.name, members_of(cautious)[1]
('lower bound', 3)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from slotv_jax.observers.common import mask_logits
from slotv_jax.observers.observer import Observer, ObserverLike

__all__ = [
    "check_caution",
    "is_lower_bound",
    "lower_bound",
    "lower_bound_observer",
    "members_of",
]

#: added to the members' variance under the square root (its gradient is finite at 0)
VAR_EPS = 1e-12


def _member_log_probs(members, call, goal_mask) -> Float[Array, "M 8"]:
    mask = jnp.asarray(goal_mask).astype(bool)
    z = jax.vmap(call)(members)
    return jax.nn.log_softmax(mask_logits(z, mask), axis=-1)


def _pooled(logp: Float[Array, "M 8"], goal_mask) -> Float[Array, " 8"]:
    mask = jnp.asarray(goal_mask).astype(bool)
    return mask_logits(jnp.mean(jnp.where(mask, logp, 0.0), axis=0), mask)


def _bound_logits(config, members, xyz, goals, goal_mask) -> Float[Array, " 8"]:
    logp = _member_log_probs(members, lambda o: o(xyz, goals, goal_mask), goal_mask)
    return _pooled(logp, goal_mask)


def _bound_prefix(config, members, xyz, goals, goal_mask, seen) -> Float[Array, " 8"]:
    call = lambda o: o.prefix(xyz, goals, goal_mask, seen)  # noqa: E731
    return _pooled(_member_log_probs(members, call, goal_mask), goal_mask)


def _n_members(members) -> int:
    leaves = jax.tree.leaves(members)
    if not leaves:
        raise ValueError("members: expected observers stacked along a leading axis, got no arrays")
    sizes = {np.shape(x)[0] if np.ndim(x) else None for x in leaves}
    if len(sizes) != 1 or None in sizes:
        raise ValueError(
            "members: expected every parameter stacked along one leading axis of M members "
            f"(jax.tree.map(lambda *p: jnp.stack(p), *observers)), got leading sizes {sizes}"
        )
    (m,) = sizes
    if m < 2:
        raise ValueError(f"members: expected at least 2 stacked members, got {m}")
    return int(m)


def check_caution(caution) -> None:
    """ValueError naming ``caution`` unless it is a finite Python number κ ≥ 0."""
    if isinstance(caution, bool) or not isinstance(caution, int | float | np.floating):
        raise ValueError(f"caution: expected a number of standard deviations >= 0, got {caution!r}")
    if not (np.isfinite(caution) and caution >= 0):
        raise ValueError(f"caution: expected a finite number >= 0, got {caution!r}")


def lower_bound_observer(members: ObserverLike, caution: float) -> Observer:
    """The planner's lower confidence bound over ``members`` (module docstring).

    ``members``: M ≥ 2 observers of one family stacked along a leading axis of every
    parameter (``jax.vmap`` of a builder, or ``jax.tree.map(lambda *p: jnp.stack(p),
    *observers)``); ``caution`` κ ≥ 0, a Python number (static: it selects the objective's
    form). An :class:`~slotv_jax.observers.observer.Observer` named "lower bound" whose
    ``params`` are the stacked members and whose ``config`` is ``("lower bound", κ, M)``;
    as an observer it gives the members' log-linear pool with equal weights."""
    check_caution(caution)
    if not callable(getattr(members, "prefix", None)):
        raise ValueError("members: expected stacked observers with a .prefix (ObserverLike)")
    m = _n_members(members)
    return Observer(
        logits_fn=_bound_logits,
        prefix_fn=_bound_prefix,
        params=members,
        config=("lower bound", float(caution), m),
        name="lower bound",
    )


def is_lower_bound(observer) -> bool:
    """Whether ``observer`` is a :func:`lower_bound_observer` (the planner then maximises
    its bound)."""
    return isinstance(observer, Observer) and observer.logits_fn is _bound_logits


def members_of(observer: Observer) -> tuple[float, int]:
    """(κ, M) of a :func:`lower_bound_observer`."""
    if not is_lower_bound(observer):
        raise ValueError(f"observer: expected a lower_bound_observer, got {observer!r}")
    _, caution, m = observer.config
    return caution, m


def lower_bound(lp: Float[Array, "M K"], caution: float) -> Float[Array, " K"]:
    """B = mean_m ℓ_m − κ sd_m ℓ_m of the members' log-probabilities ``lp`` (M, K) at each
    of K stop times (module docstring; κ = ``caution``, static); pure."""
    mean = jnp.mean(lp, axis=0)
    if caution == 0:
        return mean
    var = jnp.sum((lp - mean) ** 2, axis=0) / (lp.shape[0] - 1)
    return mean - caution * jnp.sqrt(var + VAR_EPS)
