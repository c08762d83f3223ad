"""The researcher's pick: one observer to plan with, chosen from answers alone.

A researcher who fitted several observers on a study's answers (the paper MLP, SLOT-V+,
the archetypes, the labelers with a fitted β) has only those answers to choose with. Fits
whose likelihoods differ by 1 % can give plans that differ by 20 points of gain, because
the planner seeks out whatever one fit gets wrong. So the pick is not one fit but a
*pool* of them, weighted by how well each predicts answers it was not fitted on:

1. **Out-of-fold predictions.** The answer rows are split into K folds by motion (every
   row of a motion in one fold, :func:`fold_of`); each candidate f is fitted on the other
   folds and predicts the held-out rows: ``ℓ_f(a, g) = log p_f(g | row a)``.
2. **A log-linear pool** (Genest & Zidek, Statist. Sci. 1986) of the candidates::

       P_w(g | a) = softmax_g( Σ_f w_f ℓ_f(a, g) ),   w_f ≥ 0

   with the weights that maximise the held-out log-likelihood of the answers (stacking:
   Wolpert, Neural Netw. 1992; Yao et al., Bayesian Anal. 2018)::

       w* = argmax_{w ≥ 0}  Σ_a Σ_g c_ag log P_w(g | a)

   a concave problem (the log-likelihood of a multinomial logit in w), solved by
   projected gradient ascent (:func:`fit_pool_weights`).
3. **Plan against the pool** of the candidates fitted on every answer, with ``w*``.

The people loop's ``pick`` first leaves one candidate out (``keep``): the one whose own
plans the other fits judge least legible (:func:`slotv_jax.answers.pick.trusted`), then
weighs the rest as above. The held-out likelihood cannot see the planner's side of a fit:
at the paper preset the paper MLP's share of the weight grew from 0.06 to 0.22 between
1,000 and 2,000 answers while its own plans kept half the gain, and its error, scaled by
its weight, was still there for the planner to climb (``experiments/README.md``).

Why this closes the gap between fit and plan: where the candidates disagree about a
motion, the pool's P(target) is a weighted geometric mean of theirs, so a plan scores well
only where every weighted candidate agrees; a region where one fit is wrong gains nothing.
And ``Σ_f w_f`` is a calibration: fits sharper than the held-out answers support get
weights summing below 1 (a flatter pool), fits too flat above 1. One candidate that
explains the answers best takes (nearly) all the weight, so the pool is also a selection:
:func:`pick_report` names the candidate of the largest weight.

Nothing here reads how the answers came about (a population, an oracle): only the
candidates' out-of-fold log-probabilities and the counts.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.answers.format import PROB_FLOOR
from slotv_jax.observers.observer import Observer

__all__ = [
    "POOR_FIT",
    "fit_pool_weights",
    "fit_quality",
    "fold_of",
    "heldout_nll",
    "heldout_quality",
    "pick_report",
    "pool_observer",
    "pooled_logits",
    "uniform_nll",
]

_LOG_FLOOR = float(np.log(PROB_FLOOR))
#: A fit explains the answers poorly when its held-out NLL closes less than this fraction of
#: uniform guessing's NLL (a choice, stated in the report: 1.355 → 1.29 on a four-goal study;
#: the people's own model would sit far lower, but no study knows it).
POOR_FIT = 0.05


def fold_of(groups: Int[np.ndarray, " A"], folds: int, seed: int) -> Int[np.ndarray, " A"]:
    """The fold (0..K−1) of each answer row, whole groups (motions) per fold: the distinct
    groups in a random order of ``seed``, dealt round-robin (fold sizes differ by at most
    one motion).

    >>> fold_of(np.array([7, 7, 3, 5, 3]), 2, 0).tolist()
    [1, 1, 0, 0, 0]
    """
    groups = np.asarray(groups)
    if not (isinstance(folds, int) and folds >= 2):
        raise ValueError(f"folds: expected an int >= 2, got {folds!r}")
    uniq, inv = np.unique(groups, return_inverse=True)
    if uniq.size < folds:
        raise ValueError(f"folds: {folds} folds need at least {folds} motions, got {uniq.size}")
    order = np.random.default_rng([seed, 0xF01D]).permutation(uniq.size)
    fold = np.empty(uniq.size, np.int32)
    fold[order] = np.arange(uniq.size) % folds
    return fold[inv]


def _clean(logp: Float[Array, "F A G"], mask: Bool[Array, "A G"]) -> Array:
    """Log-probabilities floored at log PROB_FLOOR on real goals, 0 on padding."""
    return jnp.where(mask, jnp.maximum(logp, _LOG_FLOOR), 0.0)


def pooled_logits(
    logp: Float[Array, "F *B G"], w: Float[Array, " F"], goal_mask: Bool[Array, "*B G"]
) -> Float[Array, "*B G"]:
    """The log-linear pool's logits ``Σ_f w_f ℓ_f`` (−∞ on padded goals); its softmax is
    ``P_w``. ``logp``: the candidates' log-probabilities (−∞ on padding)."""
    mask = jnp.asarray(goal_mask, bool)
    z = jnp.tensordot(jnp.asarray(w, logp.dtype), _clean(logp, mask), axes=1)
    return jnp.where(mask, z, -jnp.inf)


