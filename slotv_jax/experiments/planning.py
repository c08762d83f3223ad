"""Can a learned observer replace a hand-crafted one inside a legible planner?

    python -m slotv_jax.experiments.planning                     # quick preset, CPU, minutes
    python -m slotv_jax.experiments.planning --preset paper --out runs/planning_paper

Steps:

1. the dataset of the preset (:mod:`slotv_jax.data`, cached by config digest as in
   :mod:`slotv_jax.experiments.table1`): the train split for the learned observers, the
   held-out scenes of position_test and goal_count_test for the problems;
2. problems: every (held-out scene, real goal) pair, start TCP(q_home). The quick
   preset uses the stored scenes (10 per split); the paper preset draws the two
   held-out scene sets further, from the same random streams, so that the first 10
   are the stored ones (checked) and the rest are new scenes of the same splits,
   never seen in training (>= 500 problems);
3. observers: the straight line (no optimisation), the Dragan labeler (the oracle),
   SLOT-V and T-REX trained on Dragan labels, and the same three for Nikolaidis.
   Learned observers come from ``--slotv-dragan CKPT`` etc., or are trained here with
   the preset's training config and saved under ``OUT/observers/``. Beside them, in
   ``plus_planners``: SLOT-V+ and T-REX+, the same networks with values relative to the
   start's and learned time weights (``start_term``, ``time_weight``:
   :class:`slotv_jax.models.SlotV`), which a planner cannot exploit the way it exploits
   the paper's score (the paper preset trains SLOT-V+ for 5 epochs: :func:`paper`); in
   ``archetype_planners``: SLOT-V's loss with the family's parametric observer archetype
   (SPEC §10: ``dragan`` for Dragan, ``viewpoint`` for Nikolaidis), which separates what
   the loss learns from what a network can represent;
4. every observer plans every problem with :mod:`slotv_jax.planning` (one compiled
   program for all observers). One temperature per family rules the oracle planner and
   the scoring: the dataset's (``cfg.data.labels``, SPEC §4 "Default temperatures"), the
   temperature of the labels the learned observers were trained on, recorded as
   ``config.scoring_betas``. Every plan is scored by that labeler: mean and SD of
   y_target, the rate at which the target is the labeler's argmax, the path-length ratio
   to the straight line, feasibility, how often the plan's true legibility fell below the
   straight line's, and the fraction of the oracle's gain (mean y_target over the straight
   line) each learned observer keeps;
5. ``OUT/results.json`` (SPEC §10 schema plus these extras), ``OUT/plans.npz`` (example
   plans, below), the figures rendered from those two files and ``OUT/planning.md``
   rendered from ``results.json``.

``plans.npz`` (:mod:`slotv_jax.planning.plans`) holds the plans of every planner for up
to :data:`N_SAVED` problems per family: the first problems of evenly spaced held-out scenes
with at least three goals, the same problems for both families (the Dragan family's rows
first), with each row's ``family``, scoring ``beta``, ``problem``, ``split`` and ``scene``;
``y`` is under the family's labeler. A planner missing for a family (an archetype left
out) has NaN rows.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np
from flax import nnx
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.planning_report import FIGURES, render, report, write_doc
from slotv_jax.observers import models
from slotv_jax.planning import evaluation
from slotv_jax.planning.plans import save_plans
from slotv_jax.runs import command, presets
from slotv_jax.training import checkpoint, evaluate
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

FAMILIES = ("dragan", "nikolaidis")  # the true labelers; each is its own family's oracle
METHODS = ("slotv", "trex")  # the learned observers of SPEC's `planners` rows
# SLOT-V+ and T-REX+: the same networks with the learned start term and time weights
# (models._Observer); their rows are plus_planners
PLUS = {"slotv_plus": "slotv", "trex_plus": "trex"}
ARCHETYPES = {"dragan": "dragan", "nikolaidis": "viewpoint"}  # family -> archetype model
LEARNED = (*METHODS, *PLUS, "archetype")
SPLITS = ("position_test", "goal_count_test")
N_SAVED = 8  # problems per family whose plans go to plans.npz


@dataclasses.dataclass(frozen=True)
class PlanningConfig:
    """What one run of the experiment does."""

    preset: str
    data: data_lib.DataConfig
    train: dict[str, train_config.TrainConfig]  # method -> training config of the observers
    planner: planning.PlannerConfig
    n_scenes: int  # held-out scenes per split (the stored ones first)
    seed: int = 0  # training seed of the learned observers
    n_examples: int = 3  # example scenes in the figure
    # family -> training config of its archetype observer (empty: no archetype rows)
    archetype: dict[str, train_config.TrainConfig] = dataclasses.field(default_factory=dict)
    plus: bool = True  # also plan with SLOT-V+ and T-REX+ (plus_planners)
    # method ("slotv_plus", "trex_plus") -> training epochs, where they differ from the base
    # network's (the paper preset trains SLOT-V+ for 5: see paper())
    plus_epochs: dict[str, int] = dataclasses.field(default_factory=dict)

    def observer_config(self, method: str, family: str) -> train_config.TrainConfig:
        """Training config of a learned observer (``method`` in :data:`LEARNED`): the
        preset's network for SLOT-V and T-REX, the same with the learned start term and
        time weights for SLOT-V+ and T-REX+ (``_plus``; epochs from ``plus_epochs`` where
        given), the family's archetype for "archetype"."""
        if method == "archetype":
            return self.archetype[family]
        if method in PLUS:
            base = self.train[PLUS[method]]
            epochs = self.plus_epochs.get(method, base.epochs)
            return dataclasses.replace(presets.plus(base), epochs=epochs)
        return self.train[method]

    def methods(self, family: str) -> tuple[str, ...]:
        """The learned observers of ``family``: SLOT-V, T-REX and, if configured, SLOT-V+,
        T-REX+ and the family's archetype."""
        plus = tuple(PLUS) if self.plus else ()
        return (*METHODS, *plus, *(("archetype",) if family in self.archetype else ()))

    def learned(self) -> list[tuple[str, str]]:
        """``(method, family)`` of every learned observer of the run."""
        return [(m, f) for f in FAMILIES for m in self.methods(f)]

    def scoring_betas(self) -> dict[str, float]:
        """β of each family's labeler, for its oracle planner and for scoring every plan:
        the dataset's, which labelled the learned observers' training data."""
        betas = self.data.labels.betas()
        return {f: betas[f] for f in FAMILIES}

    def to_json(self) -> dict:
        return {
            "preset": self.preset,
            "scoring_betas": self.scoring_betas(),
            "data": self.data.to_json(),
            "data_digest": self.data.digest(),
            "train": {m: c.to_dict() for m, c in self.train.items()},
            "archetype": {f: c.to_dict() for f, c in self.archetype.items()},
            "plus": self.plus,
            "plus_epochs": dict(self.plus_epochs),
            "planner": self.planner.to_dict(),
            "n_scenes": self.n_scenes,
            "seed": self.seed,
        }


