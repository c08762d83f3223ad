"""Independent units of work side by side on many devices and hosts (trials, repeats, rollouts).

Table 1's trials, the sample-efficiency repeats and the hyperparameter rollouts are
independent training runs. There are two ways to give them several devices:

- **batch-parallel** (:func:`slotv_jax.training.devices.make_mesh`): one run's minibatch is
  split over a 1-D ("data",) mesh and XLA all-reduces the gradient after every update. A paper-size
  update is small (SLOT-V: 32 trajectories, 0.35 ms on one H100), so this scales poorly:
  measured on two H200s (paper preset, Dragan, bf16, one cell) 1.30× for SLOT-V and 1.45×
  for T-REX over one of them (issue 13).
- **unit-parallel** (this module): each device trains its own run. The vmapped run axis
  is sharded over a "trial" mesh axis (``jax.vmap(..., spmd_axis_name="trial")`` under
  ``jax.jit``, no ``pmap``): nothing is communicated between the runs (the compiled
  program has no collective, see tests/test_parallel.py), so N devices train N runs in
  about the time of one. More than one run per device does not help: two vmapped trials
  on one H100 took 0.398 ms per update per trial against 0.387 ms for one trial alone
  (experiments/BENCHMARKS.md, "Training"), the GPU is already busy with one.

Both are one 2-D mesh ("trial", "data") of shape (t, d) (:func:`unit_mesh`): a group of
t runs has its run axis on "trial" and each run's batch on "data".
:func:`slotv_jax.training.schedule.group_sizes` chooses the groups from the number of
pending units U and devices N:

- while at least N units are pending: groups of t = N, one run per device (d = 1);
- the last k < N units: one group with t the smallest divisor of N that is ≥ k and
  d = N / t. For k = 1 that is the batch-parallel path over all devices (1.3–1.45×
  rather than 1×); for 1 < k < N it pads the group to t runs (padding runs repeat the
  last unit and are discarded), which beats k batch-parallel runs one after another
  (k / 1.45 > 1 run-times);
- on one device every unit is its own group: the code path of a single device.

Many hosts: under :func:`initialize` (``jax.distributed.initialize``, one process per host)
the mesh spans every process's devices, so a group's runs are split across the hosts by
the same sharding; every process makes the same calls (SPMD), each feeds and computes the
shards of its own devices, and :func:`fetch` gathers the small results (accuracies) to
every process. Only process 0 writes files (:func:`is_writer`); :func:`broadcast` makes
every process agree on what is already done.

Runs that cannot share one compiled function (hyperparameter rollouts of different widths
and batch sizes) go through :func:`map_on_devices`: one unit per device, dispatched
asynchronously (JAX returns from a jitted call before the device finishes), so the host
traces and compiles the next unit while the devices run the earlier ones.

>>> from slotv_jax.training.schedule import groups
>>> groups(list("abcdefghij"), 4)  # 10 units on 4 devices
[(['a', 'b', 'c', 'd'], 4), (['e', 'f', 'g', 'h'], 4), (['i', 'j'], 2)]
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Float, Int

from slotv_jax.core.distributed import broadcast, fetch
from slotv_jax.training import evaluate, types
from slotv_jax.training import trainer as train
from slotv_jax.training.config import TrainConfig
from slotv_jax.training.schedule import TRIAL, U

# ---------------------------------------------------------------- one group of runs


def _pad(x, t: int):
    """Pad the leading axis of ``x`` to ``t`` by repeating its last row."""
    k = len(x)
    if k == t:
        return x
    return np.concatenate([np.asarray(x), np.repeat(np.asarray(x)[-1:], t - k, axis=0)])


@functools.cache
def _jit_group(trainer: train.Trainer, per_unit_labels: bool, vmapped: bool):
    def train_run(seed, data, val):
        return trainer.train(jax.random.key(seed), data, val)

    if not vmapped:
        return jax.jit(train_run)
    data_axes = types.TrainData(None, None, None, 0 if per_unit_labels else None)
    return jax.jit(jax.vmap(train_run, in_axes=(0, data_axes, None), spmd_axis_name=TRIAL))


def train_group(
    cfg: TrainConfig,
    data: types.TrainData,
    seeds: Sequence[int],
    mesh: Mesh,
    *,
    labels: Float[Array, "U N 8"] | None = None,
    val: types.TrainData | None = None,
    progress: bool = False,
) -> tuple[types.TrainState, types.Metrics]:
    """Train one run per seed side by side, the run axis sharded over ``mesh``'s "trial" axis.

    Run i is ``trainer.train(jax.random.key(seeds[i]), data_i, val)`` of
    :func:`slotv_jax.training.trainer.train_trials`, with ``data_i`` = ``data`` whose labels are
    ``labels[i]`` when given (several labelers' runs in one group: the trajectories are
    shared). The run axis is padded to a multiple of t = mesh.shape["trial"] (the padding
    runs repeat the last seed and are dropped), so each device row holds the same number of
    runs (:func:`slotv_jax.training.schedule.group_sizes`: one). Returns states and metrics
    with that padded leading axis, sharded over "trial": entry i < len(seeds) is run i.
    (Cutting the padding off on the device would move data between devices, and between
    hosts under
    ``jax.distributed``; callers cut it after :func:`fetch`.)
    """
    t = int(mesh.shape[TRIAL])
    k = len(seeds)
    if k < 1:
        raise ValueError("seeds: expected at least one seed")
    if labels is not None and len(labels) != k:
        raise ValueError(f"labels: expected one (N, 8) array per seed ({k}), got {len(labels)}")
    n_used = cfg.n_used(data.xyz.shape[0])
    data = types.trim_goals(types.subset(data, n_used))
    g = data.goals.shape[1]
    if labels is not None:
        labels = np.asarray(labels)[:, :n_used, :g]
    trainer = train.make_train(cfg, mesh=mesh, progress=progress)
    seeds = seeds_array(seeds)
    keys = jax.vmap(train.Trainer.state_key)(train.trial_keys(seeds.tolist()))
    trainer = train.packed_trainer(trainer, keys, data, range(cfg.epochs))
    rep = NamedSharding(mesh, P())
    ev = None
    if val is not None and cfg.eval_every:
        ev = jax.device_put(
            trainer.eval_data(types.trim_goals(types.subset(val, cfg.eval_size))), rep
        )
    if k == 1 and t == 1:  # one run over all devices of the mesh: the batch-parallel path
        if labels is not None:
            data = data._replace(labels=labels[0])
        out = _jit_group(trainer, False, False)(int(seeds[0]), jax.device_put(data, rep), ev)
        return jax.tree.map(lambda x: x[None], out)
    by_run = NamedSharding(mesh, P(TRIAL))
    size = -(-k // t) * t
    if labels is not None:
        data = data._replace(labels=jax.device_put(_pad(labels, size), by_run))
    shared = types.TrainData(*(jax.device_put(x, rep) for x in data[:3]), data.labels)
    if labels is None:
        shared = shared._replace(labels=jax.device_put(data.labels, rep))
    f = _jit_group(trainer, labels is not None, True)
    return f(jax.device_put(_pad(seeds, size), by_run), shared, ev)


@functools.cache
def _jit_group_accuracy(trainer: train.Trainer, per_unit_labels: bool, vmapped: bool):
    def one(params, ev, labels):
        return trainer.accuracy(params, ev if labels is None else ev._replace(labels=labels))

    if not vmapped:
        return jax.jit(one)
    axes = (0, None, 0 if per_unit_labels else None)
    return jax.jit(jax.vmap(one, in_axes=axes, spmd_axis_name=TRIAL))


def group_accuracy(
    cfg: TrainConfig,
    params,
    data: types.TrainData,
    mesh: Mesh,
    *,
    labels: Float[Array, "U N 8"] | None = None,
) -> np.ndarray:
    """:ref:`concepts-accuracy` accuracy of each run of a :func:`train_group` result on one split,
    evaluated where the run's parameters live (each device scores its own run on the whole split).

    ``labels[i]`` replaces ``data.labels`` for run i when given (fewer label sets than
    runs: the last one is repeated for the padding runs). Returns the exact fractions
    (float64, :func:`slotv_jax.training.evaluate.exact_fraction`) of every run of ``params``,
    padding included, gathered to every process.
    """
    t = int(mesh.shape[TRIAL])
    k = len(jax.tree.leaves(params)[0])
    n = data.xyz.shape[0]
    data = types.trim_goals(data)
    g = data.goals.shape[1]
    trainer = train.make_train(cfg, mesh=mesh, progress=False)
    ev = trainer.eval_data(data, size=n)
    m, c = ev.valid.shape
    rep = NamedSharding(mesh, P())
    ev = jax.device_put(ev, rep)
    ul = None
    if labels is not None:
        lab = _pad(np.asarray(labels)[:, :n, :g], k)
        lab = np.concatenate([lab, np.repeat(lab[:, :1], m * c - n, axis=1)], axis=1)
        ul = lab.reshape(k, m, c, g)
    if k == 1 and t == 1:
        out = _jit_group_accuracy(trainer, False, False)(
            jax.tree.map(lambda x: x[0], params), ev, None if ul is None else ul[0]
        )
        return evaluate.exact_fraction(fetch(out)[None], n)
    if ul is not None:
        ul = jax.device_put(ul, NamedSharding(mesh, P(TRIAL)))
    out = _jit_group_accuracy(trainer, ul is not None, True)(params, ev, ul)
    return evaluate.exact_fraction(fetch(out), n)


# ---------------------------------------------------------------- one unit per device


def map_on_devices(
    jobs: Sequence[U],
    start: Callable[[U, jax.Device], Any],
    width: int,
    *,
    devices: Sequence[jax.Device] | None = None,
    keep_going: Callable[[], bool] = lambda: True,
) -> Iterator[tuple[U, np.ndarray]]:
    """Run ``start(job, device)`` for each job, one job per device, and yield (job, result).

    The jobs go in rounds of one per device (every process's devices; a process starts only
    the jobs of its own devices). ``start`` must only dispatch work to ``device``: it runs
    under ``jax.default_device(device)`` and returns a float vector of ``width`` values,
    usually still being computed. The next round is dispatched before the current one is
    read back, so the host traces and compiles round r + 1 while the devices run round r.
    Results come back in job order, a round at a time, gathered to every process.
    ``keep_going()`` is asked before each round is dispatched (process 0's answer counts);
    after a False no more rounds start, and the ones in flight are still returned.
    """
    devices = list(jax.devices() if devices is None else devices)
    me = jax.process_index()
    rounds = [list(jobs[i : i + len(devices)]) for i in range(0, len(jobs), len(devices))]

    def dispatch(round_jobs):
        out = []
        for job, dev in zip(round_jobs, devices, strict=False):
            if dev.process_index != me:
                out.append(None)
                continue
            with jax.default_device(dev):
                out.append(start(job, dev))
        return out

    def collect(handles):
        rows = np.zeros((len(handles), width))
        for j, h in enumerate(handles):
            if h is not None:
                rows[j] = np.asarray(h, np.float64).reshape(width)
        if jax.process_count() == 1:
            return list(rows)
        every = np.asarray(multihost_utils.process_allgather(rows))  # (processes, jobs, width)
        return [every[devices[j].process_index, j] for j in range(len(handles))]

    def more(r: int) -> bool:
        return r < len(rounds) and bool(broadcast(np.array(keep_going())))

    handles = dispatch(rounds[0]) if more(0) else None
    r = 0
    while handles is not None:
        following = dispatch(rounds[r + 1]) if more(r + 1) else None
        yield from zip(rounds[r], collect(handles), strict=True)
        handles, r = following, r + 1


def seeds_array(seeds: Sequence[int]) -> Int[np.ndarray, " U"]:
    """Seeds as an int32 array (checked: each fits ``jax.random.key`` as the same key)."""
    a = np.asarray(list(seeds), np.int64)
    if a.ndim != 1 or np.any(a < 0) or np.any(a >= 2**31):
        raise ValueError(f"seeds: expected integers in [0, 2**31), got {list(seeds)}")
    return a.astype(np.int32)


def precompile_group(cfg: TrainConfig, n: int, n_points: int, n_goals: int, mesh: Mesh) -> bool:
    """Compile :func:`train_group`'s function for a full group on ``mesh`` ahead of the data.

    For a training split of ``n`` trajectories of ``n_points`` points and ``n_goals`` goal
    slots after :func:`slotv_jax.training.trainer.trim_goals`, per-run labels, no validation set (as
    Table 1 calls it); a later :func:`train_group` call of that shape reuses the
    compilation. Like :func:`slotv_jax.training.trainer.precompile` it can run in a thread while the
    dataset is generated. Returns False, compiling nothing, for a one-run group (the
    batch-parallel path) or where the compiled function depends on the data (packed SLOT-V
    updates on CPUs).
    """
    t = int(mesh.shape[TRIAL])
    trainer = train.make_train(cfg, mesh=mesh, progress=False)
    if trainer.packs or t == 1:
        return False
    n = cfg.n_used(int(n))
    rep, by_run = NamedSharding(mesh, P()), NamedSharding(mesh, P(TRIAL))

    def spec(shape, dtype, sharding=rep):
        return jax.ShapeDtypeStruct(shape, dtype, sharding=sharding)

    data = types.TrainData(
        spec((n, n_points, 3), jnp.float32),
        spec((n, n_goals, 3), jnp.float32),
        spec((n, n_goals), jnp.bool_),
        spec((t, n, n_goals), jnp.float32, by_run),
    )
    _jit_group(trainer, True, True).lower(spec((t,), jnp.int32, by_run), data, None).compile()
    return True