def _nll(w, logp, counts, mask):
    z = pooled_logits(logp, w, mask)
    lse = jax.nn.logsumexp(z, axis=-1, keepdims=True)
    return -jnp.sum(jnp.where(mask, counts * (z - lse), 0.0)) / jnp.sum(counts)


@jax.jit
def _fit(logp, counts, mask, w0, keep):
    tx = optax.adam(0.05)

    def step(carry, _):
        w, state = carry
        g = jax.grad(_nll)(w, logp, counts, mask)
        upd, state = tx.update(g, state, w)
        return (jnp.where(keep, jnp.maximum(w + upd, 0.0), 0.0), state), None

    (w, _), _ = jax.lax.scan(step, (w0, tx.init(w0)), None, length=1500)
    return w


def fit_pool_weights(
    logp: Float[np.ndarray, "F A G"],
    counts: Float[np.ndarray, "A G"],
    goal_mask: Bool[np.ndarray, "A G"],
    keep: Bool[np.ndarray, " F"] | None = None,
) -> Float[np.ndarray, " F"]:
    """``w* = argmax_{w ≥ 0} Σ_a Σ_g c_ag log softmax_g(Σ_f w_f ℓ_f(a, g))`` (module doc),
    by 1,500 steps of projected Adam (step 0.05) from the best single candidate at weight 1;
    ``logp`` the candidates' out-of-fold log-probabilities (−∞ on padded goals). ``keep``
    (F,): the candidates allowed a weight (the others' stay 0; every one by default).
    Deterministic.

    >>> lp = np.log(np.array([[[0.9, 0.1]], [[0.5, 0.5]]]))  # two candidates, one row
    >>> w = fit_pool_weights(lp, np.array([[9.0, 1.0]]), np.ones((1, 2), bool))
    >>> bool(w[0] > 0.9 and w[1] < 0.1)
    True
    >>> fit_pool_weights(lp, np.array([[9.0, 1.0]]), np.ones((1, 2), bool), [False, True])[0]
    np.float32(0.0)
    """
    logp = np.asarray(logp, np.float32)
    counts = np.asarray(counts, np.float32)
    mask = np.asarray(goal_mask, bool)
    if logp.ndim != 3 or counts.shape != logp.shape[1:] or mask.shape != counts.shape:
        raise ValueError(
            f"logp, counts, goal_mask: expected (F, A, G), (A, G), (A, G), got "
            f"{logp.shape}, {counts.shape}, {mask.shape}"
        )
    if not counts.sum() > 0:
        raise ValueError("counts: expected at least one answer")
    keep = _keep(keep, logp.shape[0])
    single = np.where(keep, heldout_nll(logp, counts, mask), np.inf)
    w0 = np.zeros(logp.shape[0], np.float32)
    w0[int(np.argmin(single))] = 1.0
    w = _fit(jnp.asarray(logp), jnp.asarray(counts), jnp.asarray(mask), w0, jnp.asarray(keep))
    w = np.asarray(w)
    return w if _nll(w, logp, counts, mask) <= _nll(w0, logp, counts, mask) else w0


