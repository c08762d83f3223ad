"""The seven dataset splits of SPEC §7: generation, labelling, storage and loading.

========================  ====================  ===========  ===================
split                     scenes                goal counts  trajectories (paper)
========================  ====================  ===========  ===================
train                     250 training scenes   {2,3,5,6}    100,000
trajectory_val / _test    the same 250          {2,3,5,6}    10,000 each
position_val / _test      10 new scenes each    {2,3,5,6}    10,000 each
goal_count_val            10 new scenes         {7}          10,000
goal_count_test           10 new scenes         {4,8}        10,000
========================  ====================  ===========  ===================

Determinism: candidate ``i`` of a split draws from ``fold_in(split_key, i)``;
the split keeps the first ``n`` accepted candidates in index order. The same
seed and config give bitwise identical splits, also across restarts. The draws
(scenes, targets, via points) do not depend on the chunk size either; the
floating-point results of another chunk size agree to float32 rounding, since
XLA compiles each batch shape on its own.
Scenes are drawn the same way, and a scene is kept only if IK reaches every one
of its goals within the residual limit.

Storage: ``DIR/<split>.npz`` (plain arrays, read with ``allow_pickle=False``) and
``DIR/<split>.json`` (config, seed, versions, per-array SHA-256, shapes,
reachability statistics, timings). Both are written to a temporary name and
renamed; the JSON is written last, so a split counts as done only once both
exist, and an interrupted run restarts at the first unfinished split.

Command line::

    python -m slotv_jax.data --preset quick --out data/quick
    python -m slotv_jax.data --relabel --out data/quick --beta-dragan 3.0
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import sys
import time
import zipfile
from collections.abc import Sequence
from pathlib import Path

import flax
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import optax
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import cli, fileio, kinematics, validation
from slotv_jax.defaults import BETAS_V1, DEFAULT_BETAS, LABELER_NAMES, SPLITS
from slotv_jax.fileio import atomic_write
from slotv_jax.labelers import label_all
from slotv_jax.scene import Scene, SceneConfig, check_scene, sample_goal_count, sample_scene
from slotv_jax.trajectories import DISTRIBUTIONS, TrajectoryConfig, plan_path, straight_path
from slotv_jax.validation import G_MAX

FORMAT_VERSION = 1
# Bump when generation code changes what a config produces, so cached datasets are not reused.
GENERATOR_VERSION = 8  # 2: IK locks joints at their limits; 3: home TCP by one compiled call;
# 4: labels from the coordinate-major labelling kernel (equal up to float32 rounding);
# 5: the trajectory distribution chosen by the fidelity ablation (trajectories.DISTRIBUTIONS);
# 6: labels from the public per-trajectory labelers under vmap (equal up to float32 rounding);
# 7: via points of the default distribution in the table box (trajectories.TABLE_VIA_BOX);
# 8: nikolaidis in homogeneous image coordinates (labels within 3e-7 of version 7's)

# Arrays stored per split: name -> (dtype, shape with "N", "S", "T" symbols).
_TRAJ_ARRAYS = {
    "xyz": (np.float32, ("N", "T", 3)),
    "q": (np.float32, ("N", "T", 7)),
    "target": (np.int32, ("N",)),
    "env_id": (np.int32, ("N",)),
    "n_via": (np.int32, ("N",)),
    "residual": (np.float32, ("N",)),
}
_SCENE_ARRAYS = {
    "scene_goals": (np.float32, ("S", G_MAX, 3)),
    "scene_mask": (np.bool_, ("S", G_MAX)),
}
_LABEL_ARRAYS = {f"y_{n}": (np.float32, ("N", G_MAX)) for n in LABELER_NAMES}


# ----------------------------------------------------------------------- config


@dataclasses.dataclass(frozen=True)
class LabelConfig:
    """Inverse temperatures of the four labelers (SPEC §4) and the Nikolaidis camera.

    The defaults are :data:`slotv_jax.defaults.DEFAULT_BETAS`, the labelers' own: four
    times the first version's (5, 7.5, 5 and 5). The paper does not state its
    temperatures, and at ×4 T-REX's accuracy on Dragan labels matches the paper's while
    SLOT-V's does not move (``experiments/fidelity.md``). :data:`LABELS_V1` keeps the
    first version's temperatures.
    """

    beta_dragan: float = DEFAULT_BETAS["dragan"]  # m⁻¹
    beta_nikolaidis: float = DEFAULT_BETAS["nikolaidis"]  # per unit of image-plane distance
    beta_effdist: float = DEFAULT_BETAS["effdist"]  # m⁻¹
    beta_fastapp: float = DEFAULT_BETAS["fastapp"]  # m⁻¹
    camera: str = "observer"

    def __post_init__(self):
        for n in LABELER_NAMES:
            validation.check_positive(f"LabelConfig.beta_{n}", getattr(self, f"beta_{n}"))

    def betas(self) -> dict[str, float]:
        """``{labeler: β}`` in the order of :data:`LABELER_NAMES`."""
        return {n: float(getattr(self, f"beta_{n}")) for n in LABELER_NAMES}


#: The first version's label temperatures (:data:`slotv_jax.defaults.BETAS_V1`).
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


def _scene_set(cfg: DataConfig, split: str) -> tuple[str, int, tuple[int, ...]]:
    """(scene-set name, number of scenes, goal counts) used by a split."""
    if split in ("train", "trajectory_val", "trajectory_test"):
        return "train", cfg.n_train_scenes, cfg.train_goal_counts
    if split in ("position_val", "position_test"):
        return split, cfg.n_new_scenes, cfg.train_goal_counts
    if split == "goal_count_val":
        return split, cfg.n_new_scenes, cfg.goal_count_val_counts
    if split == "goal_count_test":
        return split, cfg.n_new_scenes, cfg.goal_count_test_counts
    raise ValueError(f"split: expected one of {SPLITS}, got {split!r}")


def _stream_key(seed: int, kind: str, name: str) -> jax.Array:
    """A key per named random stream, derived from the seed and a stable hash of the name."""
    tag = int.from_bytes(hashlib.sha256(f"{kind}/{name}".encode()).digest()[:4], "little")
    return jax.random.fold_in(jax.random.key(seed), tag)


# ----------------------------------------------------------------------- Split


@dataclasses.dataclass(frozen=True)
class Split:
    """One dataset split, as NumPy arrays."""

    name: str
    xyz: np.ndarray  # (N, T, 3) float32: executed TCP path (m)
    q: np.ndarray  # (N, T, 7) float32: joint configurations (rad)
    target: np.ndarray  # (N,) int32: target goal slot
    env_id: np.ndarray  # (N,) int32: index into the scene arrays
    n_via: np.ndarray  # (N,) int32: via points of the path
    residual: np.ndarray  # (N,) float32: worst IK residual of the path (m)
    scene_goals: np.ndarray  # (S, 8, 3) float32: goals of the split's scenes (m)
    scene_mask: np.ndarray  # (S, 8) bool: real goal slots, real goals first
    labels: dict[str, np.ndarray]  # labeler name -> (N, 8) float32 distributions
    meta: dict  # the JSON sidecar

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def goals(self) -> np.ndarray:
        """(N, 8, 3) goals of each trajectory's scene."""
        return self.scene_goals[self.env_id]

    @property
    def goal_mask(self) -> np.ndarray:
        """(N, 8) real-goal mask of each trajectory's scene."""
        return self.scene_mask[self.env_id]

    def arrays(self) -> dict[str, np.ndarray]:
        """Every stored array by its file name."""
        out = {k: getattr(self, k) for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS)}
        out.update({f"y_{k}": v for k, v in self.labels.items()})
        return out

    def subset(self, idx) -> Split:
        """The trajectories at ``idx`` (scenes kept whole)."""
        idx = np.asarray(idx)
        pick = {k: getattr(self, k)[idx] for k in _TRAJ_ARRAYS}
        return dataclasses.replace(self, **pick, labels={k: v[idx] for k, v in self.labels.items()})