def quick() -> PlanningConfig:
    """CPU preset: quick data and observers (as Table 1's quick preset), the 20 stored
    held-out scenes (about 100 problems)."""
    d = data_lib.quick()
    t = {m: train_config.quick(m) for m in METHODS}
    a = {f: train_config.archetype("quick", m) for f, m in ARCHETYPES.items()}
    return PlanningConfig("quick", d, t, planning.PlannerConfig(), d.n_new_scenes, archetype=a)


def paper() -> PlanningConfig:
    """Paper-size data and observers (use a GPU), 60 held-out scenes per split (>= 500
    problems: about 4 goals per position_test scene and 6 per goal_count_test scene).

    SLOT-V+ trains 5 of the paper's 15 epochs **[choice]**: as accurate on held-out data,
    and its plans kept more of the Nikolaidis oracle's gain (experiments/planning_paper.md).
    """
    t = {m: train_config.paper(m) for m in METHODS}
    a = {f: train_config.archetype("paper", m) for f, m in ARCHETYPES.items()}
    return PlanningConfig(
        "paper",
        data_lib.paper(),
        t,
        planning.PlannerConfig(),
        60,
        archetype=a,
        plus_epochs={"slotv_plus": 5},
    )


def tiny() -> PlanningConfig:
    """A seconds-scale preset for tests and smoke runs (not a result)."""
    d = data_lib.DataConfig(
        preset="tiny", n_train=300, n_eval=100, n_train_scenes=20, n_new_scenes=2, chunk_size=512
    )
    t = {m: train_config.quick(m, hidden=(16, 8), epochs=1, train_size=None) for m in METHODS}
    a = {
        f: train_config.archetype("quick", m, train_size=None, epochs=1)
        for f, m in ARCHETYPES.items()
    }
    p = planning.PlannerConfig(iters=3)
    return PlanningConfig("tiny", d, t, p, n_scenes=2, n_examples=1, archetype=a)


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


# ------------------------------------------------------------------- problems


