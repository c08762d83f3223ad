"""Active selection of stimuli: how many answers does each strategy need?

The paper's second limitation (§VI): SLOT-V needs "about 10,000 unique examples" for
80 %, and "it would be interesting to see if this number can be reduced … by more
intelligently sampling trajectories". This experiment runs pool-based active learning
(:mod:`slotv_jax.asking.selection`) with each strategy, side by side, in two settings:

- ``labels`` (the paper's): the pool is the ``train`` split, an answer is the
  hand-crafted labeler's distribution of a whole motion (Dragan, Nikolaidis), the
  observer the paper's SLOT-V network, the target 80 % on ``trajectory_val`` (its first
  ``eval_size`` trajectories, :ref:`concepts-accuracy` accuracy);
- ``study`` (simulated participants, as in ``study_size``): each selected motion is
  shown to ``participants`` simulated people who guess by sampling the labeler's
  distribution (Dragan); the observers are the paper's MLP, SLOT-V+ (start term and time
  weights) and the Dragan archetype; the target a held-out accuracy on ``position_test``
  against the noise-free labeler.

Protocol (every strategy and seed of a group in one vmapped call per step):

1. round 0: ``sizes[0]`` motions drawn at random, the same for every strategy of a seed;
2. each round trains the ensemble (E = ``members``: member 0 a plain run, the others
   bootstrapped; warm start) more updates of ``batch_size`` answer rows: blocks of
   ``updates`` (study: ``study_updates``), as many as pass ``round_epochs`` times over the
   answers so far (:meth:`ActiveConfig.round_updates`), and records member 0's held-out
   accuracy against the number of answers so far;
3. the strategy scores ``subset`` motions drawn from the unasked part of the pool (the
   same draw for every strategy of a seed) and asks about the next ``sizes[r+1] −
   sizes[r]``.

Strategies and seeds share what they can (initialisation, seed set, candidate subsets,
the participants' answers to each motion), so the curves differ by the selection. The
answers a run needs for the target: the first round whose accuracy reaches it,
interpolated linearly in log answers from the round before; the mean over seeds is
``answers_to_target`` (null when a seed never reaches it within the largest size).
Choices of protocol are tried on other seeds and held-out motions than the reported
ones (``--first-seed``, ``--eval-offset``).

    python -m slotv_jax.experiments.active                  # quick (CPU, minutes)
    python -m slotv_jax.experiments.active --preset paper   # the paper's network (GPU)

Writes ``OUT/active{,_paper}_results.json`` (config, curves, ``comparisons``, timings;
a rerun resumes finished groups), ``.md`` and ``.png``, rendered from the JSON; ``--report``
renders them again from a recorded results document alone (``--preset paper --out
experiments``: ``experiments/active_paper.md``).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.asking import replay, selection
from slotv_jax.asking.replay import ORACLES, geometric, up_to
from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.active_report import fmt_answers, render, stem_of, summarise
from slotv_jax.runs import command, presets, record
from slotv_jax.training import config as train_config


@dataclasses.dataclass(frozen=True)
class ActiveConfig:
    """One active-selection experiment (module docstring)."""

    preset: str
    data: data_lib.DataConfig
    train_preset: str  # slotv_jax.config preset of the observers
    labels_labelers: tuple[str, ...]  # the labels setting's labelers (paper MLP)
    study_models: tuple[str, ...]  # the study setting's observers: mlp, slotv_plus, dragan
    label_sizes: tuple[int, ...]  # labelled motions after each round (labels setting)
    study_sizes: tuple[int, ...]  # motions asked after each round (study setting)
    updates: int  # least updates per round of the labels setting (warm start), a block
    study_updates: int  # the same for the study setting (one guess per answer: noisier)
    participants: int  # simulated answers per motion (study setting)
    study_targets: tuple[tuple[str, float], ...]  # held-out accuracy target per model
    strategies: tuple[str, ...] = selection.STRATEGIES + ORACLES  # oracles: bounds
    seeds: int = 3
    first_seed: int = 0  # seeds first_seed … first_seed + seeds − 1 (tuning runs use others)
    round_epochs: float = 0.0  # each round passes this often over the answers so far (≥ updates)
    members: int = 4  # ensemble size E
    subset: int = 1000  # candidates scored per run and round
    stride: int = 1  # keep every stride-th point of each motion (1: all)
    study_labeler: str = "dragan"
    labels_target: float = 0.8
    eval_size: int = 1000
    eval_offset: int = 0  # held-out motions eval_offset … + eval_size (tuning runs use others)
    chunk: int = 256  # candidates per scoring chunk
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides (MLP models)

    def __post_init__(self):
        for name in ("label_sizes", "study_sizes"):
            sizes = getattr(self, name)
            if len(sizes) < 2 or list(sizes) != sorted(set(sizes)) or sizes[0] < 1:
                raise ValueError(f"{name}: expected at least 2 increasing sizes, got {sizes}")
            k_max = max(b - a for a, b in itertools.pairwise(sizes))
            if self.subset < 2 * k_max:
                raise ValueError(
                    f"subset: expected at least twice the largest batch ({k_max} in {name}), "
                    f"got {self.subset}"
                )
        bad = [s for s in self.strategies if s not in selection.STRATEGIES + ORACLES]
        if bad or "random" not in self.strategies:
            raise ValueError(
                f"strategies: expected 'random' and names of {selection.STRATEGIES + ORACLES}"
            )
        if self.round_epochs < 0 or self.updates < 1 or self.study_updates < 1:
            raise ValueError("updates, study_updates: expected >= 1; round_epochs: >= 0")
        missing = [m for m in self.study_models if m not in dict(self.study_targets)]
        if missing:
            raise ValueError(f"study_targets: no target for {missing}")
        validation.check_seeds("first_seed", self.first_seed, self.seeds, count_name="seeds")

    def train_config(self, model: str) -> train_config.TrainConfig:
        if model == "dragan":
            return train_config.archetype(self.train_preset, "dragan", train_size=None)
        cfg = train_config.preset(self.train_preset, "slotv", train_size=None)
        if model == "slotv_plus":
            cfg = presets.plus(cfg)
        elif model != "mlp":
            raise ValueError(f"model: expected mlp, slotv_plus or dragan, got {model!r}")
        return train_config.apply_overrides(cfg, self.overrides)

    def round_updates(self, setting: str, size: int) -> int:
        """Updates of round with ``size`` answer rows: the smallest multiple of the block
        (``updates``, study ``study_updates``) that passes ``round_epochs`` times over the
        rows (warm start: every round trains until the answers so far are fitted, not a
        fixed budget that the largest sizes outgrow)."""
        block = self.updates if setting == "labels" else self.study_updates
        batch = self.train_config("mlp").batch_size
        return block * max(1, math.ceil(self.round_epochs * size / (batch * block)))

    def groups(self) -> list[tuple[str, str, str]]:
        """(setting, labeler, model) of every group, in run order."""
        return [("labels", lab, "mlp") for lab in self.labels_labelers] + [
            ("study", self.study_labeler, m) for m in self.study_models
        ]

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["train"] = {m: self.train_config(m).to_dict() for m in {"mlp", *self.study_models}}
        return json.loads(json.dumps(d))


def quick(**overrides) -> ActiveConfig:
    """CPU preset: the quick dataset, hidden 64/32 networks on every 4th point, E = 3, up to
    256 motions; study targets 75 % (the quick network's budget, ``study_size``)."""
    base = ActiveConfig(
        preset="quick",
        data=data_lib.quick(),
        train_preset="quick",
        labels_labelers=("dragan", "nikolaidis"),
        study_models=("mlp", "slotv_plus", "dragan"),
        label_sizes=geometric(16, 256, 2.0),
        study_sizes=geometric(16, 256, 2.0),
        updates=100,
        study_updates=100,
        participants=20,
        study_targets=(("mlp", 0.75), ("slotv_plus", 0.75), ("dragan", 0.9)),
        members=3,
        stride=4,
        subset=1024,
        round_epochs=4.0,
    )
    return dataclasses.replace(base, **overrides)


def paper(**overrides) -> ActiveConfig:
    """GPU preset: the paper's dataset and SLOT-V network (1536/768, bfloat16 matmuls) on
    every point, E = 3."""
    base = ActiveConfig(
        preset="paper",
        data=data_lib.paper(),
        train_preset="paper",
        labels_labelers=("dragan", "nikolaidis"),
        study_models=("mlp", "slotv_plus", "dragan"),
        label_sizes=geometric(8, 1024, math.sqrt(2)),
        study_sizes=geometric(8, 2048, math.sqrt(2))[:-1],  # 8 … 1,448
        updates=100,
        study_updates=300,
        round_epochs=4.0,
        participants=20,
        study_targets=(("mlp", 0.8), ("slotv_plus", 0.8), ("dragan", 0.9)),
        strategies=("random", "uncertainty", "margin", "bald", "bald_cluster", "epig", *ORACLES),
        seeds=5,
        members=3,
        subset=8192,
        eval_size=3000,
        chunk=64,
        overrides=("compute_dtype=bfloat16",),
    )
    return dataclasses.replace(base, **overrides)


PRESETS = {"quick": quick, "paper": paper}
PROG = "python -m slotv_jax.experiments.active"


# ------------------------------------------------------------------- running


def run_group(
    cfg: ActiveConfig, splits, setting: str, labeler: str, model: str, *, progress: bool = True
) -> dict:
    """Every strategy × seed of one (setting, labeler, model) group
    (:func:`slotv_jax.asking.replay.run_rounds`); returns its curves."""
    sizes = cfg.label_sizes if setting == "labels" else cfg.study_sizes
    eval_split = "trajectory_val" if setting == "labels" else "position_test"
    train = replay.motion_arrays(splits["train"], labeler, cfg.stride)
    held = replay.held_out_motions(
        splits[eval_split], eval_split, labeler, cfg.stride, cfg.eval_offset, cfg.eval_size
    )
    seeds = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    _, _, mask, probs = train
    answers = {
        sd: probs.astype(np.float32)
        if setting == "labels"
        else replay.guess_counts(sd, probs, mask, cfg.participants)
        for sd in seeds
    }
    acc, times = replay.run_rounds(
        cfg.train_config(model), train, held, answers, sizes=sizes, strategies=cfg.strategies,
        seeds=seeds, members=cfg.members, subset=cfg.subset,
        block=cfg.updates if setting == "labels" else cfg.study_updates,
        round_updates=lambda size: cfg.round_updates(setting, size), chunk=cfg.chunk,
        progress=progress, desc=f"{setting}/{labeler}/{model}",
    )  # fmt: skip
    per = 1 if setting == "labels" else cfg.participants
    runs = [(s, sd) for s in cfg.strategies for sd in seeds]
    return {
        "setting": setting,
        "labeler": labeler,
        "model": model,
        "answers": [int(s * per) for s in sizes],
        "motions": list(sizes),
        "runs": [
            {"strategy": s, "seed": sd, "accuracy": acc[i].round(6).tolist()}
            for i, (s, sd) in enumerate(runs)
        ],
        "timing": {k: round(v, 2) for k, v in times.items()},
    }


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment (ours to resume)."""
    return fileio.is_json_object_with(path, ("preset", "config", "groups"))


def run(
    cfg: ActiveConfig,
    out: Path,
    *,
    cache: Path = Path("data"),
    progress: bool = True,
    only: Sequence[tuple[str, str, str]] | None = None,
):
    """Run (or resume) every group (or the groups ``only``); returns the results document
    (also written after each group)."""
    stem = stem_of(cfg.preset)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{stem}_results.json"
    conf = cfg.to_json()
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc.get("config") != conf:
        doc = {"preset": cfg.preset, "config": conf, "groups": [], "timing": {}}
    done = {(g["setting"], g["labeler"], g["model"]) for g in doc["groups"]}
    todo = [g for g in cfg.groups() if g not in done and (only is None or g in only)]
    t_start = time.perf_counter()
    load = record.load_start()
    if todo:  # a finished document is only summarised again (where it ran, as it was)
        doc["environment"] = environment()
        doc["machine"] = record.machine()
        doc["xla"] = slotv_jax.XLA_CONFIG.summary()
        ddir = data_lib.dataset_dir(cache, cfg.data)
        splits = data_lib.generate_dataset(
            cfg.data, ddir, progress=progress, splits=("train", "trajectory_val", "position_test")
        )
        doc["dataset"] = str(ddir)
    for setting, labeler, model in tqdm(todo, desc="active groups", disable=not progress):
        t0 = time.perf_counter()
        grp = run_group(cfg, splits, setting, labeler, model, progress=progress)
        grp["timing"]["total_s"] = round(time.perf_counter() - t0, 2)
        doc["groups"].append(grp)
        summarise(doc)
        write_text(path, json.dumps(doc, indent=1))
    summarise(doc)
    if todo:
        doc["timing"]["total_s"] = doc["timing"].get("total_s", 0.0) + time.perf_counter() - t_start
        doc["load"] = record.load_end(load)
        doc["date"] = record.utc_now()
    write_text(path, json.dumps(doc, indent=1))
    return doc


def _parse_args(argv):
    ap = command.seeded_parser(PROG, __doc__.split("\n\n")[0], PRESETS)
    ap.add_argument("--updates", type=int, default=None, help="updates per round (labels)")
    ap.add_argument("--study-updates", type=int, default=None, help="updates per round (study)")
    ap.add_argument("--members", type=int, default=None, help="ensemble size E")
    ap.add_argument(
        "--study-max",
        type=int,
        default=None,
        metavar="MOTIONS",
        help="study setting: continue the preset's geometric sizes up to this many motions",
    )
    ap.add_argument(
        "--groups",
        default=None,
        help="run only these groups (setting/labeler/model, comma-separated, e.g. "
        "labels/dragan/mlp); the results document is shared",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="TrainConfig override of the MLP models, e.g. compute_dtype=bfloat16",
    )
    return ap.parse_args(argv)


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    out = Path(args.out)
    if args.report:
        again = lambda doc, cmd: render(summarise(doc), out, cmd)  # noqa: E731
        return command.render_again(
            out, stem_of(args.preset), is_results, again, f"{PROG} --preset {args.preset}"
        )
    kw = command.seeded_overrides(args, ("updates", "study_updates", "members"))
    if args.study_max is not None:
        base = PRESETS[args.preset]().study_sizes
        if args.study_max < base[1]:
            raise cli.InputError(f"--study-max: expected at least {base[1]} motions")
        kw["study_sizes"] = up_to(base, args.study_max)
    cfg = PRESETS[args.preset](**kw)
    if args.set:
        cfg = dataclasses.replace(cfg, overrides=cfg.overrides + tuple(args.set))
        cfg.train_config("mlp")
    only = None
    if args.groups:
        only = [tuple(g.strip().split("/")) for g in args.groups.split(",")]
        bad = [g for g in only if g not in cfg.groups()]
        if bad:
            raise cli.InputError(
                f"--groups: {'/'.join(bad[0])} is not a group of this preset; expected some "
                f"of {', '.join('/'.join(g) for g in cfg.groups())}"
            )
    command.prepare_out(out, stem_of(cfg.preset), is_results)
    print(slotv_jax.XLA_CONFIG.summary(), flush=True)
    doc = run(cfg, out, cache=Path(args.cache), progress=not args.no_progress, only=only)
    render(doc, out, record.command_line(PROG, argv))
    for c in doc["comparisons"] + doc["oracles"]:
        print(
            f"{c['setting']}/{c['labeler']}/{c['model']} {c['strategy']}: "
            f"{fmt_answers(c['answers_to_target'])} answers"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
