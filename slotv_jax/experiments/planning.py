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
   :class:`slotv_jax.observers.models.SlotV`), which a planner cannot exploit the way it exploits
   the paper's score (the paper preset trains SLOT-V+ for 5 epochs: :func:`paper`); in
   ``archetype_planners``: SLOT-V's loss with the family's parametric observer archetype
   (SPEC §10: ``dragan`` for Dragan, ``viewpoint`` for Nikolaidis), which separates what
   the loss learns from what a network can represent;
4. every observer plans every problem with :mod:`slotv_jax.planning` (one compiled
   program for all observers), and every plan is scored by the TRUE hand-crafted
   labeler of its family: mean and SD of y_target, the rate at which the target is the
   labeler's argmax, the path-length ratio to the straight line, feasibility, how
   often the plan's true legibility fell below the straight line's, and the fraction
   of the oracle's gain (mean y_target over the straight line) each learned observer
   keeps;
5. ``OUT/results.json`` (SPEC §10 schema plus these extras), ``OUT/plans.npz`` (every
   plan), figures rendered from those files and ``OUT/planning.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
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
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import atomic_write, save_figure, write_text
from slotv_jax.observers import labelers, models
from slotv_jax.robot.kinematics import home_tcp
from slotv_jax.training import checkpoint, evaluate, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train
from slotv_jax.world import scene
from slotv_jax.world.scene import camera, project

FAMILIES = ("dragan", "nikolaidis")  # the true labelers; each is its own family's oracle
METHODS = ("slotv", "trex")  # the learned observers of SPEC's `planners` rows
# SLOT-V+ and T-REX+: the same networks with the learned start term and time weights
# (models._Observer); their rows are plus_planners
PLUS = {"slotv_plus": "slotv", "trex_plus": "trex"}
ARCHETYPES = {"dragan": "dragan", "nikolaidis": "viewpoint"}  # family -> archetype model
LEARNED = (*METHODS, *PLUS, "archetype")
SPLITS = ("position_test", "goal_count_test")
TITLES = {"straight": "straight line", "dragan": "Dragan (oracle)",
          "nikolaidis": "Nikolaidis (oracle)", "slotv": "SLOT-V", "trex": "T-REX",
          "slotv_plus": "SLOT-V+ (start term, time weights)",
          "trex_plus": "T-REX+ (start term, time weights)",
          "archetype": "SLOT-V loss, archetype"}  # fmt: skip


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
            return dataclasses.replace(base, start_term=True, time_weight=True, epochs=epochs)
        return self.train[method]

    def methods(self, family: str) -> tuple[str, ...]:
        """The learned observers of ``family``: SLOT-V, T-REX and, if configured, SLOT-V+,
        T-REX+ and the family's archetype."""
        plus = tuple(PLUS) if self.plus else ()
        return (*METHODS, *plus, *(("archetype",) if family in self.archetype else ()))

    def learned(self) -> list[tuple[str, str]]:
        """``(method, family)`` of every learned observer of the run."""
        return [(m, f) for f in FAMILIES for m in self.methods(f)]

    def to_json(self) -> dict:
        return {
            "preset": self.preset,
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

    SLOT-V+ trains 5 of the paper's 15 epochs **[choice]**. Measured on an H100
    (experiments/planning_paper.md): its held-out accuracy is the same, and its plans keep
    more of the Nikolaidis oracle's gain (eight trainings: 79–90 %, mean 83 %; fifteen
    trainings of 15 epochs: 75–89 %, mean 79 %). The longer run fits detail of the value
    field that the planner's gradient then follows away from the labeler's.
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


