"""Accuracy of a learned observer (:ref:`concepts-accuracy`) and T-REX's pairwise accuracy.

Accuracy is the fraction of trajectories where the argmax of the model's masked
scores equals the argmax of the labeler's y over real goals,

    acc = (1/N) Σ_n 1[ argmax_k s_k(γ_n) = argmax_k y_k(γ_n) ],

ties going to the lowest slot index (``jnp.argmax`` returns the first maximum).
For SLOT-V s is the observer logits; for T-REX it is the per-goal return.

A split is evaluated in fixed-size chunks (:func:`chunk` pads the last one and
marks the padding invalid), scanned inside one compiled function, with each
chunk's batch axis sharded over the devices of the training mesh.

>>> import jax.numpy as jnp
>>> mask = jnp.array([True, True, True] + [False] * 5)
>>> int(predict(jnp.array([1.0, 3.0, 3.0, 9, 9, 9, 9, 9]), mask))  # tie -> lowest, padding ignored
1
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jax.sharding import Mesh
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import models
from slotv_jax.training import devices
from slotv_jax.training.config import TrainConfig
from slotv_jax.training.types import EvalData, TrainData, prepare, subset, trim_goals

__all__ = [
    "EvalData",
    "accuracy",
    "chunk",
    "chunked_accuracy",
    "chunked_pairwise_accuracy",
    "eval_data",
    "exact_fraction",
    "pairwise_accuracy",
    "predict",
    "split_accuracies",
    "start_accuracy",
    "target",
]


def predict(scores: Float[Array, "... 8"], goal_mask: Bool[Array, "... 8"]) -> Int[Array, "..."]:
    """argmax over real goals of the model's scores (ties: lowest index)."""
    return jnp.argmax(models.mask_logits(scores, goal_mask), axis=-1)


def target(labels: Float[Array, "... 8"], goal_mask: Bool[Array, "... 8"]) -> Int[Array, "..."]:
    """argmax over real goals of the labeler's distribution (ties: lowest index)."""
    return jnp.argmax(models.mask_logits(labels, goal_mask), axis=-1)


