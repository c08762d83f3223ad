"""The explainable-observers experiment's report, from its results document alone
(``python -m slotv_jax.experiments.explainable``): the Markdown tables (accuracy per labeler,
split and model; fitted parameters; few labels; sample efficiency) and the figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import curves, figures
from slotv_jax.runs.presets import LABELER_TITLES, SPLIT_TITLES
from slotv_jax.training.config import MODELS

MODEL_TITLES = {
    "mlp": "MLP (SLOT-V)",
    "dragan": "learnable Dragan",
    "viewpoint": "learnable viewpoint",
    "mixture": "dist./approach mixture",
}


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