def held_out_scenes(cfg: PlanningConfig, dataset: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{split: (goals (S, 8, 3), goal_mask (S, 8))}`` for the two held-out splits.

    With ``cfg.n_scenes`` above the dataset's, the scene sets are drawn further from the
    same streams (:func:`slotv_jax.data.sample_scene_sets`); their first scenes must be
    the stored ones.
    """
    out = {s: (dataset[s].scene_goals, dataset[s].scene_mask) for s in SPLITS}
    if cfg.n_scenes <= cfg.data.n_new_scenes:
        return {s: (g[: cfg.n_scenes], m[: cfg.n_scenes]) for s, (g, m) in out.items()}
    more = data_lib.sample_scene_sets(dataclasses.replace(cfg.data, n_new_scenes=cfg.n_scenes))
    for s, (stored_g, stored_m) in out.items():
        scenes = more[s][0]
        g, m = np.asarray(scenes.goals, np.float32), np.asarray(scenes.goal_mask, bool)
        k = stored_g.shape[0]
        if not (np.array_equal(g[:k], stored_g) and np.array_equal(m[:k], stored_m)):
            raise RuntimeError(f"{s}: the extended scene set does not start with the stored scenes")
        out[s] = (g, m)
    return out


def make_problems(scenes: dict) -> dict[str, np.ndarray]:
    """Every (scene, real goal slot) pair: goals, goal_mask, target, split index, scene index."""
    rows = {"goals": [], "goal_mask": [], "target": [], "split": [], "scene": []}
    for si, s in enumerate(SPLITS):
        goals, mask = scenes[s]
        for e in range(goals.shape[0]):
            for k in np.flatnonzero(mask[e]):
                rows["goals"].append(goals[e])
                rows["goal_mask"].append(mask[e])
                rows["target"].append(k)
                rows["split"].append(si)
                rows["scene"].append(e)
    return {
        "goals": np.asarray(rows["goals"], np.float32),
        "goal_mask": np.asarray(rows["goal_mask"], bool),
        "target": np.asarray(rows["target"], np.int32),
        "split": np.asarray(rows["split"], np.int32),
        "scene": np.asarray(rows["scene"], np.int32),
    }


# ------------------------------------------------------------------ observers


def train_observer(
    cfg: PlanningConfig, method: str, labeler: str, train_split, out: Path
) -> tuple[Path, float]:
    """Train one observer (``method`` in :data:`LEARNED`) with the preset's config on
    ``labeler`` labels; save it to ``out``."""
    tc = cfg.observer_config(method, labeler)
    t0 = time.perf_counter()
    data = types.prepare(train_split, labeler, size=tc.train_size)
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


def observer_key(name: str, family: str) -> str:
    """Key of an observer in the planner: the labelers by name, learned ones by method/family."""
    return name if name in FAMILIES else f"{name}/{family}"


# --------------------------------------------------------------------- scores


def true_labels(labeler: str, xyz, goals, goal_mask) -> np.ndarray:
    """The true hand-crafted labels ``(N, 8)`` of planned paths (compiled, batched)."""
    fn = labelers.LABELERS[labeler]
    if labeler == "nikolaidis":
        cam = scene.camera("observer")
        return np.asarray(
            jax.jit(jax.vmap(lambda x, g, m: fn(x, g, m, cam)))(xyz, goals, goal_mask)
        )
    return np.asarray(jax.jit(jax.vmap(fn))(xyz, goals, goal_mask))


def path_length(xyz: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(np.asarray(xyz, np.float64), axis=-2), axis=-1).sum(-1)


def summarise(observer: str, labeler: str, y, y_straight, argmax_ok, length_ratio, feasible):
    """One ``planners`` row of results.json (SPEC §10) plus the comparison to the straight line."""
    y = np.asarray(y, np.float64)
    n = y.size
    return {
        "observer": observer,
        "labeler": labeler,
        "n": int(n),
        "mean_y_target": float(y.mean()),
        "sd_y_target": float(y.std(ddof=1)) if n > 1 else 0.0,
        "argmax_rate": float(np.mean(argmax_ok)),
        "length_ratio": float(np.mean(length_ratio)),
        "feasible_rate": float(np.mean(feasible)),
        "mean_gain": float(np.mean(y - y_straight)),
        "lowered_rate": float(np.mean(y < y_straight)),
        "raised_rate": float(np.mean(y > y_straight)),
    }


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
    problems = make_problems(held_out_scenes(cfg, dataset))
    timing["scenes_s"] = time.perf_counter() - t0

    # Observers: the two labelers, and the learned ones per family (given or trained here).
    checkpoints = dict(checkpoints or {})
    observers: dict[str, planning.Observer] = {f: planning.labeler_observer(f) for f in FAMILIES}
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
    jax.block_until_ready(straight)
    timing["straight_line_s"] = time.perf_counter() - t0
    plans: dict[str, planning.PlanResult] = {}
    timing["plan_s"] = {}
    for name in tqdm(planner.observers, desc="planning", unit="observer", disable=not progress):
        t0 = time.perf_counter()
        plans[name] = jax.device_get(planner.plan_problems(straight, observer=name))
        timing["plan_s"][name] = time.perf_counter() - t0

    # Scores under the true labelers.
    goals, mask, target = problems["goals"], problems["goal_mask"], problems["target"]
    rows = np.arange(len(target))
    xyz_straight = np.asarray(straight.xyz)
    len_straight = path_length(xyz_straight)
    arrays: dict[str, np.ndarray] = {**problems, "xyz/straight": xyz_straight}
    planners, plus_planners, archetype_planners = [], [], []
    gains: dict[str, dict] = {}
    for family in FAMILIES:
        y_s_all = true_labels(family, xyz_straight, goals, mask)
        y_s = y_s_all[rows, target]
        arrays[f"y_{family}/straight"] = y_s_all
        ok_s = np.asarray(jax.device_get(straight.target_residual)) <= planning.MAX_RESIDUAL
        planners.append(summarise("straight", family, y_s, y_s, y_s_all.argmax(-1) == target,
                                  np.ones_like(len_straight), ok_s))  # fmt: skip
        for name in (family, *cfg.methods(family)):
            key = observer_key(name, family)
            res = plans[key]
            y_all = true_labels(family, res.xyz, goals, mask)
            y = y_all[rows, target]
            arrays[f"xyz/{key}"] = np.asarray(res.xyz)
            arrays[f"y_{family}/{key}"] = y_all
            ratio = path_length(res.xyz) / len_straight
            ok = res.diagnostics.feasible
            row = summarise(name, family, y, y_s, y_all.argmax(-1) == target, ratio, ok)
            d = res.diagnostics
            obj = np.asarray(d.objective)
            row["observer_p_target_straight"] = float(np.exp(obj[:, 0]).mean())
            row["observer_p_target_plan"] = float(np.exp(obj[rows, np.asarray(d.best_iter)]).mean())
            row["max_target_residual_m"] = float(np.max(d.target_residual))
            row["min_joint_margin_rad"] = float(np.min(d.joint_margin))
            row["min_table_clearance_m"] = float(np.min(d.table_clearance))
            row["max_cost_over_limit_m2"] = float(np.max(d.cost - d.cost_limit))
            row["by_split"] = {
                s: float(y[problems["split"] == i].mean()) for i, s in enumerate(SPLITS)
            }
            if name == "archetype":
                row["model"] = cfg.observer_config(name, family).model
                archetype_planners.append(row)
            elif name in PLUS:
                plus_planners.append(row)
            else:
                planners.append(row)
        oracle_gain = next(r for r in planners if r["observer"] == family)["mean_gain"]
        for r in planners + plus_planners + archetype_planners:
            if r["labeler"] == family and r["observer"] in LEARNED:
                r["oracle_gain_kept"] = r["mean_gain"] / oracle_gain if oracle_gain > 0 else None
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
        "planners": planners,
        # SLOT-V+ and T-REX+: learned start term and time weights (not SPEC `planners` rows)
        "plus_planners": plus_planners,
        # SLOT-V's loss with the family's parametric archetype (not a SPEC `planners` row)
        "archetype_planners": archetype_planners,
        "oracle_gain_kept": gains,
        "timing": timing,
    }
    write_text(out / "results.json", json.dumps(doc, indent=1))
    atomic_write(out / "plans.npz", lambda f: np.savez_compressed(f, **arrays))
    render(out, cfg.n_examples)
    write_text(out / "planning.md", report(doc))
    return doc


# ------------------------------------------------------------------- figures


def _plan_keys(family: str, plans: dict) -> list[tuple[str, str]]:
    names = (family, *LEARNED)
    keys = [(n, observer_key(n, family)) for n in names]
    return [("straight", "straight"), *((n, k) for n, k in keys if f"xyz/{k}" in plans)]


_COLOURS = {"straight": "0.4", "dragan": "C3", "nikolaidis": "C3", "slotv": "C0", "trex": "C2",
            "slotv_plus": "C9", "trex_plus": "C8", "archetype": "C1"}  # fmt: skip


def all_rows(doc: dict) -> list[dict]:
    """Every planner row of a results document: SPEC's, the ``+`` and the archetype ones."""
    return doc["planners"] + doc.get("plus_planners", []) + doc.get("archetype_planners", [])


def example_indices(plans: dict, n: int) -> list[int]:
    """Problems shown in the scene figure: the first problem of evenly spaced scenes with
    at least three goals (deterministic)."""
    many = np.flatnonzero(plans["goal_mask"].sum(-1) >= 3)
    first = [i for i in many if i == 0 or plans["scene"][i] != plans["scene"][i - 1]
             or plans["split"][i] != plans["split"][i - 1]]  # fmt: skip
    first = first or list(range(len(plans["target"])))
    pick = np.linspace(0, len(first) - 1, min(n, len(first))).round().astype(int)
    return [int(first[i]) for i in pick]


def render(out: Path, n_examples: int = 3) -> None:
    """``scenes.png`` (top view, Dragan family; observer view, Nikolaidis family) and
    ``bars.png`` (true legibility per planner ± SD), from ``plans.npz``/``results.json``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with np.load(out / "plans.npz", allow_pickle=False) as f:
        plans = {k: f[k] for k in f.files}
    doc = json.loads((out / "results.json").read_text())
    idx = example_indices(plans, n_examples)
    cam = camera("observer")
    cam64 = jax.tree.map(lambda a: np.asarray(a, np.float64), cam)
    fig, axes = plt.subplots(len(idx), 2, figsize=(11, 4.2 * len(idx)), squeeze=False)
    for row, i in enumerate(idx):
        g, m, t = plans["goals"][i], plans["goal_mask"][i], int(plans["target"][i])
        for col, family in enumerate(FAMILIES):
            ax = axes[row, col]
            y = plans[f"y_{family}/{family}"][i]  # the oracle plan's true labels
            for name, key in _plan_keys(family, plans):
                xyz = plans[f"xyz/{key}"][i]
                pts = xyz[:, :2] if col == 0 else project(xyz.astype(np.float64), cam64)[0]
                yt = plans[f"y_{family}/{key}"][i, t]
                ax.plot(pts[:, 0], pts[:, 1], color=_COLOURS[name], lw=1.6,
                        ls="--" if name == "straight" else "-",
                        label=f"{TITLES[name]}: y = {yt:.2f}")  # fmt: skip
            gp = g[m, :2] if col == 0 else project(g[m].astype(np.float64), cam64)[0]
            sc = ax.scatter(gp[:, 0], gp[:, 1], c=y[m], cmap="viridis", vmin=0, vmax=1, s=120,
                            marker="s", edgecolors="k", zorder=3)  # fmt: skip
            k = int(np.flatnonzero(m).tolist().index(t))
            ax.scatter(gp[k, 0], gp[k, 1], marker="*", s=260, c="w", edgecolors="k", zorder=4)
            home = np.asarray(home_tcp(), np.float64)
            hp = home[:2] if col == 0 else project(home[None], cam64)[0][0]
            ax.plot(*hp, "ko", ms=5)
            split = SPLITS[int(plans["split"][i])]
            if col == 0:
                title = f"{split} scene {int(plans['scene'][i])}: top view, Dragan"
                ax.set(xlabel="x (m)", ylabel="y (m)", aspect="equal", title=title)
            else:
                ax.set(xlabel="u (image plane)", ylabel="v", aspect="equal",
                       title="observer camera view, Nikolaidis")  # fmt: skip
            ax.legend(fontsize=7, loc="best", framealpha=0.6)
            fig.colorbar(sc, ax=ax, shrink=0.7, label="true y of the oracle plan")
    fig.tight_layout()
    save_figure(fig, out / "scenes.png", dpi=90)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(FAMILIES), figsize=(10, 3.8), sharey=True)
    for ax, family in zip(axes, FAMILIES, strict=True):
        rows = [r for r in all_rows(doc) if r["labeler"] == family]
        names = [_title(r).replace(" loss, ", " loss,\n") for r in rows]
        ax.bar(names, [r["mean_y_target"] for r in rows], yerr=[r["sd_y_target"] for r in rows],
               color=[_COLOURS[r["observer"]] for r in rows], capsize=4)  # fmt: skip
        ax.set(title=f"true {family} legibility (n = {rows[0]['n']})", ylabel="mean y_target ± SD")
        ax.tick_params(axis="x", rotation=25)
    fig.tight_layout()
    save_figure(fig, out / "bars.png", dpi=100)
    plt.close(fig)


# -------------------------------------------------------------------- report


def _title(row: dict) -> str:
    if row["observer"] == "archetype":
        return f"SLOT-V loss, {row['model']} archetype"
    return TITLES[row["observer"]]


def report(doc: dict, figures: str = "") -> str:
    """The Markdown report of a run (``figures``: path prefix of the two PNGs)."""
    env, t, cfg = doc["environment"], doc["timing"], doc["config"]
    lines = [
        f"# Legible planning with learned observers ({doc['preset']} preset)",
        "",
        "Every plan is scored by the TRUE hand-crafted labeler of its family. `y_target` is "
        "the labeler's probability of the goal the robot moves to; argmax: the target is the "
        "labeler's most likely goal; length ratio: path length over the straight line's; "
        "lowered: fraction of problems where the plan's true y_target is below the straight "
        "line's; gain kept: (mean y − straight) / (oracle mean y − straight).",
        "",
        f"{doc['n_problems']} problems: every (scene, goal) pair of "
        + ", ".join(f"{n} in {s}" for s, n in doc["n_problems_by_split"].items())
        + f" ({cfg['n_scenes']} held-out scenes per split), start TCP(q_home). Planner: "
        f"{cfg['planner']['iters']} covariant steps, trust-region budget "
        f"{cfg['planner']['budget']} m² on C = ½∫‖ξ'‖²dt, clearance "
        f"{cfg['planner']['clearance']} m.",
        "",
        "| true labeler | observer planned with | mean y_target ± SD | argmax rate | length ratio "
        "| feasible | lowered | raised | gain kept | observer's own P(target): straight → plan |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    every = all_rows(doc)
    for r in sorted(every, key=lambda r: FAMILIES.index(r["labeler"])):
        kept = r.get("oracle_gain_kept")
        own = (
            f"{r['observer_p_target_straight']:.3f} → {r['observer_p_target_plan']:.3f}"
            if "observer_p_target_plan" in r
            else "—"
        )
        lines.append(
            f"| {r['labeler']} | {_title(r)} | {r['mean_y_target']:.3f} ± "
            f"{r['sd_y_target']:.3f} | {r['argmax_rate']:.3f} | {r['length_ratio']:.3f} | "
            f"{r['feasible_rate']:.3f} | {r['lowered_rate']:.3f} | {r['raised_rate']:.3f} | "
            f"{'—' if kept is None else f'{kept:.0%}'} | {own} |"
        )
    plan_s = sum(t["plan_s"].values())

    def worst(field, pick):
        return pick(r[field] for r in every if field in r)

    lines += [
        "",
        f"![true legibility per planner]({figures}bars.png)",
        "",
        f"![example scenes]({figures}scenes.png)",
        "",
        "Constraints on every returned plan (worst case over problems and observers): "
        f"target residual {worst('max_target_residual_m', max) * 1e3:.2f} mm; joint-limit "
        f"margin {worst('min_joint_margin_rad', min):.4f} rad; TCP height above the "
        f"clearance {worst('min_table_clearance_m', min) * 1e3:.1f} mm; trust region "
        f"C − κ {worst('max_cost_over_limit_m2', max):.2e} m² (≤ 0 holds).",
        "",
        f"Timing: total {t['total_s']:.0f} s = data {t['data_s']:.0f} s, observer training "
        f"{t['train_s']:.0f} s, straight lines {t['straight_line_s']:.0f} s (compilation "
        f"included), planning {plan_s:.0f} s ("
        + ", ".join(f"{k} {v:.1f} s" for k, v in t["plan_s"].items())
        + "; the first includes the one compilation).",
        "",
        f"jax {env.get('jax')}, flax {env.get('flax')}, mujoco {env.get('mujoco')}, "
        f"devices {env.get('devices')}.",
        "",
        "Learned observers: accuracy (SPEC §8) on the labels of their family on the "
        "held-out splits' trajectories; the learned time-weighting exponent α of SLOT-V+ and "
        "T-REX+.",
        "",
        "| observer | " + " | ".join(f"accuracy {s}" for s in SPLITS) + " | α | source |",
        "|---|" + "---|" * len(SPLITS) + "---|---|",
    ]
    for k, v in doc["observers"].items():
        acc = v.get("accuracy", {})
        alpha = v.get("alpha")
        lines.append(
            f"| {k} | "
            + " | ".join(f"{acc[s]:.3f}" if s in acc else "—" for s in SPLITS)
            + f" | {'—' if alpha is None else f'{alpha:.3f}'} | "
            + ("trained by this run" if v["trained"] else v["checkpoint"])
            + " |"
        )
    lines.append("")
    return "\n".join(lines)


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
            p.error("--n-scenes: expected an integer >= 1")
        cfg = dataclasses.replace(cfg, n_scenes=args.n_scenes)
    changes = {k: v for k, v in (("iters", args.iters), ("budget", args.budget)) if v is not None}
    if changes:
        try:
            cfg = dataclasses.replace(cfg, planner=dataclasses.replace(cfg.planner, **changes))
        except ValueError as e:
            p.error(str(e))
    if args.compute_dtype:
        train = {m: dataclasses.replace(c, compute_dtype=args.compute_dtype)
                 for m, c in cfg.train.items()}  # fmt: skip
        cfg = dataclasses.replace(cfg, train=train)
    if args.set:
        try:
            train = {m: train_config.apply_overrides(c, args.set) for m, c in cfg.train.items()}
        except ValueError as e:
            p.error(str(e))
        cfg = dataclasses.replace(cfg, train=train)
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
    doc = run(cfg, out, checkpoints=ckpts, cache=args.cache)
    if args.doc is not None:
        args.doc.parent.mkdir(parents=True, exist_ok=True)
        stem = args.doc.stem
        for fig in ("scenes.png", "bars.png"):
            shutil.copyfile(out / fig, args.doc.parent / f"{stem}_{fig}")
        write_text(args.doc, report(doc, figures=f"{stem}_"))
    print(report(doc))
    print(f"results in {out / 'results.json'}; report in {out / 'planning.md'}; "
          f"{doc['timing']['total_s']:.0f} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