def make_problems(scenes: dict) -> dict[str, np.ndarray]:
    """Every (scene, real goal) pair of the held-out :data:`SPLITS`
    (:func:`slotv_jax.planning.evaluation.scene_problems`)."""
    return evaluation.scene_problems(scenes, SPLITS)


# ------------------------------------------------------------------ observers


def train_observer(
    cfg: PlanningConfig, method: str, labeler: str, train_split, out: Path
) -> tuple[Path, float]:
    """Train one observer (``method`` in :data:`LEARNED`) with the preset's config on
    ``labeler`` labels; save it to ``out``."""
    tc = cfg.observer_config(method, labeler)
    t0 = time.perf_counter()
    data = train.prepare(train_split, labeler, size=tc.train_size)
    state, _ = train.train_trials(tc, data, [cfg.seed], progress=False)
    state = train.select_trial(state, 0)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - t0
    meta = {
        "labeler": labeler,
        "seed": cfg.seed,
        "data_digest": cfg.data.digest(),
        "train_seconds": round(seconds, 2),
        "trained_by": "slotv_jax.experiments.planning",
    }
    checkpoint.save(out, tc, state, meta=meta)
    return out, seconds


def observer_facts(observer, labeler: str, splits: dict) -> dict:
    """What a loaded learned observer (:func:`slotv_jax.load_observer`) says about itself:
    its accuracy (SPEC §8) on the ``labeler`` labels of each split's trajectories and, with
    time weights, the learned exponent α (``alpha``)."""
    tc, params = observer.config, observer.params
    acc = {s: float(evaluate.accuracy(tc, params, d, labeler)) for s, d in splits.items()}
    facts: dict = {"accuracy": acc}
    if tc.model == "mlp":
        model = nnx.merge(models.graphdef(tc), params)
        if model.alpha is not None:
            facts["alpha"] = float(model.alpha)
    return facts


def oracles(cfg: PlanningConfig) -> dict[str, planning.Observer]:
    """The hand-crafted observer of each family at the dataset's temperature and camera."""
    cam, betas = cfg.data.labels.camera, cfg.scoring_betas()
    return {f: planning.labeler_observer(f, beta=betas[f], camera=cam) for f in FAMILIES}


def observer_key(name: str, family: str) -> str:
    """Key of an observer in the planner: the labelers by name, learned ones by method/family."""
    return name if name in FAMILIES else f"{name}/{family}"


# ------------------------------------------------------------------------ run


