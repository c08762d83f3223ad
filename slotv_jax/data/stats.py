"""Label statistics of dataset splits: per labeler the entropy of the labels, how often their
argmax is a close call and how often it picks the target, and how often the labelers agree.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from slotv_jax.core.defaults import LABELER_NAMES
from slotv_jax.data.storage import Split

NEAR_TIE = 0.01  # a top-2 probability gap below this makes the argmax a close call


# ------------------------------------------------------------------- statistics


def entropy(y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-row entropy (nats) of ``y (N, 8)`` over the real slots of ``mask``; 0 log 0 = 0."""
    y = np.asarray(y, np.float64)
    p = np.where(mask & (y > 0), y, 1.0)  # log 1 = 0 for zeros and padded slots
    return 0.0 - (np.where(mask, y, 0.0) * np.log(p)).sum(axis=-1)  # 0.0 - x: no -0.0


def masked_argmax(y: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-row argmax of ``y`` over real slots; ties go to the lowest slot index."""
    return np.argmax(np.where(mask, np.asarray(y, np.float64), -np.inf), axis=-1)


def label_stats(y: np.ndarray, target: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """Entropy, max-probability and target agreement of one labeler's labels on one split.

    Returns means over trajectories: ``entropy`` and ``uniform_entropy`` (nats),
    ``entropy_ratio`` (their ratio of means), ``max_prob`` and ``uniform_max_prob``,
    ``target_agreement`` and its chance level ``chance`` (= mean 1/n_goals),
    ``margin`` (mean gap between the two largest probabilities) and ``near_tie``
    (fraction with a gap below :data:`NEAR_TIE`), and sanity figures of the labels
    themselves: ``max_sum_error`` (worst ``|Σ_real y − 1|``), ``max_padded`` (largest
    ``|y|`` on a padded slot) and ``min_value`` (smallest y on a real slot).
    """
    mask = np.asarray(mask, bool)
    y64 = np.asarray(y, np.float64)
    n = mask.sum(axis=-1)
    h = entropy(y64, mask)
    log_n = np.log(n)
    top2 = np.sort(np.where(mask, y64, 0.0), axis=-1)[:, -2:]  # a lone goal: gap = its y
    gap = top2[:, 1] - top2[:, 0]
    return {
        "entropy": float(h.mean()),
        "uniform_entropy": float(log_n.mean()),
        "entropy_ratio": float(h.mean() / log_n.mean()),
        "max_prob": float(np.where(mask, y64, -np.inf).max(axis=-1).mean()),
        "uniform_max_prob": float((1.0 / n).mean()),
        "target_agreement": float((masked_argmax(y64, mask) == target).mean()),
        "chance": float((1.0 / n).mean()),
        "margin": float(gap.mean()),
        "near_tie": float((gap < NEAR_TIE).mean()),
        "max_sum_error": float(np.abs(np.where(mask, y64, 0.0).sum(-1) - 1.0).max()),
        "max_padded": float(np.abs(np.where(mask, 0.0, y64)).max()),
        "min_value": float(np.where(mask, y64, np.inf).min()),
    }


def split_stats(split: Split, labelers: Sequence[str] = LABELER_NAMES) -> dict:
    """Every statistic of one split: per labeler (:func:`label_stats`) and across labelers.

    ``all_agree`` is the fraction of trajectories on which every labeler's argmax
    is the same goal; ``pairwise[a][b]`` the fraction on which ``a`` and ``b`` agree.
    """
    missing = [n for n in labelers if n not in split.labels]
    if missing:
        raise ValueError(f"split {split.name!r} has no labels {missing}")
    mask = split.goal_mask
    target = np.asarray(split.target)
    arg = {n: masked_argmax(split.labels[n], mask) for n in labelers}
    stacked = np.stack([arg[n] for n in labelers])
    n_goals = mask.sum(-1)
    return {
        "n": len(split),
        "goal_counts": {int(c): int((n_goals == c).sum()) for c in np.unique(n_goals)},
        "labelers": {n: label_stats(split.labels[n], target, mask) for n in labelers},
        "all_agree": float((stacked == stacked[0]).all(axis=0).mean()),
        "pairwise": {a: {b: float((arg[a] == arg[b]).mean()) for b in labelers} for a in labelers},
    }


def collect(splits: Mapping[str, Split], labelers: Sequence[str] = LABELER_NAMES) -> dict:
    """:func:`split_stats` for every split, plus the pairwise matrix averaged over splits."""
    per = {name: split_stats(s, labelers) for name, s in splits.items()}
    mean_pair = {
        a: {b: float(np.mean([per[s]["pairwise"][a][b] for s in per])) for b in labelers}
        for a in labelers
    }
    return {"labelers": list(labelers), "splits": per, "pairwise_mean": mean_pair}