def chunk(data, size: int) -> EvalData:
    """Cut (N, ...) arrays with fields xyz/goals/goal_mask/labels into chunks of ``size``.

    The last chunk is padded with copies of the first trajectory, marked invalid.
    """
    n = data.xyz.shape[0]
    size = int(size)
    if size < 1 or n < 1:
        raise ValueError(f"chunk: expected n >= 1 trajectories and size >= 1, got {n}, {size}")
    m = -(-n // size)
    pad = m * size - n

    def cut(x):
        x = jnp.asarray(x)
        if pad:
            x = jnp.concatenate([x, jnp.repeat(x[:1], pad, axis=0)])
        return x.reshape(m, size, *x.shape[1:])

    valid = jnp.arange(m * size).reshape(m, size) < n
    return EvalData(cut(data.xyz), cut(data.goals), cut(data.goal_mask), cut(data.labels), valid)


def chunked_accuracy(
    model: models.Model, ev: EvalData, *, shard: Callable[[Array], Array] = lambda x: x
) -> Float[Array, ""]:
    """:ref:`concepts-accuracy` accuracy of ``model`` over all valid trajectories of ``ev`` (pure;
    jit it).

    ``shard`` constrains each chunk's batch axis (the training mesh's data axis).
    """

    def body(correct, xs):
        xyz, goals, goal_mask, labels, valid = (shard(x) for x in xs)
        hit = predict(model(xyz, goals, goal_mask), goal_mask) == target(labels, goal_mask)
        return correct + jnp.sum(hit & valid), None

    correct, _ = jax.lax.scan(body, jnp.zeros((), jnp.int32), ev)
    return correct / jnp.sum(ev.valid)


def chunked_pairwise_accuracy(
    model: models.Model, data, key: jax.Array, n_chunks: int, chunk_size: int, *, shard=lambda x: x
) -> Float[Array, ""]:
    """Fraction of :ref:`concepts-trex` pairs (drawn fresh from ``key``) whose order the model gets
    right: 1[R(γ₂, g_{k₂}) > R(γ₁, g_{k₁})] = ℓ. Pure; for T-REX it is the training objective's
    accuracy, for SLOT-V the same test on its per-goal scores."""

    def body(correct, k):
        idx, slot, label = models.sample_trex_pairs(k, data.goal_mask, data.labels, chunk_size)
        xyz = shard(data.xyz[idx])  # (C, 2, T, 3)
        goal = shard(data.goals[idx, slot])  # (C, 2, 3)
        r = model.scores(xyz, goal[..., None, :])[..., 0]  # (C, 2)
        return correct + jnp.sum((r[:, 1] > r[:, 0]) == (shard(label) > 0.5)), None

    correct, _ = jax.lax.scan(body, jnp.zeros((), jnp.int32), jax.random.split(key, n_chunks))
    return correct / (n_chunks * chunk_size)


def eval_data(cfg: TrainConfig, mesh: Mesh, data: TrainData, size: int | None = None) -> EvalData:
    """The first ``size`` (default ``cfg.eval_size``) trajectories of ``data``, chunked for
    ``mesh``: chunks of :meth:`~slotv_jax.training.config.TrainConfig.eval_chunk_size` trajectories
    (at most ``size`` rounded up to the data-axis size)."""
    n = cfg.eval_size if size is None else size
    n_data = devices.data_size(mesh)
    c = cfg.eval_chunk_size(n_data, data.goals.shape[-2], data.xyz.shape[1], devices.platform(mesh))
    return chunk(subset(data, n), min(c, -(-n // n_data) * n_data))


# ---------------------------------------------------------------- convenience (entry points)


def _batched(cfg: TrainConfig, params) -> bool:
    """True if ``params`` has a leading trial axis relative to the model's parameters."""
    _, abstract = nnx.split(nnx.eval_shape(lambda: models.make_model(cfg, nnx.Rngs(0))))
    ref = jax.tree.leaves(abstract)[0]
    got = jax.tree.leaves(params)[0]
    if got.shape == ref.shape:
        return False
    if got.shape[1:] == ref.shape:
        return True
    raise ValueError(
        f"params: leaf shape {got.shape} does not fit the config's model ({ref.shape}; "
        f"hidden={cfg.hidden})"
    )


@functools.cache
def _jit_accuracy(cfg: TrainConfig, mesh: Mesh, batched: bool):
    graphdef = models.graphdef(cfg)

    def f(params, ev):
        model = nnx.merge(graphdef, params)
        return chunked_accuracy(model, ev, shard=functools.partial(devices.shard_batch, mesh))

    return jax.jit(jax.vmap(f, in_axes=(0, None)) if batched else f)


def accuracy(cfg, params, data, labeler: str | None = None, *, mesh=None) -> np.ndarray:
    """:ref:`concepts-accuracy` accuracy of ``params`` on a whole split (jit-compiled, chunked,
    sharded).

    ``data`` is a :class:`slotv_jax.training.types.TrainData` or a ``Split`` with ``labeler``. Goal
    slots that no trajectory of ``data`` uses are cut first (they cannot change an argmax over real
    goals). ``params`` may carry a leading trial axis (from
    :func:`slotv_jax.training.trainer.train_trials`): then the result has shape (n_trials,), else it
    is a scalar array. The result is the exact fraction correct / N in float64: the kernel's float32
    ratio, whose last bit depends on how XLA compiled the division, is rounded back to its count
    (:func:`exact_fraction`). ``mesh`` defaults to :func:`slotv_jax.training.devices.make_mesh` of
    the batch size.
    """
    return exact_fraction(*start_accuracy(cfg, params, data, labeler, mesh=mesh))


def start_accuracy(
    cfg, params, data, labeler: str | None = None, *, mesh=None
) -> tuple[jax.Array, int]:
    """:func:`accuracy` without waiting for the device: the float32 ratio as a (possibly
    still running) device array, and N. Lets a caller dispatch work to several devices
    before reading any result back (:func:`exact_fraction` finishes it)."""
    if labeler is not None:
        data = prepare(data, labeler)
    mesh = devices.make_mesh(cfg.batch_size) if mesh is None else mesh
    n = data.xyz.shape[0]
    ev = devices.replicate(mesh, eval_data(cfg, mesh, trim_goals(data), size=n))
    batched = _batched(cfg, params)
    if batched and jax.tree.leaves(params)[0].shape[0] == 1:  # one trial: no vmap
        ratio = _jit_accuracy(cfg, mesh, False)(jax.tree.map(lambda x: x[0], params), ev)[None]
    else:
        ratio = _jit_accuracy(cfg, mesh, batched)(params, ev)
    return ratio, n


def exact_fraction(ratio, n: int) -> np.ndarray:
    """The float32 ratio correct / ``n`` of a compiled accuracy, rounded back to its count
    and returned as the exact fraction in float64 (waits for ``ratio``)."""
    return np.round(np.asarray(ratio).astype(np.float64) * n) / n


def split_accuracies(
    cfg, params, splits: Mapping[str, object], labeler: str, *, mesh=None
) -> dict[str, np.ndarray]:
    """:func:`accuracy` on each named split (``Split`` objects), keyed by split name."""
    return {name: accuracy(cfg, params, s, labeler, mesh=mesh) for name, s in splits.items()}


@functools.cache
def _jit_pairwise(cfg: TrainConfig, mesh: Mesh, batched: bool, n_chunks: int, chunk_size: int):
    graphdef = models.graphdef(cfg)
    shard = functools.partial(devices.shard_batch, mesh)

    def f(params, data, key):
        model = nnx.merge(graphdef, params)
        return chunked_pairwise_accuracy(model, data, key, n_chunks, chunk_size, shard=shard)

    return jax.jit(jax.vmap(f, in_axes=(0, None, None)) if batched else f)


def pairwise_accuracy(
    cfg, params, data, labeler: str | None = None, *, key=None, n_pairs: int = 10_000, mesh=None
) -> np.ndarray:
    """T-REX's diagnostic: accuracy of ordering ``n_pairs`` :ref:`concepts-trex` pairs of ``data``
    (rounded up to whole chunks). Same trial-axis convention as :func:`accuracy`."""
    if labeler is not None:
        data = prepare(data, labeler)
    mesh = devices.make_mesh(cfg.batch_size) if mesh is None else mesh
    size = cfg.eval_chunk_size(mesh.size, 1, data.xyz.shape[1], devices.platform(mesh)) * 2
    size = min(size, -(-n_pairs // mesh.size) * mesh.size)
    n_chunks = -(-n_pairs // size)
    key = jax.random.key(0) if key is None else key
    f = _jit_pairwise(cfg, mesh, _batched(cfg, params), n_chunks, size)
    return np.asarray(f(params, devices.replicate(mesh, data), key))
