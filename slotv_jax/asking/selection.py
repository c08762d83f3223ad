"""Active selection of stimuli: which motions to ask about next.

The SLOT-V paper names the number of labels as its main limitation ("about 10,000
unique examples to achieve 80 % validation accuracy … it would be interesting to see if
this number can be reduced … e.g. by more intelligently sampling trajectories",
Wallkötter et al. 2022, §VI). This module chooses the next k stimuli of a study from a
pool of candidates, given the answers so far and an observer family (the paper's MLP,
SLOT-V+, an archetype).

Stimuli and answers
-------------------
A candidate stimulus is a trajectory shown up to a stop time τ: its first ``seen``
points (:class:`Pool`; τ = 1 is the whole motion). An answer row is a candidate with the
guesses it got, counts c_k per goal (:class:`Answers`; the labels of a hand-crafted
observer are one answer's fractional counts). The observer's probability of goal k is
p_k = softmax_k(s), with s the scores of the seen points, for every family
(:func:`slotv_jax.answers.fitting.prefix_scores`).

The posterior: a deep ensemble
------------------------------
E members of the observer family train side by side (``jax.vmap`` over members) on the
count likelihood of the answers, −Σ_k c_k log p_k (:func:`slotv_jax.study.count_nll`).
Members differ by their initialisation and by Poisson(1) bootstrap weights on the answer
rows (Efron 1979; Osband et al. 2016); member 0 has weight 1 on every row and no other
difference from a plain training run, so it is *the* observer the answers give.
Archetypes have no random initialisation: their members differ by the bootstrap alone.
The ensemble with member weights π_e (uniform by default) is
a discrete posterior over observers (Lakshminarayanan et al. 2017).

Criteria (per candidate, from the members' predictive distributions p_e)
------------------------------------------------------------------------
Each says when it is the one to pick, from the recorded runs of
``python -m slotv_jax.experiments.active`` (``experiments/active*.md``; the paper preset
unless said otherwise).

- ``random``: k candidates uniformly without replacement. *Pick it* as the baseline every
  other strategy is measured against, and for a first round, before any answer exists;
- ``uncertainty``: the entropy of the predicted guess distribution,
  H[p̄], p̄ = Σ_e π_e p_e (Lewis & Gale 1994). *Pick it* as the textbook reference; it
  rewards a flat spread over many goals, which accuracy does not care about, yet came
  level with ``margin`` in studies with the paper's MLP (12,833 answers against 13,114);
- ``margin``: the smallest gap between the two most likely goals, 1 − (p̄_(1) − p̄_(2))
  (Scheffer et al. 2001): the motions nearest the observer's decision boundary, which is
  what accuracy (the argmax) depends on. *Pick it* by default (``study next``'s): never
  behind random in the simulated studies at either preset, 1.4–2.5× fewer labels than
  random on the paper's labels;
- ``error``: the posterior probability that the observer's guess ŷ₀ = argmax p_0 (member
  0's) is wrong, 1 − p̄(ŷ₀) (least confidence, Lewis & Gale 1994, against the posterior):
  high where member 0 holds to a goal the others reject, which ``margin`` scores low when
  p̄ has a clear favourite; these are the observer's likely mistakes. *Pick it* with the
  paper's network in studies of single guesses: the fewest answers there (2.2× fewer
  than random over 25 seeds); with small networks it falls behind ``margin``;
- ``bald``: the mutual information between the next answer y and the observer,
  I(y; θ) = H[p̄] − Σ_e π_e H[p_e] (Houlsby et al. 2011, "BALD"; Gal et al. 2017):
  high where the members disagree, zero where they agree on a noisy answer. *Pick it*
  when the observer's parameters are what the study is for (an archetype's fitted β and
  camera), not its accuracy; as a criterion of accuracy it needed more labels than random
  on the paper's labels;
- ``bald_cluster``: the ``shortlist`` candidates of highest BALD, then a k-centre greedy
  (Sener & Savarese 2018) weighted by BALD in the space of the members' predictions
  (E·G numbers per candidate), starting from the best BALD. *Pick it* in studies of
  single guesses with SLOT-V+ or an archetype: the fewest answers of every strategy there
  (2,566 against margin's 3,171 with SLOT-V+; 330 with the Dragan archetype);
- ``margin_cluster``: the same diversity on top of ``margin``: its ``shortlist`` best,
  then the k-centre greedy weighted by margin (a tie nearest the decision is worth asking
  once, not k times). *Pick it* when a batch is large beside the candidates scored, so
  that ties near the decision repeat: ahead of ``margin`` in the three study groups (a
  run of its own on the same seeds) and on the quick preset's labels, behind it on the
  paper's labels;
- ``epig``: the expected predictive information gain (Bickford Smith et al. 2023),
  EPIG(x) = E_{x*}[I(y; y* | x, x*)], the mutual information between the next answer y
  at x and the answer y* at an input x* drawn from those the observer will be asked to
  predict, under the members' joint p(y, y*) = Σ_e π_e p_e(y | x) p_e(y* | x*). BALD
  rewards any disagreement about θ, also where it never changes a prediction; EPIG only
  what changes the predictions at the x* (``targets`` scored candidates, standing in for
  the pool's input distribution). *Pick it* when the observer will only be used on a
  known set of inputs (the targets) and its guess distribution there matters; for
  accuracy it never beat ``margin`` in the recorded runs.

A greedy BALD with fantasised answers (``bald_fantasy``, a sampled BatchBALD) was
removed: ``bald_cluster`` did the same job (diverse BALD batches) better, ahead of it in
four of five groups (``experiments/active_paper_diversity/`` holds its runs).

All criteria are pure functions of fixed-shape arrays: :func:`select` compiles once for
a pool size and k, and scores 100,000 candidates in one call
(``python -m slotv_jax.benchmarks.selection``).

>>> sel = make_selector(config.quick("slotv"), members=4, capacity=512)   # doctest: +SKIP
>>> ens = sel.init(jax.random.key(0))                                      # doctest: +SKIP
>>> fit = jax.jit(sel.fit, static_argnames="updates")                        # doctest: +SKIP
>>> ens, _ = fit(ens, pool, answers, key, updates=200)                     # doctest: +SKIP
>>> logp = jax.jit(sel.log_probs)(ens.params, pool, candidates)            # doctest: +SKIP
>>> pick = select("margin", key, logp, available, k=32)                    # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.answers import fitting
from slotv_jax.observers import models
from slotv_jax.observers.common import seen_points  # re-exported: the stimuli of a pool
from slotv_jax.training import trainer as train_lib
from slotv_jax.training.config import TrainConfig

STRATEGIES = (
    "random",
    "uncertainty",
    "margin",
    "margin_cluster",
    "error",
    "bald",
    "bald_cluster",
    "epig",
)
SHORTLIST = 4  # the *_cluster shortlist: SHORTLIST × k candidates of highest score (default)
TARGETS = 1024  # epig: scored candidates standing in for the inputs to predict (default)


# ================================================================ the data


class Pool(NamedTuple):
    """Candidate stimuli: C (trajectory, stop time) pairs over N trajectories."""

    xyz: Float[Array, "N T 3"]  # trajectory points (m)
    goals: Float[Array, "N G 3"]  # goals of each trajectory's scene (m)
    goal_mask: Bool[Array, "N G"]  # real goal slots
    traj: Int[Array, " C"]  # trajectory of each candidate
    seen: Int[Array, " C"]  # points the candidate shows (2 ≤ seen ≤ T)


class Answers(NamedTuple):
    """M answer slots, the first ``n`` filled (fixed shapes: a study grows without
    recompiling)."""

    cand: Int[Array, " M"]  # candidate of each row (index into the pool)
    counts: Float[Array, "M G"]  # guesses per goal (labels: fractional counts summing to 1)
    n: Int[Array, ""]  # filled rows


class Ensemble(NamedTuple):
    """E observers trained side by side (leading axis E on every leaf)."""

    params: nnx.State  # (E, ...) model parameters
    opt_state: Any  # (E, ...) optimiser states
    boot: Float[Array, "E M"]  # bootstrap weight of each answer slot (member 0: all 1)


def make_pool(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N G 3"],
    goal_mask: Bool[np.ndarray, "N G"],
    taus: Sequence[float] = (1.0,),
) -> Pool:
    """Every trajectory × every stop time τ in ``taus`` as a :class:`Pool` (candidate
    c = n · len(taus) + j shows trajectory n up to ``taus[j]``). Validates the shapes.

    >>> pool = make_pool(np.zeros((2, 5, 3)), np.ones((2, 8, 3)), np.ones((2, 8), bool),
    ...                  taus=(0.5, 1.0))
    >>> pool.traj.tolist(), pool.seen.tolist()
    ([0, 0, 1, 1], [3, 5, 3, 5])
    """
    xyz = np.asarray(xyz, np.float32)
    goals = np.asarray(goals, np.float32)
    goal_mask = np.asarray(goal_mask, bool)
    if xyz.ndim != 3 or xyz.shape[-1] != 3 or xyz.shape[0] < 1:
        raise ValueError(f"xyz: expected shape (N, T, 3) with N >= 1, got {xyz.shape}")
    n, t = xyz.shape[:2]
    if goals.ndim != 3 or goals.shape[0] != n or goals.shape[-1] != 3:
        raise ValueError(f"goals: expected shape ({n}, G, 3), got {goals.shape}")
    if goal_mask.shape != goals.shape[:2]:
        raise ValueError(f"goal_mask: expected shape {goals.shape[:2]}, got {goal_mask.shape}")
    if not goal_mask.any(-1).all():
        raise ValueError("goal_mask: every trajectory needs at least one real goal")
    if not (np.isfinite(xyz).all() and np.isfinite(goals).all()):
        raise ValueError("xyz, goals: expected finite numbers")
    seen = seen_points(taus, t)
    return Pool(
        jnp.asarray(xyz),
        jnp.asarray(goals),
        jnp.asarray(goal_mask),
        jnp.asarray(np.repeat(np.arange(n, dtype=np.int32), seen.size)),
        jnp.asarray(np.tile(seen, n)),
    )


def trim_goals(pool: Pool, counts: Float[np.ndarray, "... G"]) -> tuple[Pool, np.ndarray]:
    """The pool and the answers' ``counts`` with the goal axis cut after the last slot that
    is real in any of the pool's trajectories, for fitting.

    As :func:`slotv_jax.training.types.trim_goals` does for SLOT-V's training: a padded slot
    adds nothing to the count likelihood or its gradient (its log-probability is −∞ and
    its count 0), but every one costs a pass of the network over the motion; the datasets'
    training scenes hold at most 6 real goals of the 8 slots. Needs a concrete goal mask;
    returns the arguments themselves when nothing can be cut. Raises ValueError if an
    answer names a slot that no trajectory has.

    >>> pool = make_pool(np.zeros((2, 5, 3)), np.ones((2, 8, 3)), np.arange(8) < [[2], [3]])
    >>> p, c = trim_goals(pool, np.zeros((4, 8)))
    >>> p.goals.shape, c.shape
    ((2, 3, 3), (4, 3))
    """
    mask = np.asarray(pool.goal_mask, bool)
    g = max(1, int(np.where(mask, np.arange(1, mask.shape[-1] + 1), 0).max(initial=0)))
    counts = np.asarray(counts)
    if g == mask.shape[-1]:
        return pool, counts
    if np.any(counts[..., g:]):
        raise ValueError(f"counts: guesses of a goal slot past the pool's last real one ({g})")
    return pool._replace(goals=pool.goals[:, :g], goal_mask=pool.goal_mask[:, :g]), counts[..., :g]


def make_answers(
    cand: Int[np.ndarray, " A"], counts: Float[np.ndarray, "A G"], capacity: int
) -> Answers:
    """:class:`Answers` holding the A rows given, padded to ``capacity`` slots."""
    cand = np.asarray(cand, np.int32).reshape(-1)
    counts = np.asarray(counts, np.float32)
    a = cand.size
    if counts.ndim != 2 or counts.shape[0] != a:
        raise ValueError(f"counts: expected shape ({a}, G), got {counts.shape}")
    if a > capacity:
        raise ValueError(f"capacity: {a} answer rows do not fit {capacity} slots")
    if not (np.isfinite(counts).all() and (counts >= 0).all()):
        raise ValueError("counts: expected finite guesses >= 0")
    c = np.zeros(capacity, np.int32)
    k = np.zeros((capacity, counts.shape[1]), np.float32)
    c[:a], k[:a] = cand, counts
    return Answers(jnp.asarray(c), jnp.asarray(k), jnp.asarray(a, jnp.int32))


# ================================================================ criteria


def _entropy(p: Float[Array, "... G"]) -> Float[Array, "..."]:
    return -jnp.sum(jnp.where(p > 0, p * jnp.log(jnp.where(p > 0, p, 1.0)), 0.0), axis=-1)


def _weights(logp: Float[Array, "E C G"], weights) -> Float[Array, " E"]:
    e = logp.shape[0]
    return jnp.full((e,), 1.0 / e, logp.dtype) if weights is None else weights


def predictive(
    logp: Float[Array, "E C G"], weights: Float[Array, " E"] | None = None
) -> Float[Array, "C G"]:
    """The ensemble's guess distribution p̄ = Σ_e π_e p_e (π uniform by default)."""
    w = _weights(logp, weights)
    return jnp.einsum("e,ecg->cg", w, jnp.exp(logp))