# ------------------------------------------------------------------- generation


_SCENE_CHUNK = 64  # scene candidates per compiled call (one compilation for every set)


@jax.jit
def _scene_candidates_chunk(key: jax.Array, idx, counts, n_counts) -> Scene:
    def one(i):
        k = jax.random.fold_in(key, i)
        k_count, k_scene = jax.random.split(k)
        return sample_scene(k_scene, sample_goal_count(k_count, counts, n_counts))

    return jax.vmap(one)(idx)


def _scene_candidates(key: jax.Array, start: int, n: int, counts: tuple[int, ...]) -> Scene:
    """Candidates ``start … start + n − 1`` of a scene set (NumPy), in fixed-size chunks."""
    padded = np.zeros(G_MAX, np.int32)
    padded[: len(counts)] = counts
    parts = []
    for i in range(start, start + n, _SCENE_CHUNK):
        idx = jnp.arange(i, i + _SCENE_CHUNK)
        parts.append(_scene_candidates_chunk(key, idx, padded, len(counts)))
    return jax.tree.map(lambda *a: np.concatenate(a)[:n], *parts)


def sample_scene_sets(cfg: DataConfig) -> dict[str, tuple[Scene, dict]]:
    """Every scene set's scenes: per set, the first ``n`` candidates whose goals IK can all reach.

    The goals of all sets are checked together, in as few compiled chunks as possible.
    """
    sets = {}
    for split in SPLITS:
        name, n, counts = _scene_set(cfg, split)
        sets[name] = (n, counts)
    kept: dict[str, list] = {k: [] for k in sets}
    drawn = dict.fromkeys(sets, 0)
    need = {k: n for k, (n, _) in sets.items()}
    while any(need.values()):
        batch = {}
        for k in [k for k, v in need.items() if v]:
            key = _stream_key(cfg.seed, "scenes", k)
            batch[k] = _scene_candidates(key, drawn[k], need[k] + 8, sets[k][1])  # + spares
        goals = np.concatenate([b.goals[b.goal_mask] for b in batch.values()])
        res_flat = _goal_residuals(cfg, goals)
        start = 0
        for k, b in batch.items():
            res = np.zeros(b.goal_mask.shape, np.float32)
            res[b.goal_mask] = res_flat[start : start + b.goal_mask.sum()]
            start += int(b.goal_mask.sum())
            ok = np.flatnonzero(np.all(~b.goal_mask | (res <= cfg.trajectory.max_residual), -1))
            take = ok[: need[k]]
            kept[k].append(jax.tree.map(lambda a, t=take: a[t], b))
            need[k] -= len(take)
            # Count candidates up to the last one used, so the rejection rate is exact.
            drawn[k] += len(b.n_goals) if need[k] else int(take[-1]) + 1
    out = {}
    for k, parts in kept.items():
        scenes = jax.tree.map(lambda *a: np.concatenate(a), *parts)
        check_scene(scenes, cfg.scene, batched=True)
        n = sets[k][0]
        stats = {"drawn": drawn[k], "kept": n, "rejection_rate": 1 - n / drawn[k]}
        out[k] = (scenes, stats)
    return out


