"""The settings that experiments share: the labelers, methods and splits of an accuracy table
with their titles, and the run presets (dataset config, training config per method, trials)
with their variants.
"""

from __future__ import annotations

import dataclasses

from slotv_jax.data import config as data_config
from slotv_jax.training import config as train_config

METHODS = train_config.METHODS
SPLIT_TITLES = {
    "train": "train",
    "trajectory_test": "trajectory",
    "position_test": "position",
    "goal_count_test": "goal count",
}
LABELER_TITLES = {
    "dragan": "Dragan",
    "effdist": "EffDist",
    "fastapp": "FastApp",
    "nikolaidis": "Nikolaidis",
}
METHOD_TITLES = {"slotv": "SLOT-V", "trex": "T-REX"}


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """What one Table 1 run does."""

    preset: str
    trials: int
    data: data_config.DataConfig
    train: dict[str, train_config.TrainConfig]  # method -> training config

    def to_json(self) -> dict:
        return {
            "preset": self.preset,
            "trials": self.trials,
            "data": self.data.to_json(),
            "data_digest": self.data.digest(),
            "train": {m: c.to_dict() for m, c in self.train.items()},
        }


def quick() -> RunConfig:
    """CPU preset: quick data, small networks, 2 trials **[choice]**."""
    return RunConfig("quick", 2, data_config.quick(), {m: train_config.quick(m) for m in METHODS})


def paper() -> RunConfig:
    """The paper's sizes and hyperparameters, 10 trials."""
    return RunConfig("paper", 10, data_config.paper(), {m: train_config.paper(m) for m in METHODS})


def tiny() -> RunConfig:
    """A seconds-scale preset for tests and smoke runs (not a result)."""
    d = data_config.DataConfig(
        preset="tiny", n_train=300, n_eval=100, n_train_scenes=20, n_new_scenes=4, chunk_size=512
    )
    t = {
        "slotv": train_config.quick("slotv", hidden=(32, 16), epochs=2, train_size=None),
        "trex": train_config.quick("trex", hidden=(32, 16), epochs=2, train_size=None),
    }
    return RunConfig("tiny", 2, d, t)


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


def with_model(cfg: RunConfig, model: str) -> RunConfig:
    """The same run with SLOT-V's network replaced by an observer archetype
    (:ref:`concepts-archetypes`,
    :func:`slotv_jax.training.config.archetype` of the matching preset; the tiny preset trains it
    2 epochs on all its data, as its MLP). T-REX keeps its network. ``"mlp"``: ``cfg``."""
    if model == "mlp":
        return cfg
    if cfg.preset == "tiny":
        tc = train_config.archetype("quick", model, epochs=2, train_size=None)
    else:
        tc = train_config.archetype("paper" if cfg.preset == "paper" else "quick", model)
    return dataclasses.replace(cfg, train={**cfg.train, "slotv": tc})


def plus(cfg: train_config.TrainConfig) -> train_config.TrainConfig:
    """SLOT-V+ (or T-REX+) of a network's config: the same network with values relative to
    the start's and learned time weights (``start_term``, ``time_weight``:
    :class:`slotv_jax.observers.models.SlotV`), the form a planner cannot exploit the way it
    exploits the paper's score (``experiments/planning_paper.md``)."""
    return dataclasses.replace(cfg, start_term=True, time_weight=True)


def _train_key(config_doc: dict) -> dict:
    """The training configs of a results document, rebuilt through TrainConfig (so that
    documents written before a field existed compare equal to their defaults)."""
    return {
        m: train_config.TrainConfig.from_dict(c).to_dict()
        for m, c in config_doc.get("train", {}).items()
    }


def with_compute_dtype(cfg: RunConfig, dtype: str) -> RunConfig:
    """The same run with the hidden matmuls in ``dtype`` (parameters stay float32)."""
    train = {m: dataclasses.replace(c, compute_dtype=dtype) for m, c in cfg.train.items()}
    return dataclasses.replace(cfg, train=train)
