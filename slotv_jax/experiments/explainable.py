"""Explainable observers against the MLP: Table 1 accuracy, fitted parameters, few-label
accuracy and sample efficiency (issue 16, :ref:`concepts-archetypes`).

    python -m slotv_jax.experiments.explainable                     # quick preset, CPU
    python -m slotv_jax.experiments.explainable --preset paper      # paper sizes (GPU)

Steps, on the Table 1 dataset of the preset (cached by config digest, as table1):

1. **Table.** For each labeler and each observer model (the MLP and the archetypes of
   :mod:`slotv_jax.observers.parametric`), train ``--trials`` trials with the preset's config (the
   MLP: SLOT-V's; an archetype: :func:`slotv_jax.training.config.archetype`) and score them on the
   four Table 1 splits (:ref:`concepts-table1`); record each archetype's fitted parameters.
2. **Few labels.** Each archetype again, on 1/10 and 1/100 of the MLP's training
   trajectories (its ``train_size``), with as many updates as the preset gives it on the
   full set (the epochs scaled up): does it still reach the accuracy of the MLP trained on
   all of them?
3. **Sample efficiency** (:ref:`concepts-sample-efficiency`'s protocol,
   :mod:`slotv_jax.runs.curves`): the MLP and, per labeler, the archetype with the best
   trajectory_test accuracy in step 1, on Dragan and Nikolaidis labels: one epoch, validation on a
   fixed trajectory_val subset every ``--every`` updates (the MLP every 10, as the paper).

Writes ``OUT/results.json`` (config, environment, cells, parameters, few-label cells, sample
efficiency summaries), ``OUT/explainable.md`` (the tables) and ``OUT/explainable.png``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.explainable_report import plot, report, report_again
from slotv_jax.runs import command, curves, presets
from slotv_jax.runs.summary import mean_sd, pooled
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate
from slotv_jax.training import trainer as train

MODELS = train_config.MODELS
SE_LABELERS = ("dragan", "nikolaidis")
FEW = (10, 100)  # train on 1/10 and 1/100 of the MLP's training trajectories


def model_config(t1: presets.RunConfig, model: str) -> train_config.TrainConfig:
    """The training config of ``model`` in the Table 1 preset ``t1``."""
    return presets.with_model(t1, model).train["slotv"]


def run(
    preset: str,
    out: Path,
    *,
    trials: int,
    models: Sequence[str] = MODELS,
    labelers: Sequence[str] = LABELER_NAMES,
    repeats: int = 3,
    every: int = 2,
    cache: Path = Path("data"),
    progress: bool = True,
) -> dict:
    """Run the three steps and write the results, tables and figure."""

    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    t1 = presets.PRESETS[preset]()
    dataset = data_lib.cached_dataset(t1.data, cache, progress=progress)
    configs = {m: model_config(t1, m) for m in models}
    doc = {
        "preset": preset,
        "trials": trials,
        "config": {
            "data": t1.data.to_json(),
            "data_digest": t1.data.digest(),
            "train": {m: c.to_dict() for m, c in configs.items()},
        },
        "environment": environment(),
        "cells": [],
        "parameters": [],
        "few_labels": [],
        "sample_efficiency": {},
        "timing": {},
    }
    mlp_size = t1.train["slotv"].n_used(len(dataset["train"]))

    def fit_and_score(lab, model, tc, seeds):
        tdata = train.prepare(dataset["train"], lab, size=tc.train_size)
        t0 = time.perf_counter()
        states, _ = train.train_trials(tc, tdata, seeds, progress=False)
        jax.block_until_ready(states)
        seconds = time.perf_counter() - t0
        accs = {}
        for split in TEST_SPLITS:
            size = tc.n_used(len(dataset["train"])) if split == "train" else None
            d = train.prepare(dataset[split], lab, size=size)
            accs[split] = np.asarray(evaluate.accuracy(tc, states.params, d)).reshape(-1)
        fitted = []
        if model != "mlp":
            trainer = train.make_train(tc, progress=False)
            for i in range(len(seeds)):
                fitted.append(trainer.model(train.select_trial(states.params, i)).parameters())
        return accs, fitted, seconds

    # 1. Table 1 for every model
    units = [(lab, m) for lab in labelers for m in models]
    bar = tqdm(units, desc="explainable table", unit="cell", disable=not progress)
    for lab, model in bar:
        bar.set_postfix_str(f"{lab}/{model}")
        accs, fitted, seconds = fit_and_score(lab, model, configs[model], list(range(trials)))
        for split in TEST_SPLITS:
            for t in range(trials):
                doc["cells"].append(
                    {"labeler": lab, "model": model, "split": split, "trial": t,
                     "accuracy": float(accs[split][t])}
                )  # fmt: skip
        for t, p in enumerate(fitted):
            doc["parameters"].append({"labeler": lab, "model": model, "trial": t, **p})
        doc["timing"].setdefault("table_cells", []).append(
            {"labeler": lab, "model": model, "train_s_all_trials": seconds}
        )

    # 2. Few labels: the archetypes on 1/10 and 1/100 of the MLP's trajectories
    archetypes = [m for m in models if m != "mlp"]
    units = [(lab, m, k) for lab in labelers for m in archetypes for k in FEW]
    bar = tqdm(units, desc="explainable few labels", unit="cell", disable=not progress)
    for lab, model, k in bar:
        base = configs[model]
        n = max(base.batch_size, mlp_size // k)
        updates = base.epochs * base.steps_per_epoch(len(dataset["train"]))
        epochs = max(1, round(updates / (n // base.batch_size)))
        tc = dataclasses.replace(base, train_size=n, epochs=epochs)
        accs, fitted, _ = fit_and_score(lab, model, tc, list(range(trials)))
        for split in TEST_SPLITS:
            m_, s_ = mean_sd(accs[split])
            doc["few_labels"].append(
                {"labeler": lab, "model": model, "fraction": f"1/{k}", "train_size": n,
                 "epochs": epochs, "split": split, "mean": m_, "sd": s_, "n": trials}
            )  # fmt: skip

    # 3. Sample efficiency: the MLP and the best archetype, Dragan and Nikolaidis labels
    summary = summarise(doc["cells"])
    for lab in [x for x in SE_LABELERS if x in labelers]:
        best = best_archetype(summary, lab, archetypes)
        runs = {}
        for model, ev in (("mlp", 10), (best, every)):
            if model is None or model not in models:
                continue
            sub = out / f"sample_efficiency_{lab}_{model}"
            se = curves.run(
                preset, sub, repeats=repeats, every=ev, methods=["slotv"], cache=cache,
                progress=progress, model=model, labeler=lab,
            )  # fmt: skip
            x, acc = curves.curve(curves.read_rows(sub), "slotv")
            runs[model] = {
                "dir": sub.name,
                "every": ev,
                "start_accuracy_mean": float(acc[:, 0].mean()),
                "examples_to_0.95_mean_curve": curves.examples_to_reach(x, acc.mean(0), 0.95),
                **se["summary"]["slotv"],
            }
        doc["sample_efficiency"][lab] = runs

    doc["summary"] = summary
    doc["timing"]["total_s"] = time.perf_counter() - t_start
    write_text(out / "results.json", json.dumps(doc, indent=1))
    write_text(out / "explainable.md", report(doc))
    plot(doc, out, out / "explainable.png")
    return doc


def summarise(cells: list[dict]) -> list[dict]:
    """Mean and SD over trials per (labeler, model, split)."""
    return pooled(cells, ("labeler", "model", "split"))


def best_archetype(summary: list[dict], labeler: str, archetypes: Sequence[str]) -> str | None:
    """The archetype with the highest mean trajectory_test accuracy on ``labeler``."""
    rows = [
        s
        for s in summary
        if s["labeler"] == labeler and s["model"] in archetypes and s["split"] == "trajectory_test"
    ]
    return max(rows, key=lambda s: s["mean"])["model"] if rows else None


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.explainable",
        description="Parametric (explainable) observers against the MLP (concepts: archetypes).",
    )
    p.add_argument("--preset", choices=sorted(presets.PRESETS), default="quick")
    p.add_argument("--trials", type=int, help="trials per cell (default: the preset's)")
    p.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    p.add_argument("--labelers", nargs="+", choices=LABELER_NAMES, default=list(LABELER_NAMES))
    p.add_argument("--repeats", type=int, default=3, help="sample-efficiency repeats")
    p.add_argument("--every", type=int, default=2, help="archetype validation interval (updates)")
    p.add_argument("--out", type=Path, help="default: runs/explainable_<preset>")
    p.add_argument("--cache", type=Path, default=Path("data"))
    p.add_argument("--report", action="store_true",
                   help="only render explainable.md (and the figure, where the curves are in "
                   "OUT) again from OUT/results.json")  # fmt: skip
    args = p.parse_args(argv)
    out = args.out or Path("runs") / f"explainable_{args.preset}"
    if args.report:
        return report_again(out)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    trials = args.trials or presets.PRESETS[args.preset]().trials
    command.at_least_one(p, trials=trials, repeats=args.repeats, every=args.every)
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    doc = run(
        args.preset, out, trials=trials, models=args.models, labelers=args.labelers,
        repeats=args.repeats, every=args.every, cache=args.cache,
    )  # fmt: skip
    print(report(doc))
    print(f"wrote {out}/results.json, explainable.md, explainable.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
