"""The people loop's report, from its results document alone
(``python -m slotv_jax.experiments.people_loop``): tables of the gain kept, the answers to
50 % and 80 %, the whole-motion against the prefix objective, the evaluation studies, the
figure of gain kept against answers and a rendered comparison of one problem."""

from __future__ import annotations

import math
import statistics
from collections import Counter
from pathlib import Path

from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.people_loop.config import (
    CAUTIOUS,
    DERIVED,
    PICK,
    PICK_CROSS,
    PRESETS,
    PRETRAINED,
)
from slotv_jax.observers import population as population_lib
from slotv_jax.observers import zoo
from slotv_jax.runs import command, figures
from slotv_jax.runs.summary import crossing

FAMILY_TITLES = {
    "mlp": "SLOT-V (paper MLP)",
    "slotv_plus": "SLOT-V+",
    "dragan_archetype": "Dragan archetype",
    "viewpoint_archetype": "viewpoint archetype",
    "mixture_archetype": "distance/approach mixture archetype",
    "reader": "motion reader (from its prior)",
    "dragan_fitted": "Dragan, β fitted",
    "nikolaidis_fitted": "Nikolaidis, β fitted",
    "pick": "**pick** (answers alone)",
    "pick_cross": "**pick by plans** (answers alone)",
    "pick_cautious": "**cautious pick** (its folds' lower bound)",
}
FAMILY_TITLES |= {f: f"{FAMILY_TITLES[b]}, pre-trained" for f, b in PRETRAINED.items()}
FAMILY_COLORS = {
    "mlp": "tab:blue",
    "slotv_plus": "tab:red",
    "dragan_archetype": "tab:green",
    "viewpoint_archetype": "tab:purple",
    "mixture_archetype": "tab:olive",
    "reader": "teal",
    "dragan_fitted": "tab:gray",
    "nikolaidis_fitted": "tab:brown",
    "pick": "black",
    "pick_cross": "darkorange",
    "pick_cautious": "crimson",
    "mlp_pre": "tab:cyan",
    "slotv_plus_pre": "deeppink",
    "dragan_archetype_pre": "yellowgreen",
    "viewpoint_archetype_pre": "orchid",
    "mixture_archetype_pre": "khaki",
}
PRETRAIN_MARGIN = 0.03  # a pre-trained family "helps" or "hurts" beyond this much gain kept
HEADLINE = 2000  # the suite's headline: the largest size at most this many answers
STRATEGY_STYLES = {"random": "--", "margin": "-", "error": ":"}
# A marker per family, so that lines of near colours or on top of each other stay apart;
# the picks (drawn from the candidates, often on one of them) are wide and pale under the
# rest, so the candidate they equal shows through them.
FAMILY_MARKERS = {
    "mlp": "o", "slotv_plus": "s", "dragan_archetype": "^", "viewpoint_archetype": "v",
    "mixture_archetype": "D", "reader": "h", "dragan_fitted": "x", "nikolaidis_fitted": "+",
    "pick": "*", "pick_cross": "P", "pick_cautious": "X",
}  # fmt: skip
PICK_COLUMNS = {"pick": "pick", "pick_cross": "by plans", "pick_cautious": "cautious"}
UNDER = {
    "pick": 4.0,
    "pick_cross": 3.0,
    "pick_cautious": 2.5,
}  # line widths of the picks, drawn under the rest
GOOD_GAIN = 0.8  # the gain kept that the report's crossing columns count the answers to
BASELINES = ("dragan_fitted", "nikolaidis_fitted")
RENDER_TAU = 0.5


def curves(doc: dict, population: str) -> dict[tuple[str, str], tuple[list, list]]:
    """(family, strategy) -> (answers, mean gain kept) from the summary."""
    out: dict[tuple[str, str], tuple[list, list]] = {}
    rows = sorted(
        (r for r in doc["summary"] if r["population"] == population), key=lambda r: r["answers"]
    )
    for r in rows:
        a, g = out.setdefault((r["family"], r["strategy"]), ([], []))
        a.append(r["answers"])
        g.append(r["gain_kept"])
    return out


def plain_title(family: str) -> str:
    """A family's title without its Markdown emphasis (for a figure's legend)."""
    return FAMILY_TITLES.get(family, family).replace("**", "")


