"""Data parallelism over a 1-D device mesh, shared by training and evaluation.

The batch axis of every update (and every evaluation chunk) is sharded over the
mesh's ``"data"`` axis through ``with_sharding_constraint`` under ``jit``;
parameters and the dataset are replicated, and XLA inserts the gradient
all-reduce. The same code runs on 1 CPU, 1 GPU or N GPUs. A mesh may also have a
``"trial"`` axis for independent runs (:mod:`slotv_jax.training.parallel`).

>>> mesh = make_mesh(32)
>>> data_size(mesh) >= 1, platform(mesh) in ("cpu", "gpu", "tpu")
(True, True)
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P


def make_mesh(batch_size: int, devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D ('data',) mesh over the largest number of devices that divides ``batch_size``."""
    devices = list(jax.local_devices() if devices is None else devices)
    n = max(d for d in range(1, len(devices) + 1) if batch_size % d == 0)
    return Mesh(np.array(devices[:n]), ("data",))


def shard_batch(mesh: Mesh, x: jax.Array) -> jax.Array:
    """Constrain the leading (batch) axis of ``x`` to the mesh's "data" axis (under jit)."""
    return jax.lax.with_sharding_constraint(x, NamedSharding(mesh, P("data")))


def replicate(mesh: Mesh, tree):
    """Place arrays (e.g. a TrainData) on every device of the mesh."""
    return jax.device_put(tree, NamedSharding(mesh, P()))


def data_size(mesh: Mesh) -> int:
    """Devices the batch axis is split over: the size of the mesh's "data" axis."""
    return int(mesh.shape["data"])


def platform(mesh: Mesh) -> str:
    """The platform of the mesh's devices ("cpu", "gpu", …)."""
    return mesh.devices.flat[0].platform