def _keep(keep, n: int) -> np.ndarray:
    """``keep`` as a (F,) bool array with at least one True (ValueError naming it)."""
    if keep is None:
        return np.ones(n, bool)
    k = np.asarray(keep)
    if k.shape != (n,) or k.dtype != bool or not k.any():
        raise ValueError(f"keep: expected {n} booleans, at least one True, got {keep!r}")
    return k


def heldout_nll(
    logp: Float[np.ndarray, "F A G"],
    counts: Float[np.ndarray, "A G"],
    goal_mask: Bool[np.ndarray, "A G"],
    w: Float[np.ndarray, " F"] | None = None,
) -> Float[np.ndarray, " F"] | float:
    """NLL per answer (nats) of each candidate alone, or of the pool with weights ``w``."""
    logp, counts, mask = (jnp.asarray(logp), jnp.asarray(counts), jnp.asarray(goal_mask, bool))
    if w is not None:
        return float(_nll(jnp.asarray(w, logp.dtype), logp, counts, mask))
    eye = jnp.eye(logp.shape[0], dtype=logp.dtype)
    return np.asarray(jax.vmap(lambda e: _nll(e, logp, counts, mask))(eye))


def uniform_nll(counts: Float[np.ndarray, "A G"], goal_mask: Bool[np.ndarray, "A G"]) -> float:
    """NLL per answer (nats) of uniform guessing, ``Σ_a c_a log |G_a| / Σ_a c_a``: the line a
    fit must beat to have learned anything from the answers.

    >>> uniform_nll(np.array([[3.0, 1.0, 0.0]]), np.array([[True, True, False]])).round(4)
    np.float64(0.6931)
    """
    c = np.asarray(counts, np.float64)
    n = np.asarray(goal_mask, bool).sum(-1)
    return np.sum(c.sum(-1) * np.log(np.maximum(n, 1))) / max(c.sum(), 1e-300)


def heldout_quality(
    logp: Float[np.ndarray, "F A G"],
    counts: Float[np.ndarray, "A G"],
    goal_mask: Bool[np.ndarray, "A G"],
) -> tuple[Float[np.ndarray, " F"], float]:
    """Each candidate's held-out NLL per answer (:func:`heldout_nll`) and uniform guessing's
    (:func:`uniform_nll`): what :func:`slotv_jax.answers.pick.trusted` weighs besides the
    plans, with no pool fitted."""
    return np.asarray(heldout_nll(logp, counts, goal_mask), np.float64), float(
        uniform_nll(counts, goal_mask)
    )


def fit_quality(heldout: Float[np.ndarray, " F"], uniform: float) -> Float[np.ndarray, " F"]:
    """How much of uniform guessing's NLL each candidate's held-out NLL closes,
    ``(NLL_u − NLL_f) / NLL_u`` (≤ 0: no better than guessing; below :data:`POOR_FIT`: a
    poor fit).

    >>> fit_quality(np.array([1.229, 1.36]), 1.355).round(3).tolist()
    [0.093, -0.004]
    """
    return (float(uniform) - np.asarray(heldout, np.float64)) / max(float(uniform), 1e-300)


