"""Simulated studies: how many trajectories × participants does a learned observer need?

The paper names the number of labels as SLOT-V's main limitation (about 10,000 labelled
examples for 80 %) and human data as the next step (§VI). A study is planned in
trajectories N and participants per trajectory P, and a participant gives one guess, not
a distribution. This experiment simulates such studies:

1. N training trajectories of the generated ``train`` split (the first N; :ref:`concepts-datasets`);
2. P simulated participants per trajectory: each sees it up to a normalised time τ drawn
   from ``taus`` (default: the whole motion) and guesses a goal by sampling the labeler's
   distribution of what they saw, with lapse rate λ (a uniform guess with probability λ),
   :func:`slotv_jax.study.simulate_study`, with the dataset's β for the labeler;
3. SLOT-V and T-REX trained on the counts (multinomial likelihood,
   :mod:`slotv_jax.study`);
4. accuracy against the noise-free labeler on held-out scenes (``position_test``, whole
   motions, :ref:`concepts-accuracy` accuracy).

``P = ∞`` (written "labels") trains on the labeler's distributions themselves: the
paper's setting, the limit of infinitely many participants. Participants and trajectories
are nested: the P participants of a cell are the first P of the largest P, and its N
trajectories the first N, so the curves differ by data, not by draws. Each trial draws
new participants and a new initialisation.

Training length **[choice]**: every cell trains the same number of updates,
``⌈updates / steps per epoch⌉`` epochs of ``⌊rows / batch⌋`` steps (at least ``updates``,
fewer than ``updates + steps``), for every N and P and for both methods. A small study is
then not starved of updates and a large one not cut short, so the curves measure data, not
training length. ``budget_curve`` checks the budget: SLOT-V and T-REX on the labels
(P = ∞) of the largest N, evaluated after ¼, ½, 1 and 2 × ``updates`` updates.

Quick preset: 2,000 updates per cell for both methods, hidden 64/32, batch 32, lr 0.005
(RMSprop for SLOT-V, Adam for T-REX). Measured on the 2-core CPU: SLOT-V on the labels
(P = ∞, N = 3,000) reached 0.58 / 0.73 / 0.75 / 0.86 after ≈ 300 / 1,000 / 3,000 / 6,000
updates at the quick Table 1's lr 0.002 and 0.64 / 0.78 / 0.83 / 0.88 at lr 0.005; wider
networks gain per update but cost 2.5–10 × per update there. ``experiments/study_size_budget.md``
(linked from the quick report's notes) has every measurement.

    python -m slotv_jax.experiments.study_size                  # quick (CPU, minutes)
    python -m slotv_jax.experiments.study_size --preset paper    # paper sizes (GPU)

Writes ``OUT/study_size{,_paper}.json`` (config, every cell, summary, what 80 % needs,
timings; a rerun resumes), ``.md`` and ``.png`` (accuracy against N, one curve per P,
one panel per method). The quick preset also times SLOT-V (quick preset, 3 epochs) on a
2,000-trajectory study of 20 participants per trajectory.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax import study
from slotv_jax.core import fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import command, record
from slotv_jax.runs.presets import METHODS
from slotv_jax.runs.summary import crossing, pooled
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate, types

UPDATES_QUICK = 2000  # updates per cell of the quick preset (module docstring)
INF = 0  # the "participants" value of the P = ∞ curve (train on the labeler's distribution)


@dataclasses.dataclass(frozen=True)
class StudySizeConfig:
    """One simulated-study experiment."""

    preset: str
    data: data_lib.DataConfig
    n_grid: tuple[int, ...]  # training trajectories N
    participants: tuple[int, ...]  # participants per trajectory P (0: P = ∞, the labels)
    trials: int
    train_preset: str  # slotv_jax.training.config preset of both methods
    updates: int  # each cell trains ⌈updates / steps per epoch⌉ epochs (module docstring)
    labeler: str = "dragan"
    taus: tuple[float, ...] = (1.0,)  # normalised times the motion may stop at
    lapse: float = 0.0
    threshold: float = 0.8
    eval_split: str = "position_test"
    seed: int = 0
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides for both methods
    budget_check: bool = True  # record budget_curve (accuracy against updates at P = ∞)

    def epochs_for(self, steps: int) -> int:
        """Epochs of ``steps`` updates that give a cell its budget: ⌈updates / steps⌉."""
        return max(1, math.ceil(self.updates / max(steps, 1)))

    def train_config(self, method: str) -> train_config.TrainConfig:
        cfg = train_config.preset(self.train_preset, method, train_size=None)
        return train_config.apply_overrides(cfg, self.overrides)

    def beta(self) -> float:
        return float(getattr(self.data.labels, f"beta_{self.labeler}"))

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["train"] = {m: self.train_config(m).to_dict() for m in METHODS}
        return d


def quick(**overrides) -> StudySizeConfig:
    """CPU preset: the quick dataset and networks; N up to 10,000, P in {1, 5, 20, ∞}."""
    base = StudySizeConfig(
        preset="quick",
        data=data_lib.quick(),
        n_grid=(100, 300, 1000, 3000, 10000),
        participants=(1, 5, 20, INF),
        trials=2,
        train_preset="quick",
        updates=UPDATES_QUICK,
        overrides=("learning_rate=0.005", "batch_size=32"),
    )
    return dataclasses.replace(base, **overrides)


def paper(**overrides) -> StudySizeConfig:
    """GPU preset: the paper's dataset and networks; N up to 100,000, P up to 30 and ∞."""
    base = StudySizeConfig(
        preset="paper",
        data=data_lib.paper(),
        n_grid=(300, 1000, 3000, 10000, 30000, 100000),
        participants=(1, 3, 10, 30, INF),
        trials=3,
        train_preset="paper",
        updates=10000,
    )
    return dataclasses.replace(base, **overrides)


