"""The fidelity ablation's report, rendered from its results document alone
(``OUT/results.json`` of :mod:`slotv_jax.experiments.fidelity`, e.g.
``experiments/fidelity_results.json``): the label statistics and the accuracy of every
setting, grouped by factor, beside the paper's values, and the figure of accuracy against
each factor.
"""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np

from slotv_jax.core.defaults import TEST_SPLITS
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import figures
from slotv_jax.runs.paper import PAPER_TABLE
from slotv_jax.runs.presets import LABELER_TITLES, METHOD_TITLES, SPLIT_TITLES

# the ablation's factors, in order, and their titles in the figure
FACTOR_TITLES = {
    "via": "via-point count",
    "beta": "label temperature (× first version's β)",
    "box": "via-point box",
    "timing": "time parameterisation",
    "defaults": "around the β ×4 defaults",
}


def _acc(row: dict, labeler: str, method: str, split: str) -> tuple[float, float, int] | None:
    for s in row["summary"]:
        if (s["labeler"], s["method"], s["split"]) == (labeler, method, split):
            return s["mean"], s["sd"], s["n"]
    return None


def render_markdown(doc: dict, *, command: str = "", wall_s: float | None = None) -> str:
    """The ablation's tables: label statistics and accuracy per setting, grouped by factor."""
    cfg = doc["config"]
    env = doc.get("environment", {})
    labs = cfg["labelers"]
    lines = [
        f"# Fidelity ablation ({doc['preset']} preset)",
        "",
        "One factor at a time from the base setting (1 via point, equal arc-length spacing, "
        "the SPEC's via box, the first version's β: 5 for Dragan, EffDist and FastApp, 7.5 for "
        "Nikolaidis); then, as a second stage, one choice at a time around the first stage's "
        "defaults (β ×4): the rows of factor `defaults`. Accuracy is Table 1's "
        "(concepts: metrics), mean ± SD over trials; label statistics are means over the four "
        "Table 1 "
        "splits. `python -m slotv_jax.experiments.fidelity` made it.",
        "",
    ]
    if command:
        lines += [f"Command: `{command}`", ""]
    date = datetime.date.today().isoformat()
    lines += [
        f"Run: {date}; jax {env.get('jax')}, flax {env.get('flax')}, mujoco {env.get('mujoco')}, "
        f"devices {env.get('devices')}"
        + (f"; wall time of this invocation {wall_s / 60:.1f} min." if wall_s else "."),
        "",
        "## Label statistics",
        "",
        "Entropy ratio: label entropy / uniform entropy over the same goals (1 = uniform). "
        "Margin: mean gap between the two largest probabilities. Target: how often "
        "argmax y is the true target (chance ≈ 0.27). Agree: all four labelers' argmaxes equal.",
        "",
        "| factor | setting | Dragan entropy / margin / target | Nikolaidis entropy / margin "
        "/ target | EffDist target | FastApp target | agree |",
        "|---|---|---|---|---|---|---|",
    ]
    rows = doc["settings"]
    for r in rows:
        m = r["label_stats"]["mean"]

        def st(lab, m=m):
            return (
                f"{m[lab]['entropy_ratio']:.3f} / {m[lab]['margin']:.3f} / "
                f"{m[lab]['target_agreement']:.3f}"
            )

        lines.append(
            f"| {r['factor']} | {r['value']} | {st('dragan')} | {st('nikolaidis')} | "
            f"{m['effdist']['target_agreement']:.3f} | {m['fastapp']['target_agreement']:.3f} | "
            f"{r['label_stats']['all_agree']:.3f} |"
        )
    lines += ["", "## Accuracy", ""]
    split_hdr = " / ".join(SPLIT_TITLES[s] for s in TEST_SPLITS)
    lines.append(f"Each cell: {split_hdr}, mean over trials (n trials).")
    lines.append("")
    hdr = "| factor | setting | " + " | ".join(
        f"{METHOD_TITLES[m]} {LABELER_TITLES[lab]}" for lab in labs for m in cfg["methods"]
    )
    lines += [hdr + " |", "|---|---|" + "---|" * (len(labs) * len(cfg["methods"]))]
    paper_row = "| paper | | " + " | ".join(
        " / ".join(f"{PAPER_TABLE[(lab, m, s)][0]:.2f}" for s in TEST_SPLITS)
        for lab in labs
        for m in cfg["methods"]
    )
    lines.append(paper_row + " |")
    for r in rows:
        cells = []
        for lab in labs:
            for m in cfg["methods"]:
                a = [_acc(r, lab, m, s) for s in TEST_SPLITS]
                if any(x is None for x in a):
                    cells.append("—")
                else:
                    sds = max(x[1] for x in a)
                    cells.append(
                        " / ".join(f"{x[0]:.2f}" for x in a) + f" (n={a[0][2]}, SD≤{sds:.2f})"
                    )
        lines.append(f"| {r['factor']} | {r['value']} | " + " | ".join(cells) + " |")
    lines += ["", "![accuracy against each factor](fidelity.png)", ""]
    return "\n".join(lines)