def _fmt(x: float | None) -> str:
    return "—" if x is None else f"{x:,.0f}"


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def population_section(doc: dict, pop: dict) -> list[str]:
    name, cfg, seeds = pop["population"], doc["config"], seeds_of(pop)
    c = curves(doc, name)
    sizes = sorted({a for (a_list, _) in c.values() for a in a_list})
    strategies = [s for s in cfg["strategies"] if any(k[1] == s for k in c)]
    families = [f for f in cfg["families"] if any(k[0] == f for k in c)]
    lines = [f"## Population `{name}`", ""]
    if name.startswith("random:"):  # a draw of the hyper-distribution: its fields
        pc = pop["population_config"]
        lines += [
            "A draw of the hyper-distribution (`slotv_jax.observers.population."
            "random_population`): viewpoints "
            + ", ".join(f"{k} {v:.2f}" for k, v in pc["viewpoints"].items())
            + "; rules "
            + ", ".join(f"{k} {v:.2f}" for k, v in pc["rules"].items())
            + "; β₀ "
            + ", ".join(f"{k} {v:.3g}" for k, v in pc["beta"].items())
            + f"; σ_log {pc['beta_sigma_log']:.2f}; memory {pc['memory']}"
            + (f" α ∈ [{pc['alpha_range'][0]:.2f}, {pc['alpha_range'][1]:.2f}]"
               if pc["alpha_range"] else "")
            + f"; lapse {pc['lapse']:.3f}.",
            "",
        ]  # fmt: skip
    lines += [
        "Gain kept, (plan − straight) / (oracle − straight), each scored by the population's "
        "mean P_pop(target | ξ_{0:τ}) over the study's stop times; the mean over "
        f"{len(seeds)} seed(s) ({', '.join(map(str, seeds))}).",
        "",
    ]
    for s in strategies:
        lines += [
            f"**{s}**",
            "",
            "| family | " + " | ".join(f"{a:,}" for a in sizes) + " |",
            "|---|" + "---|" * len(sizes),
        ]
        for f in families:
            a, g = c.get((f, s), ([], []))
            vals = dict(zip(a, g, strict=True))
            cells = [_pct(vals[x]) if x in vals else "—" for x in sizes]
            lines.append(f"| {FAMILY_TITLES.get(f, f)} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += [
        "Answers to keep 50 % and 80 % of the oracle's gain (interpolated in log answers; "
        "— : not within the sizes run):",
        "",
        "| family | " + " | ".join(f"{s}: 50 % / 80 %" for s in strategies) + " |",
        "|---|" + "---|" * len(strategies),
    ]
    for f in families:
        cells = []
        for s in strategies:
            a, g = c.get((f, s), ([], []))
            cells.append(f"{_fmt(crossing(a, g, 0.5))} / {_fmt(crossing(a, g, 0.8))}")
        lines.append(f"| {FAMILY_TITLES.get(f, f)} | " + " | ".join(cells) + " |")
    lines.append("")
    lines += verdict(doc, name, families, strategies, c)
    cmp_ = pop["comparison"]
    taus = cfg["taus"]
    lines += [
        "### What people read early: the prefix objective against the whole motion",
        "",
        "The population's P_pop(target | ξ_{0:τ}) of the oracle's plans (mean over the "
        "held-out problems) at each stop time, planned with the prefix objective (the mean "
        "over τ of log P_pop(target | ξ_{0:τ})) and with the whole-motion objective "
        "(log P_pop(target | ξ)); the evaluation study's accuracy pools every τ.",
        "",
        "| plan | " + " | ".join(f"τ = {t:g}" for t in taus) + " | mean | evaluation accuracy |",
        "|---|" + "---|" * (len(taus) + 2),
    ]
    for key, title in (
        ("straight", "straight line"),
        ("oracle_whole", "whole-motion objective"),
        ("oracle", "prefix objective"),
    ):
        v = cmp_[key]
        lines.append(
            f"| {title} | "
            + " | ".join(f"{p:.3f}" for p in v["per_tau"])
            + f" | {v['score']:.3f} | {_pct(v['accuracy'])} |"
        )
    lines.append("")
    lines += evaluation(doc, pop, families, strategies)
    for run in pop["runs"]:
        t, dev = run["timing"], device(run["environment"])
        lines.append(
            f"- Seed(s) {', '.join(map(str, run['seeds']))}: {t['total_s'] / 60:.1f} min on "
            f"{dev} ({run['date']}; fits {t['fit_s']:.0f} s, "
            f"β fits {t['beta_s']:.0f} s, "
            + (f"pick {t['pick_s']:.0f} s, " if "pick_s" in t else "")
            + (f"plans judged {t['judge_s']:.0f} s, " if t.get("judge_s") else "")
            + f"selection "
            f"{t['select_s']:.0f} s, planning "
            f"{t['plan_s']:.0f} s, evaluation {t['eval_s']:.0f} s, answers "
            f"{t['answers_s']:.0f} s)."
        )
    return [*lines, ""]


def device(env: dict) -> str:
    """The machine of an environment record: the device's kind (e.g. the GPU's name)."""
    kind = env.get("device_kind") or ", ".join(env.get("devices", []))
    return f"CPU, {env['cpu_count']} cores" if kind == "cpu" and "cpu_count" in env else kind


def seeds_of(pop: dict) -> list[int]:
    """The seeds whose rows a population's entry holds."""
    return sorted({r["seed"] for r in pop["rows"]})