def uncertainty(
    logp: Float[Array, "E C G"], weights: Float[Array, " E"] | None = None
) -> Float[Array, " C"]:
    """Entropy of the predicted guess distribution, H[p̄] (nats).

    >>> logp = jnp.log(jnp.array([[[0.5, 0.5]], [[0.5, 0.5]]]))
    >>> float(uncertainty(logp)[0])  # log 2
    0.6931...
    """
    return _entropy(predictive(logp, weights))


def margin(
    logp: Float[Array, "E C G"], weights: Float[Array, " E"] | None = None
) -> Float[Array, " C"]:
    """Margin uncertainty 1 − (p̄_(1) − p̄_(2)): one minus the gap between the two most
    likely goals of the predicted guess distribution (1: a tie, 0: a sure guess).

    >>> tie = jnp.log(jnp.array([[[0.5, 0.5, 0.0]]]))
    >>> spread = jnp.log(jnp.array([[[0.4, 0.3, 0.3]]]))
    >>> float(margin(tie)[0]), round(float(margin(spread)[0]), 6)
    (1.0, 0.9)
    """
    top2 = jax.lax.top_k(predictive(logp, weights), 2)[0]
    return 1.0 - (top2[:, 0] - top2[:, 1])


def error(
    logp: Float[Array, "E C G"], weights: Float[Array, " E"] | None = None
) -> Float[Array, " C"]:
    """The posterior probability that member 0's guess is wrong, 1 − p̄(ŷ₀) with
    ŷ₀ = argmax_k p_0,k and p̄ = Σ_e π_e p_e (ties to the lowest goal, as :ref:`concepts-metrics`).

    >>> tie = jnp.log(jnp.array([[[0.5, 0.5]], [[0.5, 0.5]]]))  # everyone at a tie
    >>> lone = jnp.log(jnp.array([[[0.9, 0.1]], [[0.1, 0.9]], [[0.1, 0.9]]]))  # member 0 alone
    >>> float(error(tie)[0]), round(float(error(lone)[0]), 6)
    (0.5, 0.633333)
    """
    guess = jnp.argmax(logp[0], axis=-1)  # (C,) member 0's decision
    pbar = predictive(logp, weights)
    return 1.0 - jnp.take_along_axis(pbar, guess[:, None], axis=-1)[:, 0]