def run(
    cfg: PlanningConfig,
    out: Path,
    *,
    checkpoints: dict[tuple[str, str], Path] | None = None,
    cache: Path = Path("data"),
    progress: bool = True,
) -> dict:
    """Run the experiment; write ``results.json``, ``plans.npz``, the figures and the report."""
    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    timing: dict[str, float] = {}

    t0 = time.perf_counter()
    ddir = data_lib.dataset_dir(cache, cfg.data)
    splits = ("train", *SPLITS)
    dataset = data_lib.generate_dataset(cfg.data, ddir, splits=splits, progress=progress)
    timing["data_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    problems = make_problems(data_lib.held_out_scenes(cfg.data, dataset, cfg.n_scenes, SPLITS))
    timing["scenes_s"] = time.perf_counter() - t0

    # Observers: the oracles, and the learned ones (given, or trained here on the dataset).
    betas, camera = cfg.scoring_betas(), cfg.data.labels.camera
    observers = oracles(cfg)
    checkpoints = dict(checkpoints or {})
    sources: dict[str, dict] = {}
    timing["train_s"] = 0.0
    for method, family in cfg.learned():
        key, path = observer_key(method, family), checkpoints.get((method, family))
        trained = path is None
        if trained:
            path, sec = train_observer(
                cfg, method, family, dataset["train"], out / "observers" / f"{method}_{family}"
            )
            timing["train_s"] += sec
        model = cfg.observer_config(method, family).model
        observers[key] = slotv_jax.load_observer(path, model=model)
        facts = observer_facts(observers[key], family, {s: dataset[s] for s in SPLITS})
        sources[key] = {"checkpoint": str(path), "trained": trained, **facts}

    # Plans: one compiled program for every observer.
    planner = planning.make_planner(observers, cfg.planner)
    n_obs = len(planner.observers)
    note = f"planning: compiling one program for {n_obs} observers (a minute or two on a CPU)"
    print(note, file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    straight = planner.straight_line(problems["goals"], problems["goal_mask"], problems["target"])
    straight = jax.device_get(straight)
    timing["straight_line_s"] = time.perf_counter() - t0
    plans: dict[str, planning.PlanResult] = {}
    timing["plan_s"] = {}
    for name in tqdm(planner.observers, desc="planning", unit="observer", disable=not progress):
        t0 = time.perf_counter()
        plans[name] = jax.device_get(planner.plan_problems(straight, observer=name))
        timing["plan_s"][name] = time.perf_counter() - t0

    # Scores under the labeler of each family at the dataset's temperature.
    goals, mask, target = problems["goals"], problems["goal_mask"], problems["target"]
    len_straight = evaluation.path_length(straight.xyz)
    rows: dict[str, list[dict]] = {"planners": [], "plus_planners": [], "archetype_planners": []}
    labels: dict[tuple[str, str], np.ndarray] = {}
    gains: dict[str, float | None] = {}
    for family in FAMILIES:
        y_s_all = evaluation.true_labels(
            family, straight.xyz, goals, mask, beta=betas[family], camera=camera
        )
        y_s = y_s_all[np.arange(len(target)), target]
        labels[family, "straight"] = y_s_all
        ok_s = np.asarray(straight.target_residual) <= planning.MAX_RESIDUAL
        ones = np.ones_like(len_straight)
        argmax = y_s_all.argmax(-1) == target
        rows["planners"].append(
            evaluation.summarise("straight", family, y_s, y_s, argmax, ones, ok_s)
        )
        for name in (family, *cfg.methods(family)):
            res = plans[observer_key(name, family)]
            y_all = evaluation.true_labels(
                family, res.xyz, goals, mask, beta=betas[family], camera=camera
            )
            labels[family, name] = y_all
            row = evaluation.plan_row(name, family, res, y_all, y_s, len_straight, problems, SPLITS)
            if name == "archetype":
                row["model"] = cfg.observer_config(name, family).model
            group = "archetype_planners" if name == "archetype" else "planners"
            rows["plus_planners" if name in PLUS else group].append(row)
        oracle_gain = next(r for r in rows["planners"] if r["observer"] == family)["mean_gain"]
        for r in (r for group in rows.values() for r in group):
            if r["labeler"] == family and r["observer"] in LEARNED:
                r["oracle_gain_kept"] = evaluation.gain_kept(r["mean_gain"], oracle_gain)
                gains[f"{r['observer']}/{family}"] = r["oracle_gain_kept"]

    timing["total_s"] = time.perf_counter() - t_start
    doc = {
        "preset": cfg.preset,
        "environment": environment(),
        "config": cfg.to_json(),
        "dataset": str(ddir),
        "observers": sources,
        "n_problems": len(target),
        "n_problems_by_split": {
            s: int((problems["split"] == i).sum()) for i, s in enumerate(SPLITS)
        },
        # SPEC's rows; SLOT-V+ and T-REX+ (learned start term and time weights); SLOT-V's
        # loss with the family's parametric archetype (the last two not SPEC rows)
        **rows,
        "oracle_gain_kept": gains,
        "timing": timing,
    }
    write_text(out / "results.json", json.dumps(doc, indent=1))
    save_plans(out / "plans.npz", saved_plans(cfg, problems, straight, plans, labels))
    render(out, cfg.n_examples)
    write_text(out / "planning.md", report(doc))
    return doc


def example_indices(problems: dict, n: int) -> list[int]:
    """The first problem of ``n`` evenly spaced scenes with at least three goals
    (deterministic; all scenes if none has three)."""
    split, scene_ = problems["split"], problems["scene"]
    many = np.flatnonzero(problems["goal_mask"].sum(-1) >= 3)
    first = [i for i in many if i == 0 or scene_[i] != scene_[i - 1] or split[i] != split[i - 1]]
    first = first or list(range(len(problems["target"])))
    pick = np.linspace(0, len(first) - 1, min(n, len(first))).round().astype(int)
    return [int(first[i]) for i in pick]


def saved_plans(cfg: PlanningConfig, problems: dict, straight, plans: dict, labels: dict) -> dict:
    """The arrays of ``plans.npz`` (:mod:`slotv_jax.planning.plans`, with the module
    docstring's extras) for the :func:`example_indices`."""
    idx = example_indices(problems, N_SAVED)
    names = ("straight", "oracle", *dict.fromkeys(m for f in FAMILIES for m in cfg.methods(f)))
    fams = [f for f in FAMILIES for _ in idx]
    probs = np.asarray(idx * len(FAMILIES), np.int32)
    T = np.shape(straight.xyz)[1]
    q = np.full((len(names), len(probs), T, 7), np.nan, np.float32)
    xyz = np.full((len(names), len(probs), T, 3), np.nan, np.float32)
    y = np.full((len(names), len(probs), problems["goals"].shape[1]), np.nan, np.float32)
    for k, name in enumerate(names):
        for p, (family, i) in enumerate(zip(fams, probs, strict=True)):
            key = {"straight": "straight", "oracle": family}.get(name, name)
            res = straight if key == "straight" else plans.get(observer_key(key, family))
            if res is not None:
                q[k, p], xyz[k, p], y[k, p] = res.q[i], res.xyz[i], labels[family, key][i]
    betas = cfg.scoring_betas()
    return {
        **{k: problems[k][probs] for k in ("goals", "goal_mask", "target", "scene")},
        "family": np.asarray(fams, str),
        "beta": np.asarray([betas[f] for f in fams], np.float32),
        "problem": probs,
        "split": np.asarray([SPLITS[s] for s in problems["split"][probs]], str),
        "names": np.asarray(names, str),
        "q": q,
        "xyz": xyz,
        "y": y,
    }


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.experiments.planning",
        description="Plan legible motion with hand-crafted and learned observers; score it with "
        "the true labelers.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--out", type=Path, help="results directory (default: runs/planning_<preset>)")
    p.add_argument("--cache", type=Path, default=Path("data"), help="dataset cache directory")
    for method in LEARNED:
        for family in FAMILIES:
            what = f"the {ARCHETYPES[family]} archetype" if method == "archetype" else method
            p.add_argument(
                f"--{method.replace('_', '-')}-{family}", type=Path, metavar="CKPT",
                help=f"checkpoint of {what} trained on {family} labels (default: train one)",
            )  # fmt: skip
    p.add_argument("--no-plus", action="store_true",
                   help="leave out SLOT-V+ and T-REX+ (plus_planners)")  # fmt: skip
    p.add_argument("--no-archetypes", action="store_true",
                   help="leave out the archetype observers (archetype_planners)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="training seed of the learned observers")
    p.add_argument("--n-scenes", type=int, help="held-out scenes per split (default: preset's)")
    p.add_argument("--iters", type=int, help="planner iterations (default: preset's)")
    p.add_argument("--budget", type=float, help="trust-region budget in m² (default: preset's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a TrainConfig field of the SLOT-V and T-REX observers, e.g. "
                   "--set activation=softplus")  # fmt: skip
    p.add_argument("--compute-dtype", choices=train_config.COMPUTE_DTYPES,
                   help="matmul dtype of the observers' training (bfloat16 on GPUs)")  # fmt: skip
    p.add_argument("--doc", type=Path, help="also write the report here, figures beside it")
    args = p.parse_args(argv)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)

    cfg = dataclasses.replace(PRESETS[args.preset](), seed=args.seed)
    if args.n_scenes is not None:
        if args.n_scenes < 1:
            raise cli.InputError(f"--n-scenes: expected an integer >= 1, got {args.n_scenes}")
        cfg = dataclasses.replace(cfg, n_scenes=args.n_scenes)
    changes = {k: v for k, v in (("iters", args.iters), ("budget", args.budget)) if v is not None}
    if changes:
        try:
            cfg = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, **changes))
        except ValueError as e:
            raise cli.InputError(f"--iters/--budget: {e}") from None
    cfg = dataclasses.replace(cfg, train=command.retrained(cfg.train, args.compute_dtype, args.set))
    if args.no_archetypes:
        cfg = dataclasses.replace(cfg, archetype={})
    if args.no_plus:
        cfg = dataclasses.replace(cfg, plus=False)
    ckpts = {
        (m, f): getattr(args, f"{m}_{f}")
        for m in LEARNED
        for f in FAMILIES
        if getattr(args, f"{m}_{f}") is not None
    }
    out = args.out or Path("runs") / f"planning_{args.preset}"
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    if args.doc is not None:
        names = [args.doc.name, *(f"{args.doc.stem}_{f}" for f in FIGURES)]
        fileio.check_output_files(args.doc.parent, names, what="--doc")
    doc = run(cfg, out, checkpoints=ckpts, cache=args.cache)
    if args.doc is not None:
        write_doc(out, doc, args.doc)
    print(report(doc))
    print(f"results in {out / 'results.json'}; report in {out / 'planning.md'}; "
          f"{doc['timing']['total_s']:.0f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
