"""Training SLOT-V and T-REX as pure, compiled functions of a key (:ref:`concepts-slotv`,
:ref:`concepts-trex`, :ref:`concepts-metrics`).

``make_train(cfg)`` returns a :class:`Trainer` whose ``train(key, data, val)``
is a pure function: parameter initialisation, every epoch and every update run
inside it, so ``jax.jit(jax.vmap(trainer.train, in_axes=(0, None, None)))``
trains several seeds in one compiled call (:func:`train_trials` does that).

Inside ``train``:

- an epoch is a ``lax.scan`` over minibatches: blocks of ``k`` updates
  (``cfg.eval_every``, else ``cfg.log_every``), each block an inner scan;
  after each block the mean loss (and, with ``eval_every``, the accuracy on a
  fixed validation subset) is recorded and reported to the host through
  ``jax.debug.callback`` (a tqdm bar): no Python loop per update, no printing
  from traced code;
- SLOT-V: each epoch shuffles the used training trajectories with
  ``jax.random.permutation`` and drops the last partial batch. The loss is the
  cross-entropy  L = −Σ_k y_k log softmax_k(s)  between the labeler's y and the
  masked observer logits s (:ref:`concepts-slotv`);
- T-REX: each update draws ``batch_size`` fresh pairs on device (:ref:`concepts-trex`):
  trajectories i₁, i₂ uniform over the used training set, a goal k_j uniform
  over the real goals of i_j's scene, label ℓ = 1[y_{k₂}(i₂) > y_{k₁}(i₁)]; an
  epoch has ⌊n/B⌋ updates, i.e. (up to the last partial batch) as many pairs as
  training trajectories. The loss is the binary cross-entropy on
  softmax([R₁, R₂])₂ = σ(R₂ − R₁) (Brown et al. 2019);
- the key of epoch e is ``fold_in(key, e)``: resuming from a saved state after
  any epoch continues exactly as an uninterrupted run.

Data parallelism: the batch axis of every update (and every evaluation chunk)
is sharded over a 1-D device ``Mesh`` through ``with_sharding_constraint``
under ``jit``; parameters and the dataset are replicated, and XLA inserts the
gradient all-reduce. The same code runs on 1 CPU, 1 GPU or N GPUs. The mesh
uses the largest number of local devices that divides ``batch_size``.

Mixed precision: ``cfg.compute_dtype="bfloat16"`` runs the hidden matmuls in
bfloat16; parameters, gradients and optimiser state stay float32.

Implementation choices that do not change the values (up to float rounding):
``make_train(backward=...)`` selects how the gradient of the first layers is formed
(see :meth:`slotv_jax.observers.models.GoalRelativeMLP.grid`; "auto" takes the fastest measured
one per platform and method, :func:`default_backward`); :func:`train_trials` cuts the
goal slots no training trajectory uses (:func:`trim_goals`) and, on CPUs, packs SLOT-V
updates to each batch's real (trajectory, goal) pairs (:func:`slotv_loss_packed`, with a
capacity counted exactly over every batch of the run).

Sample-efficiency curves (:ref:`concepts-sample-efficiency`): ``cfg.eval_every = k`` validates on
the first ``cfg.eval_size`` trajectories of ``val`` after every k updates (and once before
training), inside the compiled loop: ``metrics.eval_updates``/``eval_accuracy``.

>>> from slotv_jax.training import config, evaluate
>>> cfg = config.quick("slotv")
>>> data = prepare(splits["train"], "effdist", size=cfg.train_size)  # doctest: +SKIP
>>> states, metrics = train_trials(cfg, data, seeds=2)  # doctest: +SKIP
>>> evaluate.accuracy(cfg, states.params, splits["trajectory_test"], "effdist")  # doctest: +SKIP
array([0.96, 0.95], dtype=float32)
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Float, Int
from tqdm.auto import tqdm

from slotv_jax.observers import models
from slotv_jax.training import devices, evaluate
from slotv_jax.training.config import TrainConfig
from slotv_jax.training.devices import make_mesh
from slotv_jax.training.losses import (
    make_optimizer,
    observer_loss,
    slotv_loss,
    slotv_loss_packed,
    trex_loss,
)
from slotv_jax.training.types import EvalData, Metrics, TrainData, TrainState, subset, trim_goals

# Re-exported: the shared types and their constructors live in slotv_jax.training.types.
from slotv_jax.training.types import make_data as make_data
from slotv_jax.training.types import prepare as prepare

# ---------------------------------------------------------------- progress


class _Progress:
    """Host side of the progress callback: one tqdm bar per training call.

    The traced code reports (global update, block loss); a report with fewer updates
    than the last one starts a new bar. Reports may repeat (one per vmapped trial):
    they are idempotent.
    """

    def __init__(self, desc: str, batch_size: int):
        self.desc = desc
        self.batch_size = batch_size
        self.bar = None
        self.last = -1

    def _open(self, total: int) -> None:
        if self.bar is not None:
            self.bar.close()
        self.bar = tqdm(
            total=total * self.batch_size, desc=self.desc, unit="ex", unit_scale=True,
            leave=False, dynamic_ncols=True, file=sys.stderr,
        )  # fmt: skip
        self.last = 0

    def begin(self, total: int, note: str) -> None:
        """Open the bar of a call that reports ``total`` updates before it starts: a
        compilation and the first block report nothing, and ``note`` says what happens
        until the first report replaces it with the loss."""
        self._open(total)
        self.bar.set_postfix_str(note)

    def __call__(self, updates, loss, *, total: int):
        u = int(np.max(np.asarray(updates)))
        if u < self.last or self.last < 0:
            self._open(total)
        if self.bar is None or u <= self.last:
            return
        self.bar.set_postfix(loss=f"{float(np.mean(np.asarray(loss))):.4f}", refresh=False)
        self.bar.update((u - self.last) * self.batch_size)
        self.last = u
        if u >= total:
            self.bar.close()
            self.bar = None


# ---------------------------------------------------------------- objectives


@dataclasses.dataclass(frozen=True)
class RowObjective:
    """A loss over the rows of another data set than :class:`TrainData` (for example a
    study's answer rows, :mod:`slotv_jax.answers.fitting`), trained by the one :class:`Trainer`.

    An epoch shuffles the ``rows(data)`` rows with the run's key (as SLOT-V's epochs do),
    cuts ⌊rows / B⌋ batches of row indices ``idx``, and each update minimises
    ``loss(model, *batch(data, idx), data=data, backward=...)``, where every array of
    ``batch`` has the batch axis first (it is sharded over the mesh's "data" axis).
    Initialisation, optimiser, sharding, precision, blocks and progress are the trainer's.
    The objective is hashable (module-level functions), so trainers stay cached.
    """

    what: str  # the rows in error messages, "{n}" their number ("study: {n} answer rows")
    rows: Callable[[Any], int]
    batch: Callable[[Any, Int[Array, " B"]], tuple]
    loss: Callable[..., Float[Array, ""]]


# ---------------------------------------------------------------- the trainer


@dataclasses.dataclass(frozen=True, eq=False)
class Trainer:
    """Pure training functions for one config and mesh (build with :func:`make_train`)."""

    cfg: TrainConfig
    mesh: Mesh
    graphdef: Any  # nnx.GraphDef of the model
    tx: optax.GradientTransformation
    progress: _Progress | None
    backward: str = "fused"  # first-layer gradient implementation (models.GoalRelativeMLP.grid)
    # SLOT-V: real (trajectory, goal) pairs computed per update (0: all B·G slots). Set by
    # train_trials and the CLI from an exact count over every batch (pair_capacity).
    packed_pairs: int = 0
    objective: RowObjective | None = None  # None: SLOT-V's or T-REX's loss on TrainData

    # ---- sharding helpers
    def _shard_batch(self, x):
        return devices.shard_batch(self.mesh, x)

    @property
    def platform(self) -> str:
        """The platform of the mesh's devices ("cpu", "gpu", …)."""
        return devices.platform(self.mesh)

    @property
    def n_data(self) -> int:
        """Devices the batch axis is split over: the mesh's "data" axis (a mesh may also
        have a "trial" axis for independent runs, :mod:`slotv_jax.training.parallel`)."""
        return devices.data_size(self.mesh)

    @property
    def packs(self) -> bool:
        """Whether :func:`train_trials` packs this trainer's updates to the real pairs."""
        return (
            self.cfg.method == "slotv"
            and self.cfg.model == "mlp"
            and self.objective is None
            and packs_updates(self.platform)
        )

    def replicate(self, tree):
        """Place arrays (e.g. a TrainData) on every device of the mesh."""
        return devices.replicate(self.mesh, tree)

    # ---- pieces
    @staticmethod
    def _init_keys(key: jax.Array) -> jax.Array:
        return jax.random.split(key)  # (model key, TrainState key)

    def init(self, key: jax.Array, params: nnx.State | None = None) -> TrainState:
        """Fresh parameters and optimiser state from ``key`` (pure; vmappable). With
        ``params`` the run starts from θ₀ = ``params`` instead (fine-tuning, Howard & Ruder
        2018: ``train --init``), with the optimiser state of θ₀ and the key's own batches."""
        k_model, k_train = self._init_keys(key)
        if params is None:
            _, params = nnx.split(models.make_model(self.cfg, nnx.Rngs(params=k_model)))
        return TrainState(params, self.tx.init(params), jnp.zeros((), jnp.int32), k_train)

    @staticmethod
    def state_key(key: jax.Array) -> jax.Array:
        """The TrainState key that :meth:`init` derives from ``key``."""
        return Trainer._init_keys(key)[1]

    def model(self, params: nnx.State):
        return nnx.merge(self.graphdef, params)

    def _update(self, state, loss_fn, *batch):
        params, opt_state = state

        def f(p):
            return loss_fn(self.model(p), *batch)

        loss, grads = jax.value_and_grad(f)(params)
        updates, opt_state = self.tx.update(grads, opt_state, params)
        return (optax.apply_updates(params, updates), opt_state), loss

    def _slotv_step(self, data: TrainData, carry, idx):
        idx = self._shard_batch(idx)
        batch = [self._shard_batch(x[idx]) for x in data]
        if self.cfg.model != "mlp":
            return self._update(carry, observer_loss, *batch)
        if self.packed_pairs:
            loss = functools.partial(
                slotv_loss_packed,
                capacity=self.packed_pairs,
                backward=self.backward,
                shard=self._shard_batch,
            )
        else:
            loss = functools.partial(slotv_loss, backward=self.backward)
        return self._update(carry, loss, *batch)

    def _objective_step(self, data, carry, idx):
        idx = self._shard_batch(idx)
        batch = [self._shard_batch(x) for x in self.objective.batch(data, idx)]
        loss = functools.partial(self.objective.loss, data=data, backward=self.backward)
        return self._update(carry, loss, *batch)

    def slotv_batches(self, key: jax.Array, epoch, n: int) -> Int[Array, "S B"]:
        """The minibatches (trajectory indices) of SLOT-V epoch ``epoch`` of a run whose
        state key is ``key``: a fresh permutation, cut into ⌊n/B⌋ batches (pure)."""
        steps, bs = self.cfg.steps_per_epoch(n), self.cfg.batch_size
        perm = jax.random.permutation(jax.random.fold_in(key, epoch), n)[: steps * bs]
        return perm.reshape(steps, bs).astype(jnp.int32)

    def pair_capacity(self, state_keys: jax.Array, goal_mask, epochs: Sequence[int]) -> int:
        """Pairs per update that make packed SLOT-V updates exact for these runs: the largest
        number of real (trajectory, goal) pairs in any batch of the given ``epochs`` of any
        run (``state_keys``: the TrainState keys, stacked), rounded up to a multiple of 8
        and of the data-axis size; 0 when that is no fewer than all B·G slots."""
        mask = jnp.asarray(goal_mask)
        n, g = mask.shape
        n = self.cfg.n_used(n)
        counts = mask[:n].sum(-1)
        ep = jnp.asarray(list(epochs), jnp.int32)
        if ep.size == 0 or self.cfg.steps_per_epoch(n) < 1:
            return 0

        def most(key, e):  # the most real pairs in one batch of epoch e of one run
            return counts[self.slotv_batches(key, e, n)].sum(-1).max()

        grid = jax.vmap(jax.vmap(most, in_axes=(None, 0)), in_axes=(0, None))  # (runs, epochs)
        m = int(jax.jit(grid)(jnp.reshape(state_keys, (-1,)), ep).max())
        step = int(np.lcm(8, self.n_data))
        cap = -(-m // step) * step
        return 0 if cap >= self.cfg.batch_size * g else cap

    def _trex_step(self, data: TrainData, carry, key):
        idx, slot, label = models.sample_trex_pairs(
            key, data.goal_mask, data.labels, self.cfg.batch_size
        )
        idx, slot, label = (self._shard_batch(a) for a in (idx, slot, label))
        xyz = self._shard_batch(data.xyz[idx])  # (B, 2, T, 3)
        goal = self._shard_batch(data.goals[idx, slot])  # (B, 2, 3)
        loss = functools.partial(trex_loss, backward=self.backward)
        return self._update(carry, loss, xyz, goal, label)

    def accuracy(self, params: nnx.State, val: EvalData) -> Float[Array, ""]:
        """Accuracy of ``params`` on a chunked evaluation set (pure)."""
        return evaluate.chunked_accuracy(self.model(params), val, shard=self._shard_batch)

    def eval_data(self, data: TrainData, size: int | None = None) -> EvalData:
        """The fixed validation subset (first ``size`` or ``cfg.eval_size``), chunked
        (:func:`slotv_jax.training.evaluate.eval_data`)."""
        return evaluate.eval_data(self.cfg, self.mesh, data, size)

    # ---- the compiled loop
    def run(
        self,
        state: TrainState,
        data: TrainData,
        val: EvalData | None = None,
        *,
        epochs: int,
    ) -> tuple[TrainState, Metrics]:
        """``epochs`` more epochs from ``state`` (pure; jit it, vmap it over states)."""
        cfg, objective = self.cfg, self.objective
        if objective is None:
            data = subset(data, cfg.n_used(data.xyz.shape[0]))
            n = data.xyz.shape[0]
        else:
            n = cfg.n_used(objective.rows(data))
        steps = cfg.steps_per_epoch(n)
        if steps < 1:
            what = "training set: {n} trajectories" if objective is None else objective.what
            raise ValueError(what.format(n=n) + f" give no full batch of {cfg.batch_size}")
        k = cfg.block_size(n)
        n_blocks, tail = divmod(steps, k)
        validate = cfg.eval_every > 0 and val is not None
        total = cfg.epochs * steps
        if objective is not None:
            step_fn = functools.partial(self._objective_step, data)
        else:
            step_fn = functools.partial(
                self._slotv_step if cfg.method == "slotv" else self._trex_step, data
            )

        def report(updates, loss):
            if self.progress is not None:
                jax.debug.callback(functools.partial(self.progress, total=total), updates, loss)

        def block(carry, xs):
            (params, opt_state), epoch = carry
            b, inputs = xs
            (params, opt_state), losses = jax.lax.scan(step_fn, (params, opt_state), inputs)
            updates = epoch * steps + (b + 1) * k
            acc = self.accuracy(params, val) if validate else jnp.float32(jnp.nan)
            report(updates, losses.mean())
            return ((params, opt_state), epoch), (losses.mean(), updates, acc)

        def epoch_fn(carry, _):
            params, opt_state, epoch, key = carry
            if cfg.method == "slotv" or objective is not None:
                inputs = self.slotv_batches(key, epoch, n)
            else:
                inputs = jax.random.split(jax.random.fold_in(key, epoch), steps)
            main = jax.tree.map(
                lambda x: x[: n_blocks * k].reshape(n_blocks, k, *x.shape[1:]), inputs
            )
            ((params, opt_state), _), (losses, upd, acc) = jax.lax.scan(
                block, ((params, opt_state), epoch), (jnp.arange(n_blocks), main)
            )
            if tail:
                rest = jax.tree.map(lambda x: x[n_blocks * k :], inputs)
                (params, opt_state), tail_losses = jax.lax.scan(step_fn, (params, opt_state), rest)
                losses = jnp.concatenate([losses, tail_losses.mean()[None]])
                report((epoch + 1) * steps, tail_losses.mean())
            if not validate:
                upd, acc = upd[:0], acc[:0]
            return (params, opt_state, epoch + 1, key), (losses, upd, acc)

        start = self.accuracy(state.params, val) if validate else jnp.float32(jnp.nan)
        (params, opt_state, epoch, key), (loss, upd, acc) = jax.lax.scan(
            epoch_fn, tuple(state), None, length=epochs
        )
        return TrainState(params, opt_state, epoch, key), Metrics(loss, upd, acc, start)

    def train(
        self, key: jax.Array, data: TrainData, val: EvalData | None = None
    ) -> tuple[TrainState, Metrics]:
        """Initialise from ``key`` and train ``cfg.epochs`` epochs (pure; jit/vmap it)."""
        return self.run(self.init(key), data, val, epochs=self.cfg.epochs)


@functools.cache
def _make_train(
    cfg: TrainConfig,
    mesh: Mesh,
    progress: bool,
    backward: str,
    packed_pairs: int,
    objective: RowObjective | None,
) -> Trainer:
    graphdef = models.graphdef(cfg)
    bar = _Progress(f"{cfg.method} ", cfg.batch_size) if progress else None
    tx = make_optimizer(cfg)
    return Trainer(cfg, mesh, graphdef, tx, bar, backward, packed_pairs, objective)


def default_backward(platform: str, method: str = "slotv") -> str:
    """The fastest measured gradient implementation of the first layers (same values):
    "recompute" on CPUs; on GPUs (H100, experiments/BENCHMARKS.md) "fused" for SLOT-V's
    (T, G) grid and "autodiff" for T-REX's one-goal rows."""
    if platform == "cpu":
        return "recompute"
    return "fused" if method == "slotv" else "autodiff"


def packs_updates(platform: str) -> bool:
    """Whether :func:`train_trials` packs SLOT-V updates to the real pairs (measured: twice
    as fast on CPUs, where the arithmetic counts; slower on an H100, where the (T, G) grid
    shares each point's first-layer work between goals)."""
    return platform == "cpu"


def make_train(
    cfg: TrainConfig,
    *,
    mesh: Mesh | None = None,
    progress: bool = True,
    backward: str = "auto",
    packed_pairs: int = 0,
    objective: RowObjective | None = None,
) -> Trainer:
    """The :class:`Trainer` for ``cfg`` (cached: the same arguments give the same object, so
    jitted calls reuse their compilation).

    ``mesh`` defaults to :func:`make_mesh`; ``progress`` reports to a tqdm bar;
    ``backward`` picks the implementation of the first layers' gradient (same values, see
    :meth:`slotv_jax.observers.models.GoalRelativeMLP.grid`; "auto": :func:`default_backward`);
    ``packed_pairs`` > 0 computes SLOT-V updates on that many real (trajectory, goal) pairs
    (:func:`slotv_loss_packed`): it must come from :meth:`Trainer.pair_capacity` for the
    runs it trains, as in :func:`train_trials`. ``objective`` trains another loss over
    another data set's rows (:class:`RowObjective`) instead of SLOT-V's or T-REX's.
    """
    if not isinstance(cfg, TrainConfig):
        raise ValueError(f"cfg: expected a TrainConfig, got {type(cfg).__name__}")
    mesh = make_mesh(cfg.batch_size) if mesh is None else mesh
    platform = devices.platform(mesh)
    if backward == "auto":
        backward = default_backward(platform, cfg.method)
    if backward not in models.BACKWARDS:
        raise ValueError(
            f"backward: expected 'auto' or one of {models.BACKWARDS}, got {backward!r}"
        )
    if packed_pairs and (cfg.method != "slotv" or objective is not None):
        raise ValueError("packed_pairs: only SLOT-V updates on TrainData can be packed")
    return _make_train(cfg, mesh, bool(progress), backward, int(packed_pairs), objective)


def packed_trainer(trainer: Trainer, state_keys: jax.Array, data: TrainData, epochs) -> Trainer:
    """``trainer`` with SLOT-V updates packed to the real pairs of every batch that runs with
    ``state_keys`` (TrainState keys) will meet in ``epochs`` (exact count, see
    :meth:`Trainer.pair_capacity`); ``trainer`` itself for T-REX, on platforms where packing
    does not pay (:func:`packs_updates`) or when nothing is saved."""
    if not trainer.packs:
        return trainer
    cap = trainer.pair_capacity(state_keys, data.goal_mask, epochs)
    if cap == trainer.packed_pairs:
        return trainer
    progress = trainer.progress is not None
    return make_train(
        trainer.cfg, mesh=trainer.mesh, progress=progress, backward=trainer.backward,
        packed_pairs=cap,
    )  # fmt: skip


# ---------------------------------------------------------------- drivers


@functools.cache
def _jit_trials(trainer: Trainer, vmapped: bool):
    if vmapped:
        return jax.jit(jax.vmap(trainer.train, in_axes=(0, None, None)))
    return jax.jit(trainer.train)


# The compiled training programs, by trainer, trial axis and argument shapes. Held here rather
# than left to jit's own executable cache, which every jitted function of the process shares
# and which, late in a long process (a test suite, a sweep), drops entries: a training step
# would then be compiled again, and its bar could not tell beforehand whether it will be.
_PROGRAMS: dict[tuple, jax.stages.Compiled] = {}


def _program_key(trainer: Trainer, vmapped: bool, args) -> tuple:
    leaves, tree = jax.tree.flatten(args)
    return trainer, vmapped, tree, tuple((tuple(x.shape), x.dtype) for x in leaves)


def _trials_program(trainer: Trainer, vmapped: bool, args) -> jax.stages.Compiled:
    """The compiled program of :func:`_jit_trials` for ``args`` (arrays or shape specs),
    compiled on the first request and kept."""
    key = _program_key(trainer, vmapped, args)
    if key not in _PROGRAMS:
        _PROGRAMS[key] = _jit_trials(trainer, vmapped).lower(*args).compile()
    return _PROGRAMS[key]


def trial_keys(seeds: int | Sequence[int]) -> jax.Array:
    """Keys for trials: ``jax.random.key(s)`` for each seed (an int n means seeds 0..n−1)."""
    seeds = range(seeds) if isinstance(seeds, int) else seeds
    return jnp.stack([jax.random.key(int(s)) for s in seeds])


def train_trials(
    cfg: TrainConfig,
    data: TrainData,
    seeds: int | Sequence[int],
    *,
    val: TrainData | None = None,
    mesh: Mesh | None = None,
    progress: bool = True,
) -> tuple[TrainState, Metrics]:
    """Train one model per seed in one compiled, vmapped call.

    Returns the final states and metrics with a leading trial axis; trial i equals
    ``trainer.train(jax.random.key(seeds[i]), data, val)`` (up to float rounding: the
    padded goal slots that no trajectory uses are cut first, :func:`trim_goals`). With
    ``cfg.eval_every`` > 0 and ``val`` given, ``metrics.eval_accuracy`` is the validation
    curve on the first ``cfg.eval_size`` trajectories of ``val``.
    """
    trainer = make_train(cfg, mesh=mesh, progress=progress)
    keys = trial_keys(seeds)
    data = trainer.replicate(trim_goals(subset(data, cfg.n_used(data.xyz.shape[0]))))
    ev = None
    if val is not None and cfg.eval_every:
        ev = trainer.replicate(trainer.eval_data(trim_goals(subset(val, cfg.eval_size))))
    trainer = packed_trainer(trainer, jax.vmap(Trainer.state_key)(keys), data, range(cfg.epochs))
    vmapped = len(keys) > 1  # no trial axis for one trial (XLA keeps a size-1 batch)
    args = (keys if vmapped else keys[0], data, ev)
    if trainer.progress is not None:  # the bar shows from the start, through the compilation
        total = cfg.epochs * cfg.steps_per_epoch(data.xyz.shape[0])
        compiled = _program_key(trainer, vmapped, args) in _PROGRAMS
        trainer.progress.begin(total, "starting" if compiled else "compiling the training step")
    out = _trials_program(trainer, vmapped, args)(*args)
    return out if vmapped else jax.tree.map(lambda x: x[None], out)


def precompile(
    cfg: TrainConfig,
    n: int,
    n_points: int,
    n_goals: int,
    *,
    mesh: Mesh | None = None,
    progress: bool = False,
) -> bool:
    """Compile :func:`train_trials`'s one-trial function ahead of the data.

    For a training set of ``n`` trajectories of ``n_points`` points with ``n_goals`` goal
    slots after :func:`trim_goals` (no validation set); a later :func:`train_trials` call
    with data of that shape (and the same ``mesh`` and ``progress``) reuses the
    compilation. XLA compiles without holding the GIL, so this can run in a thread while
    the dataset is generated. Returns False, compiling nothing, where the compiled
    function depends on the data (packed SLOT-V updates, :func:`packs_updates`).
    """
    trainer = make_train(cfg, mesh=mesh, progress=progress)
    if trainer.packs:
        return False
    n = cfg.n_used(int(n))
    rep = NamedSharding(trainer.mesh, P())

    def spec(shape, dtype):
        return jax.ShapeDtypeStruct(shape, dtype, sharding=rep)

    data = TrainData(
        spec((n, n_points, 3), jnp.float32),
        spec((n, n_goals, 3), jnp.float32),
        spec((n, n_goals), jnp.bool_),
        spec((n, n_goals), jnp.float32),
    )
    key = jax.eval_shape(lambda: jax.random.key(0))
    _trials_program(trainer, False, (key, data, None))
    return True


def select_trial(tree, i: int):
    """Trial ``i`` of a vmapped result (state or metrics)."""
    return jax.tree.map(lambda x: x[i], tree)