def bald(
    logp: Float[Array, "E C G"], weights: Float[Array, " E"] | None = None
) -> Float[Array, " C"]:
    """BALD: the mutual information between the next answer and the observer,
    I(y; θ) = H[Σ_e π_e p_e] − Σ_e π_e H[p_e] (nats; Houlsby et al. 2011).

    >>> agree = jnp.log(jnp.array([[[0.5, 0.5]], [[0.5, 0.5]]]))  # same noisy answer
    >>> split = jnp.log(jnp.array([[[1.0, 0.0]], [[0.0, 1.0]]]))  # members disagree
    >>> float(bald(agree)[0]), float(bald(split)[0])
    (0.0, 0.6931...)
    """
    w = _weights(logp, weights)
    return _entropy(predictive(logp, w)) - jnp.einsum("e,ec->c", w, _entropy(jnp.exp(logp)))


def epig(
    logp: Float[Array, "E C G"],
    target_logp: Float[Array, "E S G"],
    weights: Float[Array, " E"] | None = None,
    *,
    chunk: int = 128,
) -> Float[Array, " C"]:
    """EPIG: the expected predictive information gain of each candidate x about the
    answers at the targets x*_s (nats; Bickford Smith et al. 2023, eq. 4):

        EPIG(x) = 1/S Σ_s I(y; y*_s) = H[p̄(y)] + 1/S Σ_s (H[p̄(y*_s)] − H[p(y, y*_s)]),

    with the joint p(y, y*) = Σ_e π_e p_e(y | x) p_e(y* | x*_s) of the members (and its
    marginals p̄). ``chunk`` candidates at a time (memory C·S·G² → chunk·S·G²).

    >>> split = jnp.log(jnp.array([[[1.0, 0.0]], [[0.0, 1.0]]]))  # members disagree
    >>> same = jnp.log(jnp.array([[[0.5, 0.5]], [[0.5, 0.5]]]))  # members agree
    >>> float(epig(split, split)[0]), float(epig(split, same)[0])  # y tells y*: log 2
    (0.6931..., 0.0)
    """
    w = _weights(logp, weights)
    p, q = jnp.exp(logp), jnp.exp(target_logp)
    h_target = jnp.mean(_entropy(predictive(target_logp, w)))
    c = logp.shape[1]
    pad = (-c) % chunk
    pc = jnp.pad(p, ((0, 0), (0, pad), (0, 0))).reshape(p.shape[0], -1, chunk, p.shape[-1])

    def block(pb: Float[Array, "E B G"]) -> Float[Array, " B"]:
        joint = jnp.einsum("e,ebg,esh->bsgh", w, pb, q)
        h_joint = _entropy(joint.reshape(*joint.shape[:2], -1)).mean(-1)
        return _entropy(jnp.einsum("e,ebg->bg", w, pb)) + h_target - h_joint

    return jax.lax.map(block, pc.transpose(1, 0, 2, 3)).reshape(-1)[:c]


