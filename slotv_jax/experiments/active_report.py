"""Rendering of the active-selection experiment: the Markdown report and the figure, from
the results document alone (``python -m slotv_jax.experiments.active``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from slotv_jax.core.fileio import save_figure, write_text

MODEL_TITLES = {"mlp": "SLOT-V (paper MLP)", "slotv_plus": "SLOT-V+", "dragan": "Dragan archetype"}
STRATEGY_COLORS = {
    "random": "black",
    "uncertainty": "tab:orange",
    "margin": "tab:red",
    "bald": "tab:blue",
    "bald_fantasy": "tab:green",
    "bald_cluster": "tab:purple",
}


def target_of(doc_cfg: dict, setting: str, model: str) -> float:
    if setting == "labels":
        return float(doc_cfg["labels_target"])
    return float(dict(doc_cfg["study_targets"])[model])


# ------------------------------------------------------------------ rendering


def fmt_answers(x: float | None) -> str:
    return "not reached" if x is None else f"{x:,.0f}"


def _points(stride: int) -> str:
    return "every point" if stride == 1 else f"every {stride}th point"


def report(doc: dict, stem: str, command: str) -> str:
    """The Markdown report, rendered from the results document alone."""
    cfg, env = doc["config"], doc["environment"]
    lines = [
        f"# Active selection of stimuli ({doc['preset']} preset)",
        "",
        f"```bash\n{command}\n```",
        "",
        f"- Date: {doc.get('date', '')}; machine: {doc.get('machine', '')}, devices "
        f"{env.get('devices', '')}; versions: python {env.get('python')}, jax {env.get('jax')}, "
        f"flax {env.get('flax')}, optax {env.get('optax')}, numpy {env.get('numpy')}",
        f"- Protocol (`slotv_jax/experiments/active.py`): {cfg['seeds']} seeds × strategies "
        f"{', '.join(cfg['strategies'])}; ensembles of {cfg['members']} (member 0 is scored); "
        f"{cfg['updates']} (labels) and {cfg.get('study_updates', cfg['updates'])} (study) "
        "updates per round (warm start), batch "
        f"{cfg['train']['mlp']['batch_size']}; each round scores {cfg['subset']:,} unasked "
        f"motions; {_points(cfg['stride'])} of each "
        f"motion; dataset preset `{cfg['data']['preset']}` ({cfg['data']['n_train']:,} "
        "training motions = the pool).",
        f"- Labels setting: labelled motions {list(cfg['label_sizes'])}, target "
        f"{cfg['labels_target']:.0%} on the first {cfg['eval_size']:,} of `trajectory_val`. "
        f"Study setting: motions asked {list(cfg['study_sizes'])}, {cfg['participants']} "
        f"simulated participants each (sampling the {cfg['study_labeler']} labeler), targets "
        + ", ".join(f"{MODEL_TITLES[m]} {t:.0%}" for m, t in cfg["study_targets"])
        + f" on the first {cfg['eval_size']:,} of `position_test`.",
        f"- Time: {doc['timing'].get('total_s', 0) / 60:.1f} min for the whole command"
        + (
            f"; 1-minute load average {doc['load']['start']:.1f} at the start and "
            f"{doc['load']['end']:.1f} at the end on {doc['load']['cpus']} CPUs (shared)"
            if "load" in doc
            else ""
        )
        + ".",
        "",
        f"![learning curves]({stem}.png)",
        "",
        "## Answers to the target (mean over seeds)",
        "",
        "| setting | labeler | model | target | strategy | answers to target | seeds reached "
        "| random / this | final accuracy |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in doc["comparisons"]:
        ratio = c["ratio_random_over_this"]
        shown = "—" if ratio is None else f"{ratio:.2f}"
        if c.get("ratio_at_least") is not None:
            shown = f"≥ {c['ratio_at_least']:.2f}"
        lines.append(
            f"| {c['setting']} | {c['labeler']} | {MODEL_TITLES[c['model']]} | "
            f"{c['target']:.0%} | {c['strategy']} | {fmt_answers(c['answers_to_target'])} | "
            f"{c['seeds_reached']}/{c['seeds']} | {shown} "
            f"| {c['final_accuracy']:.3f} |"
        )
    lines += [
        "",
        "Answers to the target: per seed, the first round at or above it, interpolated "
        "linearly in log answers from the round before; 'not reached' when a seed stays "
        "below it up to the largest size. 'random / this' > 1 means fewer answers than "
        "random selection in the same run; '≥' a lower bound where random missed the target "
        "in some seed (counted at the largest size).",
        "",
        "## Best strategy against random",
        "",
    ]
    for grp in doc["groups"]:
        cs = [
            c
            for c in doc["comparisons"]
            if (c["setting"], c["labeler"], c["model"])
            == (grp["setting"], grp["labeler"], grp["model"])
        ]
        rnd = next(c for c in cs if c["strategy"] == "random")
        hit = [c for c in cs if c["strategy"] != "random" and c["answers_to_target"] is not None]
        name = f"{grp['setting']} / {grp['labeler']} / {MODEL_TITLES[grp['model']]}"
        if not hit:
            lines.append(
                f"- {name}: no active strategy reached the target in every seed "
                f"(random: {fmt_answers(rnd['answers_to_target'])})."
            )
            continue
        best = min(hit, key=lambda c: c["answers_to_target"])
        r = best["ratio_random_over_this"]
        if r is None and best.get("ratio_at_least") is not None:
            lines.append(
                f"- {name}: best {best['strategy']} {fmt_answers(best['answers_to_target'])} "
                f"answers; random did not reach the target in every seed: random / best "
                f"**≥ {best['ratio_at_least']:.2f}** (its unreached seeds counted at the "
                "largest size)."
            )
            continue
        lines.append(
            f"- {name}: best {best['strategy']} {fmt_answers(best['answers_to_target'])} answers, "
            f"random {fmt_answers(rnd['answers_to_target'])}"
            + ("" if r is None else f": random / best = **{r:.2f}**")
            + "."
        )
    lines += ["", "## Accuracy per round (mean over seeds)", ""]
    for grp in doc["groups"]:
        lines += [
            f"**{grp['setting']} / {grp['labeler']} / {MODEL_TITLES[grp['model']]}** "
            f"(fit {grp['timing']['fit_s']:.0f} s, scoring {grp['timing']['score_s']:.0f} s, "
            f"selection {grp['timing']['select_s']:.0f} s, evaluation "
            f"{grp['timing']['eval_s']:.0f} s)",
            "",
            "| strategy | " + " | ".join(f"{a:,}" for a in grp["answers"]) + " |",
            "|---|" + "---|" * len(grp["answers"]),
        ]
        for s in cfg["strategies"]:
            acc = np.array([r["accuracy"] for r in grp["runs"] if r["strategy"] == s])
            lines.append(f"| {s} | " + " | ".join(f"{v:.3f}" for v in acc.mean(0)) + " |")
        lines.append("")
    lines += NOTES
    return "\n".join(lines) + "\n"


NOTES = [
    "## Notes",
    "",
    "- The paper's Fig. 3 counts examples of one pass over fresh motions (5,760 to 80 % on "
    "Dragan at the paper preset, `experiments/sample_efficiency.json`). Here every answer "
    "is reused for as many updates as the rounds give (a study pays for answers, not "
    "updates), so random selection itself needs far fewer distinct answers; the ratios "
    "compare strategies within this protocol.",
    "- Member 0 of each ensemble is an ordinary training run on the answers so far (no "
    "bootstrap): its accuracy is the observer the study would deliver. The other members "
    "only feed the criteria.",
    "- Why the criteria differ. `margin` asks about motions near the observer's decision "
    "between two goals, which is what held-out accuracy (the argmax) measures. `uncertainty` "
    "(entropy) also rewards motions whose guesses spread over many goals. The BALD family "
    "asks about what the ensemble members disagree on; with few answers that is the "
    "atypical motions, which teach little about the typical held-out motion (the "
    "cold-start problem of disagreement-based selection; an ensemble of a few members is a "
    "coarse posterior).",
    "- What bounds the ratios. (1) Seeds: a strategy's answers to the target vary between "
    "seeds by a factor of up to 5 (`per_seed` in the JSON), so with 3 seeds a ratio is "
    "known to about ±50 %. (2) Training: each round trains a fixed number of updates, so "
    "the smallest sizes are limited by training as well as by data, and a group whose "
    "accuracy still climbs at its largest size (the paper MLP on single guesses) is "
    "limited by training throughout. (3) The grid: sizes double between rounds; answers to "
    "the target are interpolated between them. (4) The pool subset: each round scores "
    "`subset` unasked motions, and picks up to half of them at the largest step, where "
    "any criterion is close to random.",
]


def plot(doc: dict, path: Path) -> None:
    """Accuracy against answers, one panel per group, mean ± SD over seeds per strategy."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = doc["groups"]
    cols = min(3, len(groups))
    rows = math.ceil(len(groups) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), dpi=130, squeeze=False)
    for ax, grp in zip(axes.flat, groups, strict=False):
        x = np.asarray(grp["answers"], float)
        target = target_of(doc["config"], grp["setting"], grp["model"])
        for s in doc["config"]["strategies"]:
            acc = np.array([r["accuracy"] for r in grp["runs"] if r["strategy"] == s])
            m, sd = acc.mean(0), acc.std(0)
            col = STRATEGY_COLORS.get(s)
            ax.plot(x, m, marker="o", ms=3, color=col, label=s)
            ax.fill_between(x, m - sd, m + sd, color=col, alpha=0.15, linewidth=0)
        ax.axhline(target, color="grey", linestyle="--", linewidth=0.8)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        step = 1 if len(x) <= 6 else 2  # label every size, or every other one
        ax.set_xticks(x[::step], [f"{v:,.0f}" for v in x[::step]], fontsize=7)
        ax.set_title(
            f"{grp['setting']}: {grp['labeler']}, {MODEL_TITLES[grp['model']]}", fontsize=9
        )
        ax.set_xlabel("answers" if grp["setting"] == "study" else "labelled motions")
        ax.set_ylabel("held-out accuracy")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(groups) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="lower right")
    fig.suptitle(
        f"Active selection ({doc['preset']} preset, mean ± SD over {doc['config']['seeds']} seeds)",
        fontsize=10,
    )
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)


def stem_of(preset: str) -> str:
    return "active" if preset == "quick" else f"active_{preset}"


def render(doc: dict, out: Path, command: str) -> None:
    """Write ``.md`` and ``.png`` from the results document."""
    stem = stem_of(doc["preset"])
    plot(doc, out / f"{stem}.png")
    write_text(out / f"{stem}.md", report(doc, stem, command))
