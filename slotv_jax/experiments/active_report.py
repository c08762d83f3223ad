"""The active-selection experiment's results, from the results document alone
(``python -m slotv_jax.experiments.active``): answers to the target and the comparisons
(:ref:`concepts-commands`), the Markdown report and the figure."""

from __future__ import annotations

import itertools
import math
from importlib import resources
from pathlib import Path

import numpy as np

from slotv_jax.asking.replay import ORACLES
from slotv_jax.core.fileio import write_text
from slotv_jax.runs import figures
from slotv_jax.runs.summary import against_random, ratio_se

MODEL_TITLES = {"mlp": "SLOT-V (paper MLP)", "slotv_plus": "SLOT-V+", "dragan": "Dragan archetype"}


def target_of(doc_cfg: dict, setting: str, model: str) -> float:
    if setting == "labels":
        return float(doc_cfg["labels_target"])
    return float(dict(doc_cfg["study_targets"])[model])


# ------------------------------------------------------------------ the summary


def comparisons(doc: dict) -> list[dict]:
    """One entry per (setting, labeler, model, strategy), the oracles' too
    (:func:`slotv_jax.runs.summary.against_random` of each group; :ref:`concepts-commands`'s list
    ``comparisons`` is that of the strategies: :func:`summarise`)."""
    out = []
    for grp in doc["groups"]:
        target = target_of(doc["config"], grp["setting"], grp["model"])
        for c in against_random(grp["answers"], grp["runs"], doc["config"]["strategies"], target):
            out.append({k: grp[k] for k in ("setting", "model", "labeler")} | c)
    return out


def summarise(doc: dict) -> dict:
    """Set the document's ``comparisons`` (the strategies, :ref:`concepts-active-selection`) and
    ``oracles`` (the same entries for the oracles, kept apart: they read the labels) from its
    groups."""
    every = comparisons(doc)
    doc["comparisons"] = [c for c in every if c["strategy"] not in ORACLES]
    doc["oracles"] = [c for c in every if c["strategy"] in ORACLES]
    return doc


# ------------------------------------------------------------------ rendering


def _every(doc: dict) -> list[dict]:
    """The strategies' comparisons, then the oracles'."""
    return doc["comparisons"] + doc.get("oracles", [])


def _of(grp: dict, entries: list[dict]) -> list[dict]:
    """The comparisons of ``entries`` that belong to the group ``grp``."""
    key = ("setting", "labeler", "model")
    return [c for c in entries if all(c[k] == grp[k] for k in key)]


def fmt_answers(x: float | None) -> str:
    return "not reached" if x is None else f"{x:,.0f}"


def _points(stride: int) -> str:
    return "every point" if stride == 1 else f"every {stride}th point"


def _seeds(cfg: dict) -> str:
    first = cfg.get("first_seed", 0)
    return f"{cfg['seeds']} seeds" + (f" (from seed {first})" if first else "")


def _updates(cfg: dict) -> str:
    blocks = f"{cfg['updates']} (labels) and {cfg.get('study_updates', cfg['updates'])} (study)"
    if not cfg.get("round_epochs"):
        return f"{blocks} updates per round (warm start)"
    return (
        f"updates per round (warm start): the smallest multiple of {blocks} that passes "
        f"{cfg['round_epochs']:g} times over the answers so far"
    )


def _held_out(cfg: dict) -> str:
    off = cfg.get("eval_offset", 0)
    if not off:
        return f"the first {cfg['eval_size']:,}"
    return f"motions {off:,} to {off + cfg['eval_size'] - 1:,}"


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
        f"- Protocol (`slotv_jax/experiments/active.py`): {_seeds(cfg)} × strategies "
        f"{', '.join(cfg['strategies'])}; ensembles of {cfg['members']} (member 0 is scored); "
        f"{_updates(cfg)}, batch "
        f"{cfg['train']['mlp']['batch_size']}; each round scores {cfg['subset']:,} unasked "
        f"motions; {_points(cfg['stride'])} of each "
        f"motion; dataset preset `{cfg['data']['preset']}` ({cfg['data']['n_train']:,} "
        "training motions = the pool).",
        f"- Labels setting: labelled motions {list(cfg['label_sizes'])}, target "
        f"{cfg['labels_target']:.0%} on {_held_out(cfg)} of `trajectory_val`. "
        f"Study setting: motions asked {list(cfg['study_sizes'])}, {cfg['participants']} "
        f"simulated participants each (sampling the {cfg['study_labeler']} labeler), targets "
        + ", ".join(f"{MODEL_TITLES[m]} {t:.0%}" for m, t in cfg["study_targets"])
        + f" on {_held_out(cfg)} of `position_test`.",
        f"- Time: {doc['timing'].get('total_s', 0) / 60:.1f} min of running in all"
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
    for c in _every(doc):
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
        cs = _of(grp, doc["comparisons"])
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
            + (
                ""
                if r is None
                else f": random / best = **{r:.2f}** ± "
                f"{ratio_se(rnd['per_seed'], best['per_seed']):.2f}"
            )
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
    lines += notes(doc)
    return "\n".join(lines) + "\n"