def select_epig(
    key: jax.Array,
    logp: Float[Array, "E C G"],
    available: Bool[Array, " C"],
    k: int,
    targets: int | None = None,
) -> Int[Array, " k"]:
    """The k available candidates of highest :func:`epig`, the targets x* being
    :func:`epig_targets` of the C scored candidates."""
    tgt = epig_targets(key, logp.shape[1], targets)
    return masked_top_k(epig(logp, logp[:, tgt]), available, k)


def epig_targets(key: jax.Array, n: int, targets: int | None = None) -> Int[Array, " S"]:
    """S = min(``targets`` (default :data:`TARGETS`), n) of n scored candidates, uniformly
    without replacement: a sample of the inputs the observer will meet (the pool)."""
    s = min(TARGETS if targets is None else targets, n)
    return jax.random.choice(key, n, (s,), replace=False)


def masked_top_k(
    score: Float[Array, " C"], available: Bool[Array, " C"], k: int
) -> Int[Array, " k"]:
    """The k available candidates of highest ``score``, best first."""
    return jax.lax.top_k(jnp.where(available, score, -jnp.inf), k)[1]


def select_random(key: jax.Array, available: Bool[Array, " C"], k: int) -> Int[Array, " k"]:
    """k available candidates uniformly without replacement (Gumbel top-k)."""
    return masked_top_k(jax.random.gumbel(key, available.shape), available, k)


