"""The arrays that flow between training, evaluation, checkpoints and the experiments.

They live here, below every module that uses them (:mod:`slotv_jax.training.evaluate`,
:mod:`slotv_jax.train`, :mod:`slotv_jax.training.checkpoint`, :mod:`slotv_jax.training.parallel`,
:mod:`slotv_jax.study`), so that no module has to import one above it to name them:

- :class:`TrainData` — one labelled split, with the functions that build it
  (:func:`prepare`, :func:`make_data`) and cut it (:func:`trim_goals`, :func:`subset`);
- :class:`EvalData` — a split cut into fixed-size chunks for evaluation;
- :class:`TrainState` — everything a resumed run needs (what a checkpoint stores);
- :class:`Metrics` — what one training call records.

``slotv_jax.train`` and ``slotv_jax.training.evaluate`` re-export them under their old names.

>>> import numpy as np
>>> mask = np.arange(8) < 2
>>> goals = np.arange(24.0).reshape(1, 8, 3) * mask[:, None]  # two real goals, apart
>>> d = make_data(np.zeros((1, 4, 3)), goals, mask[None],
...               np.where(mask, 0.5, 0.0)[None])
>>> trim_goals(d).goals.shape
(1, 2, 3)
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation


class TrainData(NamedTuple):
    """One labelled split as device arrays (N trajectories of T points)."""

    xyz: Float[Array, "N T 3"]  # executed TCP path (m)
    goals: Float[Array, "N 8 3"]  # goals of each trajectory's scene (m)
    goal_mask: Bool[Array, "N 8"]  # real goal slots
    labels: Float[Array, "N 8"]  # labeler's distribution over goals (0 on padding)


class EvalData(NamedTuple):
    """A split cut into M chunks of C trajectories (the padding has ``valid`` False)."""

    xyz: Float[Array, "M C T 3"]
    goals: Float[Array, "M C G 3"]  # G ≤ 8 goal slots (unused trailing slots may be cut)
    goal_mask: Bool[Array, "M C G"]
    labels: Float[Array, "M C G"]
    valid: Bool[Array, "M C"]


class TrainState(NamedTuple):
    """Everything a resumed run needs."""

    params: nnx.State  # model parameters, float32
    opt_state: optax.OptState  # optimiser state, float32
    epoch: Int[Array, ""]  # epochs completed
    key: Array  # typed PRNG key; epoch e uses fold_in(key, e)


class Metrics(NamedTuple):
    """What one call of ``run``/``train`` records (E epochs, K loss blocks, V validations)."""

    loss: Float[Array, "E K"]  # mean training loss of each block of updates
    eval_updates: Int[Array, "E V"]  # global update count at each validation
    eval_accuracy: Float[Array, "E V"]  # validation accuracy after those updates
    start_accuracy: Float[Array, ""]  # validation accuracy before the first update (NaN: none)


def prepare(split, labeler: str, *, size: int | None = None) -> TrainData:
    """Validated arrays for one labeler from a :class:`slotv_jax.data.Split`.

    ``size`` keeps the first ``size`` trajectories. Raises ValueError on wrong shapes,
    NaN, a scene with no real goal, or labels that are not distributions.
    """
    if labeler not in split.labels:
        raise ValueError(f"labeler: expected one of {sorted(split.labels)}, got {labeler!r}")
    n = len(split) if size is None else min(int(size), len(split))
    if n < 1:
        raise ValueError(f"split {getattr(split, 'name', '?')!r}: expected at least 1 trajectory")
    xyz = np.asarray(split.xyz[:n], np.float32)
    goals = np.asarray(split.goals[:n], np.float32)
    goal_mask = np.asarray(split.goal_mask[:n], bool)
    labels = np.asarray(split.labels[labeler][:n], np.float32)
    return make_data(xyz, goals, goal_mask, labels)


def make_data(xyz, goals, goal_mask, labels) -> TrainData:
    """Validate raw arrays (N, T, 3), (N, 8, 3), (N, 8), (N, 8) and pack them."""
    validation.check_array("xyz", xyz, (None, None, 3))
    n, t = np.shape(xyz)[:2]
    if t < 2:
        raise ValueError(
            f"xyz: expected at least 2 points per trajectory, got shape {np.shape(xyz)}"
        )
    validation.check_goals("goals", goals, goal_mask, batch_shape=(n,))
    validation.check_labels("labels", labels, goal_mask)
    return TrainData(
        jnp.asarray(xyz, jnp.float32),
        jnp.asarray(goals, jnp.float32),
        jnp.asarray(goal_mask, bool),
        jnp.asarray(labels, jnp.float32),
    )


def trim_goals(data: TrainData) -> TrainData:
    """The same data with the goal axis cut after its last real slot in any trajectory.

    Padded slots add nothing to the loss, its gradient or the accuracy (their logits are
    −∞ and their labels 0), but every one of them costs a full pass of the network over
    the trajectory. The training split of :ref:`concepts-datasets` has at most 6 real goals of the 8
    slots, so this removes a quarter of SLOT-V's work. Needs concrete ``goal_mask`` (host or
    device arrays, not tracers); returns ``data`` itself when nothing can be cut.
    """
    mask = np.asarray(data.goal_mask, bool)
    used = np.where(mask, np.arange(1, mask.shape[-1] + 1), 0)
    g = max(1, int(used.max(initial=0)))
    if g == mask.shape[-1]:
        return data
    return data._replace(
        goals=data.goals[:, :g], goal_mask=data.goal_mask[:, :g], labels=data.labels[:, :g]
    )


def subset(data: TrainData, n: int) -> TrainData:
    """The first ``n`` trajectories (static slicing; also fine on tracers)."""
    return TrainData(*(x[:n] for x in data))