@functools.cache  # compiled once per config and shared by every split
def _compiled_plan(cfg: TrajectoryConfig):
    @jax.jit
    def candidates(split_key, idx, n_scenes):
        keys = jax.vmap(lambda i: jax.random.fold_in(split_key, i))(idx)
        pick = lambda k: jax.random.randint(jax.random.fold_in(k, 0), (), 0, n_scenes)  # noqa: E731
        return keys, jax.vmap(pick)(keys)

    @jax.jit
    def plan(keys, goals, goal_mask, n_goals):
        scenes = Scene(goals=goals, goal_mask=goal_mask, n_goals=n_goals)
        return jax.vmap(lambda k, s: plan_path(jax.random.fold_in(k, 1), s, cfg))(keys, scenes)

    @jax.jit
    def straight(goals):  # (C, 3) -> (C, T, 3)
        return jax.vmap(lambda g: straight_path(g, cfg.n_points))(goals)

    return candidates, plan, straight


@functools.cache  # the expensive compilation: keyed by the IK settings alone
def _compiled_path_ik(ik: kinematics.IKConfig):
    @jax.jit
    def path_ik(paths):  # (C, T, 3) -> PathIK with (C, T, ...) fields
        q0 = jnp.asarray(kinematics.Q_HOME, paths.dtype)
        return jax.vmap(lambda p: kinematics.solve_path_ik(p, q0, ik))(paths)

    return path_ik