def _spread(doc: dict) -> str:
    """Random's largest seed-to-seed factor of answers to the target, and where."""
    out = []
    for c in doc["comparisons"]:
        per = [p for p in c["per_seed"] if p is not None]
        if c["strategy"] == "random" and len(per) > 1:
            out.append((max(per) / min(per), f"{c['setting']} / {MODEL_TITLES[c['model']]}"))
    if not out:
        return "the seeds"
    f, where = max(out)
    return f"a factor of up to {f:.1f} between seeds ({where})"


def _floor(doc: dict) -> list[str]:
    """Groups where a seed reaches the target at the first size with every strategy."""
    out = []
    for grp in doc["groups"]:
        cs = _of(grp, _every(doc))
        first = grp["answers"][0]
        seeds = [i for i in range(cs[0]["seeds"]) if all(c["per_seed"][i] == first for c in cs)]
        if seeds:
            out.append(f"{MODEL_TITLES[grp['model']]} ({len(seeds)} of {cs[0]['seeds']} seeds)")
    return out


def _oracles(doc: dict) -> list[str]:
    """'group: oracle ratio, …' of every group that ran an oracle."""
    out = []
    for grp in doc["groups"]:
        cs = _of(grp, doc.get("oracles", []))
        if cs:
            parts = []
            for c in cs:
                r, low = c["ratio_random_over_this"], c.get("ratio_at_least")
                shown = "not reached" if c["answers_to_target"] is None else (
                    f"≥ {low:.2f}" if r is None and low is not None else
                    "—" if r is None else f"{r:.2f}")  # fmt: skip
                parts.append(f"{c['strategy']} {shown}")
            out.append(f"{grp['setting']} / {grp['labeler']} / {MODEL_TITLES[grp['model']]} "
                       + ", ".join(parts))  # fmt: skip
    return out


def notes(doc: dict) -> list[str]:
    """The report's notes: what the ratios mean and what bounds them (from the document,
    plus the tuning runs of the paper preset)."""
    cfg = doc["config"]
    k_max = max(
        b - a
        for sizes in (cfg["label_sizes"], cfg["study_sizes"])
        for a, b in itertools.pairwise(sizes)
    )
    step = cfg["label_sizes"][-1] / cfg["label_sizes"][-2]
    out = [
        *NOTES,
        "- What bounds the ratios. (1) Seeds: answers to the target vary by "
        f"{_spread(doc)}, so a ratio over {cfg['seeds']} seeds is known to the ± above "
        "(one standard error), and the best of several strategies is an optimistic pick "
        "(the largest of several noisy ratios). (2) The grid: sizes grow by "
        f"×{step:.2g} between rounds and answers to the target are interpolated between "
        f"them. (3) The pool subset: each round scores {cfg['subset']:,} unasked motions; "
        f"the largest step asks about {k_max:,} of them ({k_max / cfg['subset']:.0%}), and "
        "the closer to all of them, the closer any criterion is to random.",
    ]
    oracles = _oracles(doc)
    if oracles:
        out.append(
            "- The oracles read the labels of the candidates (the labeler's noise-free guess "
            "distribution), which no study has before it asks: `oracle_loss` asks about the "
            "motions member 0 gets most wrong (largest cross-entropy), `oracle_margin` about "
            "those nearest the labeler's own decision between two goals. They are not "
            "strategies (left out of the best strategy above) and not strict bounds (the best "
            "set of questions needs a search over sets), but two natural uses of knowledge no "
            "criterion of the observer's own can have. Random / oracle: " + "; ".join(oracles) + "."
        )
    floor = _floor(doc)
    if floor:
        out.append(
            "- A seed that reaches the target at the first size with every strategy (its "
            f"random first draw suffices: {', '.join(floor)}) adds the same answers to every "
            "strategy's mean and pulls its ratio towards 1."
        )
    if doc["preset"] == "paper":
        out += PAPER_NOTES
    out += _three_fold(doc)
    return out