PRESETS = {"quick": quick, "paper": paper}


def stem_of(preset: str) -> str:
    """The file stem of a preset's outputs: ``study_size``, ``study_size_paper``."""
    return "study_size" if preset == "quick" else f"study_size_{preset}"


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment (ours to resume)."""
    return fileio.is_json_object_with(path, ("preset", "config", "cells", "summary", "needed"))


def p_name(p: int) -> str:
    return "∞ (labels)" if p == INF else str(p)


# ------------------------------------------------------------------- running


def _cell_key(c: dict) -> tuple:
    return (c["method"], c["participants"], c["n"], c["trial"])


def recorded_references(folder: Path) -> dict:
    """The numbers of other recorded experiments that the report sets beside this one's,
    read from their results documents in ``folder`` (missing ones are left out): SLOT-V's
    paper-preset Table 1 accuracy on Dragan's ``position_test`` with that run's training
    size and epochs, and the examples its paper-preset sample-efficiency curve needs."""
    ref: dict = {}
    t1 = Path(folder) / "table1_paper_results.json"
    if t1.is_file():
        d = json.loads(t1.read_text())
        key = ("dragan", "slotv", "position_test")
        hit = [s for s in d["summary"] if (s["labeler"], s["method"], s["split"]) == key]
        if hit:
            ref["table1_slotv_dragan_position"] = hit[0]["mean"]
            ref["table1_n_train"] = d["config"]["data"]["n_train"]
            ref["table1_epochs"] = d["config"]["train"]["slotv"]["epochs"]
    se = Path(folder) / "sample_efficiency.json"
    if se.is_file():
        d = json.loads(se.read_text())
        if d.get("preset") == "paper" and "slotv" in d.get("summary", {}):
            ref["sample_efficiency_slotv_examples"] = d["summary"]["slotv"][
                "examples_to_threshold_mean_curve"
            ]
    return ref


def run(
    cfg: StudySizeConfig,
    out: Path,
    *,
    cache: Path = Path("data"),
    progress: bool = True,
    references: Path = Path("experiments"),
):
    """Run (or resume) every cell; returns the results document (also written to ``out``).
    ``references``: the folder of the recorded results the report compares with
    (:func:`recorded_references`)."""

    stem = stem_of(cfg.preset)
    path = out / f"{stem}.json"
    command.prepare_out(out, stem, is_results, results=path.name)  # before any work
    conf = json.loads(json.dumps(cfg.to_json()))
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc.get("config") != conf:
        doc = {"preset": cfg.preset, "config": conf, "cells": [], "timing": {}}
    done = {_cell_key(c) for c in doc["cells"]}
    todo = [
        (m, p, n, t)
        for m in METHODS
        for p in cfg.participants
        for n in cfg.n_grid
        for t in range(cfg.trials)
        if (m, p, n, t) not in done
    ]
    if (
        not todo
        and ("budget" in doc or not cfg.budget_check)
        and ("measure" in doc or cfg.preset != "quick")
    ):  # a finished record: kept as it is (its machine, its times), no dataset loaded
        return doc
    doc["environment"] = environment()
    doc["date"] = record.utc_now()  # the report's date: the run's, not the rendering's
    doc["references"] = recorded_references(references)
    doc["xla"] = slotv_jax.XLA_CONFIG.summary()
    t_start = t0 = time.perf_counter()
    load = record.load_start()
    splits = data_lib.cached_dataset(
        cfg.data, cache, splits=("train", cfg.eval_split), progress=progress
    )
    doc["dataset"] = str(data_lib.dataset_dir(cache, cfg.data))
    doc["timing"]["data_s"] = time.perf_counter() - t0
    tr = splits["train"]
    n_max = max(cfg.n_grid)
    if n_max > len(tr):
        raise ValueError(f"n_grid: {n_max} trajectories asked, the train split has {len(tr)}")
    xyz, goals, mask = tr.xyz[:n_max], tr.goals[:n_max], tr.goal_mask[:n_max]
    t0 = time.perf_counter()
    probs = study.prefix_labels(xyz, goals, mask, cfg.taus, labeler=cfg.labeler, beta=cfg.beta())
    doc["timing"]["labels_s"] = time.perf_counter() - t0
    ev = types.prepare(splits[cfg.eval_split], cfg.labeler)
    p_max = max(cfg.participants)
    sims: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    bar = tqdm(total=len(todo), desc="study_size cells", unit="cell", disable=not progress)
    for m, p, n, t in todo:
        bar.set_postfix_str(f"{m} P={p_name(p)} N={n} trial {t}")
        tc = cfg.train_config(m)
        if p == INF:
            s = study.study_from_labels(xyz[:n], goals[:n], mask[:n], cfg.taus, probs[:n])
        else:
            if t not in sims:
                key = jax.random.fold_in(jax.random.key(cfg.seed), t)
                sims[t] = study.simulate_guesses(key, probs, mask, p_max, lapse=cfg.lapse)
            which, guess = sims[t]
            s = study.study_from_guesses(
                xyz[:n], goals[:n], mask[:n], cfg.taus, which[:n, :p], guess[:n, :p]
            )
        steps = s.n_rows // tc.batch_size
        epochs = cfg.epochs_for(steps)
        tc = dataclasses.replace(tc, epochs=epochs)
        t1 = time.perf_counter()
        state = study.train_study(tc, s, jax.random.key(1000 * cfg.seed + t), progress=False)
        jax.block_until_ready(state.params)
        train_s = time.perf_counter() - t1
        acc = float(evaluate.accuracy(tc, state.params, ev))
        doc["cells"].append(
            {
                "method": m,
                "participants": p,
                "n": n,
                "trial": t,
                "accuracy": acc,
                "rows": s.n_rows,
                "answers": s.n_answers,
                "epochs": epochs,
                "updates": epochs * steps,
                "train_s": round(train_s, 3),
            }
        )
        bar.update(1)
        _write(doc, cfg, out, stem)
    bar.close()
    if cfg.budget_check and "budget" not in doc:
        doc["budget"] = budget_curve(cfg, xyz, goals, mask, probs, ev, progress=progress)
        _write(doc, cfg, out, stem)
    if cfg.preset == "quick" and "measure" not in doc:
        doc["measure"] = measure(splits["train"], cfg, progress=progress)
    doc["timing"]["total_s"] = doc["timing"].get("total_s", 0.0) + time.perf_counter() - t_start
    if todo or "load" not in doc:  # the load while the cells ran, not while a resume reports
        doc["load"] = record.load_end(load)
    _write(doc, cfg, out, stem)
    return doc


BUDGET_FRACTIONS = (0.25, 0.5, 1.0, 2.0)


def budget_curve(cfg: StudySizeConfig, xyz, goals, mask, probs, ev, *, progress=True) -> dict:
    """Accuracy against updates on the labels (P = ∞) of the largest N, for each method:
    one run (trial 0's key) evaluated after ``BUDGET_FRACTIONS`` × ``cfg.updates`` updates
    (whole epochs, as the cells train). Flat between 1 and 2 × means the cells' budget
    does not limit them."""

    n = max(cfg.n_grid)
    s = study.study_from_labels(xyz[:n], goals[:n], mask[:n], cfg.taus, probs[:n])
    data = study.study_data(s)
    out = {"n": n}
    for m in METHODS:
        tc = cfg.train_config(m)
        steps = s.n_rows // tc.batch_size
        state, rows, t0 = None, [], time.perf_counter()
        for f in BUDGET_FRACTIONS:
            epochs = max(1, math.ceil(f * cfg.updates / steps))
            tc = dataclasses.replace(tc, epochs=epochs)
            state = study.train_study(
                tc, data, jax.random.key(1000 * cfg.seed), progress=progress, state=state
            )
            acc = float(evaluate.accuracy(tc, state.params, ev))
            rows.append({"updates": epochs * steps, "accuracy": acc})
        out[m] = {"points": rows, "seconds": round(time.perf_counter() - t0, 1)}
    return out


def measure(tr, cfg: StudySizeConfig, *, n: int = 2000, participants: int = 20, progress=True):
    """Wall time of SLOT-V (quick preset, as the CLI trains it) on an N × P simulated study,
    whole motions and prefixes (τ ∈ {0.25, 0.5, 0.75, 1}); two runs each, the first
    including compilation."""

    out = {}
    for name, taus in (("whole motions", (1.0,)), ("prefixes", (0.25, 0.5, 0.75, 1.0))):
        s = study.simulate_study(
            jax.random.key(cfg.seed + 7),
            tr.xyz[:n],
            tr.goals[:n],
            tr.goal_mask[:n],
            participants,
            labeler=cfg.labeler,
            beta=cfg.beta(),
            taus=taus,
            lapse=cfg.lapse,
        )
        tc = train_config.quick("slotv", train_size=None)
        runs = []
        for seed in range(2):
            t0 = time.perf_counter()
            state = study.train_study(tc, s, jax.random.key(seed), progress=progress)
            jax.block_until_ready(state.params)
            runs.append(round(time.perf_counter() - t0, 2))
        out[name] = {
            "n": n,
            "participants": participants,
            "rows": s.n_rows,
            "answers": s.n_answers,
            "epochs": tc.epochs,
            "updates": tc.epochs * (s.n_rows // tc.batch_size),
            "seconds": runs,
        }
    return out


# ------------------------------------------------------------------ summaries


def summarise(doc: dict) -> list[dict]:
    """Mean and SD of accuracy over trials per (method, P, N)."""
    return pooled(doc["cells"], ("method", "participants", "n"), count="trials")


def needed(summary: list[dict], threshold: float) -> list[dict]:
    """Per (method, P): the smallest N whose mean accuracy reaches ``threshold``,
    interpolated linearly in log N between the grid points around the crossing
    (:func:`slotv_jax.runs.summary.crossing`)."""
    out = []
    for m in sorted({r["method"] for r in summary}):
        for p in sorted({r["participants"] for r in summary if r["method"] == m}):
            pts = sorted(
                (r["n"], r["mean"]) for r in summary if (r["method"], r["participants"]) == (m, p)
            )
            ns, acc = np.array([a for a, _ in pts], float), np.array([b for _, b in pts])
            hit = np.flatnonzero(acc >= threshold)
            rec = {
                "method": m,
                "participants": p,
                "best": float(acc.max()),
                "best_n": int(ns[acc.argmax()]),
                "n": crossing(ns, acc, threshold),
            }
            if hit.size and hit[0] == 0:
                rec["at_most"] = True
            if rec["n"] is not None and p != 0:
                rec["answers"] = rec["n"] * p
            if hit.size:  # a later grid point below the threshold again: a noisy crossing
                rec["falls_back"] = bool((acc[hit[0] :] < threshold).any())
            out.append(rec)
    return out


def _write(doc: dict, cfg: StudySizeConfig, out: Path, stem: str) -> None:
    doc["summary"] = summarise(doc)
    doc["needed"] = needed(doc["summary"], cfg.threshold)
    write_text(out / f"{stem}.json", json.dumps(doc, indent=1))