def _goal_residuals(cfg: DataConfig, goals: np.ndarray) -> np.ndarray:
    """Worst residual of a straight home-to-goal path IK, per goal (chunked like trajectories)."""
    straight = _compiled_plan(cfg.trajectory)[2]
    path_ik = _compiled_path_ik(cfg.trajectory.ik)
    C = cfg.chunk_size
    out = []
    for i in range(0, len(goals), C):
        g = goals[i : i + C]
        pad = np.concatenate([g, np.repeat(g[-1:], C - len(g), 0)])
        ik = path_ik(straight(jnp.asarray(pad, jnp.float32)))
        out.append(np.asarray(ik.residual).max(-1)[: len(g)])
    return np.concatenate(out)


def generate_split(
    cfg: DataConfig,
    name: str,
    scenes: Scene,
    n: int | None = None,
    *,
    progress: bool = True,
    label: bool = True,
) -> Split:
    """Generate (and label) one split from its scenes, keeping the first ``n`` accepted draws."""
    n = cfg.split_size(name) if n is None else int(n)
    t0 = time.perf_counter()
    candidates, plan, _ = _compiled_plan(cfg.trajectory)
    path_ik = _compiled_path_ik(cfg.trajectory.ik)
    split_key = _stream_key(cfg.seed, "trajectories", name)
    s_goals, s_mask = np.asarray(scenes.goals), np.asarray(scenes.goal_mask)
    s_ngoals = np.asarray(scenes.n_goals)
    parts: list[dict[str, np.ndarray]] = []
    n_kept = drawn = 0
    C = cfg.chunk_size
    bar = tqdm(total=n, desc=f"{name:>16s}", unit="traj", disable=not progress, leave=False)
    while n_kept < n:
        idx = jnp.arange(drawn, drawn + C, dtype=jnp.uint32)
        keys, env = candidates(split_key, idx, s_goals.shape[0])
        env = np.asarray(env)
        target, n_via, _, paths = plan(keys, s_goals[env], s_mask[env], s_ngoals[env])
        ik = path_ik(paths)
        res = np.asarray(ik.residual).max(-1)
        ok = np.flatnonzero(res <= cfg.trajectory.max_residual)[: n - n_kept]
        parts.append(
            {
                "xyz": np.asarray(ik.xyz)[ok],
                "q": np.asarray(ik.q)[ok],
                "target": np.asarray(target)[ok],
                "env_id": env[ok],
                "n_via": np.asarray(n_via)[ok],
                "residual": res[ok],
            }
        )
        n_kept += len(ok)
        # Count candidates up to the last one used, so the rejection rate is exact.
        drawn += C if n_kept < n else int(ok[-1]) + 1 if len(ok) else C
        bar.update(len(ok))
        bar.set_postfix(rejected=f"{drawn - n_kept}")
    bar.close()
    arrays = {k: np.concatenate([p[k] for p in parts]).astype(_TRAJ_ARRAYS[k][0]) for k in parts[0]}
    t_gen = time.perf_counter() - t0
    meta = {
        "reachability": {
            "trajectories_drawn": drawn,
            "trajectories_kept": n,
            "trajectory_rejection_rate": 1 - n / drawn,
            "max_residual_m": float(arrays["residual"].max()),
        },
        "timing_s": {"trajectories": t_gen},
    }
    split = Split(
        name=name,
        **arrays,
        scene_goals=s_goals.astype(np.float32),
        scene_mask=s_mask.astype(bool),
        labels={},
        meta=meta,
    )
    return relabel(split, cfg.labels, progress=progress) if label else split