def verdict(doc: dict, name: str, families, strategies, c) -> list[str]:
    """The issue's question in numbers: the best family within 2,000 answers, the fewest
    answers from which it keeps 80 %, and the fitted baselines at the same answers."""
    out = []
    for s in strategies:
        best, best_g, at = None, -math.inf, None
        for f in (f for f in families if f not in BASELINES):  # the best *learned* family
            a, g = c.get((f, s), ([], []))
            within = [(ai, gi) for ai, gi in zip(a, g, strict=True) if ai <= 2000]
            if within and within[-1][1] > best_g:
                best, (at, best_g) = f, within[-1]
        if best is None:
            continue
        base = {f: dict(zip(*c[(f, s)], strict=True)) for f in BASELINES if (f, s) in c}
        beats = [f for f, v in base.items() if best_g > v.get(at, math.inf)]
        reach = crossing(*c[(best, s)], 0.8)
        out.append(
            f"- {s}: at {at:,} answers the best family is {FAMILY_TITLES.get(best, best)}, "
            f"keeping {_pct(best_g)} of the oracle's gain"
            + (f" (80 % from {_fmt(reach)} answers)" if reach is not None else "")
            + (
                "; the fitted baselines keep "
                + " and ".join(f"{_pct(v[at])} ({FAMILY_TITLES[f]})" for f, v in base.items())
                if base
                else ""
            )
            + (f": it beats {'both' if len(beats) == 2 else 'one'}" if beats else "")
            + "."
        )
    return [*out, ""] if out else []


def evaluation(doc: dict, pop: dict, families, strategies) -> list[str]:
    """The evaluation study at the largest size: accuracy of fresh participants with its
    95 % interval (the first seed)."""
    cfg = doc["config"]
    last = max(r["answers"] for r in pop["rows"])
    seed = min(r["seed"] for r in pop["rows"])
    n = cfg["problems"] * len(cfg["taus"]) * cfg["eval_participants"]
    lines = [
        f"### Evaluation studies at {last:,} answers (seed {seed}, {n:,} guesses each)",
        "",
        "| family | " + " | ".join(strategies) + " |",
        "|---|" + "---|" * len(strategies),
    ]
    for f in families:
        cells = []
        for s in strategies:
            r = next(
                (
                    r
                    for r in pop["rows"]
                    if (r["family"], r["strategy"], r["answers"], r["seed"]) == (f, s, last, seed)
                ),
                None,
            )
            cells.append(
                "—"
                if r is None
                else f"{_pct(r['accuracy'])} "
                f"[{100 * r['accuracy_95'][0]:.0f}, {100 * r['accuracy_95'][1]:.0f}]"
            )
        lines.append(f"| {FAMILY_TITLES.get(f, f)} | " + " | ".join(cells) + " |")
    c = pop["comparison"]
    lines += [
        "",
        f"Straight line {_pct(c['straight']['accuracy'])}, oracle "
        f"{_pct(c['oracle']['accuracy'])} (chance ≈ 1 / goals).",
        "",
    ]
    return lines


DEFAULT_OUT = command.DEFAULT_OUT  # the command's --out default: its line leaves it out


def report(doc: dict, stem: str, out: Path = DEFAULT_OUT) -> str:
    """``STEM.md``'s text for a document written to ``out``: its commands name that folder."""
    cfg = doc["config"]
    env = doc["populations"][0]["runs"][-1]["environment"]
    seeds = sorted({sd for p in doc["populations"] for sd in seeds_of(p)})
    best = best_family(doc, doc["populations"][0])
    redraw = render_command(stem, out, best)
    head = [
        f"# From people's answers to motion people read ({doc['preset']} preset)",
        "",
        "Every number here comes from **simulated people** (`slotv_jax.observers.population`"
        + (
            "; the zoo of people outside its model, `slotv_jax.observers.zoo`"
            if any(p["population"] in zoo.zoo_names() for p in doc["populations"])
            else ""
        )
        + "), not from a study with humans: the population named in each section.",
        "",
        f"Rendered from `{stem}_results.json` (`{command_line(doc, out)}`). Stop times τ = "
        f"{', '.join(f'{t:g}' for t in cfg['taus'])}; "
        f"{cfg['per_stimulus']} answers per asked stimulus; pool {cfg['pool']:,} training motions; "
        f"{cfg['problems']} held-out problems; seeds {', '.join(map(str, seeds))}"
        + (
            f"; active selection asks an ensemble of {cfg['members']} "
            f"{FAMILY_TITLES.get(cfg['select_family'])} observers."
            if set(cfg["strategies"]) != {"random"}
            else "; the motions asked about are picked at random."
        )
        + (
            f" Every round after the first asks {100 * cfg['plan_share']:.0f} % of its stimuli "
            "about the planner's own plans of the study's scenes, the candidates' and the "
            "pick's in turn (rounds of plans, `--plan-share`; never an evaluation problem's scene)."
            if cfg.get("plan_share")
            else ""
        ),
        "",
        f"Machine: {device(env)}; Python {env.get('python')}, jax "
        f"{env.get('jax')}, flax {env.get('flax')}, optax {env.get('optax')}, mujoco "
        f"{env.get('mujoco')}, numpy {env.get('numpy')} (the last run; each population's "
        "section lists its runs, their machines and times).",
        "",
        f"![gain kept against answers]({stem}.png)",
        "",
        f"![straight line, oracle and the best learned plan at τ = {RENDER_TAU}]"
        f"({stem}_render.png)",
        "",
        f"*The first held-out problem of population `{doc['populations'][0]['population']}`, "
        f"seen from the `observer_angle` camera at τ = {RENDER_TAU}: the straight line, the "
        f"oracle's plan (the population's own P_pop) and the plan of the family that keeps the "
        f"most gain at the largest size "
        f"({FAMILY_TITLES.get(best or '', '—')}); drawn by `{' '.join(redraw)}` from "
        f"`{stem}_plans.npz`.*",
        "",
    ]
    suite = [line.replace("{stem}", stem) for line in suite_section(doc)]
    suite += pretrain_section(doc)
    body = [line for p in doc["populations"] for line in population_section(doc, p)]
    return "\n".join(head + suite + body)


