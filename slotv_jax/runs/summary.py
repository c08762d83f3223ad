"""Pooled summaries of repeated runs: the mean and SD over trials (or seeds) of each group of
cells, and where a curve over a growing budget first reaches a target.

Every experiment repeats its runs over trials or seeds and reports them pooled; these are
the one definition of that pooling (Table 1's cells, the explainable observers' cells, the
simulated studies' cells; the answers to a target of the active-selection runs and the
trajectories a study needs).

>>> cells = [{"method": "slotv", "trial": t, "accuracy": a} for t, a in enumerate([0.5, 0.7])]
>>> pooled(cells, ("method",))
[{'method': 'slotv', 'mean': 0.6, 'sd': 0.1414..., 'n': 2}]
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from jaxtyping import Float


def mean_sd(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample SD (ddof = 1; 0 for a single value) of ``values``, in float64."""
    a = np.asarray(values, np.float64)
    if a.size == 0:
        raise ValueError("values: expected at least one value")
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0


def pooled(
    cells: Sequence[dict], keys: Sequence[str], *, value: str = "accuracy", count: str = "n"
) -> list[dict]:
    """Mean and SD (:func:`mean_sd`) of ``cell[value]`` over the cells of each group of equal
    ``keys``, in sorted order of the keys: one dict per group holding the keys, ``mean``,
    ``sd`` and the number of cells (under the name ``count``)."""
    groups: dict[tuple, list[float]] = {}
    for c in cells:
        groups.setdefault(tuple(c[k] for k in keys), []).append(c[value])
    out = []
    for key, values in sorted(groups.items()):
        mean, sd = mean_sd(values)
        out.append({**dict(zip(keys, key, strict=True)), "mean": mean, "sd": sd,
                    count: len(values)})  # fmt: skip
    return out


def examples_to_reach(
    examples: Float[np.ndarray, " V"], acc: Float[np.ndarray, " V"], threshold: float
) -> float | None:
    """First x at which ``acc`` reaches ``threshold`` (None if it never does): the paper's
    Fig. 3 count, read off the evaluations without interpolating."""
    hit = np.flatnonzero(acc >= threshold)
    return float(examples[hit[0]]) if hit.size else None


def crossing(x: Sequence[float], y: Sequence[float], target: float) -> float | None:
    """Where ``y`` (over increasing x > 0) first reaches ``target``: linear in log x between
    the point before and the first point at or above it,

        x* = exp(log x_{j−1} + f (log x_j − log x_{j−1})),
        f = (target − y_{j−1}) / (y_j − y_{j−1}),

    the first x if y already starts there, None if it never gets there.

    >>> crossing([10, 100], [0.6, 0.9], 0.75)  # halfway in log: sqrt(10 · 100)
    31.62...
    """
    a, v = np.asarray(x, float), np.asarray(y, float)
    hit = np.flatnonzero(v >= target)
    if hit.size == 0:
        return None
    j = int(hit[0])
    if j == 0:
        return float(a[0])
    f = (target - v[j - 1]) / (v[j] - v[j - 1])
    return float(np.exp(np.log(a[j - 1]) + f * (np.log(a[j]) - np.log(a[j - 1]))))


def against_random(
    x: Sequence[float], runs: Sequence[dict], strategies: Sequence[str], target: float
) -> list[dict]:
    """Strategies against random selection, over seeds: ``runs`` are {``strategy``, ``seed``,
    ``accuracy``} curves over the budgets ``x`` (answers, motions), ``"random"`` among the
    strategies. One entry per strategy, in order:

    - ``per_seed``: each run's :func:`crossing` of ``target`` (None: never reached),
      ``seeds_reached`` how many reached it, ``answers_to_target`` their mean (None unless
      every seed reached it), ``final_accuracy`` the mean at the largest budget
      ``answers_max``;
    - ``ratio_random_over_this``: random's mean over this strategy's (> 1: fewer answers
      than random); ``ratio_at_least`` a lower bound on it where random missed the target
      in some seed but not all (its unreached seeds counted at ``answers_max``).
    """
    out = []
    for s in strategies:
        mine = [r for r in runs if r["strategy"] == s]
        per = [crossing(x, r["accuracy"], target) for r in mine]
        reached = [p for p in per if p is not None]
        final = [r["accuracy"][-1] for r in mine]
        out.append(
            {
                "strategy": s,
                "answers_to_target": float(np.mean(per)) if len(reached) == len(per) else None,
                "seeds": len(mine),
                "target": target,
                "per_seed": per,
                "seeds_reached": len(reached),
                "final_accuracy": float(np.mean(final)),
                "answers_max": x[-1],
            }
        )
    rnd = next(c for c in out if c["strategy"] == "random")
    for c in out:
        a, b = rnd["answers_to_target"], c["answers_to_target"]
        c["ratio_random_over_this"] = None if a is None or b is None else a / b
        low = [c["answers_max"] if p is None else p for p in rnd["per_seed"]]
        c["ratio_at_least"] = (
            float(np.mean(low)) / b
            if a is None and b is not None and rnd["seeds_reached"]
            else None
        )
    return out


def ratio_se(baseline: Sequence[float], this: Sequence[float]) -> float:
    """Standard error of mean(baseline) / mean(this) over seeds (delta method, the two
    means taken as independent: conservative where a seed's runs share its first draw);
    NaN with fewer than two seeds on either side."""
    a, b = np.asarray(baseline, float), np.asarray(this, float)
    if a.size < 2 or b.size < 2:
        return float("nan")
    rel = a.var(ddof=1) / (a.size * a.mean() ** 2) + b.var(ddof=1) / (b.size * b.mean() ** 2)
    return float(a.mean() / b.mean() * np.sqrt(rel))


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation of ``x`` and ``y``: Pearson's correlation of their ranks
    (tied values share their average rank); NaN if either is constant."""

    def rank(a):
        order = np.argsort(a, kind="stable")
        r = np.empty(len(a))
        r[order] = np.arange(len(a))
        for v in np.unique(a):  # average ties
            r[a == v] = r[a == v].mean()
        return r

    rx, ry = rank(np.asarray(x, float)), rank(np.asarray(y, float))
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])
