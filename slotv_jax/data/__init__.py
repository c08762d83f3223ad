"""The seven dataset splits of :ref:`concepts-datasets`: configs (:mod:`.config`), generation
(:mod:`.generate`), storage (:mod:`.storage`) and the command line (:mod:`.cli`, ``python -m
slotv_jax.data``).

This package re-exports the public names of its modules, so ``slotv_jax.data.load_split``
(:ref:`concepts-public-names`) and ``slotv_jax.data.quick()`` read as before.
"""

from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.data.config import (
    DATA_DISTRIBUTIONS,
    GENERATOR_VERSION,
    LABELS_V1,
    PRESETS,
    DataConfig,
    LabelConfig,
    config_for,
    paper,
    quick,
    with_distribution,
)
from slotv_jax.data.generate import (
    cached_dataset,
    generate_dataset,
    generate_split,
    held_out_scenes,
    make_tiny_dataset,
    relabel,
    sample_scene_sets,
)
from slotv_jax.data.storage import (
    DEFAULT_CACHE,
    FORMAT_VERSION,
    Split,
    data_command,
    dataset_dir,
    find_dataset,
    is_dataset_dir,
    load_split,
    preset_dir,
    save_split,
)

__all__ = [
    "DATA_DISTRIBUTIONS",
    "DEFAULT_CACHE",
    "FORMAT_VERSION",
    "GENERATOR_VERSION",
    "LABELER_NAMES",
    "LABELS_V1",
    "PRESETS",
    "SPLITS",
    "DataConfig",
    "LabelConfig",
    "Split",
    "cached_dataset",
    "config_for",
    "data_command",
    "dataset_dir",
    "find_dataset",
    "generate_dataset",
    "generate_split",
    "held_out_scenes",
    "is_dataset_dir",
    "load_split",
    "make_tiny_dataset",
    "paper",
    "preset_dir",
    "quick",
    "relabel",
    "sample_scene_sets",
    "save_split",
    "with_distribution",
]
