"""The four hand-crafted legibility labelers (:ref:`concepts-labelers`,
:ref:`concepts-public-names`) under their public name.

The code lives in :mod:`slotv_jax.observers.labelers` (one trajectory) and
:mod:`slotv_jax.observers.labelling` (many at once); this package keeps the public names
of :ref:`concepts-public-names` and holds the command line ``python -m slotv_jax.labelers``
(:mod:`.cli`).
"""

from slotv_jax.observers.labelers import (
    CHUNK_LABELS,
    DEFAULT_BETAS,
    DEPTH_EPS,
    LABELER_NAMES,
    LABELERS,
    TimeWeights,
    depth_ok,
    dragan,
    effdist,
    fastapp,
    nikolaidis,
)
from slotv_jax.observers.labelling import (
    label_all,
)

__all__ = [
    "CHUNK_LABELS",
    "DEFAULT_BETAS",
    "DEPTH_EPS",
    "LABELERS",
    "LABELER_NAMES",
    "TimeWeights",
    "depth_ok",
    "dragan",
    "effdist",
    "fastapp",
    "label_all",
    "nikolaidis",
]
