"""The motion reader's prior: what many kinds of people would answer, learned before any
answer of the study is seen.

1,000-2,000 answers are too few to place a network's weights from a random draw, but they
suffice to *adapt* a network that already reads motion the way people in general do
(fine-tuning from a prior, Howard & Ruder 2018; amortised over people, as in learning to
infer from many related tasks). The prior of :class:`slotv_jax.observers.reader.MotionReader`
is trained, by the same count likelihood as the answers (:mod:`slotv_jax.answers.fitting`),
on the motions the study can show, seen up to the study's stop times, each row labelled by
the mean guess distribution of the **sources**:

- the four hand-crafted labelers at their default temperatures (:ref:`concepts-labelers`,
  Nikolaidis seen from the dataset's ``observer`` camera);
- :data:`PRIOR_DRAWS` populations drawn from the population hyper-distribution
  (:func:`slotv_jax.observers.population.random_population` of K = 1000, 1001, …: none of
  the suite's draws, :data:`slotv_jax.observers.population.SUITE_DRAWS`);
- every member of the zoo (:mod:`slotv_jax.observers.zoo`);

less the ones named in ``exclude`` (a zoo member's name, or ``random:K`` for a draw): the
people a study is scored on are never among its prior's sources.

    y_prior(k | ξ_{0:τ}) = (1/S) Σ_s P_s(k | ξ_{0:τ})

The prior sees only these models' probabilities of the motions, never an answer, so a
study's answers are used once, by the fit that adapts the prior (its updates start from the
prior's parameters with a fresh optimiser state).

>>> [name for name, _ in sources(exclude=("anchor",), draws=1)][:6]
['dragan', 'nikolaidis', 'effdist', 'fastapp', 'random:1000', 'inverse_planning']
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float

from slotv_jax.answers import fitting
from slotv_jax.answers.format import Study, make_study
from slotv_jax.core.defaults import LABELER_NAMES
from slotv_jax.core.shapes import pad_rows
from slotv_jax.observers import population as population_lib
from slotv_jax.observers import reader as reader_lib
from slotv_jax.observers import zoo
from slotv_jax.observers.common import seen_points
from slotv_jax.observers.observer import Observer
from slotv_jax.planning import labeler_observer
from slotv_jax.training.config import TrainConfig
from slotv_jax.world import scene

__all__ = [
    "FIRST_DRAW",
    "PRIOR_DRAWS",
    "answered_prior",
    "prior_labels",
    "prior_params",
    "prior_study",
    "source_names",
    "sources",
]

PRIOR_DRAWS = 8  # populations of the hyper-distribution among the sources
FIRST_DRAW = 1000  # their K: far from the suite's draws (0-7) and any screen of them
PRIOR_SEED = 4_000  # the prior's training key
CHUNK = 256  # rows per compiled call of the sources' probabilities


def source_names(exclude: Sequence[str] = (), draws: int = PRIOR_DRAWS) -> tuple[str, ...]:
    """The names of :func:`sources` ``(exclude, draws)``, in its order, without building them:
    two studies whose names are the same have the same prior."""
    left_out = set(exclude)
    draw_names = [f"random:{k}" for k in range(FIRST_DRAW, FIRST_DRAW + draws)]
    return (
        *LABELER_NAMES,
        *(n for n in draw_names if n not in left_out),
        *(n for n in zoo.MEMBERS if n not in left_out),
    )


def sources(exclude: Sequence[str] = (), draws: int = PRIOR_DRAWS) -> list[tuple[str, object]]:
    """``(name, observer)`` of every source of the prior (module docstring), the zoo's
    members and the draws (``random:K``) named in ``exclude`` left out
    (:func:`source_names`). Each observer has ``prefix(xyz, goals, goal_mask, seen) -> log P``."""

    def observer(name: str):
        if name in LABELER_NAMES:
            return labeler_observer(name)
        if name in zoo.MEMBERS:
            return zoo.MEMBERS[name]
        k = int(name.removeprefix("random:"))  # one quadrature shape: one compilation
        return population_lib.quadrature_observer(
            population_lib.quadrature(population_lib.random_population(k))
        )

    return [(n, observer(n)) for n in source_names(exclude, draws)]


def _probs(observer, x, g, m, s):
    return jax.nn.softmax(observer.prefix(x, g, m, s))


_PYTREE = jax.jit(jax.vmap(_probs, in_axes=(None, 0, 0, 0, 0)))  # an Observer: its leaves traced
_STATIC = jax.jit(jax.vmap(_probs, in_axes=(None, 0, 0, 0, 0)), static_argnums=0)  # a zoo member


def _probs_fn(observer):
    if isinstance(observer, Observer):
        return lambda *a: _PYTREE(observer, *a)
    return lambda *a: _STATIC(observer, *a)


def prior_labels(
    srcs: Sequence[tuple[str, object]],
    xyz: Float[np.ndarray, "A T 3"],
    goals: Float[np.ndarray, "A 8 3"],
    goal_mask: Bool[np.ndarray, "A 8"],
    seen: np.ndarray,
) -> Float[np.ndarray, "A 8"]:
    """y_prior of each row (motion ``xyz[a]`` seen up to its first ``seen[a]`` points): the
    mean of the sources' probabilities (float64; 0 on padded slots)."""
    a = xyz.shape[0]
    size = a + (-a % CHUNK)  # whole chunks: one compiled shape per source
    arrays = [pad_rows(v, size) for v in (xyz, goals, goal_mask, np.asarray(seen, np.int32))]
    total = np.zeros((a, goals.shape[1]), np.float64)
    for _, obs in srcs:
        f = _probs_fn(obs)
        parts = []
        for i in range(0, size, CHUNK):
            chunk = [jnp.asarray(v[i : i + CHUNK]) for v in arrays]
            parts.append(np.asarray(f(*chunk), np.float64))
        p = np.concatenate(parts)[:a]
        if not np.all(np.isfinite(p)):
            raise ValueError("prior: a source gave a non-finite probability")
        total += p
    y = np.where(goal_mask, total / len(srcs), 0.0)
    return y / y.sum(-1, keepdims=True)


