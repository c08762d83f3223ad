"""The seven dataset splits of :ref:`concepts-datasets`: generation, labelling, storage and loading.

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
exist, and an interrupted run restarts at the first unfinished split. The folder is
made with its first split: a run interrupted before that leaves none.

Command line (without ``--out``: the cache folder ``data/<preset>-<digest>`` that the main job
uses, which other commands read by the preset's name, ``--data quick``)::

    python -m slotv_jax.data --preset quick
    python -m slotv_jax.data --relabel --data quick --out data/quick_dragan3 --beta-dragan 3.0
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float
from tqdm.auto import tqdm

from slotv_jax.core import distributed
from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.fileio import check_output_dir
from slotv_jax.core.validation import G_MAX
from slotv_jax.data.config import DataConfig, LabelConfig
from slotv_jax.data.storage import (
    _TRAJ_ARRAYS,
    Split,
    _check_dir_config,
    dataset_dir,
    has_split,
    is_dataset_dir,
    load_split,
    save_split,
)
from slotv_jax.observers.labelling import label_with
from slotv_jax.robot import kinematics
from slotv_jax.world.scene import Scene, check_scene, sample_goal_count, sample_scene
from slotv_jax.world.trajectories import TrajectoryConfig, plan_path, straight_path


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


def held_out_scenes(
    cfg: DataConfig, dataset: Mapping[str, Split], n: int, splits: Sequence[str]
) -> dict[str, tuple[Float[np.ndarray, "n 8 3"], Bool[np.ndarray, "n 8"]]]:
    """The first ``n`` scenes of each of ``splits`` (scene sets of new scenes, e.g.
    ``position_test``): ``{split: (goals (n, 8, 3), goal_mask (n, 8))}``.

    Beyond the ``cfg.n_new_scenes`` stored with ``dataset``, the sets are drawn further from
    the same random streams (:func:`sample_scene_sets` with ``n_new_scenes = n``): new
    scenes of the same distribution, never seen in training. Their first scenes must be the
    stored ones (RuntimeError otherwise: the dataset is not ``cfg``'s).
    """
    if n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n}")
    out = {s: (dataset[s].scene_goals, dataset[s].scene_mask) for s in splits}
    if n <= cfg.n_new_scenes:
        return {s: (g[:n], m[:n]) for s, (g, m) in out.items()}
    more = sample_scene_sets(dataclasses.replace(cfg, n_new_scenes=n))
    for s, (stored_g, stored_m) in out.items():
        scenes = more[s][0]
        g, m = np.asarray(scenes.goals, np.float32), np.asarray(scenes.goal_mask, bool)
        k = stored_g.shape[0]
        if not (np.array_equal(g[:k], stored_g) and np.array_equal(m[:k], stored_m)):
            raise RuntimeError(f"{s}: the extended scene set does not start with the stored scenes")
        out[s] = (g, m)
    return out


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
    y = label_with(labels, split.xyz, split.goals, split.goal_mask, progress=progress)
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
    """Generate every split; with ``out``, write each one as it finishes and skip finished ones.

    ``out`` is checked before any work (a place that cannot be written, a folder that is not
    a dataset, or one of another config is an error) and made only when its first split is
    written: a run interrupted before that (Ctrl-C in the first split's minutes) leaves no
    folder named like the dataset; one interrupted later leaves its finished splits, which
    the next run keeps (a split is written atomically, its sidecar last).
    """
    out = Path(out) if out is not None else None
    if out is not None:
        check_output_dir(out, ours=is_dataset_dir, resume=True, what="dataset folder")
        if out.is_dir():
            _check_dir_config(out, cfg)
    result: dict[str, Split] = {}
    scene_sets: dict[str, tuple[Scene, dict]] | None = None
    bar = tqdm(splits, desc="splits", unit="split", disable=not progress)
    for name in bar:
        if out is not None and has_split(out, name):
            result[name] = load_split(out, name)
            continue
        if scene_sets is None:  # what the bar waits for: compiling IK, checking every goal
            bar.set_postfix_str("scenes: compiling inverse kinematics, checking the goals")
            t0 = time.perf_counter()
            scene_sets = sample_scene_sets(cfg)
            bar.set_postfix_str("")
            for _, stats in scene_sets.values():
                stats["time_all_sets_s"] = time.perf_counter() - t0
        set_name, _, counts = _scene_set(cfg, name)
        scenes, stats = scene_sets[set_name]
        split = generate_split(cfg, name, scenes, progress=progress)
        split.meta["reachability"]["scenes"] = {"set": set_name, "goal_counts": counts, **stats}
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
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


def cached_dataset(
    cfg: DataConfig,
    cache: str | Path,
    *,
    splits: Sequence[str] = SPLITS,
    progress: bool = True,
) -> dict[str, Split]:
    """The ``splits`` of ``cfg`` (default all seven) from :func:`dataset_dir` ``(cache, cfg)``,
    generated and saved there on first use (:func:`generate_dataset` resumes at the first
    unfinished split). Under ``jax.distributed`` process 0 generates (or loads) first while
    the others wait at a barrier, then they load: on a shared disk the dataset is made once.

    >>> ds = cached_dataset(quick(), "data", splits=["train"])  # doctest: +SKIP
    """
    ddir = dataset_dir(cache, cfg)
    writer = distributed.is_writer()
    if not writer:
        distributed.barrier(f"dataset {ddir.name}")
    out = generate_dataset(cfg, ddir, splits=splits, progress=progress and writer)
    if writer:
        distributed.barrier(f"dataset {ddir.name}")
    return out
