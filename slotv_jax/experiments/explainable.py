"""Explainable observers against the MLP: Table 1 accuracy, fitted parameters, few-label
accuracy and sample efficiency (issue 16, SPEC §10).

    python -m slotv_jax.experiments.explainable                     # quick preset, CPU
    python -m slotv_jax.experiments.explainable --preset paper      # paper sizes (GPU)

Steps, on the Table 1 dataset of the preset (cached by config digest, as table1):

1. **Table.** For each labeler and each observer model (the MLP and the archetypes of
   :mod:`slotv_jax.observers.parametric`), train ``--trials`` trials with the preset's config (the
   MLP: SLOT-V's; an archetype: :func:`slotv_jax.training.config.archetype`) and score them on the
   four Table 1 splits (SPEC §8); record each archetype's fitted parameters.
2. **Few labels.** Each archetype again, on 1/10 and 1/100 of the MLP's training
   trajectories (its ``train_size``), with as many updates as the preset gives it on the
   full set (the epochs scaled up): does it still reach the accuracy of the MLP trained on
   all of them?
3. **Sample efficiency** (SPEC §8's protocol, :mod:`slotv_jax.runs.curves`):
   the MLP and, per labeler, the archetype with the best trajectory_test accuracy in step 1,
   on Dragan and Nikolaidis labels: one epoch, validation on a fixed trajectory_val subset
   every ``--every`` updates (the MLP every 10, as the paper).

Writes ``OUT/results.json`` (config, environment, cells, parameters, few-label cells, sample
efficiency summaries), ``OUT/explainable.md`` (the tables) and ``OUT/explainable.png``.
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
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import command, curves, figures, presets
from slotv_jax.runs.presets import LABELER_TITLES, SPLIT_TITLES
from slotv_jax.runs.summary import mean_sd, pooled
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate
from slotv_jax.training import trainer as train

MODELS = train_config.MODELS
MODEL_TITLES = {
    "mlp": "MLP (SLOT-V)",
    "dragan": "learnable Dragan",
    "viewpoint": "learnable viewpoint",
    "mixture": "dist./approach mixture",
}
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


# ------------------------------------------------------------------ report


def _fmt_params(model: str, rows: list[dict]) -> str:
    """Fitted parameters, mean ± SD over trials, with units."""
    if not rows:
        return ""

    def ms(key, scale=1.0, digits=3):
        v = np.asarray([r[key] for r in rows], np.float64) * scale
        sd = v.std(ddof=1) if v.size > 1 else 0.0
        return f"{v.mean():.{digits}g} ± {sd:.2g}"

    if model == "dragan":
        return (f"β {ms('beta')} /m; α {ms('alpha')}; w₀ {ms('start_weight')}; metric x "
                f"{ms('metric_x')}, y {ms('metric_y')}, z {ms('metric_z')}")  # fmt: skip
    if model == "viewpoint":
        deg = 180 / np.pi
        return (f"yaw {ms('yaw', deg)}°, pitch {ms('pitch', deg)}°, distance "
                f"{ms('distance')} m; β {ms('beta')} /image unit")  # fmt: skip
    return (f"EffDist share {ms('effdist_share', 100)} %; β_E {ms('beta_effdist')} /m, "
            f"α_E {ms('alpha_effdist')}; β_F {ms('beta_fastapp')} /m, "
            f"α_F {ms('alpha_fastapp')}")  # fmt: skip


def report(doc: dict) -> str:
    """Markdown tables: accuracy per labeler, split and model; fitted parameters; few
    labels; sample efficiency."""
    by = {(s["labeler"], s["model"], s["split"]): s for s in doc["summary"]}
    models = list(doc["config"]["train"])
    labelers = sorted({s["labeler"] for s in doc["summary"]}, key=LABELER_NAMES.index)
    lines = [
        "| labeler | split | " + " | ".join(MODEL_TITLES[m] for m in models) + " |",
        "|---|---|" + "---|" * len(models),
    ]
    for lab in labelers:
        for i, split in enumerate(TEST_SPLITS):
            row = [LABELER_TITLES[lab] if i == 0 else "", SPLIT_TITLES[split]]
            for m in models:
                s = by.get((lab, m, split))
                row.append("—" if s is None else f"{s['mean']:.3f} ± {s['sd']:.3f}")
            lines.append("| " + " | ".join(row) + " |")
    table = "\n".join(lines)

    plines = [
        "| labeler | archetype | fitted parameters (mean ± SD over trials) |",
        "|---|---|---|",
    ]
    for lab in labelers:
        for m in models:
            rows = [p for p in doc["parameters"] if p["labeler"] == lab and p["model"] == m]
            if rows:
                plines.append(f"| {LABELER_TITLES[lab]} | {MODEL_TITLES[m]} | "
                              f"{_fmt_params(m, rows)} |")  # fmt: skip

    flines = [
        "| labeler | archetype | trajectories (fraction of the MLP's) | epochs | "
        "trajectory_test | position_test | goal_count_test |",
        "|---|---|---|---|---|---|---|",
    ]
    few: dict[tuple, dict] = {}
    for r in doc["few_labels"]:
        few.setdefault((r["labeler"], r["model"], r["fraction"]), {})[r["split"]] = r
    for (lab, m, frac), d in few.items():
        r0 = next(iter(d.values()))
        accs = [f"{d[s]['mean']:.3f} ± {d[s]['sd']:.3f}" for s in TEST_SPLITS[1:]]
        flines.append(f"| {LABELER_TITLES[lab]} | {MODEL_TITLES[m]} | {r0['train_size']} "
                      f"({frac}) | {r0['epochs']} | " + " | ".join(accs) + " |")  # fmt: skip

    slines = [
        "| labeler | observer | accuracy before training | examples to 80 % (mean curve) "
        "| per repeat | examples to 95 % (mean curve) | final accuracy | validated every |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for lab, runs in doc["sample_efficiency"].items():
        for m, r in runs.items():
            hit = r["examples_to_threshold_mean_curve"]
            per = ", ".join("never" if x is None else f"{x:,.0f}"
                            for x in r["examples_to_threshold_per_repeat"])  # fmt: skip
            h95 = r["examples_to_0.95_mean_curve"]
            slines.append(
                f"| {LABELER_TITLES[lab]} | {MODEL_TITLES[m]} | {r['start_accuracy_mean']:.3f} | "
                f"{'never' if hit is None else f'{hit:,.0f}'} | {per} | "
                f"{'never' if h95 is None else f'{h95:,.0f}'} | "
                f"{r['final_accuracy_mean']:.3f} ± {r['final_accuracy_sd']:.3f} | "
                f"{r['every']} updates |"
            )
    env = doc["environment"]
    return "\n".join(
        [
            f"# Explainable observers ({doc['preset']} preset)",
            "",
            f"jax {env.get('jax')}, flax {env.get('flax')}, optax {env.get('optax')}, devices "
            f"{env.get('devices')}; {doc['trials']} trials per cell; whole run "
            f"{doc['timing']['total_s']:.0f} s.",
            "",
            "## Accuracy (mean ± SD over trials)",
            "",
            table,
            "",
            "## Fitted parameters",
            "",
            "\n".join(plines),
            "",
            "## Few labels",
            "",
            "\n".join(flines),
            "",
            "## Sample efficiency (examples needed for 80 % validation accuracy)",
            "",
            "\n".join(slines),
            "",
        ]
    )


def plot(doc: dict, out: Path, path: Path) -> None:
    """Left: trajectory_test accuracy per labeler and model. Right: sample-efficiency
    curves (mean ± SD over repeats) of the MLP and the best archetype on each of the
    sample-efficiency labelers."""
    plt = figures.pyplot()
    se = doc["sample_efficiency"]
    fig, axes = plt.subplots(1, 1 + len(se), figsize=(5.2 * (1 + len(se)), 4.0), dpi=150)
    axes = np.atleast_1d(axes)
    ax = axes[0]
    by = {(s["labeler"], s["model"], s["split"]): s for s in doc["summary"]}
    models = list(doc["config"]["train"])
    labelers = sorted({s["labeler"] for s in doc["summary"]}, key=LABELER_NAMES.index)
    width = 0.8 / len(models)
    colors = dict(zip(MODELS, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True))
    for j, m in enumerate(models):
        vals = [by.get((lab, m, "trajectory_test"), {"mean": np.nan, "sd": 0}) for lab in labelers]
        ax.bar(np.arange(len(labelers)) + (j - (len(models) - 1) / 2) * width,
               [v["mean"] for v in vals], width, yerr=[v["sd"] for v in vals],
               color=colors[m], label=MODEL_TITLES[m])  # fmt: skip
    ax.set_xticks(np.arange(len(labelers)), [LABELER_TITLES[lab] for lab in labelers])
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("trajectory_test accuracy")
    ax.set_title(f"Table 1 accuracy ({doc['preset']} preset)")
    ax.legend(loc="lower left", fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    for ax, (lab, runs) in zip(axes[1:], se.items(), strict=True):
        for m, r in runs.items():
            x, acc = curves.curve(curves.read_rows(out / r["dir"]), "slotv")
            figures.band(ax, x, *figures.mean_sd(acc, ddof=1), color=colors[m], alpha=0.25,
                         label=f"{MODEL_TITLES[m]} (n={len(acc)})")  # fmt: skip
            hit = r["examples_to_threshold_mean_curve"]
            if hit is not None:
                ax.axvline(hit, color=colors[m], linestyle=":", linewidth=1)
        ax.axhline(0.8, color="grey", linestyle="--", linewidth=0.8)
        ax.set_xscale("symlog", linthresh=32)
        ax.set_xlim(0, max(r["examples_per_epoch"] for r in runs.values()) * 1.05)
        ax.set_ylim(0, 1)
        ax.set_xlabel("training trajectories seen")
        ax.set_ylabel("validation accuracy (trajectory_val)")
        ax.set_title(f"Sample efficiency, {LABELER_TITLES[lab]} labels")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    figures.save(fig, path)


def report_again(out: Path) -> int:
    """Write ``OUT/explainable.md`` again from ``OUT/results.json`` alone, and the figure
    where the sample-efficiency curves it draws are in ``OUT``."""
    path = out / "results.json"
    if not fileio.is_json_object_with(path, ("preset", "cells", "summary", "sample_efficiency")):
        raise cli.InputError(f"--report: {path} is not a results document of this experiment")
    fileio.check_output_files(out, ["explainable.md", "explainable.png"])
    doc = json.loads(path.read_text())
    write_text(out / "explainable.md", report(doc))
    dirs = [out / r["dir"] for runs in doc["sample_efficiency"].values() for r in runs.values()]
    if all((d / "sample_efficiency.csv").is_file() for d in dirs):
        plot(doc, out, out / "explainable.png")
    print(f"wrote {out}/explainable.md")
    return 0


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.experiments.explainable",
        description="Parametric (explainable) observers against the MLP (SPEC §10).",
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