def command_line(doc: dict, out: Path = DEFAULT_OUT) -> str:
    """The command that runs the document's config (its preset and the flags that differ)
    and writes it to ``out``."""
    cfg, words = doc["config"], ["python -m slotv_jax.experiments.people_loop"]
    words += ["--preset", doc["preset"]]
    base = _preset_config(doc["preset"])
    for k in ("strategies", "sizes", "families", "problems"):
        if base is not None and cfg[k] != base.get(k):
            v = cfg[k]
            words += [f"--{k}", ",".join(map(str, v)) if isinstance(v, list) else str(v)]
    if base is not None and cfg.get("plan_share", 0) != base.get("plan_share", 0):
        words += ["--plan-share", f"{cfg.get('plan_share', 0):g}"]
    pops = [p["population"] for p in doc["populations"]]
    if pops != ["default"]:
        groups = {"suite": population_lib.suite_specs(), "zoo": zoo.zoo_names()}
        named = [g for g, members in groups.items() if set(members) <= set(pops)]
        rest = [q for q in pops if not any(q in groups[g] for g in named)]
        words += ["--population", ",".join([*named, *rest])]
    if Path(out) != DEFAULT_OUT:
        words += ["--out", str(out)]
    return " ".join(words)


def _preset_config(preset: str) -> dict | None:
    f = PRESETS.get(preset)
    return None if f is None else f().to_json()


def plot(doc: dict, path: Path) -> None:
    """The gain kept against answers, one panel per population, a line per family and
    strategy (:func:`figure`), written to ``path``."""
    figures.save(figure(doc), path, dpi=120)


def figure(doc: dict):
    """:func:`plot`'s figure: a line per (family, strategy), each its own colour, marker and
    dashes, the picks wide and pale beneath the candidates; the 0.8 line labelled; one
    legend for every panel, below them."""
    plt = figures.pyplot()
    pops = [p["population"] for p in doc["populations"]]
    cols = min(len(pops), 4)
    rows = math.ceil(len(pops) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 4.2 * rows + 1.2), squeeze=False)
    for ax in axes.flat[len(pops) :]:
        ax.set_axis_off()
    handles: dict[str, object] = {}
    for ax, name in zip(axes.flat, pops, strict=False):
        for (f, s), (a, g) in curves(doc, name).items():
            under = f in UNDER
            (line,) = ax.plot(
                a, g, STRATEGY_STYLES.get(s, "-."), color=FAMILY_COLORS.get(f, "k"),
                marker=FAMILY_MARKERS.get(f, "o"), ms=9 if under else 4,
                lw=UNDER.get(f, 1.2), alpha=0.45 if under else 1.0, zorder=1 if under else 3,
                label=f"{plain_title(f)}, {s}",
            )  # fmt: skip
            handles.setdefault(line.get_label(), line)
        good = ax.axhline(GOOD_GAIN, color="k", lw=0.8, ls=(0, (1, 3)), zorder=0,
                          label=f"{GOOD_GAIN} of the oracle's gain")  # fmt: skip
        handles.setdefault(good.get_label(), good)
        ax.set_xscale("log")
        sizes = sorted({r["answers"] for r in doc["summary"] if r["population"] == name})
        ax.set_xticks(sizes, [f"{a:,}" for a in sizes])
        ax.minorticks_off()
        ax.set_xlabel("answers")
        ax.set_ylabel("gain kept (plan − straight) / (oracle − straight)")
        ax.set_title(f"population: {name} (simulated people)")
    fig.legend(handles.values(), handles.keys(), loc="lower center",
               ncol=min(len(handles), 4), fontsize=9, frameon=False)  # fmt: skip
    fig.tight_layout(rect=(0, 1.1 / fig.get_figheight(), 1, 1))
    return fig