def relabel(split: Split, labels: LabelConfig, *, progress: bool = True) -> Split:
    """Recompute the four labels of a split (for example after a β change)."""
    t0 = time.perf_counter()
    y = label_all(
        split.xyz,
        split.goals,
        split.goal_mask,
        progress=progress,
        labelers=LABELER_NAMES,
        camera=labels.camera,
        **{f"beta_{n}": getattr(labels, f"beta_{n}") for n in LABELER_NAMES},
    )
    meta = json.loads(json.dumps(split.meta))
    meta.setdefault("timing_s", {})["labels"] = time.perf_counter() - t0
    meta["label_config"] = dataclasses.asdict(labels)
    return dataclasses.replace(
        split, labels={n: np.asarray(y[n], np.float32) for n in LABELER_NAMES}, meta=meta
    )


def generate_dataset(
    cfg: DataConfig,
    out: str | Path | None = None,
    *,
    splits: Sequence[str] = SPLITS,
    progress: bool = True,
) -> dict[str, Split]:
    """Generate every split; with ``out``, write each one as it finishes and skip finished ones."""
    out = Path(out) if out is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        _check_dir_config(out, cfg)
    result: dict[str, Split] = {}
    scene_sets: dict[str, tuple[Scene, dict]] | None = None
    for name in tqdm(splits, desc="splits", unit="split", disable=not progress):
        if out is not None and (out / f"{name}.json").exists():
            result[name] = load_split(out, name)
            continue
        if scene_sets is None:
            t0 = time.perf_counter()
            scene_sets = sample_scene_sets(cfg)
            for _, stats in scene_sets.values():
                stats["time_all_sets_s"] = time.perf_counter() - t0
        set_name, _, counts = _scene_set(cfg, name)
        scenes, stats = scene_sets[set_name]
        split = generate_split(cfg, name, scenes, progress=progress)
        split.meta["reachability"]["scenes"] = {"set": set_name, "goal_counts": counts, **stats}
        if out is not None:
            split = dataclasses.replace(split, meta=save_split(out, split, cfg))
        result[name] = split
    return result


def make_tiny_dataset(
    seed: int = 0,
    *,
    n_train: int = 300,
    n_eval: int = 100,
    n_train_scenes: int = 20,
    n_new_scenes: int = 4,
    splits: Sequence[str] = SPLITS,
    **overrides,
) -> dict[str, Split]:
    """A small, real, labelled dataset in memory (for tests and examples)."""
    cfg = DataConfig(
        preset="tiny",
        seed=seed,
        n_train=n_train,
        n_eval=n_eval,
        n_train_scenes=n_train_scenes,
        n_new_scenes=n_new_scenes,
        **{"chunk_size": 512, **overrides},
    )
    return generate_dataset(cfg, None, splits=splits, progress=False)


# -------------------------------------------------------------------------- I/O


