"""Simulated participants: goal guesses drawn from a labeler on trajectory prefixes, assembled
into a study.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jaxtyping import Bool, Float, Int

from slotv_jax.answers.crossval import labeler_probs
from slotv_jax.answers.format import Study, make_study
from slotv_jax.core.validation import G_MAX

# ============================================================== simulation


def prefix_labels(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    *,
    labeler: str = "dragan",
    beta: float | None = None,
    camera: str = "observer",
) -> Float[np.ndarray, "N K 8"]:
    """The labeler's distribution of each trajectory seen up to each normalised time τ
    (``taus``, K of them, in (0, 1]): :func:`labeler_probs` on every (trajectory, τ)."""
    taus = check_taus(taus)
    n = np.shape(xyz)[0]
    grid = make_study(
        xyz, goals, goal_mask, np.repeat(np.arange(n), taus.size),
        np.repeat(np.eye(G_MAX)[[0]], n * taus.size, axis=0),
        answer_tau=np.tile(taus, n), source="prefix_labels",
    )  # fmt: skip
    y = labeler_probs(grid, labeler, beta=beta, camera=camera)
    return y.reshape(n, taus.size, G_MAX)


def check_taus(taus) -> np.ndarray:
    taus = np.asarray(sorted({float(x) for x in taus}), np.float64)
    if taus.size == 0 or not (taus.min() > 0 and taus.max() <= 1):
        raise ValueError(f"taus: expected normalised times in (0, 1], got {taus.tolist()}")
    return taus


def simulate_guesses(
    key: jax.Array,
    probs: Float[np.ndarray, "N K 8"],
    goal_mask: Bool[np.ndarray, "N 8"],
    participants: int,
    *,
    lapse: float = 0.0,
) -> tuple[Int[np.ndarray, "N P"], Int[np.ndarray, "N P"]]:
    """Simulated participants: participant j sees trajectory n at a τ drawn uniformly from
    the K of ``probs`` and guesses a goal from

        p = (1 − λ) · probs[n, τ] + λ · uniform over the real goals   (lapse rate λ).

    Returns ``(which_tau, guess)``, each (N, P). Participant j's draws come from
    ``fold_in(key, j)`` alone: the first P participants of a larger simulation are the
    participants of a smaller one.
    """
    if not (isinstance(participants, int | np.integer) and participants >= 1):
        raise ValueError(f"participants: expected an int >= 1, got {participants!r}")
    if not 0.0 <= lapse <= 1.0:
        raise ValueError(f"lapse: expected a rate in [0, 1], got {lapse!r}")
    probs = np.asarray(probs, np.float64)
    goal_mask = np.asarray(goal_mask, bool)
    n, k = probs.shape[:2]
    uniform = goal_mask / goal_mask.sum(-1, keepdims=True)
    p = (1 - lapse) * probs + lapse * uniform[:, None, :]
    which = np.zeros((n, participants), np.int64)
    u = np.zeros((n, participants))
    for j in range(participants):
        k_tau, k_guess = jax.random.split(jax.random.fold_in(key, j))
        which[:, j] = np.asarray(jax.random.randint(k_tau, (n,), 0, k))
        u[:, j] = np.asarray(jax.random.uniform(k_guess, (n,)), np.float64)
    cdf = np.cumsum(p[np.arange(n)[:, None], which], -1)  # (N, P, 8)
    real = goal_mask.sum(-1)[:, None]
    guess = np.minimum((u[..., None] >= cdf).sum(-1), real - 1)
    return which, guess


def study_from_guesses(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    which_tau: Int[np.ndarray, "N P"],
    guess: Int[np.ndarray, "N P"],
) -> Study:
    """Aggregate per-participant guesses into a :class:`Study` (one row per seen (n, τ))."""
    taus = check_taus(taus)
    n = np.shape(xyz)[0]
    counts = np.zeros((n, taus.size, G_MAX))
    np.add.at(counts, (np.arange(n)[:, None], which_tau, guess), 1.0)
    has = counts.sum(-1) > 0
    rows = np.argwhere(has)
    return make_study(
        xyz, goals, goal_mask, rows[:, 0], counts[has], answer_tau=taus[rows[:, 1]],
        source="simulated study",
    )  # fmt: skip


def study_from_labels(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    probs: Float[np.ndarray, "N K 8"],
) -> Study:
    """The study of infinitely many participants (P = ∞): one row per trajectory n and stop
    time τ_k, holding the labeler's distribution ``probs[n, k]`` (:func:`prefix_labels`) as
    one answer, so the cross-entropy trains on the labels themselves (SLOT-V's loss,
    Wallkötter et al. 2022, Eq. 3)."""
    taus = check_taus(taus)
    n, k = np.shape(xyz)[0], taus.size
    if np.shape(probs)[:2] != (n, k):
        raise ValueError(f"probs: expected ({n}, {k}, 8) for {n} trajectories and {k} taus, "
                         f"got {np.shape(probs)}")  # fmt: skip
    return make_study(
        xyz, goals, goal_mask, np.repeat(np.arange(n), k), probs=np.reshape(probs, (n * k, -1)),
        n_answers=np.ones(n * k), answer_tau=np.tile(taus, n), source="labels",
    )  # fmt: skip


def simulate_study(
    key: jax.Array,
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    participants: int,
    *,
    labeler: str = "dragan",
    beta: float | None = None,
    taus: Sequence[float] = (1.0,),
    lapse: float = 0.0,
    camera: str = "observer",
) -> Study:
    """A simulated study: :func:`prefix_labels`, :func:`simulate_guesses` (P =
    ``participants`` per trajectory, each seeing it up to one τ of ``taus``), then
    :func:`study_from_guesses`."""
    probs = prefix_labels(xyz, goals, goal_mask, taus, labeler=labeler, beta=beta, camera=camera)
    which, guess = simulate_guesses(key, probs, goal_mask, participants, lapse=lapse)
    return study_from_guesses(xyz, goals, goal_mask, taus, which, guess)
