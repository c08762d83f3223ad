"""Checkpoints (Orbax) and the learned observer as a plain JAX function
(:ref:`concepts-public-names`).

A checkpoint is a directory:

- ``config.json`` — format tag, the :class:`~slotv_jax.training.config.TrainConfig` that
  rebuilds the model, the epoch, free-form ``meta`` (labeler, seed, accuracies),
  and the path, shape and dtype of every saved array;
- ``state/`` — an Orbax checkpoint of the parameters, the optimiser state, the
  epoch counter and the PRNG key (all float32 / int32 / uint32 arrays), stored
  as a flat dict keyed by each leaf's path in the training state.

Writes are atomic: everything goes to a temporary sibling directory that is
renamed into place; an existing checkpoint is swapped out only after the new one
is complete (:func:`slotv_jax.core.fileio.replace_dir`). Anything at the path that is
not a checkpoint (a file, a user's directory) is never replaced. Loading checks
the saved shapes against the model the config builds (and, for resuming, against
the caller's config) and raises ValueError naming the mismatch; a missing path
raises FileNotFoundError, truncated files a ValueError that says so.

>>> observer = load_observer("runs/slotv_effdist")        # doctest: +SKIP
>>> logits = observer(xyz, goals, goal_mask)  # (8,), padded slots −∞  # doctest: +SKIP
>>> jax.grad(lambda x: jax.nn.softmax(observer(x, goals, goal_mask))[0])(xyz)  # doctest: +SKIP
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import os
import re
import shutil
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import fileio
from slotv_jax.observers import models
from slotv_jax.training import trainer as train_lib
from slotv_jax.training.config import MODELS, TrainConfig

FORMAT = "slotv_jax.checkpoint/1"
CONFIG_FILE = "config.json"
STATE_DIR = "state"


# ------------------------------------------------------------ Orbax's event loops
# Orbax runs each save and restore in a fresh asyncio event loop that it closes when the
# call returns (orbax.checkpoint._src.asyncio_utils.run_sync). TensorStore reports each
# finished read to its loop from its own threads (loop.call_soon_threadsafe). When a read
# fails (a truncated or corrupt file), the restore raises at once, the loop is closed, and
# every read still in flight then calls a closed loop: Python prints one "RuntimeError:
# Event loop is closed" traceback per read, from TensorStore's threads, after our error
# has been reported (tens of them for one bad checkpoint). Those callbacks belong to a
# call that is over and has nobody left to tell; the loops below drop them silently.


class _QuietAfterCloseLoop(asyncio.SelectorEventLoop):
    """An event loop that ignores callbacks scheduled from other threads once closed."""

    def call_soon_threadsafe(self, callback, *args, context=None):
        if self.is_closed():
            return None
        try:
            return super().call_soon_threadsafe(callback, *args, context=context)
        except RuntimeError:
            if self.is_closed():  # closed between the check and the call
                return None
            raise

    def call_exception_handler(self, context):
        # Another read of the failed restore, collected after the call: asyncio would log
        # "Task exception was never retrieved" with its traceback; the restore's own error
        # was reported already.
        if self.is_closed() and "never retrieved" in str(context.get("message", "")):
            return
        super().call_exception_handler(context)


class _QuietAfterClosePolicy(asyncio.DefaultEventLoopPolicy):
    def new_event_loop(self) -> asyncio.AbstractEventLoop:
        return _QuietAfterCloseLoop()


_POLICY_LOCK = threading.Lock()


@contextlib.contextmanager
def _orbax_loops():
    """Orbax's per-call event loops, made inside this block, drop late callbacks."""
    with _POLICY_LOCK:
        old = asyncio.get_event_loop_policy()
        asyncio.set_event_loop_policy(_QuietAfterClosePolicy())
        try:
            yield
        finally:
            asyncio.set_event_loop_policy(old)


def _leaf_name(path) -> str:
    parts = []
    for k in path:
        if isinstance(k, jax.tree_util.DictKey):
            parts.append(str(k.key))
        elif isinstance(k, jax.tree_util.SequenceKey):
            parts.append(str(k.idx))
        elif isinstance(k, jax.tree_util.GetAttrKey):
            parts.append(k.name)
        elif isinstance(k, jax.tree_util.FlattenedIndexKey):
            parts.append(str(k.key))
        else:
            parts.append(str(k))
    return ".".join(parts)


def _raw_key(state):
    """TrainState with its typed PRNG key replaced by the raw uint32 key data."""
    return state._replace(key=jax.random.key_data(state.key))


def _flatten(state) -> dict[str, Any]:
    """TrainState (with a raw key) → {path: array}."""
    flat, _ = jax.tree_util.tree_flatten_with_path(state)
    return {_leaf_name(p): x for p, x in flat}


