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
    backward: str = "autodiff",
) -> Float[Array, "... G"]:
    """Unmasked scores of the first ``seen`` points of each trajectory.

    SLOT-V: s_k = (1/L) Σ_{i<L} V(p_i, g_k); T-REX: s_k = Σ_{i<L} r(p_i, g_k), with
    L = ``seen``. A model with time weights u_i weights the seen points by them: SLOT-V's
    s_k is then Σ_{i<L} u_i V(p_i, g_k) / Σ_{i<L} u_i, T-REX's Σ_{i<L} u_i r(p_i, g_k); a
    model with the start term takes every value relative to f(p_0, g_k) (p_0 is always
    seen).
    Points i ≥ L are replaced by p_0 before the network and weighted 0, so their values
    reach neither the scores nor any gradient. With L = T this is
    ``model.scores`` (up to summation order).

    >>> m = models.SlotV((8, 4), rngs=nnx.Rngs(0))  # doctest: +SKIP
    >>> prefix_scores(m, xyz[None], goals[None], jnp.array([40]))  # doctest: +SKIP
    """
    t = xyz.shape[-2]
    vis = jnp.arange(t) < seen[..., None]  # (..., T)
    x = jnp.where(vis[..., None], xyz, xyz[..., :1, :])
    v = model.network.grid(x, goals, backward=backward)  # (..., T, G)
    if model.start_term:  # values relative to the start's (point 0 is always seen)
        v = v - v[..., :1, :]
    w = vis.astype(v.dtype)
    u = model.point_weights(t)  # time weights of mean 1 over the whole trajectory, or None
    if u is not None:
        w = w * u.astype(v.dtype)
    if model.method == "slotv":
        w = w / w.sum(-1, keepdims=True)
    return jnp.einsum("...tg,...t->...g", v, w, precision=jax.lax.Precision.HIGHEST)


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
    s = prefix_scores(model, xyz, goals, seen, backward=backward)
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
            return prefix_scores(model, data.xyz[traj], data.goals[traj], seen)

        s = jax.lax.map(lambda a: one(*a), (data.row_trajectory, data.row_seen), batch_size=256)
        return models.mask_logits(s, data.goal_mask[data.row_trajectory])

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