def select_cluster(
    logp: Float[Array, "E C G"],
    available: Bool[Array, " C"],
    k: int,
    shortlist: int | None = None,
    weights: Float[Array, " E"] | None = None,
    criterion: str = "bald",
) -> Int[Array, " k"]:
    """Diverse picks by ``criterion`` (``"bald"`` or ``"margin"``, score s ≥ 0): among the
    ``shortlist`` (default ``SHORTLIST`` · k) available candidates of highest s, start at
    the best and then add, k − 1 times, the one that maximises s × its Euclidean distance
    to the nearest pick so far, in the space of the members' predictions p_e (E·G numbers
    per candidate): a k-centre greedy (Sener & Savarese 2018) weighted by informativeness,
    so that a copy of a pick (distance 0) and a motion with nothing to teach (s = 0) both
    score 0. The first j picks do not depend on k for a fixed ``shortlist``."""
    m = min(SHORTLIST * k if shortlist is None else shortlist, logp.shape[1])
    if m < k:
        raise ValueError(f"shortlist: expected at least k = {k}, got {m}")
    if criterion not in ("bald", "margin"):
        raise ValueError(f"criterion: expected 'bald' or 'margin', got {criterion!r}")
    score = CRITERIA[criterion](logp, weights)
    info = jnp.where(available, score, -jnp.inf)
    val, top = jax.lax.top_k(info, m)  # (m,), best first
    feat = jnp.exp(logp[:, top]).transpose(1, 0, 2).reshape(m, -1)  # (m, E·G)
    ok = jnp.isfinite(val)

    def pick(i, carry):
        dmin, taken, out = carry
        gain = jnp.where(taken | ~ok, -jnp.inf, jnp.maximum(val, 0.0) * dmin)
        j = jnp.where(i == 0, 0, jnp.argmax(gain))
        d = jnp.sqrt(jnp.sum((feat - feat[j]) ** 2, axis=-1))
        return jnp.minimum(dmin, d), taken.at[j].set(True), out.at[i].set(top[j])

    init = (jnp.full((m,), jnp.inf), jnp.zeros((m,), bool), jnp.zeros((k,), jnp.int32))
    return jax.lax.fori_loop(0, k, pick, init)[2]