def plot(doc: dict, path: Path) -> None:
    """Accuracy (mean over the four splits, ± SD over trials) against each factor, one panel
    per factor; the paper's values (mean over its four splits) as dashed reference lines."""
    plt = figures.pyplot()
    cfg = doc["config"]
    labs, methods = cfg["labelers"], cfg["methods"]
    fig, axes = plt.subplots(1, len(FACTOR_TITLES), figsize=(4.2 * len(FACTOR_TITLES), 4), dpi=130)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    series = [(lab, m) for lab in labs for m in methods]
    for ax, factor in zip(axes, FACTOR_TITLES, strict=True):
        rows = [r for r in doc["settings"] if r["factor"] == factor]
        x = np.arange(len(rows))
        for i, (lab, m) in enumerate(series):
            c = colors[i % len(colors)]
            means, sds = [], []
            for r in rows:
                trials = {}
                for cell in r["cells"]:
                    if (cell["labeler"], cell["method"]) == (lab, m):
                        trials.setdefault(cell["trial"], []).append(cell["accuracy"])
                per_trial = np.array([np.mean(v) for v in trials.values()]) if trials else None
                means.append(np.nan if per_trial is None else per_trial.mean())
                sds.append(
                    0.0 if per_trial is None or per_trial.size < 2 else per_trial.std(ddof=1)
                )
            style = "-o" if m == "slotv" else "--s"
            ax.errorbar(x, means, yerr=sds, fmt=style, color=c, capsize=3, ms=4,
                        label=f"{METHOD_TITLES[m]} {LABELER_TITLES[lab]}")  # fmt: skip
            ref = np.mean([PAPER_TABLE[(lab, m, s)][0] for s in TEST_SPLITS])
            ax.axhline(ref, color=c, linestyle=":", linewidth=1)
        ax.set_xticks(x, [r["value"] for r in rows], rotation=30, ha="right")
        ax.set_title(FACTOR_TITLES[factor], fontsize=9)
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("accuracy, mean of the 4 Table 1 splits")
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=len(series), fontsize=7, frameon=False)
    fig.suptitle(
        f"Fidelity ablation ({doc['preset']} preset); dotted lines: the paper's values",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    figures.save(fig, path)


def write_report(doc: dict, doc_path: Path, *, command: str = "", wall_s: float | None = None):
    """Write the Markdown report and, beside it, ``fidelity.png``."""
    doc_path.parent.mkdir(parents=True, exist_ok=True)
    png = doc_path.with_suffix(".png")
    text = render_markdown(doc, command=command, wall_s=wall_s)
    write_text(doc_path, text.replace("(fidelity.png)", f"({png.name})"))
    if doc["settings"]:
        plot(doc, png)