def _template(cfg: TrainConfig):
    """Abstract TrainState, raw key (shapes and dtypes only), for ``cfg``."""
    trainer = train_lib.make_train(cfg, progress=False)
    return jax.eval_shape(lambda k: _raw_key(trainer.init(k)), jax.random.key(0))


def _describe(flat: Mapping[str, Any]) -> dict[str, dict]:
    return {
        k: {"shape": list(np.shape(v)), "dtype": str(jnp.dtype(v.dtype))} for k, v in flat.items()
    }


def exists(path: str | os.PathLike) -> bool:
    """True if ``path`` holds a complete checkpoint."""
    p = Path(path)
    return (p / CONFIG_FILE).is_file() and (p / STATE_DIR).is_dir()


def save(
    path: str | os.PathLike, cfg: TrainConfig, state, *, meta: Mapping[str, Any] | None = None
) -> Path:
    """Write ``state`` (a :class:`~slotv_jax.training.types.TrainState` of one trial) atomically."""
    path = Path(path).absolute()
    flat = _flatten(_raw_key(state))
    want = _describe(_flatten(_template(cfg)))
    got = _describe(flat)
    if want != got:
        raise ValueError(_mismatch("state", want, got, cfg))
    flat = jax.device_get(flat)
    if path.is_symlink() or (path.exists() and not exists(path) and any(path.iterdir())):
        raise fileio.OutputError(
            f"checkpoint {path}: something that is not a slotv_jax checkpoint is there; "
            "it is left untouched: choose another path"
        )  # an empty directory is fine; a file or a user's directory is never replaced
    tmp = fileio.temp_dir_beside(path)
    try:
        with _orbax_loops(), ocp.StandardCheckpointer() as ckptr:
            ckptr.save(tmp / STATE_DIR, flat)
            ckptr.wait_until_finished()
        doc = {
            "format": FORMAT,
            "config": cfg.to_dict(),
            "epoch": int(np.asarray(flat["epoch"])),
            "meta": dict(meta or {}),
            "arrays": got,
        }
        fileio.write_text(tmp / CONFIG_FILE, json.dumps(doc, indent=2, sort_keys=True, default=str))
        if path.is_dir() and not exists(path):
            path.rmdir()  # empty (checked above)
        fileio.replace_dir(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return path


def _read_doc(path: Path) -> dict:
    f = path / CONFIG_FILE
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path}: does not exist")
    if not f.is_file() or not (path / STATE_DIR).is_dir():
        raise ValueError(
            f"checkpoint {path}: not a slotv_jax checkpoint (missing {CONFIG_FILE} or {STATE_DIR}/)"
        )
    doc = fileio.read_json(f)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        doc = {} if not isinstance(doc, dict) else doc
        raise ValueError(f"checkpoint {path}: format {doc.get('format')!r}, expected {FORMAT!r}")
    return doc


def _mismatch(what: str, want: dict, got: dict, cfg: TrainConfig) -> str:
    lines = []
    for k in sorted(set(want) | set(got)):
        if want.get(k) != got.get(k):
            w = want.get(k)
            g = got.get(k)
            lines.append(
                f"  {k}: config builds {w['shape'] if w else 'nothing'}"
                f"{'' if not w else ' ' + w['dtype']}, {what} has {g['shape'] if g else 'nothing'}"
                f"{'' if not g else ' ' + g['dtype']}"
            )
        if len(lines) >= 6:
            lines.append("  ...")
            break
    return (
        f"checkpoint {what} does not fit the model of its config (model={cfg.model}, "
        f"method={cfg.method}, hidden={cfg.hidden}, optimizer={cfg.optimizer}):\n"
        + "\n".join(lines)
    )


def _check_field(where: Path, name: str, value, kind: str) -> None:
    """Raise unless a JSON ``value`` has the type a TrainConfig field's annotation names."""
    parts = {p.strip() for p in kind.split("|")}
    if value is None and "None" in parts:
        return
    if name == "hidden":
        ok = isinstance(value, list | tuple) and len(value) > 0
        ok = ok and all(isinstance(h, int) and not isinstance(h, bool) for h in value)
        want = "a list of positive integers (hidden widths)"
    elif "bool" in parts:
        ok, want = isinstance(value, bool), "true or false"
    elif "int" in parts:
        ok, want = isinstance(value, int) and not isinstance(value, bool), "an integer"
    elif "float" in parts:
        ok, want = isinstance(value, int | float) and not isinstance(value, bool), "a number"
    elif "str" in parts:
        ok, want = isinstance(value, str), "a string"
    else:
        return
    if not ok:
        null = " or null" if "None" in parts else ""
        raise ValueError(f"{where}: field 'config.{name}': expected {want}{null}, got {value!r}")