def prior_study(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    exclude: Sequence[str] = (),
    draws: int = PRIOR_DRAWS,
) -> Study:
    """The prior's training rows as a :class:`~slotv_jax.answers.Study`: every motion at
    every stop time of ``taus``, one answer's worth of y_prior each (``probs`` with
    ``n_answers`` 1, so a row weighs as much as one person's guess)."""
    xyz = np.asarray(xyz, np.float32)
    n, t = xyz.shape[:2]
    taus = np.asarray(sorted({float(x) for x in taus}))
    rows_traj = np.repeat(np.arange(n), taus.size)
    rows_tau = np.tile(taus, n)
    seen = np.tile(seen_points(taus, t), n)
    return _labelled(xyz, goals, goal_mask, rows_traj, seen, exclude, draws, answer_tau=rows_tau)


def _labelled(xyz, goals, goal_mask, traj, seen, exclude, draws, **study) -> Study:
    """The rows (motion ``traj[a]`` seen up to ``seen[a]`` points) as a Study, each labelled
    by y_prior of the sources less ``exclude`` (one answer's worth a row)."""
    y = prior_labels(
        sources(exclude, draws), np.asarray(xyz, np.float32)[traj], np.asarray(goals)[traj],
        np.asarray(goal_mask, bool)[traj], seen,
    )  # fmt: skip
    return make_study(xyz, goals, goal_mask, traj, probs=y, n_answers=np.ones(traj.size),
                      source="the motion reader's prior", **study)  # fmt: skip


def prior_params(cfg: TrainConfig, study: Study, camera: scene.Camera | None = None):
    """The prior's parameters: ``cfg``'s motion reader trained on ``study``
    (:func:`prior_study`) by :func:`slotv_jax.answers.fitting.train_study`, key
    :data:`PRIOR_SEED`, with the study's ``camera`` (default: ``cfg.camera``'s)."""
    if cfg.model != "reader":
        raise ValueError(f"cfg.model: the prior is the motion reader's, got {cfg.model!r}")
    trainer, key = fitting.study_trainer(cfg), jax.random.key(PRIOR_SEED)
    state = trainer.init(key)
    if camera is not None:  # the same draw, filmed by the study's camera
        state = trainer.init(key, reader_lib.with_camera(state.params, camera))
    state = fitting.train_study(cfg, study, jax.random.key(PRIOR_SEED), progress=False,
                                state=state)  # fmt: skip
    return state.params


def answered_prior(study: Study, exclude: Sequence[str] = ()) -> Study:
    """The prior's rows for a real study: its own stimuli (each answer row's motion, seen as
    its participants saw it), each labelled by y_prior instead of the answers (one
    answer's worth a row). The answers themselves are never read, so a fit started from
    this prior and scored on held-out answers sees each answer once, in its own folds."""
    traj = np.asarray(study.answer_trajectory)
    seen = np.asarray(study.seen(), np.int32)
    return _labelled(study.xyz, study.goals, study.goal_mask, traj, seen, exclude, PRIOR_DRAWS,
                     answer_tau=study.answer_tau, t=study.t, length=study.length)  # fmt: skip