CRITERIA = {"uncertainty": uncertainty, "margin": margin, "error": error, "bald": bald}
RANKS_BY = {"margin_cluster": "margin", "bald_cluster": "bald"}


def select(
    strategy: str,
    key: jax.Array,
    logp: Float[Array, "E C G"] | None,
    available: Bool[Array, " C"],
    k: int,
    *,
    shortlist: int | None = None,
) -> Int[Array, " k"]:
    """The next k candidates (indices into the C scored ones) by ``strategy`` (one of
    :data:`STRATEGIES`; the module docstring defines them). ``logp`` holds the members'
    log guess probabilities (−∞ on padded goals; unused by ``random``), ``available`` the
    candidates that may be picked (at least k). Pure: jit it with ``strategy`` and ``k``
    static."""
    if strategy == "random":
        return select_random(key, available, k)
    if strategy in CRITERIA:
        return masked_top_k(CRITERIA[strategy](logp), available, k)
    if strategy in ("bald_cluster", "margin_cluster"):
        return select_cluster(logp, available, k, shortlist, criterion=RANKS_BY[strategy])
    if strategy == "epig":
        return select_epig(key, logp, available, k)
    raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")


def ranking_score(
    strategy: str, key: jax.Array, logp: Float[Array, "E C G"]
) -> tuple[str, Float[Array, " C"]]:
    """The criterion ``strategy`` ranks candidates by, as (name, score) for the record of
    a round: its own (:data:`CRITERIA`), that of its diverse form
    (:data:`RANKS_BY`), ``epig`` against the targets :func:`select` draws with ``key``, and
    ``bald`` for ``random`` (how informative its picks were)."""
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy: expected one of {STRATEGIES}, got {strategy!r}")
    if strategy == "epig":
        return "epig", epig(logp, logp[:, epig_targets(key, logp.shape[1])])
    name = strategy if strategy in CRITERIA else RANKS_BY.get(strategy, "bald")
    return name, CRITERIA[name](logp)


