"""Training configurations for SLOT-V and T-REX (:ref:`concepts-slotv`, :ref:`concepts-trex`,
:ref:`concepts-metrics`).

A configuration is one frozen :class:`TrainConfig`. Two preset builders make
them, one per method:

- :func:`paper` — the paper's hyperparameters (:ref:`concepts-slotv`, :ref:`concepts-trex`):
  SLOT-V hidden (1536, 768), RMSprop lr 0.005, ρ 0.9, momentum 0, batch 32,
  15 epochs; T-REX hidden (1792, 768), Adam lr 0.005, β1 0.9, β2 0.999,
  batch 128, 25 epochs.
- :func:`quick` — small networks and few epochs that fit the 2-core CPU budget
  of :ref:`concepts-table1` (the whole quick Table 1 in about 5 minutes, data included).

Both take keyword overrides; :func:`apply_overrides` parses ``key=value``
strings from the command line. Derived values (steps per epoch, the number of
evaluations, the evaluation chunk) are computed by methods, never stored.

>>> cfg = quick("slotv", epochs=2)
>>> cfg.method, cfg.epochs, cfg.steps_per_epoch(1000) == 1000 // cfg.batch_size
('slotv', 2, True)
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any

METHODS = ("slotv", "trex")
# Observer models: "mlp" is the paper's network (:ref:`concepts-observers`); the others are the
# parametric
# archetypes of slotv_jax.observers.parametric, trained with SLOT-V's loss
# (:ref:`concepts-archetypes`); "reader" is the motion reader of slotv_jax.observers.reader
# (:ref:`concepts-reader`), a network over what a person watching a clip can read.
MODELS = ("mlp", "dragan", "viewpoint", "mixture", "reader")
ARCHETYPE_MODELS = ("dragan", "viewpoint", "mixture")  # the analytic ones: no network
# Activation elements per (point, goal) pair an archetype holds, standing in for
# hidden[0] when the evaluation chunk is sized (a handful of values per pair).
ARCHETYPE_WIDTH = 8
OPTIMIZERS = ("rmsprop", "adam")
# What each optimiser never reads (the other's hyperparameters), and the fields only the
# MLP reads (an archetype has no network): TrainConfig.used_dict leaves them out.
UNUSED_BY_OPTIMIZER = {"rmsprop": ("b1", "b2"), "adam": ("rho", "momentum")}
MLP_ONLY = ("hidden", "activation", "start_term", "time_weight", "compute_dtype")
READER_UNUSED = ("start_term", "time_weight", "compute_dtype")  # the reader has a network
COMPUTE_DTYPES = ("float32", "bfloat16")
# Hidden activations of the MLP: "relu" is the paper's (:ref:`concepts-slotv`); "softplus" makes V
# smooth,
# which legible planning needs (slotv_jax.observers.models, experiments/planning_paper.md).
ACTIVATIONS = ("relu", "softplus")
# Elements of the first hidden activation (rows × width) one evaluation chunk may hold:
# small on CPUs (cache-friendly), large on accelerators (fewer, bigger matmuls).
EVAL_CHUNK_BUDGET = {"cpu": 1 << 24, "accelerator": 1 << 28}


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that defines one training run (and rebuilds its model).

    The model is V(r, g) = MLP(r − g) with the ``hidden`` widths (ReLU, or softplus with
    ``activation="softplus"``) and a linear scalar output; SLOT-V averages it over the
    trajectory, T-REX sums it.
    """

    # "slotv" (:ref:`concepts-slotv`) or "trex" (:ref:`concepts-trex`)
    method: str = "slotv"
    # observer: the MLP, or an archetype of slotv_jax.observers.parametric
    # (:ref:`concepts-archetypes`)
    model: str = "mlp"
    hidden: tuple[int, ...] = (1536, 768)  # hidden widths after the r − g layer
    activation: str = "relu"  # of the hidden layers: "relu" (the paper) or "softplus" (smooth)
    start_term: bool = False  # values relative to the start's, f(p_i, g) − f(p_0, g) (models)
    time_weight: bool = False  # weight the points by (1 − t)^α, α learned (models._ScoreNetwork)
    compute_dtype: str = "float32"  # matmul dtype of the hidden layers; params stay float32
    optimizer: str = "rmsprop"  # "rmsprop" or "adam"
    learning_rate: float = 0.005
    rho: float = 0.9  # RMSprop decay of the squared-gradient average
    momentum: float = 0.0  # RMSprop momentum (0: none)
    b1: float = 0.9  # Adam β1
    b2: float = 0.999  # Adam β2
    eps: float = 1e-8  # added to the root of the second moment (both optimisers)
    batch_size: int = 32  # trajectories (SLOT-V) or pairs (T-REX) per update
    epochs: int = 15
    train_size: int | None = None  # use only the first n training trajectories (None: all)
    eval_every: int = 0  # validate every k updates inside the loop (0: never)
    eval_size: int = 1000  # trajectories of the fixed validation subset
    eval_chunk: int | None = None  # trajectories per evaluation chunk (None: derived)
    log_every: int = 50  # updates between progress reports (when not validating)
    # the study's camera (a name of the scene or a camera file): the motion reader's image
    # view; only model="reader" reads it (and only its dict stores it)
    camera: str = "observer"

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"TrainConfig.method: expected one of {METHODS}, got {self.method!r}")
        if self.model not in MODELS:
            raise ValueError(f"TrainConfig.model: expected one of {MODELS}, got {self.model!r}")
        if self.model != "mlp" and self.method != "slotv":
            raise ValueError(
                f"TrainConfig.model: the {self.model!r} archetype trains with SLOT-V's loss "
                f"(method='slotv'); T-REX trains only the MLP, got method={self.method!r}"
            )
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(
                f"TrainConfig.optimizer: expected one of {OPTIMIZERS}, got {self.optimizer!r}"
            )
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"TrainConfig.activation: expected one of {ACTIVATIONS}, got {self.activation!r}"
            )
        for name in ("start_term", "time_weight"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"TrainConfig.{name}: expected True or False, got {getattr(self, name)!r}"
                )
        if self.model == "reader" and (self.start_term or self.time_weight):
            raise ValueError(
                "TrainConfig: start_term and time_weight belong to the MLP; the motion reader "
                "learns its own weighting of the points (leave them False)"
            )
        if not isinstance(self.camera, str) or not self.camera:
            raise ValueError(
                f"TrainConfig.camera: expected a camera name or file, got {self.camera!r}"
            )
        if self.camera != "observer" and self.model != "reader":
            raise ValueError(
                f"TrainConfig.camera: only the motion reader (model='reader') reads a camera, "
                f"got camera={self.camera!r} for model={self.model!r}"
            )
        if self.model in ARCHETYPE_MODELS and (
            self.start_term or self.time_weight or self.activation != "relu"
        ):
            raise ValueError(
                f"TrainConfig: start_term, time_weight and activation belong to the MLP; the "
                f"{self.model!r} archetype has none of them (leave start_term=False, "
                "time_weight=False, activation='relu')"
            )
        if self.compute_dtype not in COMPUTE_DTYPES:
            raise ValueError(
                f"TrainConfig.compute_dtype: expected one of {COMPUTE_DTYPES}, "
                f"got {self.compute_dtype!r}"
            )
        hidden = tuple(self.hidden)
        if not hidden or any(not isinstance(h, int) or h < 1 for h in hidden):
            raise ValueError(
                "TrainConfig.hidden: expected a non-empty tuple of positive ints, "
                f"got {self.hidden!r}"
            )
        object.__setattr__(self, "hidden", hidden)
        for name in ("learning_rate", "eps"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and v > 0 and v < float("inf")):
                raise ValueError(f"TrainConfig.{name}: expected a finite number > 0, got {v!r}")
        for name in ("rho", "b1", "b2"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"TrainConfig.{name}: expected a number in [0, 1), got {v!r}")
        if not 0.0 <= self.momentum <= 1.0:
            raise ValueError(
                f"TrainConfig.momentum: expected a number in [0, 1], got {self.momentum!r}"
            )
        for name in ("batch_size", "eval_size", "log_every"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ValueError(f"TrainConfig.{name}: expected an int >= 1, got {v!r}")
        for name in ("epochs", "eval_every"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 0:
                raise ValueError(f"TrainConfig.{name}: expected an int >= 0, got {v!r}")
        for name in ("train_size", "eval_chunk"):
            v = getattr(self, name)
            if v is not None and (not isinstance(v, int) or v < 1):
                raise ValueError(f"TrainConfig.{name}: expected None or an int >= 1, got {v!r}")

    # ---- derived values (computed, never stored) ----

    def n_used(self, n_train: int) -> int:
        """Training trajectories used: the first ``train_size`` of ``n_train`` (or all)."""
        return n_train if self.train_size is None else min(self.train_size, n_train)

    def steps_per_epoch(self, n_train: int) -> int:
        """Updates per epoch: ⌊n_used / batch⌋ (SLOT-V drops the last partial batch;
        T-REX draws n_used pairs per epoch, :ref:`concepts-trex`)."""
        return self.n_used(n_train) // self.batch_size

    def block_size(self, n_train: int) -> int:
        """Updates between host reports (and validations, when ``eval_every`` > 0)."""
        k = self.eval_every if self.eval_every > 0 else self.log_every
        return max(1, min(k, self.steps_per_epoch(n_train)))

    def evals_per_epoch(self, n_train: int) -> int:
        """Validations per epoch when ``eval_every`` > 0: after each full block of k updates."""
        if self.eval_every == 0:
            return 0
        return self.steps_per_epoch(n_train) // self.block_size(n_train)

    def eval_chunk_size(
        self, n_devices: int = 1, n_goals: int = 8, n_points: int = 100, platform: str = "cpu"
    ) -> int:
        """Trajectories per evaluation chunk: ``eval_chunk`` or the largest power of two whose
        first hidden activation (chunk · T · G · H1 elements, all devices together; H1 is
        ARCHETYPE_WIDTH for an archetype) fits
        EVAL_CHUNK_BUDGET of the platform, rounded up to a multiple of ``n_devices``."""
        if self.eval_chunk is not None:
            c = self.eval_chunk
        else:
            budget = EVAL_CHUNK_BUDGET["cpu" if platform == "cpu" else "accelerator"]
            budget *= n_devices
            width = ARCHETYPE_WIDTH if self.model in ARCHETYPE_MODELS else self.hidden[0]
            per = n_points * n_goals * width
            c = 1
            while 2 * c * per <= budget and c < 8192:
                c *= 2
        return -(-c // n_devices) * n_devices

    # ---- serialisation ----

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (tuples become lists)."""
        d = dataclasses.asdict(self)
        d["hidden"] = list(self.hidden)
        if self.model != "reader":  # only the reader reads it: the others' dicts stay as before
            del d["camera"]
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)

    def used_dict(self) -> dict[str, Any]:
        """:meth:`to_dict` less the fields this run never reads, for printing: an archetype's
        has no network (``hidden``, ``activation``, ``start_term``, ``time_weight``,
        ``compute_dtype``), the motion reader none of the MLP's options (``start_term``,
        ``time_weight``, ``compute_dtype``), and each optimiser drops the other's
        hyperparameters (Adam ``rho`` and ``momentum``, RMSprop ``b1`` and ``b2``)."""
        unused = set(UNUSED_BY_OPTIMIZER[self.optimizer])
        if self.model in ARCHETYPE_MODELS:
            unused |= set(MLP_ONLY)
        elif self.model == "reader":
            unused |= set(READER_UNUSED)
        return {k: v for k, v in self.to_dict().items() if k not in unused}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TrainConfig:
        """Rebuild from :meth:`to_dict` output; unknown keys raise ValueError."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"TrainConfig: unknown fields {unknown}")
        kw = dict(d)
        if "hidden" in kw:
            kw["hidden"] = tuple(int(h) for h in kw["hidden"])
        return cls(**kw)


def paper(method: str, **overrides: Any) -> TrainConfig:
    """The paper's hyperparameters (:ref:`concepts-slotv`, :ref:`concepts-trex`), with optional
    overrides.

    SLOT-V: hidden (1536, 768), RMSprop lr 0.005, ρ 0.9, momentum 0, batch 32, 15 epochs.
    T-REX: hidden (1792, 768), Adam lr 0.005, β1 0.9, β2 0.999, batch 128, 25 epochs.
    """
    if method == "slotv":
        base = TrainConfig(
            method="slotv",
            hidden=(1536, 768),
            optimizer="rmsprop",
            learning_rate=0.005,
            rho=0.9,
            momentum=0.0,
            batch_size=32,
            epochs=15,
        )
    elif method == "trex":
        base = TrainConfig(
            method="trex",
            hidden=(1792, 768),
            optimizer="adam",
            learning_rate=0.005,
            b1=0.9,
            b2=0.999,
            batch_size=128,
            epochs=25,
        )
    else:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    return dataclasses.replace(base, **overrides)


def quick(method: str, **overrides: Any) -> TrainConfig:
    """Small, CPU-cheap settings for the quick Table 1 (:ref:`concepts-table1`) **[choice]**.

    Both methods: hidden (64, 32). SLOT-V: RMSprop lr 0.005, batch 32, 3 epochs of the first
    8,000 training trajectories. On the datasets of generator version 5 and later (one via
    point, sharper labels) this was measured against lr 0.002 on 4,000 trajectories (the
    earlier choice): +0.06 to +0.15 on Dragan, FastApp and Nikolaidis, EffDist within 0.01.
    T-REX: Adam lr 0.005, batch 64, 6 epochs of 4,000 pairs (more epochs or data did not
    help it). A few seconds per (labeler, method, trial) on the 2-core CPU, evaluation on
    the four Table 1 splits included (see experiments/table1_quick.md).
    """
    if method == "slotv":
        base = paper(
            "slotv", hidden=(64, 32), learning_rate=0.005, batch_size=32, epochs=3, train_size=8000
        )
    elif method == "trex":
        base = paper("trex", hidden=(64, 32), batch_size=64, epochs=6, train_size=4000)
    else:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    return dataclasses.replace(base, **overrides)


PRESETS = {"quick": quick, "paper": paper}


def archetype(name: str, model: str, **overrides: Any) -> TrainConfig:
    """Preset ``name`` ("quick" or "paper") for an observer archetype (:ref:`concepts-archetypes`)
    **[choice]**.

    An archetype has 4-6 parameters, so it takes the same SLOT-V loss with Adam at a much
    larger learning rate, lr 0.1, batch 32. Quick: 2 epochs of the first 4,000 training
    trajectories (as the quick MLP; 250 updates); paper: one epoch of all of them.
    Measured on the quick data (experiments/explainable.md): the parameters settle within
    about 200 updates at lr 0.1; 0.05 is still short of them after 250.
    """
    if model not in MODELS or model == "mlp":
        raise ValueError(f"model: expected one of {MODELS[1:]}, got {model!r}")
    if name not in PRESETS:
        raise ValueError(f"preset: expected one of {tuple(PRESETS)}, got {name!r}")
    if model == "reader":
        return reader(name, **overrides)
    base = paper("slotv", model=model, optimizer="adam", learning_rate=0.1, epochs=1)
    if name == "quick":
        base = dataclasses.replace(base, train_size=4000, epochs=2)
    return dataclasses.replace(base, **overrides)


def reader(name: str, **overrides: Any) -> TrainConfig:
    """Preset ``name`` ("quick" or "paper") for the motion reader (:ref:`concepts-reader`)
    **[choice]**: a softplus MLP (smooth, for the planner's gradients) of widths (32, 32)
    (quick) or (128, 128) (paper) over its 14 reading features, Adam at lr 0.003, batch 32;
    quick: 3 epochs of the first 8,000 training trajectories (as the quick MLP), paper: 5
    epochs of all of them. Its parameters number ~1,600 (quick) to ~19,000 (paper): a fraction
    of the paper MLP's 1.2 million, so that a prior and 1,000-2,000 answers can place them.
    The quick widths were (64, 64) before 2026-12-07: (32, 32) fits in 0.59 of the time on a
    2-core CPU and kept as much of the oracle's gain in the people loop
    (``experiments/BENCHMARKS.md``, "The quick preset within 40 minutes")."""
    if name not in PRESETS:
        raise ValueError(f"preset: expected one of {tuple(PRESETS)}, got {name!r}")
    base = paper(
        "slotv",
        model="reader",
        hidden=(128, 128),
        activation="softplus",
        optimizer="adam",
        learning_rate=0.003,
        epochs=5,
    )
    if name == "quick":
        base = dataclasses.replace(base, hidden=(32, 32), epochs=3, train_size=8000)
    return dataclasses.replace(base, **overrides)


def preset(name: str, method: str, model: str = "mlp", **overrides: Any) -> TrainConfig:
    """``PRESETS[name](method, **overrides)`` for the MLP, :func:`archetype` for the other
    ``model`` values (``method`` must then be "slotv"), with a clear error for an unknown
    preset."""
    if name not in PRESETS:
        raise ValueError(f"preset: expected one of {tuple(PRESETS)}, got {name!r}")
    if model != "mlp":
        if method != "slotv":
            raise ValueError(
                f"method: the {model!r} archetype trains with SLOT-V's loss ('slotv'); "
                f"T-REX trains only the MLP, got {method!r}"
            )
        return archetype(name, model, **overrides)
    return PRESETS[name](method, **overrides)


#: The observer families fitted on people's answers: the paper MLP, SLOT-V+ (the MLP with
#: the start term and time weights), the Dragan, viewpoint and mixture archetypes, and the
#: motion reader.
FAMILIES = (
    "mlp",
    "slotv_plus",
    "dragan_archetype",
    "viewpoint_archetype",
    "mixture_archetype",
    "reader",
)


def family(name: str, fam: str, **overrides: Any) -> TrainConfig:
    """Preset ``name``'s SLOT-V config of an observer family of :data:`FAMILIES`, fitted on
    answers (``train_size=None``: every answer row)."""
    if fam.endswith("_archetype") and fam in FAMILIES:
        return archetype(name, fam.split("_")[0], train_size=None, **overrides)
    if fam == "reader":
        return reader(name, train_size=None, **overrides)
    cfg = preset(name, "slotv", train_size=None, **overrides)
    if fam == "slotv_plus":
        return dataclasses.replace(cfg, start_term=True, time_weight=True)
    if fam != "mlp":
        raise ValueError(f"family: expected one of {FAMILIES}, got {fam!r}")
    return cfg


def _parse_value(name: str, text: str, annotation: Any) -> Any:
    hint = typing.get_type_hints(TrainConfig)[name]
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType) and type(None) in args:
        if text.strip().lower() in {"none", "null", ""}:
            return None
        hint = next(a for a in args if a is not type(None))
        origin = typing.get_origin(hint)
    try:
        if origin is tuple:
            return tuple(int(v) for v in text.replace("/", ",").split(",") if v.strip())
        if hint is bool:
            low = text.strip().lower()
            if low not in {"true", "false", "1", "0"}:
                raise ValueError(text)
            return low in {"true", "1"}
        if hint is int:
            return int(text)
        if hint is float:
            return float(text)
        return text
    except ValueError as e:
        raise ValueError(f"override {name}={text!r}: cannot parse as {hint}") from e


def apply_overrides(cfg: TrainConfig, items: Iterable[str]) -> TrainConfig:
    """Apply ``key=value`` strings (e.g. ``"hidden=256,128"``, ``"epochs=3"``) to ``cfg``."""
    fields = {f.name: f for f in dataclasses.fields(TrainConfig)}
    changes: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"override {item!r}: expected key=value")
        key, text = (s.strip() for s in item.split("=", 1))
        key = key.replace("-", "_")
        if key not in fields:
            raise ValueError(f"override {item!r}: unknown field {key!r}; known: {sorted(fields)}")
        changes[key] = _parse_value(key, text, fields[key].type)
    return dataclasses.replace(cfg, **changes)
