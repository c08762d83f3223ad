"""A simulated study on a pool of stimuli: a population's answers to the candidates asked,
a fresh fit of an observer family on each run's answers, and the hand-crafted labelers'
temperatures fitted on the same answers (the baselines a researcher would use without a
learned observer).

A *run* is one (strategy, seed) of a study; runs share a :class:`~.selection.Pool` and
keep their answers side by side in arrays with a leading run axis (``cand (R, cap)``,
``counts (R, cap, G)``, the first ``rows`` of each filled), so one compiled program fits
every run at once (``jax.vmap`` over runs). Every draw comes from the seed and the
candidate alone, so a stimulus gets the same answers under every strategy of a seed, and
padded batch sizes (:func:`slotv_jax.core.shapes.bucket`) keep the compiled shapes few.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, Int

from slotv_jax.answers import crossval
from slotv_jax.answers.format import PROB_FLOOR, make_study
from slotv_jax.asking import selection
from slotv_jax.core.shapes import bucket, pad_rows
from slotv_jax.observers import people as people_lib
from slotv_jax.training.config import TrainConfig

_FITTERS: dict = {}


def population_answers(
    pop: people_lib.People,
    seed: int,
    pool: selection.Pool,
    cand: Int[np.ndarray, " K"],
    per: int,
) -> Float[np.ndarray, "K G"]:
    """Guess counts of ``per`` fresh participants of ``pop`` (a population or a zoo
    member, :mod:`slotv_jax.observers.people`) for each candidate stimulus: candidate c's
    participants are drawn from ``fold_in(key(10_000 + seed), c)``
    (:func:`slotv_jax.observers.people.guesses_batch`), whatever else is asked."""
    n = len(cand)
    cand = pad_rows(np.asarray(cand), bucket(n))  # a few compiled shapes; cut off below
    t = np.asarray(pool.traj)[cand]
    keys = jax.vmap(lambda c: jax.random.fold_in(jax.random.key(10_000 + seed), c))(
        jnp.asarray(cand)
    )
    guesses = people_lib.guesses_batch(
        pop, keys, pool.xyz[t], pool.goals[t], pool.goal_mask[t], pool.seen[jnp.asarray(cand)], per
    )
    return np.asarray(jax.nn.one_hot(guesses[:n], pool.goals.shape[1]).sum(1), np.float32)


def fitter(sel: selection.Selector, updates: int):
    """``fit(ensembles (R, ...), pool, answers (R, ...), keys (R,))``: ``updates`` steps of
    :meth:`~.selection.Selector.fit` for every run at once (compiled once per selector)."""
    if (sel, updates) not in _FITTERS:
        _FITTERS[sel, updates] = jax.jit(
            jax.vmap(
                lambda e, p, a, k: sel.fit(e, p, a, k, updates=updates), in_axes=(0, None, 0, 0)
            )
        )
    return _FITTERS[sel, updates]


def fit_runs(
    tc: TrainConfig,
    pool: selection.Pool,
    cand: Int[np.ndarray, "R cap"],
    counts: Float[np.ndarray, "R cap G"],
    rows: int,
    keys: jax.Array,
    blocks: int,
    block: int,
    init=None,
):
    """A fresh one-member fit of ``tc``'s observer on each run's first ``rows`` answer rows
    (the count likelihood of :mod:`slotv_jax.answers.fitting`, prefixes included),
    ``blocks × block`` updates from ``keys (R,)``: its parameters with a leading run axis.
    ``init`` (the observer's parameters, no run axis) starts every run from θ₀ = ``init``
    instead of a random draw, with a fresh optimiser state (fine-tuning, Howard & Ruder
    2018); the keys still draw the minibatches. The goal slots that no trajectory of the
    pool uses are cut first (:func:`~slotv_jax.asking.selection.trim_goals`)."""
    pool, counts = selection.trim_goals(pool, counts)  # padded goal slots cost, add nothing
    sel = selection.make_selector(tc, 1, cand.shape[1])
    ens = jax.jit(jax.vmap(sel.init, in_axes=(0, None)))(keys, init)
    ans = selection.Answers(
        jnp.asarray(cand), jnp.asarray(counts), jnp.full((cand.shape[0],), rows, jnp.int32)
    )
    fit = fitter(sel, block)
    for j in range(blocks):
        ens, _ = fit(ens, pool, ans, jax.vmap(lambda k, j=j: jax.random.fold_in(k, j))(keys))
    return jax.tree.map(lambda x: x[:, 0], ens.params)


def answers_study(
    pool: selection.Pool,
    taus: Sequence[float],
    cand: Int[np.ndarray, " A"],
    counts: Float[np.ndarray, "A G"],
):
    """One run's answer rows as a :class:`slotv_jax.answers.Study` (τ the stop time of each
    candidate's prefix; the motions asked, in order of first use)."""
    traj = np.asarray(pool.traj)[cand]
    used, row_traj = np.unique(traj, return_inverse=True)
    return make_study(
        np.asarray(pool.xyz)[used],
        np.asarray(pool.goals)[used],
        np.asarray(pool.goal_mask)[used],
        row_traj,
        counts,
        answer_tau=np.asarray(taus)[cand % len(taus)],
        source="simulated study",
    )


def fitted_betas(
    pool: selection.Pool,
    taus: Sequence[float],
    cand: Int[np.ndarray, " A"],
    counts: Float[np.ndarray, "A G"],
    labelers: Sequence[str],
    camera: str = "observer",
) -> list[float]:
    """β of each hand-crafted labeler fitted on one run's answers by maximum likelihood
    (:func:`slotv_jax.answers.crossval.fit_beta` on :func:`answers_study`)."""
    study = answers_study(pool, taus, cand, counts)
    return [crossval.fit_beta(study, lab, camera=camera)[0] for lab in labelers]


def labeler_log_probs(
    pool: selection.Pool,
    taus: Sequence[float],
    cand: Int[np.ndarray, " A"],
    labeler: str,
    beta: float,
    camera: str = "observer",
) -> Float[np.ndarray, "A G"]:
    """log p(g) of the hand-crafted ``labeler`` at temperature ``beta`` for each candidate
    (its prefix; −∞ on padded goals, probabilities floored at PROB_FLOOR)."""
    g = int(pool.goals.shape[1])
    one = np.zeros((len(cand), g), np.float32)
    one[:, 0] = 1.0  # any valid counts: only the motions and stop times are read
    study = answers_study(pool, taus, cand, one)
    y = crossval.labeler_probs(study, labeler, beta=beta, camera=camera)[:, :g]
    mask = study.goal_mask[study.answer_trajectory, :g]
    return np.where(mask, np.log(np.maximum(y, PROB_FLOOR)), -np.inf).astype(np.float32)