def render_command(stem: str, out: Path, best: str | None) -> list[str]:
    """The command that draws ``STEM_render.png``: the straight line, the oracle and the
    best learned plan of the example problem, stopped at τ = :data:`RENDER_TAU`."""
    planners = ",".join(["straight", "oracle"] + ([best] if best else []))
    flags = f"--problem 0 --planner {planners} --tau {RENDER_TAU} --camera observer_angle "
    flags += "--mark-target --size 480x270 --overwrite"
    plans, png = out / f"{stem}_plans.npz", out / f"{stem}_render.png"
    return ["python", "-m", "slotv_jax.render", "--plans", str(plans), *flags.split(),
            "--out", str(png)]  # fmt: skip


def best_family(doc: dict, pop: dict) -> str | None:
    """The learned family with the highest gain kept at the largest size (any strategy)."""
    last = max(r["answers"] for r in pop["rows"])
    rows = [
        r
        for r in doc["summary"]
        if r["population"] == pop["population"]
        and r["answers"] == last
        and r["family"] not in (*BASELINES, PICK_CROSS)  # PICK_CROSS: another's plans
    ]
    return max(rows, key=lambda r: r["gain_kept"])["family"] if rows else None


def finished(doc: dict) -> tuple[dict, list[str]]:
    """The document without the populations a stopped run left mid-way (``partial``: the
    sizes they finished, which the next run of the command redoes), and their names.
    ValueError if no population has finished."""
    stopped = [p["population"] for p in doc["populations"] if p.get("partial")]
    done = [p for p in doc["populations"] if not p.get("partial")]
    if not done:
        raise ValueError(
            "the results document holds no finished population yet "
            f"({', '.join(stopped) or 'none'} stopped mid-way): nothing to report; run the "
            "command again to finish it"
        )
    return {**doc, "populations": done}, stopped


def render(doc: dict, out: Path, stem: str) -> None:
    """Write ``STEM.md`` and ``STEM.png`` from the document's finished populations
    (:func:`finished`; ``STEM_render.png`` is drawn from ``STEM_plans.npz`` by
    :func:`render_command`)."""
    doc, stopped = finished(doc)
    plot(doc, out / f"{stem}.png")
    plot_fit_plan(doc, out / f"{stem}_fit_plan.png")
    text = report(doc, stem, out)
    if stopped:
        text += (
            f"\n\n**Stopped mid-way, not in this report:** {', '.join(stopped)} (the document "
            "keeps the sizes they finished; the next run of the command redoes them).\n"
        )
    write_text(out / f"{stem}.md", text)


# ------------------------------------------------------------------ the suite and the pick


def _gain(doc: dict, pop: str, family: str, strategy: str = "random") -> dict[int, float]:
    return {
        r["answers"]: r["gain_kept"]
        for r in doc["summary"]
        if (r["population"], r["family"], r["strategy"]) == (pop, family, strategy)
    }


def headline_size(doc: dict) -> int | None:
    """The largest size at most :data:`HEADLINE` answers that every population ran."""
    per = [
        {r["answers"] for r in doc["summary"] if r["population"] == p["population"]}
        for p in doc["populations"]
    ]
    common = set.intersection(*per) if per else set()
    within = [a for a in common if a <= HEADLINE]
    return max(within) if within else None


def suite_summary(doc: dict, strategy: str = "random", family: str = PICK) -> dict | None:
    """A pick over the populations (random picks): each population's gain kept at every
    size, the median and worst at each size, and the suite's mean curve (None if a
    population lacks the family)."""
    pops = [p["population"] for p in doc["populations"]]
    if not pops or not all(_gain(doc, q, family, strategy) for q in pops):
        return None
    sizes = sorted(set.intersection(*(set(_gain(doc, q, family, strategy)) for q in pops)))
    table = {q: _gain(doc, q, family, strategy) for q in pops}
    out = {"sizes": sizes, "populations": pops, "gain": table}
    for name, fn in (("median", statistics.median), ("worst", min), ("mean", statistics.fmean)):
        out[name] = {a: fn(table[q][a] for q in pops) for a in sizes}
    return out


def _leaves_one_out(doc: dict) -> bool:
    """Whether the document's pick left a family out of its pool (its rows name it)."""
    return any("left_out" in r for p in doc["populations"] for r in p["rows"]
               if r["family"] == PICK)  # fmt: skip


