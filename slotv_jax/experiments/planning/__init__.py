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
   (:ref:`concepts-archetypes`: ``dragan`` for Dragan, ``viewpoint`` for Nikolaidis), which
   separates what the loss learns from what a network can represent;
4. every observer plans every problem with :mod:`slotv_jax.planning` (one compiled
   program for all observers). One temperature per family rules the oracle planner and
   the scoring: the dataset's (``cfg.data.labels``, :ref:`concepts-temperatures` "Default
   temperatures"), the temperature of the labels the learned observers were trained on, recorded as
   ``config.scoring_betas``. Every plan is scored by that labeler: mean and SD of
   y_target, the rate at which the target is the labeler's argmax, the path-length ratio
   to the straight line, feasibility, how often the plan's true legibility fell below the
   straight line's, and the fraction of the oracle's gain (mean y_target over the straight
   line) each learned observer keeps;
5. ``OUT/results.json`` (:ref:`concepts-archetypes` schema plus these extras), ``OUT/plans.npz``
   (example plans, below), the figures rendered from those two files and ``OUT/planning.md``
   rendered from ``results.json``.

``plans.npz`` (:mod:`slotv_jax.planning.plans`) holds the plans of every planner for up
to :data:`N_SAVED` problems per family: the first problems of evenly spaced held-out scenes
with at least three goals, the same problems for both families (the Dragan family's rows
first), with each row's ``family``, scoring ``beta``, ``problem``, ``split`` and ``scene``;
``y`` is under the family's labeler. A planner missing for a family (an archetype left
out) has NaN rows.

The package: :mod:`~slotv_jax.experiments.planning.config` (families, observers, presets),
:mod:`~slotv_jax.experiments.planning.examples` (the plans kept), this module (problems,
observers, the run) and ``__main__`` (the command line); the report and figures are
:mod:`slotv_jax.experiments.planning_report`; the figure of its plans seen by the
observer is ``python -m slotv_jax.render --plans PLANS --grid`` (the README's command).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import numpy as np
from flax import nnx
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.planning.config import (  # noqa: F401  (the package's names)
    ARCHETYPES,
    FAMILIES,
    LEARNED,
    METHODS,
    N_SAVED,
    PLUS,
    PRESETS,
    SPLITS,
    PlanningConfig,
    observer_key,
    paper,
    quick,
    tiny,
)
from slotv_jax.experiments.planning.examples import example_indices, saved_plans  # noqa: F401
from slotv_jax.experiments.planning_report import render, report
from slotv_jax.observers import models
from slotv_jax.planning import evaluation
from slotv_jax.planning.plans import save_plans
from slotv_jax.training import checkpoint, evaluate
from slotv_jax.training import trainer as train

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
    its accuracy (:ref:`concepts-accuracy`) on the ``labeler`` labels of each split's trajectories
    and, with time weights, the learned exponent α (``alpha``)."""
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