# ================================================================ the ensemble


def candidate_scores(
    model,
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    goal_mask: Bool[Array, "... G"],
    seen: Int[Array, "..."],
    *,
    backward: str = "autodiff",
) -> Float[Array, "... G"]:
    """Unmasked scores of the first ``seen`` points, for every observer family
    (:func:`slotv_jax.answers.fitting.prefix_scores`: the networks' mean or sum over the
    seen points; an archetype's formula on the prefix at its own times)."""
    return fitting.prefix_scores(model, xyz, goals, seen, goal_mask=goal_mask, backward=backward)


@dataclasses.dataclass(frozen=True, eq=False)
class Selector:
    """An ensemble of E observers of one config, trained on answers with a fixed capacity
    of M slots (build with :func:`make_selector`). Every method is pure: jit it."""

    cfg: TrainConfig
    base: train_lib.Trainer  # initialisation, optimiser and model of the config
    members: int  # E
    capacity: int  # M answer slots

    @property
    def is_mlp(self) -> bool:
        return self.cfg.model == "mlp"

    def check_pool(self, pool: Pool) -> None:
        """Every candidate shows 2 ≤ seen ≤ T points (every family scores prefixes)."""
        seen = np.asarray(pool.seen)
        if seen.size and not (seen.min() >= 2 and seen.max() <= pool.xyz.shape[1]):
            raise ValueError(
                f"pool.seen: expected 2 <= seen <= {pool.xyz.shape[1]} points per candidate, "
                f"got {int(seen.min())}..{int(seen.max())}"
            )

    def init(self, key: jax.Array, params: nnx.State | None = None) -> Ensemble:
        """E fresh members (member e from ``fold_in(split(key)[0], e)``) and their bootstrap
        weights (Poisson(1) from ``split(key)[1]``). With ``params`` every member starts
        from θ₀ = ``params`` (:meth:`slotv_jax.training.Trainer.init`)."""
        k_members, k_boot = jax.random.split(key)
        keys = jax.vmap(lambda e: jax.random.fold_in(k_members, e))(jnp.arange(self.members))
        states = jax.vmap(lambda k: self.base.init(k, params))(keys)
        boot = jax.random.poisson(k_boot, 1.0, (self.members, self.capacity))
        boot = boot.astype(jnp.float32).at[0].set(1.0)
        return Ensemble(states.params, states.opt_state, boot)

    def _scores(self, params, pool: Pool, cand: Int[Array, " B"]) -> tuple[Array, Array]:
        """One member's scores of the candidates ``cand`` and their goal masks."""
        t = pool.traj[cand]
        s = candidate_scores(
            self.base.model(params),
            pool.xyz[t],
            pool.goals[t],
            pool.goal_mask[t],
            pool.seen[cand],
            backward=self.base.backward,
        )
        return s, pool.goal_mask[t]

    def _logp(self, params, pool: Pool, cand: Int[Array, " B"]) -> Float[Array, "B G"]:
        s, mask = self._scores(params, pool, cand)
        return jax.nn.log_softmax(models.mask_logits(s, mask), axis=-1)

    def loss(self, params, pool: Pool, answers: Answers, rows: Int[Array, " B"], boot):
        """Minibatch count NLL of ``rows`` weighted by ``boot`` (per answer, unbiased)."""
        s, mask = self._scores(params, pool, answers.cand[rows])
        nll = fitting.count_nll(s, mask, answers.counts[rows])
        filled = jnp.arange(self.capacity) < answers.n
        n_bar = jnp.sum(jnp.where(filled[:, None], answers.counts, 0.0)) / jnp.maximum(answers.n, 1)
        return jnp.sum(boot[rows] * nll) / (rows.shape[0] * n_bar)

    def fit(
        self, ens: Ensemble, pool: Pool, answers: Answers, key: jax.Array, *, updates: int
    ) -> tuple[Ensemble, Float[Array, "U E"]]:
        """``updates`` more updates of every member (warm start from ``ens``): each draws
        ``cfg.batch_size`` of the ``answers.n`` filled rows uniformly with replacement
        (its own key) and takes one optimiser step on their bootstrap-weighted count
        NLL. Returns the ensemble and the losses."""
        bs, e = self.cfg.batch_size, self.members
        tx = self.base.tx

        def member(params, opt_state, boot, k):
            rows = jax.random.randint(k, (bs,), 0, jnp.maximum(answers.n, 1))
            loss, grads = jax.value_and_grad(self.loss)(params, pool, answers, rows, boot)
            upd, opt_state = tx.update(grads, opt_state, params)
            return optax.apply_updates(params, upd), opt_state, loss

        def step(carry, k):
            params, opt_state = carry
            params, opt_state, loss = jax.vmap(member)(
                params, opt_state, ens.boot, jax.random.split(k, e)
            )
            return (params, opt_state), loss

        (params, opt_state), losses = jax.lax.scan(
            step, (ens.params, ens.opt_state), jax.random.split(key, updates)
        )
        return Ensemble(params, opt_state, ens.boot), losses

    def log_probs(
        self, params, pool: Pool, cand: Int[Array, " C"], *, chunk: int = 256
    ) -> Float[Array, "E C G"]:
        """Every member's log guess probabilities of the candidates ``cand`` (−∞ on padded
        goals), ``chunk`` candidates at a time (``jax.lax.map``). ``params`` may hold any
        number of members (e.g. member 0 alone: ``jax.tree.map(lambda x: x[:1], params)``)."""
        c = cand.shape[0]
        pad = (-c) % chunk
        idx = jnp.concatenate([cand, jnp.zeros((pad,), cand.dtype)]).reshape(-1, chunk)

        def one(ix):
            return jax.vmap(lambda p: self._logp(p, pool, ix))(params)  # (E, chunk, G)

        out = jax.lax.map(one, idx)  # (chunks, E, chunk, G)
        e, g = out.shape[1], out.shape[-1]
        return out.transpose(1, 0, 2, 3).reshape(e, -1, g)[:, :c]


@functools.cache
def make_selector(cfg: TrainConfig, members: int, capacity: int) -> Selector:
    """The :class:`Selector` of ``cfg`` with E = ``members`` and M = ``capacity`` (cached:
    the same arguments give the same object, so jitted methods reuse compilations)."""
    if not isinstance(cfg, TrainConfig) or cfg.method != "slotv":
        raise ValueError("cfg: expected a SLOT-V TrainConfig (the count likelihood of guesses)")
    if not (isinstance(members, int) and members >= 1):
        raise ValueError(f"members: expected an int >= 1, got {members!r}")
    if not (isinstance(capacity, int) and capacity >= 1):
        raise ValueError(f"capacity: expected an int >= 1, got {capacity!r}")
    return Selector(cfg, train_lib.make_train(cfg, progress=False), members, capacity)