def suite_section(doc: dict) -> list[str]:
    """The suite: one row per population (the pick, the pick by plans where it ran, both
    fitted baselines and the oracle's choice of one family), the median, the worst and the
    mean curve; whether more answers ever cost."""
    picks = {f: s for f in DERIVED if (s := suite_summary(doc, family=f)) is not None}
    if PICK not in picks:
        return []
    s = picks[PICK]
    sizes, at = s["sizes"], headline_size(doc)
    both = len(picks) > 1
    suite_pops = [q for q in s["populations"] if q in population_lib.suite_specs()]
    missing = [q for q in population_lib.suite_specs() if q not in s["populations"]]
    only_zoo = all(q in zoo.zoo_names() for q in s["populations"])
    if not suite_pops:  # the zoo alone (or files): nothing of the suite to miss
        missing = []
    title = (
        "The zoo: the pick on every member"
        if only_zoo
        else "The pick on every population"
        if missing
        else "The suite: the pick on every population"
    )
    lines = [
        f"## {title} (random picks)",
        "",
        "Gain kept by the **pick**, the log-linear pool of the fitted families weighted by the "
        "held-out likelihood of the answers alone (`slotv_jax.answers.pooling`)"
        + (
            ", less the family whose plans the other families' fits judge least legible "
            "(`slotv_jax.answers.pick.trusted`)"
            if _leaves_one_out(doc)
            else ", every family weighed (the rule before the pick left one family out)"
        )
        + _and_by(
            [
                "the **pick by plans**, the plans of the family that the other families' fits "
                "judge the most legible (`slotv_jax.experiments.people_loop.loop.cross_judged`)"
            ]
            * (PICK_CROSS in picks)
            + [
                "the **cautious pick**, the pick's pools of its folds' fits and of its fits on "
                "every answer planned for their lower confidence bound "
                "(`slotv_jax.planning.caution`)"
            ]
            * (CAUTIOUS in picks)
        )
        + (
            f"; beside {'them' if both else 'it'} the fitted baselines at {at:,} answers."
            if at
            else "."
        ),
        "",
        "| population | seeds | "
        + " | ".join(f"{PICK_COLUMNS[f]} {a:,}" for f in picks for a in sizes)
        + (
            " | Dragan, β fitted | Nikolaidis, β fitted | the best single family (oracle's "
            "choice) |"
            if at
            else " |"
        ),
        "|---|---|" + "---|" * (len(sizes) * len(picks) + (3 if at else 0)),
    ]
    seeds = {p["population"]: len(seeds_of(p)) for p in doc["populations"]}
    for q in s["populations"]:
        cells = [str(seeds[q])] + [_pct(p["gain"][q][a]) for p in picks.values() for a in sizes]
        if at:
            cells += [_pct(v[at]) if at in (v := _gain(doc, q, b)) else "—" for b in BASELINES]
            single = {
                f: v[at]
                for f in FAMILY_TITLES
                if f not in DERIVED and at in (v := _gain(doc, q, f))
            }
            best = max(single, key=single.get) if single else None
            cells.append(f"{FAMILY_TITLES[best]} {_pct(single[best])}" if best else "—")
        lines.append(f"| `{q}` | " + " | ".join(cells) + " |")
    for name in ("median", "worst", "mean"):
        lines.append(
            f"| **{name}** | | "
            + " | ".join(_pct(p[name][a]) for p in picks.values() for a in sizes)
            + (" | | | |" if at else " |")
        )
    zoo_pops = [q for q in s["populations"] if q in zoo.zoo_names()]
    if suite_pops and zoo_pops:  # suite ∪ zoo above; each part alone here
        for part, members in (("suite", suite_pops), ("zoo", zoo_pops)):
            for name, fn in (("median", statistics.median), ("worst", min)):
                lines.append(
                    f"| {name}, {part} alone | | "
                    + " | ".join(
                        _pct(fn(p["gain"][q][a] for q in members))
                        for p in picks.values()
                        for a in sizes
                    )
                    + (" | | | |" if at else " |")
                )
    if missing:
        lines += [
            "",
            f"Of the suite's {len(population_lib.suite_specs())} populations this run has "
            f"{len(population_lib.suite_specs()) - len(missing)} (not yet run: "
            f"{', '.join(f'`{q}`' for q in missing)}); the same command with "
            "`--population suite` resumes and adds them.",
        ]
    lines.append("")
    for f, p in picks.items():
        drops = [
            (a, b, p["mean"][a] - p["mean"][b])
            for i, a in enumerate(p["sizes"])
            for b in p["sizes"][i + 1 :]
            if p["mean"][a] - p["mean"][b] > 0.03
        ]
        title = plain_title(f)
        lines.append(
            f"- {title}: more answers never cost more than 3 points of the suite's mean curve."
            if not drops
            else f"- {title}: the suite's mean curve falls by more than 3 points: "
            + "; ".join(f"{a:,} → {b:,} answers: −{100 * d:.1f}" for a, b, d in drops)
            + "."
        )
    lines.append("")
    lines += pick_agreement(doc)
    return lines