def pick_report(
    names: Sequence[str],
    logp: Float[np.ndarray, "F A G"],
    counts: Float[np.ndarray, "A G"],
    goal_mask: Bool[np.ndarray, "A G"],
    keep: Bool[np.ndarray, " F"] | None = None,
) -> dict:
    """The pick from out-of-fold predictions: each candidate's held-out NLL per answer,
    the pool's weights (only ``keep``'s candidates weighted, :func:`fit_pool_weights`) and
    NLL, ``pick`` the candidate of the largest weight, ``best_single`` the candidate of
    the lowest held-out NLL, ``uniform_nll`` (:func:`uniform_nll`), each candidate's
    ``quality`` (:func:`fit_quality`) and ``poor_fit``: True when even the best closes
    less than :data:`POOR_FIT` of uniform guessing's NLL (no candidate explains the
    answers: a plan made against them rests on little)."""
    if len(names) != np.shape(logp)[0]:
        raise ValueError(f"names: expected {np.shape(logp)[0]} candidates, got {len(names)}")
    w = fit_pool_weights(logp, counts, goal_mask, keep)
    single = heldout_nll(logp, counts, goal_mask)
    u = uniform_nll(counts, goal_mask)
    q = fit_quality(single, u)
    return {
        "candidates": list(names),
        "heldout_nll": [round(float(x), 6) for x in single],
        "weights": [round(float(x), 6) for x in w],
        "pool_nll": round(heldout_nll(logp, counts, goal_mask, w), 6),
        "pick": names[int(np.argmax(w))],
        "best_single": names[int(np.argmin(single))],
        "uniform_nll": round(float(u), 6),
        "quality": [round(float(x), 6) for x in q],
        "poor_fit": bool(q.max() < POOR_FIT),
    }


def _pool(logits: Sequence[Array], w, goal_mask: Bool[Array, " G"]) -> Float[Array, " G"]:
    logp = jnp.stack([jax.nn.log_softmax(z) for z in logits])
    return pooled_logits(logp, w, goal_mask)


def _pool_logits(names, params, xyz, goals, goal_mask) -> Float[Array, " G"]:
    zs = [o(xyz, goals, goal_mask) for o in params["members"]]
    return _pool(zs, params["weights"], jnp.asarray(goal_mask, bool))


def _pool_prefix(names, params, xyz, goals, goal_mask, seen) -> Float[Array, " G"]:
    zs = [o.prefix(xyz, goals, goal_mask, seen) for o in params["members"]]
    return _pool(zs, params["weights"], jnp.asarray(goal_mask, bool))


def pool_observer(
    observers: Sequence[Any], weights: Sequence[float], names: Sequence[str] | None = None
) -> Observer:
    """The log-linear pool of ``observers`` (each with ``prefix``) with ``weights`` (F,)
    (an array or a list, traced or not):
    ``logits = Σ_f w_f log softmax(observer_f)`` on the real goals, −∞ on padding, for the
    whole motion and for each prefix (``prefix(xyz, goals, goal_mask, seen)``). Pure: use it
    under ``jit``, ``vmap`` and ``grad``.

    An :class:`~slotv_jax.observers.observer.Observer` named "pool" whose ``params`` are
    ``{"members": the observers, "weights": w (F,) float32}`` (the members' own
    parameters are its leaves where they are the library's observers) and whose
    ``config`` is the members' ``names`` (default: each observer's ``name``, or "")."""
    w = jnp.asarray(weights, jnp.float32)  # may be traced (the loop's fitted weights)
    if not observers or w.shape != (len(observers),):
        raise ValueError(
            f"weights: expected one weight per observer ({len(observers)}), got shape {w.shape}"
        )
    if names is None:
        names = [getattr(o, "name", "") for o in observers]
    if len(names) != len(observers):
        raise ValueError(f"names: expected one name per observer ({len(observers)}), got {names}")
    return Observer(
        logits_fn=_pool_logits,
        prefix_fn=_pool_prefix,
        params={"members": tuple(observers), "weights": w},
        config=tuple(str(n) for n in names),
        name="pool",
    )
