"""Dataset configs: the split names, the labelers and their temperatures, sizes and
distributions of the seven splits (:ref:`concepts-datasets`), presets.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np

from slotv_jax.core.defaults import BETAS_V1
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers.labelling import LabelConfig
from slotv_jax.robot import kinematics
from slotv_jax.world.scene import SceneConfig
from slotv_jax.world.trajectories import DISTRIBUTIONS, TrajectoryConfig

# Bump when generation code changes what a config produces, so cached datasets are not reused.
GENERATOR_VERSION = 10  # 2: IK locks joints at their limits; 3: home TCP by one compiled call;
# 4: labels from the coordinate-major labelling kernel (equal up to float32 rounding);
# 5: the trajectory distribution chosen by the fidelity ablation (trajectories.DISTRIBUTIONS);
# 6: labels from the public per-trajectory labelers under vmap (equal up to float32 rounding);
# 7: via points of the default distribution in the table box (trajectories.TABLE_VIA_BOX);
# 8: nikolaidis in homogeneous image coordinates (labels within 3e-7 of version 7's)
# 9: the arm's kinematics as the MJCF's chain, not mjx.kinematics (poses within 2e-6)
# 10: the scene's cameras and the home TCP from MuJoCo C (both within one float32 ulp)


# ----------------------------------------------------------------------- config


#: The first version's label temperatures (:data:`slotv_jax.core.defaults.BETAS_V1`).
LABELS_V1 = LabelConfig(**{f"beta_{n}": b for n, b in BETAS_V1.items()})
#: Named dataset distributions: trajectories and label temperatures together. ``default`` is
#: the one chosen by the fidelity ablation; ``spec_v1`` the first version's (3–5 via points,
#: the SPEC's β), kept to reproduce earlier results.
DATA_DISTRIBUTIONS = {
    "default": (DISTRIBUTIONS["default"], LabelConfig()),
    "spec_v1": (DISTRIBUTIONS["spec_v1"], LABELS_V1),
}


def with_distribution(cfg: DataConfig, name: str) -> DataConfig:
    """``cfg`` with the trajectories and label temperatures of a named distribution."""
    if name not in DATA_DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {tuple(DATA_DISTRIBUTIONS)}, got {name!r}")
    traj, labels = DATA_DISTRIBUTIONS[name]
    return dataclasses.replace(cfg, trajectory=traj, labels=labels)


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """Sizes and distributions of the seven splits."""

    preset: str = "quick"
    seed: int = 0
    n_train: int = 20_000  # trajectories in the train split
    n_eval: int = 2_000  # trajectories in each val/test split
    n_train_scenes: int = 250  # scenes shared by train, trajectory_val and trajectory_test
    n_new_scenes: int = 10  # scenes of each position_* and goal_count_* split
    train_goal_counts: tuple[int, ...] = (2, 3, 5, 6)
    goal_count_val_counts: tuple[int, ...] = (7,)
    goal_count_test_counts: tuple[int, ...] = (4, 8)
    scene: SceneConfig = dataclasses.field(default_factory=SceneConfig)
    trajectory: TrajectoryConfig = dataclasses.field(default_factory=TrajectoryConfig)
    labels: LabelConfig = dataclasses.field(default_factory=LabelConfig)
    chunk_size: int = 2048  # trajectories generated per compiled call

    def __post_init__(self):
        for f in ("n_train", "n_eval", "n_train_scenes", "n_new_scenes", "chunk_size"):
            v = getattr(self, f)
            if not isinstance(v, int | np.integer) or v <= 0:
                raise ValueError(f"DataConfig.{f}: expected a positive integer, got {v!r}")
        for f in ("train_goal_counts", "goal_count_val_counts", "goal_count_test_counts"):
            counts = getattr(self, f)
            if not counts or any(not 1 <= int(c) <= G_MAX for c in counts):
                raise ValueError(
                    f"DataConfig.{f}: expected goal counts in 1..{G_MAX}, got {counts!r}"
                )
        if not isinstance(self.labels, LabelConfig) or not isinstance(self.labels.camera, str):
            raise ValueError(
                "DataConfig.labels: expected a LabelConfig with a camera name (a dataset's "
                f"config is stored as JSON), got {self.labels!r}"
            )

    def split_size(self, name: str) -> int:
        return self.n_train if name == "train" else self.n_eval

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    def digest(self) -> str:
        """Short hash of the config and generator version: equal digests, identical datasets."""
        blob = json.dumps([GENERATOR_VERSION, self.to_json()], sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:16]


def quick(**overrides) -> DataConfig:
    """The CPU-sized preset: every split and scene count, fewer trajectories."""
    return DataConfig(**{"preset": "quick", "n_train": 20_000, "n_eval": 2_000, **overrides})


def paper(**overrides) -> DataConfig:
    """The paper's sizes: 100,000 train and 10,000 per val/test split."""
    return DataConfig(**{"preset": "paper", "n_train": 100_000, "n_eval": 10_000, **overrides})


PRESETS = {"quick": quick, "paper": paper}


def config_for(
    preset: str,
    *,
    distribution: str = "default",
    labels: dict | None = None,
    **overrides,
) -> DataConfig:
    """The config that ``python -m slotv_jax.data`` builds from its options: a preset, a
    named distribution (trajectories and label temperatures), label overrides
    (``{"beta_dragan": 3.0, "camera": ...}``) and other fields (``seed``, ``n_train``, ...)."""
    if preset not in PRESETS:
        raise ValueError(f"preset: expected one of {sorted(PRESETS)}, got {preset!r}")
    if distribution not in DATA_DISTRIBUTIONS:
        raise ValueError(
            f"distribution: expected one of {sorted(DATA_DISTRIBUTIONS)}, got {distribution!r}"
        )
    traj, label_cfg = DATA_DISTRIBUTIONS[distribution]
    if labels:
        label_cfg = dataclasses.replace(label_cfg, **labels)
    return PRESETS[preset](**{"trajectory": traj, "labels": label_cfg, **overrides})


def _config_from_json(d: dict) -> DataConfig:
    """Rebuild a DataConfig from its JSON form."""
    d = dict(d)
    d["scene"] = SceneConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in d["scene"].items()}
    )
    tr = dict(d["trajectory"])
    tr["ik"] = kinematics.IKConfig(**tr["ik"])
    d["trajectory"] = TrajectoryConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in tr.items()}
    )
    d["labels"] = LabelConfig(**d["labels"])
    for k in ("train_goal_counts", "goal_count_val_counts", "goal_count_test_counts"):
        d[k] = tuple(d[k])
    return DataConfig(**d)