def _and_by(phrases: list[str]) -> str:
    """ ", and by A" or ", by A, and by B" (nothing for no phrase)."""
    if not phrases:
        return ""
    return "".join(", by " + p for p in phrases[:-1]) + ", and by " + phrases[-1]


def _runs(doc: dict):
    """Every (population, seed, size) of random picks: {family: row}."""
    for p in doc["populations"]:
        by: dict = {}
        for r in p["rows"]:
            if r["strategy"] == "random":
                by.setdefault((r["seed"], r["answers"]), {})[r["family"]] = r
        yield from by.values()


def left_out_line(doc: dict) -> str:
    """Which families the pick's pool left out, and how often the one left out had the
    plans of least gain among the candidates (by the population's score, which the pick
    never reads); "" for a document whose pick weighed every family. A record of the rule
    that left exactly one family out of each run (``left_out`` a name, not a list) reads as
    it did."""
    out, worst, runs, none, one = Counter(), 0, 0, 0, True
    for rows in _runs(doc):
        if PICK in rows and "left_out" in rows[PICK]:
            single = {g: r["gain_kept"] for g, r in rows.items() if g not in DERIVED}
            left = rows[PICK]["left_out"]
            one &= isinstance(left, str)
            left = [left] if isinstance(left, str) else left
            runs += 1
            none += not left
            out.update(left)
            worst += min(single, key=single.get) in left
    if not runs:
        return ""
    names = ", ".join(f"{FAMILY_TITLES.get(f, f)} in {n}" for f, n in out.most_common())
    if one:
        return (
            f" The pool left out {names} of {runs} runs; the family left out had the"
            f" plans of least gain among the candidates in {worst} of them."
        )
    kept = f"; it left none out in {none}" if none else ""
    return (
        f" Of {runs} runs, the pool left out {names or 'no family'}{kept}; the family of the"
        f" plans of least gain among the candidates was among those left out in {worst}."
    )


def pick_agreement(doc: dict) -> list[str]:
    """How often each pick is the family the oracle would have chosen (the best single
    family by gain kept, per population, seed and size), and what it gains or loses
    against that family."""
    lines = []
    for f, chose in ((PICK, "picked"), (PICK_CROSS, "chosen")):
        same, diff, unweighted = 0, [], 0
        for rows in _runs(doc):
            if f not in rows or chose not in rows[f]:
                continue
            single = {g: r["gain_kept"] for g, r in rows.items() if g not in DERIVED}
            best = max(single, key=single.get)
            same += rows[f][chose] == best
            unweighted += rows[f].get("weights", {}).get(best, 0.0) < 0.01
            diff.append(rows[f]["gain_kept"] - single[best])
        if not diff:
            continue
        cost = (
            f"{100 * statistics.fmean(diff):+.1f} points of gain against that family on "
            f"average (median {100 * statistics.median(diff):+.1f}, worst {100 * min(diff):+.1f})"
        )
        if f == PICK:
            lines.append(
                f"The pick's largest weight is on the family the oracle would have chosen in "
                f"{same} of {len(diff)} runs (population × seed × size); the pool keeps {cost}. "
                f"In {unweighted} of those runs the pool gave that family no weight (under "
                "0.01): the answers alone did not show that its plans were the best."
                + left_out_line(doc)
            )
        else:
            lines.append(
                f"The pick by plans chose the family the oracle would have chosen in {same} of "
                f"{len(diff)} runs; it keeps {cost}."
            )
        lines.append("")
    if not lines:
        return []
    return [
        *lines,
        "![held-out answer likelihood against the plans' gain]({stem}_fit_plan.png)",
        "",
        "*Each candidate's held-out NLL per answer (out-of-fold, by motion) against the gain "
        "its plans keep, every population, seed and size: the single fits (colours) and the "
        "pool (black)"
        + (
            "; right, the mean P(target) that the other families' fits give its plans (what "
            "the pick by plans ranks by) against the same gain.*"
            if any(PICK_CROSS in rows for rows in _runs(doc))
            else ".*"
        ),
        "",
    ]


def others_judgment(row: dict) -> float | None:
    """The mean P(target) that the other families' fits give a family's plans (the score
    of :func:`slotv_jax.experiments.people_loop.loop.cross_judged`), None without one."""
    j = row.get("judged_by")
    others = [v for g, v in (j or {}).items() if g != row["family"]]
    return statistics.fmean(others) if others else None


