"""The one table of names and default temperatures shared by every module and command.

- :data:`LABELER_NAMES`: the four hand-crafted labelers, in the order of :ref:`concepts-labelers`.
- :data:`SPLITS`: the seven dataset splits of :ref:`concepts-datasets`; :data:`TEST_SPLITS`: the
  four an accuracy table reports (train and the three held-out test splits,
  :ref:`concepts-public-names`).
- :data:`DEFAULT_BETAS`: the inverse temperature of each labeler where none is given
  (:ref:`concepts-temperatures`, "Default temperatures"): the public labelers, the datasets, the
  labelers' command line, the oracle planners and the scoring of plans all take it from here, so
  that a label computed anywhere without β equals the dataset's. The values are the ones
  the fidelity ablation chose for the datasets (``experiments/fidelity.md``).
- :data:`BETAS_V1`: the first version's temperatures, kept as the ``spec_v1``
  distribution (:data:`slotv_jax.data.DATA_DISTRIBUTIONS`).

Both tables are read-only mappings ``{labeler: β}``.

>>> DEFAULT_BETAS["dragan"], BETAS_V1["nikolaidis"]
(20.0, 7.5)
>>> tuple(DEFAULT_BETAS) == LABELER_NAMES
True
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

__all__ = ["BETAS_V1", "DEFAULT_BETAS", "LABELER_NAMES", "SPLITS", "TEST_SPLITS"]

LABELER_NAMES: tuple[str, ...] = ("dragan", "nikolaidis", "effdist", "fastapp")

SPLITS: tuple[str, ...] = (
    "train",
    "trajectory_val",
    "trajectory_test",
    "position_val",
    "position_test",
    "goal_count_val",
    "goal_count_test",
)
TEST_SPLITS: tuple[str, ...] = ("train", "trajectory_test", "position_test", "goal_count_test")

#: dragan, effdist, fastapp: per metre; nikolaidis: per unit of image plane **[choice]**.
DEFAULT_BETAS: Mapping[str, float] = MappingProxyType(
    {"dragan": 20.0, "nikolaidis": 30.0, "effdist": 20.0, "fastapp": 20.0}
)
#: The first version's temperatures (the ``spec_v1`` distribution).
BETAS_V1: Mapping[str, float] = MappingProxyType(
    {"dragan": 5.0, "nikolaidis": 7.5, "effdist": 5.0, "fastapp": 5.0}
)
