"""Training SLOT-V and T-REX on goal guesses: the count likelihood of answer rows over
trajectory prefixes.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int
from tqdm.auto import tqdm

from slotv_jax.answers.format import Study
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers import models
from slotv_jax.training import trainer as train_lib
from slotv_jax.training import types
from slotv_jax.training.config import TrainConfig

# ================================================================= training


class StudyData(NamedTuple):
    """A study as device arrays for training (N trajectories, A answer rows, G goal slots)."""

    xyz: Float[Array, "N T 3"]  # points (m), zeros after each trajectory's length
    goals: Float[Array, "N G 3"]  # goals (m); G ≤ 8: slots no trajectory uses are cut
    goal_mask: Bool[Array, "N G"]  # real goal slots
    row_trajectory: Int[Array, " A"]  # trajectory of each answer row
    row_seen: Int[Array, " A"]  # points its participants saw (2 ≤ L ≤ length)
    counts: Float[Array, "A G"]  # guesses per goal slot


def study_data(study: Study) -> StudyData:
    """The training arrays of a :class:`Study` (goal slots after the last real one cut)."""
    g = max(1, int(np.max(np.where(study.goal_mask, np.arange(1, G_MAX + 1), 0))))
    return StudyData(
        jnp.asarray(study.xyz, jnp.float32),
        jnp.asarray(study.goals[:, :g], jnp.float32),
        jnp.asarray(study.goal_mask[:, :g], bool),
        jnp.asarray(study.answer_trajectory, jnp.int32),
        jnp.asarray(study.seen(), jnp.int32),
        jnp.asarray(study.counts[:, :g], jnp.float32),
    )


def prefix_scores(
    model: models.Model,
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    seen: Int[Array, "..."],
    *,
    goal_mask: Bool[Array, "... G"] | None = None,
    backward: str = "autodiff",
) -> Float[Array, "... G"]:
    """Unmasked scores of the first ``seen`` = L points of each trajectory, for every
    observer family (padded slots: any finite value; mask them).

    SLOT-V: s_k = (1/L) Σ_{i<L} V(p_i, g_k); T-REX: s_k = Σ_{i<L} r(p_i, g_k)
    (:meth:`slotv_jax.observers.models.SlotV.prefix_scores`: with time weights u_i the seen
    points are weighted by them, with the start term every value is taken relative to
    f(p_0, g_k)). An archetype (``goal_mask`` required): its formula applied to
    ``xyz[:L]`` at the prefix's own times t_i = i/(L − 1)
    (:meth:`slotv_jax.observers.parametric.LearnableDragan.prefix_scores`).
    Points i ≥ L reach neither the scores nor any gradient. With L = T this is
    ``model.scores`` (up to summation order).

    >>> m = models.SlotV((8, 4), rngs=nnx.Rngs(0))  # doctest: +SKIP
    >>> prefix_scores(m, xyz[None], goals[None], jnp.array([40]))  # doctest: +SKIP
    """
    if goal_mask is None and not isinstance(model, models.SlotV | models.TRex):
        raise ValueError(f"goal_mask: the {model.name!r} archetype needs the goal mask")
    return model.prefix_scores(xyz, goals, goal_mask, seen, backward=backward)


def prefix_logits(
    model: models.Model,
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    goal_mask: Bool[Array, "... G"],
    seen: Int[Array, "..."],
    *,
    backward: str = "autodiff",
) -> Float[Array, "... G"]:
    """The logits of any observer model (network or archetype) for the motion seen up to
    its first ``seen`` points: :func:`prefix_scores`, −∞ on padded slots. softmax of them
    is the observer's P(goal | ξ_{0:τ}), what training on answers fits."""
    s = prefix_scores(model, xyz, goals, seen, goal_mask=goal_mask, backward=backward)
    return models.mask_logits(s, goal_mask)


def count_nll(
    scores: Float[Array, "B G"], goal_mask: Bool[Array, "B G"], counts: Float[Array, "B G"]
) -> Float[Array, " B"]:
    """Per row, −Σ_k c_k log softmax_k(s) over the real goals (the multinomial negative
    log-likelihood of the counts, without the constant multinomial coefficient)."""
    lse = jax.nn.logsumexp(models.mask_logits(scores, goal_mask), axis=-1, keepdims=True)
    return -jnp.sum(jnp.where(goal_mask, counts * (scores - lse), 0.0), axis=-1)


def study_loss(
    model: models.Model,
    xyz: Float[Array, "B T 3"],
    goals: Float[Array, "B G 3"],
    goal_mask: Bool[Array, "B G"],
    seen: Int[Array, " B"],
    counts: Float[Array, "B G"],
    answers_per_row: Float[Array, ""] | float,
    *,
    backward: str = "autodiff",
) -> Float[Array, ""]:
    """Minibatch estimate of the per-answer multinomial NLL (module docstring):

        L_batch = −Σ_b Σ_k c_bk log softmax_k(s_b) / (B · n̄),   n̄ = ``answers_per_row``

    With one answer per row (n̄ = 1) this is the mean cross-entropy against one-hot labels.
    """
    s = prefix_scores(model, xyz, goals, seen, goal_mask=goal_mask, backward=backward)
    return count_nll(s, goal_mask, counts).sum() / (xyz.shape[0] * answers_per_row)