def _sha256(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


def environment() -> dict:
    """Library versions and devices, recorded with every output."""
    return {
        "slotv_jax": slotv_jax.__version__,
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "mujoco": mujoco.__version__,
        "numpy": np.__version__,
        "devices": [str(d) for d in jax.devices()],
        "xla_flags": slotv_jax.XLA_CONFIG.xla_flags,
        "xla": slotv_jax.XLA_CONFIG.summary(),
    }


def _check_dir_config(out: Path, cfg: DataConfig) -> None:
    """Refuse to mix splits of different configs in one directory."""
    for p in sorted(out.glob("*.json")):
        if p.stem not in SPLITS:
            continue
        meta = _read_json(p)
        if meta.get("config_digest") != cfg.digest():
            raise ValueError(
                f"{p}: this directory holds splits of another config "
                f"(digest {meta.get('config_digest')}, requested {cfg.digest()}); "
                "use another --out directory"
            )


def save_split(out: str | Path, split: Split, cfg: DataConfig) -> dict:
    """Write ``<split>.npz`` then its ``<split>.json`` sidecar, each atomically.

    Returns the sidecar as a reader of the file sees it.
    """
    out = Path(out)
    arrays = split.arrays()
    atomic_write(out / f"{split.name}.npz", lambda f: np.savez(f, **arrays))
    meta = {
        **split.meta,
        "format_version": FORMAT_VERSION,
        "split": split.name,
        "seed": cfg.seed,
        "config": cfg.to_json(),
        "config_digest": cfg.digest(),
        "environment": environment(),
        "arrays": {
            k: {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": _sha256(a)}
            for k, a in arrays.items()
        },
    }
    blob = json.dumps(meta, indent=1, default=str).encode()
    atomic_write(out / f"{split.name}.json", lambda f: f.write(blob))
    return json.loads(blob)


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as e:
        raise FileNotFoundError(
            f"{path}: split sidecar not found (was the split generated?)"
        ) from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: corrupt JSON sidecar ({e})") from e


def load_split(directory: str | Path, name: str) -> Split:
    """Read one split and verify its arrays against the sidecar's shapes and SHA-256."""
    if name not in SPLITS:
        raise ValueError(f"name: expected one of {SPLITS}, got {name!r}")
    directory = Path(directory)
    meta = _read_json(directory / f"{name}.json")
    path = directory / f"{name}.npz"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: split arrays not found")
    expected = meta.get("arrays")
    if not isinstance(expected, dict):
        raise ValueError(f"{directory / f'{name}.json'}: sidecar has no 'arrays' table")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
        raise ValueError(f"{path}: corrupt or truncated file ({e})") from e
    if set(arrays) != set(expected):
        raise ValueError(
            f"{path}: arrays {sorted(arrays)} do not match the sidecar's {sorted(expected)}"
        )
    for k, a in arrays.items():
        e = expected[k]
        if a.dtype.str != e["dtype"] or list(a.shape) != e["shape"]:
            raise ValueError(
                f"{path}: array {k!r} is {a.dtype.str}{list(a.shape)}, "
                f"sidecar says {e['dtype']}{e['shape']}"
            )
        if _sha256(a) != e["sha256"]:
            raise ValueError(f"{path}: array {k!r} fails its SHA-256 checksum")
    _check_layout(path, arrays)
    labels = {n: arrays[f"y_{n}"] for n in LABELER_NAMES if f"y_{n}" in arrays}
    fields = {k: arrays[k] for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS)}
    return Split(name=name, **fields, labels=labels, meta=meta)


def _check_layout(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Shapes agree across arrays and match the expected layout."""
    missing = [k for k in (*_TRAJ_ARRAYS, *_SCENE_ARRAYS) if k not in arrays]
    if missing:
        raise ValueError(f"{path}: missing arrays {missing}")
    sizes = {"N": arrays["xyz"].shape[0], "S": arrays["scene_goals"].shape[0]}
    sizes["T"] = arrays["xyz"].shape[1] if arrays["xyz"].ndim == 3 else -1
    for k, (dtype, shape) in {**_TRAJ_ARRAYS, **_SCENE_ARRAYS, **_LABEL_ARRAYS}.items():
        if k not in arrays:
            continue
        want = tuple(sizes.get(s, s) for s in shape)
        if arrays[k].shape != want or arrays[k].dtype != dtype:
            raise ValueError(
                f"{path}: array {k!r} should be {np.dtype(dtype).name}{want}, "
                f"got {arrays[k].dtype.name}{arrays[k].shape}"
            )
    env = arrays["env_id"]
    if env.size and (env.min() < 0 or env.max() >= sizes["S"]):
        raise ValueError(f"{path}: env_id outside 0..{sizes['S'] - 1}")


# -------------------------------------------------------------------------- CLI


def is_dataset_dir(path: str | Path) -> bool:
    """True if ``path`` holds a split written by :func:`save_split` (its marker: a split's
    ``.json`` sidecar, or its ``.npz`` alone if a run stopped between the two)."""
    return any((Path(path) / f"{n}{x}").is_file() for n in SPLITS for x in (".json", ".npz"))


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.data", description="Generate the seven SLOT-V dataset splits."
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--splits", nargs="+", choices=SPLITS, default=list(SPLITS))
    p.add_argument("--n-train", type=int, help="override the preset's train size")
    p.add_argument("--n-eval", type=int, help="override the preset's val/test size")
    p.add_argument("--chunk-size", type=int, help="trajectories per compiled call")
    p.add_argument(
        "--distribution",
        choices=sorted(DATA_DISTRIBUTIONS),
        default="default",
        help="named trajectory distribution and label temperatures (default: the one chosen "
        "by the fidelity ablation; spec_v1: the first version's)",
    )
    p.add_argument(
        "--relabel", action="store_true", help="recompute the labels of existing splits only"
    )
    for n in LABELER_NAMES:
        p.add_argument(f"--beta-{n}", type=float, help=f"inverse temperature of {n}")
    p.add_argument("--camera", help="camera of the Nikolaidis labeler")
    args = p.parse_args(argv)
    if args.relabel and not is_dataset_dir(args.out):
        raise cli.InputError(f"--out {args.out}: holds no dataset splits to --relabel")
    # a dataset of ours is resumed (finished splits are kept); anything else is refused
    fileio.check_output_dir(args.out, ours=is_dataset_dir, resume=True)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)

    label_kw = {f"beta_{n}": getattr(args, f"beta_{n}") for n in LABELER_NAMES}
    label_kw["camera"] = args.camera
    label_kw = {k: v for k, v in label_kw.items() if v is not None}
    if args.relabel:
        for name in args.splits:
            split = load_split(args.out, name)
            cfg = _config_from_json(split.meta["config"])
            labels = dataclasses.replace(cfg.labels, **label_kw)
            cfg = dataclasses.replace(cfg, labels=labels)
            meta = {k: v for k, v in split.meta.items() if k in ("reachability", "timing_s")}
            split = relabel(dataclasses.replace(split, meta=meta), labels)
            save_split(args.out, split, cfg)
            print(f"{name}: relabelled with {dataclasses.asdict(labels)}")
        return 0

    traj, labels = DATA_DISTRIBUTIONS[args.distribution]
    overrides = {"seed": args.seed, "trajectory": traj, "labels": labels}
    if args.n_train is not None:
        overrides["n_train"] = args.n_train
    if args.n_eval is not None:
        overrides["n_eval"] = args.n_eval
    if args.chunk_size is not None:
        overrides["chunk_size"] = args.chunk_size
    if label_kw:
        overrides["labels"] = dataclasses.replace(labels, **label_kw)
    cfg = PRESETS[args.preset](**overrides)
    t0 = time.perf_counter()
    data = generate_dataset(cfg, args.out, splits=args.splits)
    dt = time.perf_counter() - t0
    for name, s in data.items():
        r = s.meta["reachability"]
        print(
            f"{name:>16s}: {len(s):>7d} trajectories, {s.scene_goals.shape[0]:>3d} scenes, "
            f"trajectory rejection {r['trajectory_rejection_rate']:.2%}, "
            f"scene rejection {r['scenes']['rejection_rate']:.2%}"
        )
    print(f"wrote {args.out} in {dt:.1f} s (config digest {cfg.digest()})")
    return 0


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


if __name__ == "__main__":
    sys.exit(main())