def plot_fit_plan(doc: dict, path: Path) -> bool:
    """Held-out NLL per answer against gain kept, a point per row that has one; beside it,
    where the plans were judged, the other fits' judgment of each family's plans against
    their gain."""
    rows = [r for p in doc["populations"] for r in p["rows"] if "heldout_nll" in r]
    if not rows:
        return False
    judged = [r for r in rows if others_judgment(r) is not None]
    plt = figures.pyplot()
    n = 2 if judged else 1
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 4.5), squeeze=False)
    panels = [
        (axes[0, 0], rows, lambda r: r["heldout_nll"], "held-out NLL per answer (nats)"),
    ]
    if judged:
        xlabel = "the other fits' mean P(target) of its plans"
        panels.append((axes[0, 1], judged, others_judgment, xlabel))
    for ax, rs_all, x_of, xlabel in panels:
        for f in dict.fromkeys(r["family"] for r in rs_all):
            rs = [r for r in rs_all if r["family"] == f]
            ax.scatter(
                [x_of(r) for r in rs],
                [r["gain_kept"] for r in rs],
                s=14 if f == PICK else 8,
                color=FAMILY_COLORS.get(f, "k"),
                label=plain_title(f),
                alpha=0.8,
            )
        ax.set_xlabel(xlabel)
        ax.set_ylabel("gain kept by its plans")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.legend(fontsize=7)
    axes[0, 0].set_title("fit against plan (simulated people)")
    if judged:
        axes[0, 1].set_title("plans judged by the other fits against plan")
    fig.tight_layout()
    figures.save(fig, path, dpi=120)
    return True


def _mean_nll(doc: dict, pop: str, family: str) -> dict[int, float]:
    """The mean held-out NLL per answer of ``family``'s rows at each size (random picks)."""
    by: dict[int, list[float]] = {}
    for p in doc["populations"]:
        for r in p["rows"]:
            if (r["population"], r["family"], r["strategy"]) == (pop, family, "random"):
                if "heldout_nll" in r:
                    by.setdefault(r["answers"], []).append(r["heldout_nll"])
    return {a: statistics.fmean(v) for a, v in by.items()}


def pretrain_section(doc: dict) -> list[str]:
    """Pre-trained against from nothing, for every learned family that ran both ways: per
    population and size, the gain kept (random picks) both ways and the held-out NLL per
    answer both ways where the pick computed it; then where pre-training helps or hurts by
    more than :data:`PRETRAIN_MARGIN`."""
    fams = doc["config"]["families"]
    pairs = [(b, f) for f, b in PRETRAINED.items() if f in fams and b in fams]
    if not pairs:
        return []
    pops = [p["population"] for p in doc["populations"]]
    recipe = doc["config"].get("pretrain", {})
    lines = [
        "## Pre-trained against from nothing",
        "",
        "Each learned family fitted on the answers from a random draw (*from nothing*) and "
        "from θ₀ trained on the labels of the dataset's labelers (*pre-trained*: "
        f"{recipe.get('labels', 'the labelers')}; {recipe.get('protocol', '')}), with the same "
        "updates and the same minibatches (`slotv_jax.experiments.people_loop.loop."
        "pretrained_params`). Gain kept at each size, from nothing → pre-trained (the "
        "difference in points); held-out NLL per answer (out-of-fold, the pick's) likewise "
        "where the document has it.",
        "",
    ]
    tally: dict[str, dict[str, int]] = {}
    for base, pre in pairs:
        lines += [f"**{FAMILY_TITLES[base]}**", ""]
        sizes = sorted({a for q in pops for a in _gain(doc, q, base)})
        lines += [
            "| population | "
            + " | ".join(f"{a:,} answers" for a in sizes)
            + " | NLL, largest size |",
            "|---|" + "---|" * (len(sizes) + 1),
        ]
        t = tally.setdefault(base, {"helps": 0, "hurts": 0, "level": 0})
        for q in pops:
            g0, g1 = _gain(doc, q, base), _gain(doc, q, pre)
            cells = []
            for a in sizes:
                if a in g0 and a in g1:
                    d = g1[a] - g0[a]
                    cells.append(f"{_pct(g0[a])} → {_pct(g1[a])} ({100 * d:+.0f})")
                    key = (
                        "helps"
                        if d > PRETRAIN_MARGIN
                        else "hurts"
                        if d < -PRETRAIN_MARGIN
                        else "level"
                    )
                    t[key] += 1
                else:
                    cells.append("—")
            n0, n1 = _mean_nll(doc, q, base), _mean_nll(doc, q, pre)
            top = max(set(n0) & set(n1), default=None)
            nll = "—" if top is None else f"{n0[top]:.3f} → {n1[top]:.3f}"
            lines.append(f"| `{q}` | " + " | ".join(cells) + f" | {nll} |")
        lines.append("")
    m = f"{100 * PRETRAIN_MARGIN:.0f}"
    lines.append(
        f"Where pre-training helps (more than {m} points of gain kept), where it hurts (more "
        f"than {m} points less), over population × size:"
    )
    lines.append("")
    for base, t in tally.items():
        n = sum(t.values())
        lines.append(
            f"- {FAMILY_TITLES[base]}: helps in {t['helps']} of {n}, hurts in {t['hurts']}, "
            f"level in {t['level']}."
        )
    lines.append("")
    return lines