def _rows(data: StudyData) -> int:
    return data.counts.shape[0]


def _batch(data: StudyData, idx: Int[Array, " B"]) -> tuple[Array, ...]:
    traj = data.row_trajectory[idx]
    return (
        data.xyz[traj],
        data.goals[traj],
        data.goal_mask[traj],
        data.row_seen[idx],
        data.counts[idx],
    )


def _loss(model, xyz, goals, goal_mask, seen, counts, *, data: StudyData, backward: str):
    n_bar = data.counts.sum() / data.counts.shape[0]  # answers per row (loop-invariant)
    return study_loss(model, xyz, goals, goal_mask, seen, counts, n_bar, backward=backward)


#: Study fitting as an objective of the one trainer (:class:`slotv_jax.training.trainer.Trainer`):
#: an epoch shuffles the A answer rows with ``fold_in(key, epoch)``, drops the last partial
#: batch, and each update minimises :func:`study_loss`. Initialisation, optimiser (RMSprop for
#: SLOT-V, Adam for T-REX), sharding, precision and state are the trainer's, so checkpoints
#: load with :func:`slotv_jax.load_observer`.
ANSWERS = train_lib.RowObjective(
    "study: {n} answer rows (lower batch_size, e.g. --set batch_size=8)", _rows, _batch, _loss
)


def study_trainer(cfg: TrainConfig) -> train_lib.Trainer:
    """The trainer of ``cfg`` on study answers (cached, so jitted calls reuse compilations).
    ``cfg.train_size`` does not apply: every answer row is used."""
    cfg = dataclasses.replace(cfg, train_size=None)
    return train_lib.make_train(cfg, progress=False, objective=ANSWERS)


@functools.cache
def _jit_run(trainer: train_lib.Trainer, epochs: int):
    return jax.jit(functools.partial(trainer.run, epochs=epochs))


@functools.cache
def _jit_scores(trainer: train_lib.Trainer):
    def scores(params, data: StudyData) -> Float[Array, "A G"]:
        model = trainer.model(params)

        def one(traj, seen):
            return prefix_logits(
                model, data.xyz[traj], data.goals[traj], data.goal_mask[traj], seen
            )

        return jax.lax.map(lambda a: one(*a), (data.row_trajectory, data.row_seen), batch_size=256)

    return jax.jit(scores)


def answer_logits(cfg: TrainConfig, params, study: Study) -> np.ndarray:
    """Masked scores (logits) of ``cfg``'s model with ``params`` for every answer row of
    ``study``: each row's trajectory up to the points its participants saw, ``(A, G)``."""
    trainer = study_trainer(cfg)
    return np.asarray(_jit_scores(trainer)(params, trainer.replicate(study_data(study))))


def _epoch_loss(cfg: TrainConfig, n_rows: int, block_losses) -> float:
    """The mean loss of one epoch's updates from its blocks' mean losses."""
    steps, k = cfg.steps_per_epoch(n_rows), cfg.block_size(n_rows)
    full, tail = divmod(steps, k)
    w = np.array([k] * full + ([tail] if tail else []), np.float64)
    return float(np.dot(np.asarray(block_losses, np.float64), w) / steps)


def train_study(
    cfg: TrainConfig,
    study: Study | StudyData,
    key: jax.Array,
    *,
    progress: bool = True,
    on_epoch: Callable[[types.TrainState, float], None] | None = None,
    state: types.TrainState | None = None,
) -> types.TrainState:
    """Train ``cfg``'s model on a study's answers (one compiled call per epoch, a tqdm bar).

    ``cfg.train_size`` is ignored (every answer row is used). ``on_epoch(state, loss)`` is
    called after each epoch (e.g. to checkpoint). ``state`` resumes a run. Returns the final
    :class:`slotv_jax.training.types.TrainState`.
    """
    trainer = study_trainer(cfg)
    data = study_data(study) if isinstance(study, Study) else study
    data = trainer.replicate(data)
    state = trainer.init(key) if state is None else state
    # one compiled call per epoch when the caller looks at every epoch, else one for all
    chunk = 1 if on_epoch is not None else max(cfg.epochs - int(state.epoch), 1)
    run = _jit_run(trainer, chunk)
    bar = tqdm(
        total=cfg.epochs, initial=int(state.epoch), desc=f"{cfg.method} (study)", unit="epoch",
        disable=not progress, leave=False, file=sys.stderr,
    )  # fmt: skip
    while int(state.epoch) < cfg.epochs:
        state, metrics = run(state, data)
        loss = _epoch_loss(trainer.cfg, _rows(data), metrics.loss[-1])
        if not math.isfinite(loss):
            raise ValueError(f"study training: the loss became {loss} at epoch {int(state.epoch)}")
        bar.update(chunk)
        bar.set_postfix(loss=f"{loss:.4f}")
        if on_epoch is not None:
            on_epoch(state, loss)
    bar.close()
    return state
