"""What a result was computed with: library versions, devices and the XLA settings.

Every command and experiment stores :func:`environment` beside its results, so that a
number can be traced to the software and hardware that produced it.

>>> env = environment()  # doctest: +SKIP
>>> sorted(env)[:3]  # doctest: +SKIP
['devices', 'flax', 'jax']
"""

from __future__ import annotations

import os
import sys
from importlib import metadata

import jax
import numpy as np

from slotv_jax.core import __version__
from slotv_jax.core.xla import XLA_CONFIG


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "not installed"


def environment() -> dict:
    """Library versions and devices, recorded with every output."""
    devices = jax.devices()
    return {
        "slotv_jax": __version__,
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "flax": _version("flax"),
        "optax": _version("optax"),
        "mujoco": _version("mujoco"),
        "numpy": np.__version__,
        "devices": [str(d) for d in devices],
        "device_kind": devices[0].device_kind,
        "cpu_count": os.cpu_count(),
        "xla_flags": XLA_CONFIG.xla_flags,
        "xla": XLA_CONFIG.summary(),
    }
