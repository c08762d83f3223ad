"""Which units of work run together: groups of independent runs over the devices, and the
(trial, data) mesh of one group.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import jax
import numpy as np
from jax.sharding import Mesh

TRIAL = "trial"  # mesh axis of independent runs
DATA = "data"  # mesh axis of one run's minibatch (train.Trainer shards over it)
U = TypeVar("U")


# ---------------------------------------------------------------- groups


def group_sizes(n_units: int, n_devices: int) -> list[tuple[int, int]]:
    """(units, trial-axis size t) of each group that runs ``n_units`` on ``n_devices``.

    Groups of t = N while N or more units are left; the last k < N as one group with t the
    smallest divisor of N that is ≥ k (its batch axis then spans d = N / t devices). One
    device: one unit per group.

    >>> group_sizes(10, 4), group_sizes(1, 4), group_sizes(3, 1)
    ([(4, 4), (4, 4), (2, 2)], [(1, 1)], [(1, 1), (1, 1), (1, 1)])
    """
    if n_units < 0 or n_devices < 1:
        raise ValueError(
            f"group_sizes: expected n_units >= 0 and n_devices >= 1, got {n_units}, {n_devices}"
        )
    full, rest = divmod(n_units, n_devices)
    out = [(n_devices, n_devices)] * full
    if rest:
        out.append((rest, min(t for t in range(rest, n_devices + 1) if n_devices % t == 0)))
    return out


def groups(units: Sequence[U], n_devices: int) -> list[tuple[list[U], int]]:
    """``units`` cut into the groups of :func:`group_sizes`, in order: (units, trial-axis size)."""
    out, i = [], 0
    for k, t in group_sizes(len(units), n_devices):
        out.append((list(units[i : i + k]), t))
        i += k
    return out


def unit_mesh(t: int, batch_size: int, devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A ("trial", "data") mesh of shape (t, d) over ``devices`` (default: every process's).

    d = N / t, lowered to the largest divisor of ``batch_size`` (the minibatch is split
    evenly over "data"); devices left over stay idle. Rows are consecutive devices, so a
    run's batch axis stays on one host where it can.
    """
    devices = list(jax.devices() if devices is None else devices)
    if t < 1 or len(devices) % t:
        raise ValueError(f"t: expected a divisor of the {len(devices)} devices, got {t}")
    d = len(devices) // t
    d = max(k for k in range(1, d + 1) if batch_size % k == 0)
    return Mesh(np.array(devices[: t * d]).reshape(t, d), (TRIAL, DATA))