def _config_of(path: Path, doc: dict) -> TrainConfig:
    """The :class:`TrainConfig` of a checkpoint's ``config.json`` document; an error names
    the file and the field (``config.hidden``, ``config.model``, ...)."""
    where = path / CONFIG_FILE
    d = doc.get("config")
    if not isinstance(d, dict):
        raise ValueError(
            f"{where}: field 'config': expected an object (the training config), "
            f"got {type(d).__name__ if d is not None else 'nothing'}"
        )
    known = {f.name: str(f.type) for f in dataclasses.fields(TrainConfig)}
    unknown = sorted(set(d) - set(known))
    if unknown:
        raise ValueError(
            f"{where}: field 'config.{unknown[0]}': not a training config field (known: "
            f"{', '.join(sorted(known))})"
        )
    for name, value in d.items():
        _check_field(where, name, value, known[name])
    try:
        return TrainConfig.from_dict(d)
    except (ValueError, TypeError) as e:
        m = re.match(r"TrainConfig\.(\w+): (.*)", str(e), re.S)
        field, text = (f"config.{m.group(1)}", m.group(2)) if m else ("config", str(e))
        raise ValueError(f"{where}: field {field!r}: {text}") from None


def load_config(path: str | os.PathLike) -> TrainConfig:
    """The :class:`TrainConfig` stored with a checkpoint."""
    path = Path(path).absolute()
    return _config_of(path, _read_doc(path))


def restore(path: str | os.PathLike, cfg: TrainConfig | None = None):
    """Read a checkpoint: ``(cfg, state, meta)``.

    If ``cfg`` is given (resuming a run), the stored config must describe the same
    model and optimiser; ``epochs`` and the evaluation/logging fields may differ.
    Raises ValueError on any mismatch of config or array shapes.
    """
    path = Path(path).absolute()
    doc = _read_doc(path)
    saved = _config_of(path, doc)
    if cfg is not None and cfg.model != saved.model:
        raise ValueError(_wrong_model(path, saved.model, cfg.model))
    if cfg is not None:
        free = {"epochs", "eval_every", "eval_size", "eval_chunk", "log_every"}
        a, b = saved.to_dict(), cfg.to_dict()
        diff = {k: (a[k], b[k]) for k in a if k not in free and a[k] != b[k]}
        if diff:
            raise ValueError(
                f"checkpoint {path}: its config differs from the requested one in "
                + ", ".join(
                    f"{k} (saved {v[0]!r}, requested {v[1]!r})" for k, v in sorted(diff.items())
                )
            )
    use = saved if cfg is None else cfg
    template = _template(use)
    tflat = _flatten(template)
    want = _describe(tflat)
    if want != doc.get("arrays"):
        raise ValueError(
            f"checkpoint {path}: " + _mismatch("arrays", want, doc.get("arrays") or {}, use)
        )
    abstract = {k: jax.ShapeDtypeStruct(v.shape, v.dtype) for k, v in tflat.items()}
    try:
        with _orbax_loops(), ocp.StandardCheckpointer() as ckptr:
            flat = ckptr.restore(path / STATE_DIR, abstract)
    except Exception as e:  # the layout matched config.json, so the data itself is bad
        first = str(e).strip().splitlines()[0][:300] if str(e).strip() else type(e).__name__
        raise ValueError(
            f"checkpoint {path}: the stored arrays in {STATE_DIR}/ are truncated or corrupt "
            f"({first})"
        ) from e
    leaves_paths, treedef = jax.tree_util.tree_flatten_with_path(template)
    leaves = [jnp.asarray(flat[_leaf_name(p)]) for p, _ in leaves_paths]
    state = jax.tree_util.tree_unflatten(treedef, leaves)
    state = state._replace(key=jax.random.wrap_key_data(state.key))
    return use, state, doc.get("meta", {})


def initial_params(path: str | os.PathLike, cfg: TrainConfig):
    """The parameters of the checkpoint at ``path`` to start a run of ``cfg`` from
    (``python -m slotv_jax.train --init CKPT``: a model trained on labels, fine-tuned on
    answers; the optimiser, epoch and key are the new run's). ``θ₀ = θ_CKPT`` instead of a
    random draw, the fine-tuning of Howard & Ruder (2018). ValueError naming the checkpoint
    unless it holds the same observer (``model``) trained by the same method, with
    parameters of the same names and shapes as ``cfg``'s."""
    path = Path(path).absolute()
    if not exists(path):
        raise ValueError(f"{path}: no checkpoint there (config.json and state/ of `train --out`)")
    saved, state, _ = restore(path)
    if saved.model != cfg.model:
        raise ValueError(_wrong_model(path, saved.model, cfg.model))
    if saved.method != cfg.method:
        raise ValueError(
            f"checkpoint {path}: trained by {saved.method!r}, not the requested {cfg.method!r}"
        )
    want = _describe(_flatten(_template(cfg).params))
    got = _describe(_flatten(state.params))
    if want != got:
        a, b = saved.to_dict(), cfg.to_dict()
        diff = [f"{k} (saved {a[k]!r}, requested {b[k]!r})" for k in sorted(a) if a[k] != b.get(k)]
        raise ValueError(
            f"checkpoint {path}: its parameters have other shapes than the requested "
            f"{cfg.model!r} observer's; the configs differ in " + ", ".join(diff)
        )
    return state.params