def _notes_file(name: str) -> list[str]:
    """The lines of a notes file beside this module (prose kept as Markdown, not code)."""
    return (resources.files(__package__) / name).read_text(encoding="utf-8").splitlines()


NOTES = _notes_file("active_notes.md")  # why the criteria differ, what member 0 is

# PAPER_NOTES: the tuning runs of the paper preset (python -m slotv_jax.experiments.active
# --preset paper --seeds 3 --first-seed 10 --eval-offset 5000 --groups
# labels/dragan/mlp,study/dragan/mlp with --strategies random,uncertainty,margin,margin_cluster,
# once with random alone and --updates 300 --study-updates 900, and once with
# random,uncertainty,margin,epig and the two oracles); then for studies with the paper MLP up
# to 2,048 motions, --seeds 5 --first-seed 10, once with --members 6 and once with sizes
# geometric(8, 2048, 2 ** 0.25)): other seeds, other held-out motions than the report's.
PAPER_NOTES = _notes_file("active_paper_notes.md")


def _three_fold(doc: dict) -> list[str]:
    """Why 3× on the Dragan labels is out of reach (from the document's own numbers)."""
    cs = {c["strategy"]: c for c in _every(doc)
          if (c["setting"], c["labeler"]) == ("labels", "dragan")}  # fmt: skip
    rnd = cs.get("random")
    if rnd is None or rnd["answers_to_target"] is None:
        return []
    per, first = rnd["per_seed"], doc["config"]["label_sizes"][0]
    third = rnd["answers_to_target"] / 3
    best = min((c for s, c in cs.items() if s != "random" and s not in ORACLES
                and c["answers_to_target"] is not None),
               key=lambda c: c["answers_to_target"], default=None)  # fmt: skip
    line = (
        f"- Why 3× on the paper's Dragan labels is out of reach here: random selection reaches "
        f"80 % after {min(per):.0f} to {max(per):.0f} labelled motions (mean "
        f"{rnd['answers_to_target']:.0f}). A third of that is about {third:.0f} motions, "
        f"{third - first:.0f} of them chosen by observers trained on {first} to {third:.0f}"
    )
    if best is not None:
        line += f" ({best['strategy']}'s best seed needs {min(best['per_seed']):.0f})"
    oracles = [c for s, c in cs.items() if s in ORACLES
               and c["ratio_random_over_this"] is not None]  # fmt: skip
    labelled = [c["ratio_random_over_this"] for c in doc.get("oracles", [])
                if c["setting"] == "labels"
                and c["ratio_random_over_this"] is not None]  # fmt: skip
    if oracles and best is not None and best["ratio_random_over_this"] is not None:
        line += (
            ". Knowing the labels does not close the gap: the oracles need "
            + " and ".join(f"{c['ratio_random_over_this']:.2f}×" for c in oracles)
            + f" fewer motions than random, less than {best['strategy']}'s "
            f"{best['ratio_random_over_this']:.2f}×, and at most {max(labelled):.2f}× on any "
            "labeler. A likely reason: each label is the labeler's whole guess distribution, so "
            "every labelled motion teaches the observer's value function along its whole path, "
            "and which motions are labelled matters less than how many; where each answer is "
            "a single noisy guess (the simulated studies) the oracle of largest loss goes "
            "further than any criterion"
        )
    return [line + "."]


def plot(doc: dict, path: Path) -> None:
    """Accuracy against answers, one panel per group, mean ± SD over seeds per strategy."""
    plt = figures.pyplot()
    import matplotlib.ticker

    groups = doc["groups"]
    cols = min(3, len(groups))
    rows = math.ceil(len(groups) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), dpi=130, squeeze=False)
    for ax, grp in zip(axes.flat, groups, strict=False):
        x = np.asarray(grp["answers"], float)
        target = target_of(doc["config"], grp["setting"], grp["model"])
        for s in doc["config"]["strategies"]:
            acc = np.array([r["accuracy"] for r in grp["runs"] if r["strategy"] == s])
            style = "--" if s in ORACLES else "-"  # an oracle reads the labels: dashed
            figures.band(ax, x, *figures.mean_sd(acc), marker="o", ms=3, label=s,
                         color=figures.STRATEGY_COLORS.get(s), linestyle=style)  # fmt: skip
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
    figures.save(fig, path)


def stem_of(preset: str) -> str:
    return "active" if preset == "quick" else f"active_{preset}"


def render(doc: dict, out: Path, command: str) -> None:
    """Write ``.md`` and ``.png`` from the results document."""
    stem = stem_of(doc["preset"])
    plot(doc, out / f"{stem}.png")
    write_text(out / f"{stem}.md", report(doc, stem, command))
