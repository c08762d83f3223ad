"""Active selection replayed on a pool whose answers are known: strategies × seeds side by
side, in one vmapped call per step, on the motions of a dataset split whose answers are its
labeler's distributions (the paper's labels) or simulated participants' guesses.

Two protocols, each returning every run's accuracy curve on held-out motions:

- :func:`run_rounds`: a study in rounds. Round 0 asks about ``sizes[0]`` motions drawn at
  random (the same for every strategy of a seed); each round trains the ensemble
  (:func:`slotv_jax.asking.selection.make_selector`, warm start) on every answer so far, records
  member 0's held-out accuracy, and the strategy picks the next ``sizes[r+1] − sizes[r]``
  motions from ``subset`` unasked candidates (the same draw for every strategy of a seed).
  Every answer is reused for as many updates as the rounds give (a study pays for answers).
- :func:`run_one_pass`: the paper's Fig. 3 protocol (:ref:`concepts-metrics`) with a strategy
  choosing each batch: one observer, each labelled motion used for exactly one optimiser step.

Besides the strategies of :data:`slotv_jax.asking.selection.STRATEGIES`, both run two
*oracles* (:data:`ORACLES`) that read the candidates' labels, which no study has before it
asks: bounds on what a criterion of the observer's own could reach, not strategies.
Strategies and seeds share what they can (initialisation, candidate subsets, the answers to
each motion), so the curves of one seed differ by the selection alone.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float
from tqdm.auto import tqdm

from slotv_jax.asking import selection
from slotv_jax.training import evaluate, types
from slotv_jax.training.config import TrainConfig

# Criteria that read the labels y of the candidates (the labeler's noise-free guess
# distribution): ``oracle_loss`` the candidates of largest cross-entropy −Σ_g y_g log p_g of
# member 0 (the observer's worst mistakes, known); ``oracle_margin`` those of smallest gap
# between the labeler's two most likely goals (the true decision boundary, known).
ORACLES = ("oracle_loss", "oracle_margin")

# (xyz (N, T, 3), goals (N, G, 3), goal_mask (N, G), labels (N, G)) of N motions
Motions = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def oracle_score(
    name: str, logp0: Float[Array, "C G"], labels: Float[Array, "C G"]
) -> Float[Array, " C"]:
    """Score of an oracle (higher: ask first) from member 0's log probabilities log p_g
    (−∞ on padded goals) and the labeler's distributions y (0 on padded goals):
    ``oracle_loss`` the cross-entropy −Σ_g y_g log p_g, ``oracle_margin`` the labeler's
    margin 1 − (y_(1) − y_(2)) (Scheffer et al. 2001, with the true distribution)."""
    if name == "oracle_loss":
        return -jnp.sum(jnp.where(labels > 0, labels * logp0, 0.0), -1)
    if name == "oracle_margin":
        top2 = jax.lax.top_k(labels, 2)[0]
        return 1.0 - (top2[:, 0] - top2[:, 1])
    raise ValueError(f"strategy: expected one of {ORACLES}, got {name!r}")


def motion_arrays(split, labeler: str, stride: int, n: int | None = None) -> Motions:
    """(xyz (N, T', 3), goals (N, G, 3), goal_mask (N, G), labels (N, G)) of the first ``n``
    motions of a split (all: None), on every ``stride``-th point and always the last."""
    d = types.prepare(split, labeler)
    cut = slice(None) if n is None else slice(0, n)
    xyz = np.asarray(d.xyz[cut])
    # every stride-th point, always keeping the last (the motion's end)
    pts = np.unique(np.r_[np.arange(0, xyz.shape[1], stride), xyz.shape[1] - 1])
    return (
        xyz[:, pts],
        np.asarray(d.goals[cut]),
        np.asarray(d.goal_mask[cut]),
        np.asarray(d.labels[cut]),
    )


def held_out_motions(
    split, name: str, labeler: str, stride: int, offset: int, size: int
) -> Motions:
    """:func:`motion_arrays` of motions ``offset`` … ``offset + size − 1`` of the split
    ``name``; a clear error if it holds fewer."""
    held = tuple(a[offset:] for a in motion_arrays(split, labeler, stride, offset + size))
    if held[0].shape[0] != size:
        raise ValueError(
            f"eval_offset, eval_size: {name} holds {offset + held[0].shape[0]} "
            f"motions, asked for {offset} + {size}"
        )
    return held


def guess_counts(seed: int, probs: np.ndarray, mask: np.ndarray, participants: int) -> np.ndarray:
    """(C, G) counts: ``participants`` guesses per motion sampled from ``probs`` (one
    random stream per seed: every strategy of a seed gets the same answers)."""
    rng = np.random.default_rng([seed, 7])
    u = rng.random((probs.shape[0], participants))
    cdf = np.cumsum(np.where(mask, probs, 0.0), -1)
    cdf = cdf / cdf[:, -1:]
    guess = np.minimum((u[..., None] >= cdf[:, None, :]).sum(-1), mask.sum(-1)[:, None] - 1)
    counts = np.zeros(probs.shape, np.float32)
    np.add.at(counts, (np.arange(probs.shape[0])[:, None], guess), 1.0)
    return counts


def geometric(start: int, stop: int, ratio: float) -> tuple[int, ...]:
    """Sizes start, ≈ start·ratio, … up to stop (rounded, distinct)."""
    n = math.floor(math.log(stop / start) / math.log(ratio) + 1e-9) + 1
    return tuple(sorted({round(start * ratio**i) for i in range(n)}))


def up_to(sizes: Sequence[int], stop: int) -> tuple[int, ...]:
    """``sizes`` cut at ``stop``, or continued by their last ratio up to it.

    >>> up_to((8, 11, 16), 23), up_to((16, 32, 64), 300), up_to((16, 32, 64), 40)
    ((8, 11, 16, 23), (16, 32, 64, 128, 256), (16, 32))
    """
    out = [s for s in sizes if s <= stop]
    if len(out) == len(sizes):
        ratio = sizes[-1] / sizes[-2]
        while round(out[-1] * ratio) <= stop:
            out.append(round(out[-1] * ratio))
    return tuple(out)


def _picker(strategy: str, k: int, avail=None):
    """(key, log p (E, C, G), available (C,), labels (C, G)) -> k picks of ``strategy``; with
    ``avail`` given, (key, log p, labels) -> k picks among those."""

    def pick(key, lp, av, y):
        if strategy in ORACLES:
            return selection.masked_top_k(oracle_score(strategy, lp[0], y), av, k)
        return selection.select(strategy, key, lp, av, k)

    return pick if avail is None else (lambda key, lp, y: pick(key, lp, avail, y))


def run_rounds(
    tc: TrainConfig,
    train: Motions,
    held_out: Motions,
    answers: Mapping[int, np.ndarray],
    *,
    sizes: Sequence[int],
    strategies: Sequence[str],
    seeds: Sequence[int],
    members: int,
    subset: int,
    block: int,
    round_updates: Callable[[int], int],
    chunk: int = 256,
    progress: bool = True,
    desc: str = "rounds",
) -> tuple[np.ndarray, dict]:
    """Every strategy × seed of the round protocol (module docstring) on the pool ``train``.
    ``answers[seed]`` holds the (N, G) answer counts of every pool motion for that seed;
    each round trains ``round_updates(size)`` updates (a multiple of ``block``) of
    ``tc.batch_size`` answer rows. Returns member 0's held-out accuracy (runs, rounds), the
    runs being (strategy, seed) in the order of ``strategies`` then ``seeds``, and the time
    spent fitting, scoring, selecting and evaluating."""
    xyz, goals, mask, probs = train
    pool = selection.make_pool(xyz, goals, mask)
    evpool = selection.make_pool(*held_out[:3])
    etarget = np.asarray(evaluate.target(jnp.asarray(held_out[3]), jnp.asarray(held_out[2])))
    n_pool = pool.traj.shape[0]
    if sizes[-1] > n_pool:
        raise ValueError(f"sizes: {sizes[-1]} motions asked, the pool holds {n_pool}")
    runs = [(s, seed) for s in strategies for seed in seeds]
    n_runs, cap, g = len(runs), sizes[-1], probs.shape[1]
    sel = selection.make_selector(tc, members, cap)
    seed_keys = {seed: jax.random.key(1000 + seed) for seed in seeds}
    ens = jax.jit(jax.vmap(sel.init))(jnp.stack([seed_keys[sd] for _, sd in runs]))
    cand = np.zeros((n_runs, cap), np.int32)
    counts = np.zeros((n_runs, cap, g), np.float32)
    asked = np.zeros((n_runs, n_pool), bool)
    for i, (_, sd) in enumerate(runs):
        first = np.random.default_rng([sd, 1]).choice(n_pool, sizes[0], replace=False)
        cand[i, : sizes[0]] = first
        asked[i, first] = True
    fit = jax.jit(jax.vmap(lambda e, a, k: sel.fit(e, pool, a, k, updates=block)))
    evc = jnp.arange(evpool.traj.shape[0])
    acc_fn = jax.jit(
        jax.vmap(
            lambda p: jnp.argmax(
                sel.log_probs(jax.tree.map(lambda x: x[:1], p), evpool, evc, chunk=chunk)[0], -1
            )
        )
    )
    score = jax.jit(jax.vmap(lambda p, c: sel.log_probs(p, pool, c, chunk=chunk)))
    k_max = max(b - a for a, b in itertools.pairwise(sizes))
    pickers = {s: jax.jit(jax.vmap(_picker(s, k_max))) for s in strategies}
    acc = np.zeros((n_runs, len(sizes)))
    times = {"fit_s": 0.0, "score_s": 0.0, "select_s": 0.0, "eval_s": 0.0}
    bar = tqdm(total=len(sizes), desc=desc, unit="round", disable=not progress, leave=False)
    for r, size in enumerate(sizes):
        for i, (_, sd) in enumerate(runs):
            counts[i, :size] = answers[sd][cand[i, :size]]
        ans = selection.Answers(
            jnp.asarray(cand), jnp.asarray(counts), jnp.full((n_runs,), size, jnp.int32)
        )
        keys = jnp.stack([jax.random.fold_in(seed_keys[sd], 100 + r) for _, sd in runs])
        t0 = time.perf_counter()
        for j in range(round_updates(size) // block):
            kj = keys if j == 0 else jax.vmap(lambda k, j=j: jax.random.fold_in(k, 10 + j))(keys)
            ens, _ = fit(ens, ans, kj)
        jax.block_until_ready(ens.params)
        t1 = time.perf_counter()
        pred = np.asarray(acc_fn(ens.params))
        acc[:, r] = (pred == etarget[None]).mean(-1)
        t2 = time.perf_counter()
        times["fit_s"] += t1 - t0
        times["eval_s"] += t2 - t1
        bar.update(1)
        if r + 1 == len(sizes):
            break
        k = sizes[r + 1] - size
        sub = np.zeros((n_runs, subset), np.int32)
        for i, (_, sd) in enumerate(runs):  # the same subset for every strategy of a seed
            free = np.flatnonzero(~asked[i])
            sub[i] = np.random.default_rng([sd, 2, r]).choice(
                free, min(subset, free.size), replace=False
            )
        t0 = time.perf_counter()
        logp = score(ens.params, jnp.asarray(sub))
        jax.block_until_ready(logp)
        t1 = time.perf_counter()
        pick = np.zeros((n_runs, k_max), np.int32)
        for s, fn in pickers.items():
            idx = [i for i, run in enumerate(runs) if run[0] == s]
            pk = jnp.stack([jax.random.fold_in(keys[i], 1) for i in idx])
            avail = jnp.ones((len(idx), subset), bool)
            y = jnp.asarray(probs[sub[idx]]) if s in ORACLES else jnp.zeros((len(idx),))
            pick[idx] = np.asarray(fn(pk, logp[np.asarray(idx)], avail, y))
        times["score_s"] += t1 - t0
        times["select_s"] += time.perf_counter() - t1
        for i in range(n_runs):
            new = sub[i, pick[i, :k]]
            assert not asked[i, new].any() and np.unique(new).size == k
            cand[i, size : size + k] = new
            asked[i, new] = True
    bar.close()
    return acc, times


def run_one_pass(
    tc: TrainConfig,
    train: Motions,
    held_out: Motions,
    *,
    strategies: Sequence[str],
    seeds: Sequence[int],
    steps: int,
    subset: int,
    every: int,
    chunk: int = 256,
    progress: bool = True,
) -> dict:
    """Every strategy × seed of the one-pass protocol (module docstring): before each of
    ``steps`` updates the strategy scores ``subset`` not yet labelled motions of ``train``
    with the current observer (one member) and picks ``tc.batch_size`` of them, which are
    labelled (their labels) and used for that one optimiser step only; every ``every``
    updates, the accuracy on ``held_out`` is recorded. Returns the curves (examples,
    per-run accuracy), the motions each run labelled (in order), the observers at the end
    (leading axis: runs) and the timing."""
    bs = tc.batch_size
    xyz, goals, mask, probs = train
    pool = selection.make_pool(xyz, goals, mask)
    n_pool = pool.traj.shape[0]
    if (steps - 1) * bs + subset > n_pool:
        raise ValueError(
            f"train: {steps} updates of {bs} new motions, each from {subset} "
            f"unlabelled ones, need {(steps - 1) * bs + subset} motions, got {n_pool}"
        )
    evpool = selection.make_pool(*held_out[:3])
    etarget = np.asarray(evaluate.target(jnp.asarray(held_out[3]), jnp.asarray(held_out[2])))
    runs = [(s, seed) for s in strategies for seed in seeds]
    sel = selection.make_selector(tc, 1, bs)  # one member: the observer itself
    ens = jax.jit(jax.vmap(sel.init))(jnp.stack([jax.random.key(1000 + sd) for _, sd in runs]))
    rows = jnp.arange(bs)

    def update(e: selection.Ensemble, ans: selection.Answers) -> selection.Ensemble:
        """One optimiser step on the batch's rows, each once (Fig. 3's epoch)."""

        def member(params, opt_state, boot):
            grads = jax.grad(sel.loss)(params, pool, ans, rows, boot)
            upd, opt_state = sel.base.tx.update(grads, opt_state, params)
            return optax.apply_updates(params, upd), opt_state

        params, opt_state = jax.vmap(member)(e.params, e.opt_state, e.boot)
        return selection.Ensemble(params, opt_state, e.boot)

    step = jax.jit(jax.vmap(update))
    score = jax.jit(jax.vmap(lambda p, c: sel.log_probs(p, pool, c, chunk=chunk)))
    evc = jnp.arange(evpool.traj.shape[0])
    predict = jax.jit(
        jax.vmap(lambda p: jnp.argmax(sel.log_probs(p, evpool, evc, chunk=chunk)[0], -1))
    )
    avail = jnp.ones((subset,), bool)
    pickers = {s: jax.jit(jax.vmap(_picker(s, bs, avail))) for s in strategies}
    members = {s: np.asarray([i for i, r in enumerate(runs) if r[0] == s]) for s in pickers}
    asked = np.zeros((len(runs), n_pool), bool)
    labelled = np.zeros((len(runs), steps * bs), np.int32)
    acc, xs = [], []
    times = {"score_s": 0.0, "select_s": 0.0, "update_s": 0.0, "eval_s": 0.0}
    for u in tqdm(range(steps + 1), desc="updates", disable=not progress, leave=False):
        if u % every == 0 or u == steps:
            t0 = time.perf_counter()
            acc.append((np.asarray(predict(ens.params)) == etarget[None]).mean(-1))
            xs.append(u * bs)
            times["eval_s"] += time.perf_counter() - t0
        if u == steps:
            break
        sub = np.zeros((len(runs), subset), np.int32)
        for i, (_, sd) in enumerate(runs):
            free = np.flatnonzero(~asked[i])
            sub[i] = np.random.default_rng([sd, 2, u]).choice(free, subset, replace=False)
        t0 = time.perf_counter()
        logp = score(ens.params, jnp.asarray(sub))
        jax.block_until_ready(logp)
        t1 = time.perf_counter()
        keys = jnp.stack([jax.random.fold_in(jax.random.key(1000 + sd), u) for _, sd in runs])
        pick = np.zeros((len(runs), bs), np.int32)
        for s, fn in pickers.items():
            idx = members[s]
            y = jnp.asarray(probs[sub[idx]]) if s in ORACLES else jnp.zeros((idx.size,))
            pick[idx] = np.asarray(fn(keys[idx], logp[idx], y))
        new = np.take_along_axis(sub, pick, 1)  # (runs, bs) motions labelled now
        t2 = time.perf_counter()
        for i in range(len(runs)):
            asked[i, new[i]] = True
        labelled[:, u * bs : (u + 1) * bs] = new
        ans = selection.Answers(
            jnp.asarray(new),
            jnp.asarray(probs[new], jnp.float32),
            jnp.full((len(runs),), bs, jnp.int32),
        )
        ens = step(ens, ans)
        jax.block_until_ready(ens.params)
        times["score_s"] += t1 - t0
        times["select_s"] += t2 - t1
        times["update_s"] += time.perf_counter() - t2
    curves = np.stack(acc, 1)  # (runs, evaluations)
    return {
        "examples": xs,
        "runs": [
            {"strategy": s, "seed": sd, "accuracy": curves[i].round(6).tolist()}
            for i, (s, sd) in enumerate(runs)
        ],
        "labelled": labelled,
        "params": ens.params,
        "timing": {k: round(v, 2) for k, v in times.items()},
    }