def _wrong_model(path, saved: str, requested: str) -> str:
    return (
        f"checkpoint {path}: it holds a {saved!r} observer, not the requested {requested!r} "
        f"(its config says model={saved!r}); load it without a model, or as {saved!r}"
    )


def _learned_logits(
    cfg: TrainConfig,
    params,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
) -> Float[Array, " 8"]:
    models.check_observer_inputs(xyz, goals, goal_mask)
    model = nnx.merge(models.graphdef(cfg), params)
    return model(jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(goal_mask, bool))


def _learned_prefix(
    cfg: TrainConfig,
    params,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""],
) -> Float[Array, " 8"]:
    models.check_observer_inputs(xyz, goals, goal_mask)
    models.check_seen(seen, jnp.shape(xyz)[0])
    model = nnx.merge(models.graphdef(cfg), params)
    return model.prefix(
        jnp.asarray(xyz), jnp.asarray(goals), jnp.asarray(goal_mask, bool), jnp.asarray(seen)
    )


def _learned_model(cfg: TrainConfig, params):
    return nnx.merge(models.graphdef(cfg), params)


def make_observer(cfg: TrainConfig, params) -> models.Observer:
    """The observer ``observer(xyz (T, 3), goals (8, 3), goal_mask (8,)) -> logits (8,)``
    of ``cfg``'s model at ``params``: an :class:`slotv_jax.observers.observer.Observer`
    whose ``config`` is ``cfg`` and whose ``params`` are ``params`` (its pytree leaves).

    SLOT-V: s_k = (1/T) Σ_i V(p_i, g_k); T-REX: R_k = Σ_i r(p_i, g_k) (with the config's options,
    :class:`slotv_jax.observers.models.SlotV`); padded slots −∞. Shapes are checked on every call;
    values (NaN, an empty mask) on concrete inputs. Works under ``jit``, ``vmap`` and ``grad``
    (w.r.t. ``xyz``, ``goals`` or the observer's parameters). ``prefix(xyz, goals, goal_mask,
    seen) -> logits (8,)`` gives the logits of the motion seen up to its first ``seen``
    points (2 ≤ seen ≤ T, may be traced), what training on answers fits
    (:func:`slotv_jax.answers.fitting.prefix_logits`). An archetype's observer also has
    ``describe()`` and ``parameters()`` (its fitted values); ``model()`` is the network or
    archetype itself.

    ``params`` may be traced: build the observer inside a jitted function of the parameters
    to plan or score with many fitted observers of one config in one compiled program
    (:func:`slotv_jax.planning.make_family_planner`), or stack the observers of one config
    and ``vmap`` over them.
    """
    name = cfg.method if cfg.model == "mlp" else cfg.model
    return models.Observer(
        logits_fn=_learned_logits,
        prefix_fn=_learned_prefix,
        params=params,
        config=cfg,
        name=name,
        model_fn=_learned_model,
    )


def load_observer(path: str | os.PathLike, model: str | None = None) -> models.Observer:
    """Load a checkpoint as ``observer(xyz (T, 3), goals (8, 3), goal_mask (8,)) -> logits (8,)``.

    The logits are SLOT-V's observer scores (softmax gives P(goal | trajectory)) or
    T-REX's per-goal returns; padded goals are −∞. The observer is pure: use it under
    ``jit``, ``vmap`` (batch the arguments) and ``grad`` with respect to ``xyz``; it is an
    :class:`slotv_jax.observers.observer.Observer` (:func:`make_observer`), a pytree of
    its parameters, so ``jit``, ``vmap`` and ``grad`` also take the observer itself.

    ``model`` (optional: "mlp", "dragan", "viewpoint", "mixture") is the observer the
    caller expects; a checkpoint of another one raises ValueError. An archetype's
    observer also has ``describe()`` and ``parameters()`` (its fitted values,
    :ref:`concepts-archetypes`).
    """
    if model is not None and model not in MODELS:
        raise ValueError(f"model: expected one of {MODELS} or None, got {model!r}")
    if (Path(path) / "pool.json").is_file():  # study pick --by pool's folder
        raise ValueError(
            f"{path}: a pool of observers (pool.json), not one checkpoint: "
            "load it with slotv_jax.answers.load_pool"
        )
    cfg, state, _ = restore(path)
    if model is not None and model != cfg.model:
        raise ValueError(_wrong_model(Path(path), cfg.model, model))
    return make_observer(cfg, state.params)
