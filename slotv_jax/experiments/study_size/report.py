"""The study-size report, rendered from the results document: the Markdown, its notes and
the figure.
"""

from __future__ import annotations

import platform
from pathlib import Path

import numpy as np

from slotv_jax.experiments.study_size import BUDGET_FRACTIONS, INF, p_name
from slotv_jax.runs import figures
from slotv_jax.runs.presets import METHOD_TITLES, METHODS


def plot(doc: dict, path: Path) -> None:
    plt = figures.pyplot()
    cfg = doc["config"]
    methods = [m for m in METHODS if any(r["method"] == m for r in doc["summary"])]
    fig, axes = plt.subplots(
        1, len(methods), figsize=(5.2 * len(methods), 4.0), sharey=True, squeeze=False
    )
    for ax, m in zip(axes[0], methods, strict=True):
        for p in cfg["participants"]:
            rows = sorted(
                (r for r in doc["summary"] if (r["method"], r["participants"]) == (m, p)),
                key=lambda r: r["n"],
            )
            if not rows:
                continue
            n = np.array([r["n"] for r in rows])
            mu, sd = np.array([r["mean"] for r in rows]), np.array([r["sd"] for r in rows])
            style = {"ls": "--", "color": "k"} if p == INF else {"marker": "o"}
            figures.band(ax, n, mu, sd, label=f"P = {p_name(p)}", outline=True, **style)
        ax.axhline(cfg["threshold"], color="grey", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xlabel("training trajectories N")
        ax.set_title(f"{METHOD_TITLES[m]}, {cfg['train_preset']} networks")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(f"accuracy vs. noise-free {cfg['labeler']} ({cfg['eval_split']})")
    axes[0][-1].legend(title="participants / trajectory", fontsize=8)
    taus = cfg["taus"]
    seen = "whole motions" if list(taus) == [1.0] else f"stopped at τ ∈ {taus}"
    fig.suptitle(
        f"Simulated studies ({seen}, lapse {cfg['lapse']}); ≈ {cfg['updates']:,} updates per "
        f"cell; mean ± SD of {cfg['trials']} trials",
        fontsize=10,
    )
    fig.tight_layout()
    figures.save(fig, path, dpi=120)


def report(doc: dict, stem: str, command: str) -> str:
    cfg = doc["config"]
    env = doc["environment"]
    tcs = cfg["train"]
    lines = [
        "# Simulated studies: trajectories × participants for a learned observer "
        f"({doc['preset']})",
        "",
        "```bash",
        command,
        "```",
        "",
        f"- Date: {doc.get('date', 'not recorded')[:10]}; "
        f"machine: {platform.processor() or platform.machine()}"
        f", devices {env.get('devices')}; versions: "
        + ", ".join(
            f"{k} {v}" for k, v in env.items() if k in ("jax", "flax", "optax", "numpy", "python")
        ),
        f"- XLA: {doc.get('xla')}",
        f"- Scale: dataset preset `{cfg['data']['preset']}` (cached in `{doc['dataset']}`); "
        f"N ∈ {cfg['n_grid']} training trajectories, P ∈ "
        f"{[p_name(p) for p in cfg['participants']]} participants per trajectory, "
        f"{cfg['trials']} trials per cell; evaluation on all of `{cfg['eval_split']}` (held-out "
        "scenes) against the noise-free labeler.",
        f"- Participants: guess by sampling the {cfg['labeler']} labeler (β = "
        f"{cfg['data']['labels']['beta_' + cfg['labeler']]}, the dataset's) of what they saw; "
        f"stops τ ∈ {cfg['taus']}; lapse rate {cfg['lapse']}.",
        f"- Networks (`{cfg['train_preset']}` preset): SLOT-V hidden {tcs['slotv']['hidden']}, "
        f"{tcs['slotv']['optimizer']} lr {tcs['slotv']['learning_rate']}, batch "
        f"{tcs['slotv']['batch_size']}; T-REX hidden {tcs['trex']['hidden']}, "
        f"{tcs['trex']['optimizer']} lr {tcs['trex']['learning_rate']}, batch "
        f"{tcs['trex']['batch_size']}"
        + (f" (overrides for both: {', '.join(cfg['overrides'])})" if cfg["overrides"] else "")
        + f"; every cell trains ⌈{cfg['updates']:,} / steps per epoch⌉ epochs (≈ "
        f"{cfg['updates']:,} updates, the same for every N and P and both methods; "
        f"{_update_range(doc)}) on the multinomial likelihood of the counts.",
        f"- Time: data {doc['timing'].get('data_s', 0):.0f} s, cells "
        f"{sum(c['train_s'] for c in doc['cells']):.0f} s of training in all "
        f"({len(doc['cells'])} cells); the whole command "
        f"{doc['timing'].get('total_s', 0) / 60:.1f} min wall.",
        "",
        f"![accuracy against N]({stem}.png)",
        "",
        f"## What {cfg['threshold']:.0%} needs",
        "",
        "| method | participants P | trajectories N for "
        f"{cfg['threshold']:.0%} | answers N × P | best accuracy (at N) |",
        "|---|---|---|---|---|",
    ]
    for r in doc["needed"]:
        if r["n"] is None:
            n, ans = f"not reached by N = {max(cfg['n_grid']):,}", "—"
        else:
            n = f"{'≤ ' if r.get('at_most') else '≈ '}{r['n']:,.0f}"
            n += " †" if r.get("falls_back") else ""
            ans = "—" if r["participants"] == INF else f"≈ {r['answers']:,.0f}"
        lines.append(
            f"| {METHOD_TITLES[r['method']]} | {p_name(r['participants'])} | {n} | "
            f"{ans} | {r['best']:.3f} ({r['best_n']:,}) |"
        )
    lines += [
        "",
        "N is interpolated linearly in log N between the two grid points around the crossing "
        "of the mean curve; '≤' means the smallest N of the grid already reaches it; '†' "
        "that a larger N of the grid falls below it again (a crossing within the trials' "
        "noise: read it as 'about there, give or take a grid step').",
        "",
        "## Accuracy (mean ± SD over trials)",
        "",
        "| method | P | " + " | ".join(f"N = {n:,}" for n in cfg["n_grid"]) + " |",
        "|---|---|" + "---|" * len(cfg["n_grid"]),
    ]
    for m in METHODS:
        for p in cfg["participants"]:
            cells = {
                r["n"]: r for r in doc["summary"] if (r["method"], r["participants"]) == (m, p)
            }
            if not cells:
                continue
            vals = [
                f"{cells[n]['mean']:.3f} ± {cells[n]['sd']:.3f}" if n in cells else "—"
                for n in cfg["n_grid"]
            ]
            lines.append(f"| {METHOD_TITLES[m]} | {p_name(p)} | " + " | ".join(vals) + " |")
    if "budget" in doc:
        lines += _budget_lines(doc)
    if "measure" in doc:
        lines += ["", "## Training time (acceptance: ≤ 60 s)", ""]
        for name, r in doc["measure"].items():
            lines.append(
                f"- SLOT-V, quick preset ({r['epochs']} epochs, {r['updates']} updates), "
                f"{r['n']:,} trajectories × {r['participants']} participants, {name}: "
                f"{r['rows']:,} answer rows, {r['answers']:,.0f} answers: "
                f"**{r['seconds'][0]:.1f} s** with compilation, {r['seconds'][1]:.1f} s again."
            )
    lines += _notes(doc)
    return "\n".join(lines) + "\n"


def _update_range(doc: dict) -> str:
    u = [c["updates"] for c in doc["cells"]]
    return f"{min(u):,}–{max(u):,} in this run" if u else "no cells yet"


def _budget_lines(doc: dict) -> list[str]:
    b, cfg = doc["budget"], doc["config"]
    fr = " / ".join(f"{f:g}" for f in BUDGET_FRACTIONS)
    lines = [
        "",
        "## Training budget check",
        "",
        f"Accuracy on the labels (P = ∞, N = {b['n']:,}) after {fr} × the cells' "
        f"{cfg['updates']:,} updates (one run, trial 0's key):",
        "",
        "| method | " + " | ".join(f"{f:g} ×" for f in BUDGET_FRACTIONS) + " | time |",
        "|---|" + "---|" * (len(BUDGET_FRACTIONS) + 1),
    ]
    for m in METHODS:
        pts = b[m]["points"]
        cells = " | ".join(f"{p['accuracy']:.3f} ({p['updates']:,})" for p in pts)
        lines.append(f"| {METHOD_TITLES[m]} | {cells} | {b[m]['seconds']:.0f} s |")
    i1, i2 = BUDGET_FRACTIONS.index(1.0), BUDGET_FRACTIONS.index(2.0)
    gains = ", ".join(
        f"{round(b[m]['points'][i2]['accuracy'] - b[m]['points'][i1]['accuracy'], 3) + 0.0:+.3f} "
        f"({METHOD_TITLES[m]})"
        for m in METHODS
    )
    lines += [
        "",
        f"Doubling the budget adds {gains} at N = {b['n']:,} on the labels (one run: "
        "compare with the trials' SD above). Where that gain is well above the SD, the "
        "cells of large N are limited by training length, not data: their accuracy is a "
        "lower bound on what this network reaches with more updates, and an N for "
        f"{cfg['threshold']:.0%} found at large N an upper bound. Cells of small N see "
        "each trajectory many times within the budget and are limited by their data.",
    ]
    return lines


def _paper_scale(ref: dict) -> str:
    """The recorded paper-preset Table 1 accuracy the notes compare with, or nothing."""
    if "table1_slotv_dragan_position" not in ref:
        return ""
    return (
        f"At paper scale ({ref['table1_n_train']:,} trajectories, {ref['table1_epochs']} "
        f"epochs) SLOT-V reaches {ref['table1_slotv_dragan_position']:.3f} on Dragan's "
        "`position_test` (`experiments/table1_paper_results.json`). "
    )


def _ours_examples(ref: dict) -> str:
    """The recorded paper-preset sample-efficiency figure the notes compare with, or nothing."""
    if ref.get("sample_efficiency_slotv_examples") is None:
        return ""
    return (
        f"; {ref['sample_efficiency_slotv_examples']:,.0f} in ours at paper scale, "
        "`experiments/sample_efficiency.json`"
    )


def _notes(doc: dict) -> list[str]:
    """The report's notes, generated from the config and the results."""
    cfg, tcs = doc["config"], doc["config"]["train"]
    nmax = max(cfg["n_grid"])
    lines = ["", "## Notes", ""]
    if doc["preset"] == "quick":
        lines.append(
            "- Scale: the CPU quick preset, not the paper's. Networks "
            f"{tcs['slotv']['hidden']} (SLOT-V) and {tcs['trex']['hidden']} (T-REX) instead of "
            "the paper's 1536/768 and 1792/768, ≈ "
            f"{cfg['updates']:,} updates per cell instead of 15 epochs of 100,000, a "
            f"{cfg['data']['n_train']:,}-trajectory dataset, {cfg['trials']} trials. The "
            "numbers of trajectories above are those this small observer needs within this "
            "budget. " + _paper_scale(doc.get("references", {})) + "How many trajectories a "
            "paper-size observer needs is what the paper preset (GPU) measures: "
            "`python -m slotv_jax.experiments.study_size --preset paper --set "
            "compute_dtype=bfloat16` (writes `study_size_paper.{md,json,png}`, resumes if "
            "cut off)."
        )
    else:
        lines.append(
            f"- Scale: the `{doc['preset']}` preset, {cfg['updates']:,} updates per cell, "
            f"{cfg['trials']} trials."
        )
    for m in METHODS:
        rows = [r for r in doc["needed"] if r["method"] == m]
        hit = [r for r in rows if r["n"] is not None]
        miss = [p_name(r["participants"]) for r in rows if r["n"] is None]
        parts = [
            f"P = {p_name(r['participants'])} at N {'≤' if r.get('at_most') else '≈'} "
            f"{r['n']:,.0f}" + (f" ({r['answers']:,.0f} answers)" if "answers" in r else "")
            for r in hit
        ]
        text = f"- {METHOD_TITLES[m]} reaches {cfg['threshold']:.0%} with " + (
            "; ".join(parts) if parts else "no P"
        )
        if miss:
            text += f"; not by N = {nmax:,} with P = {', '.join(miss)}"
        lines.append(text + ".")
    bs = {tcs[m]["batch_size"] for m in METHODS}
    per = f"{cfg['updates'] * min(bs):,}" if len(bs) == 1 else "≈ updates × batch"
    lines.append(
        f"- Trajectories are not examples: every cell consumes ≈ {per} examples (N = "
        f"{min(cfg['n_grid']):,}: each trajectory many times over). The paper's 'about "
        "10,000 examples for 80 %' (its Fig. 3"
        + _ours_examples(doc.get("references", {}))
        + ") counts examples of one pass over fresh trajectories. A "
        "study pays for distinct trajectories and answers, which is what N and N × P count "
        "here; reusing them costs only compute."
    )
    lines.append(
        "- T-REX here is trained like SLOT-V, on the count likelihood with its summed "
        "rewards as the logits (`slotv_jax.study`), not on pairwise preferences as in "
        "Table 1 and Fig. 3, where it stays far below SLOT-V on Dragan labels; its curves "
        "are not comparable with those numbers."
    )
    load = doc.get("load")
    if load:
        lines.append(
            f"- The machine ({load['cpus']} CPUs) was shared: 1-minute load average "
            f"{load['start']:.1f} at the start and {load['end']:.1f} at the end of the run, "
            "so the times above are upper bounds for an idle machine."
        )
    if doc["preset"] == "quick":
        lines.append(
            "- How the quick budget was chosen, and why the study trainer agrees with the "
            "ordinary one: `experiments/study_size_budget.md` (measured before this run)."
        )
    return lines
