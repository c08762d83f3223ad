"""The training losses: cross-entropy of SLOT-V against soft labels (:ref:`concepts-slotv`) and
T-REX's pairwise Bradley-Terry loss (:ref:`concepts-trex`), and the optimiser.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Array, Float

from slotv_jax.observers import models
from slotv_jax.training.config import TrainConfig


def make_optimizer(cfg: TrainConfig) -> optax.GradientTransformation:
    """RMSprop or Adam with the config's hyperparameters.

    RMSprop: ν ← ρν + (1−ρ)g², θ ← θ − lr·g/(√ν + ε) (ε outside the root, as in PyTorch
    and Keras **[choice]**), with optional heavy-ball momentum. Adam: Kingma & Ba (2015).
    """
    if cfg.optimizer == "rmsprop":
        return optax.rmsprop(
            cfg.learning_rate,
            decay=cfg.rho,
            eps=cfg.eps,
            eps_in_sqrt=False,
            momentum=cfg.momentum if cfg.momentum > 0 else None,
        )
    return optax.adam(cfg.learning_rate, b1=cfg.b1, b2=cfg.b2, eps=cfg.eps)


# ---------------------------------------------------------------- losses


def slotv_loss(
    model: models.SlotV, xyz, goals, goal_mask, labels, *, backward: str = "fused"
) -> Float[Array, ""]:
    """Mean over the batch of  −Σ_k y_k (s_k − logsumexp_{real j} s_j)  (:ref:`concepts-slotv`)."""
    return _cross_entropy(model.scores(xyz, goals, backward=backward), goal_mask, labels)


def observer_loss(model, xyz, goals, goal_mask, labels) -> Float[Array, ""]:
    """:ref:`concepts-slotv`'s cross-entropy for any observer with ``scores(xyz, goals, goal_mask)``
    (finite per-goal scores, e.g. the archetypes of :mod:`slotv_jax.observers.parametric`): batch
    mean
    of −Σ_k y_k log softmax_k(s) over the real goals."""
    return _cross_entropy(model.scores(xyz, goals, goal_mask), goal_mask, labels)


def _cross_entropy(s, goal_mask, labels) -> Float[Array, ""]:
    """Batch mean of −Σ_k y_k log softmax_k(s) over the real goals of (B, G) scores."""
    lse = jax.nn.logsumexp(models.mask_logits(s, goal_mask), axis=-1, keepdims=True)
    ce = -jnp.sum(jnp.where(goal_mask, labels * (s - lse), 0.0), axis=-1)
    return ce.mean()


def slotv_loss_packed(
    model: models.SlotV,
    xyz,
    goals,
    goal_mask,
    labels,
    *,
    capacity: int,
    backward: str = "fused",
    shard=lambda x: x,
) -> Float[Array, ""]:
    """:func:`slotv_loss` computed on the batch's real (trajectory, goal) pairs only.

    The real slots of the (B, G) batch are listed in order (``jnp.nonzero`` with a static
    ``capacity``, padded with invalid pairs), V is integrated along each pair's trajectory
    as a one-goal grid, and the scores are put back into their (B, G) slots: the network
    runs on ``capacity`` pairs instead of B·G slots. ``capacity`` must be at least the
    number of real pairs of every batch (:meth:`Trainer.pair_capacity` counts them exactly
    before training); pairs beyond it would be dropped.
    """
    b_size, g = goal_mask.shape
    flat = jnp.nonzero(goal_mask.reshape(-1), size=capacity, fill_value=0)[0]
    valid = shard(jnp.arange(capacity) < goal_mask.sum())
    b, k = shard(flat // g), shard(flat % g)
    pair_xyz = shard(xyz[b])  # (C, T, 3)
    pair_goal = shard(goals[b, k])[:, None, :]  # (C, 1, 3)
    sp = model.scores(pair_xyz, pair_goal, backward=backward)[:, 0]  # (C,)
    s = jnp.zeros((b_size, g), sp.dtype).at[b, k].add(jnp.where(valid, sp, 0.0))
    return _cross_entropy(s, goal_mask, labels)


def trex_loss(model: models.TRex, xyz, goal, label, *, backward: str = "fused") -> Float[Array, ""]:
    """Mean over pairs of the BCE on σ(R₂ − R₁) (:ref:`concepts-trex`).

    xyz (B, 2, T, 3), goal (B, 2, 3), label (B,) in {0, 1}.
    """
    ret = model.scores(xyz, goal[..., None, :], backward=backward)[..., 0]  # (B, 2)
    d = ret[:, 1] - ret[:, 0]
    return jnp.mean(label * jax.nn.softplus(-d) + (1.0 - label) * jax.nn.softplus(d))
