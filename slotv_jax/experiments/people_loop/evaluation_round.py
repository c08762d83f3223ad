"""Does an evaluation round pay? The researcher's third pick, measured from a people-loop
results document (``python -m slotv_jax.experiments.people_loop.evaluation_round``).

An *evaluation round* asks fresh participants about each candidate's plans and keeps the
candidate whose plans they read best. Every answer counts in the budget: with T answers in
all, the candidates are fitted on the first T/2 (the loop's previous size) and the other
T/2 go to the round. The rules read the round's answers only (counts of correct guesses):

- ``uniform``: the same number of answers for every candidate, the most correct kept;
- ``halving``: sequential halving (Karnin, Koren & Somekh 2013, "Almost optimal
  exploration in multi-armed bandits", ICML): ⌈log₂ C⌉ rounds, each with an equal share of
  the budget split evenly over the candidates left, the better half kept each time;
- ``cross_top2``: the two candidates that the pick by plans scores highest
  (:func:`slotv_jax.experiments.people_loop.loop.cross_judged`, from the fits alone), half
  the round each;
- ``two_picks``: the pool's plans (``pick``) against the pick by plans' (``pick_cross``),
  half the round each.

**Why the round can be simulated from the document.** A fresh participant shown family f's
plan for a random held-out problem, stopped at a random τ of the study's, guesses the
target with probability s_f = (1/PK) Σ_p Σ_τ P_pop(target_p | ξ_{0:τ}), which is exactly
each row's ``score`` (:func:`slotv_jax.planning.evaluation.population_scores`, exact, not
sampled). So n independent answers are Binomial(n, s_f) draws, and the round is simulated
without planning again: ``score`` plays the people, the rules see only the draws. What the
simulation leaves out: one participant answering several candidates' plans (a paired
round, whose answers correlate through that person's own β and viewpoint).

**How many answers the round needs**, two candidates d of the gain apart (s̄ their mean
score, Δ = oracle − straight): n = (z_{0.975} + z_{0.8})² · 2 s̄(1 − s̄) / (d Δ)² answers
each, a two-sided 5 % test with 80 % power (normal approximation of two proportions).
"""

from __future__ import annotations

import json
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.experiments.people_loop.config import PICK, PICK_CROSS
from slotv_jax.experiments.people_loop.report import FAMILY_TITLES
from slotv_jax.runs import command, figures

RULES = ("uniform", "halving", "cross_top2", "two_picks")
RULE_TITLES = {
    "uniform": "evaluation round, uniform",
    "halving": "evaluation round, sequential halving",
    "cross_top2": "evaluation round of the pick by plans' top 2",
    "two_picks": "evaluation round of the two picks",
}
DRAWS = 2_000  # simulated rounds per (population, seed, budget)
EXTRA = (250, 500, 1_000, 2_000, 4_000, 8_000, 16_000, 32_000, 64_000)  # the curve's rounds
Z = 1.959964 + 0.841621  # z_{0.975} + z_{0.8}
DETECT = 0.10  # the gain difference of the power calculation

#: ``ask(idx (M, k), n) -> correct (M, k)``: n fresh answers to each listed candidate's
#: plans, for each of M independent rounds.
Ask = Callable[[np.ndarray, int], np.ndarray]


def _argmax(rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
    """The index of each row's largest value (M,), ties broken at random."""
    return np.argmax(x + rng.uniform(0, 1e-9, x.shape), axis=-1)


def uniform_round(ask: Ask, n_cand: int, budget: int, m: int, rng) -> np.ndarray:
    """⌊budget / C⌋ answers for each of the C candidates; the most correct kept (M,)."""
    n = budget // n_cand
    if n < 1:
        raise ValueError(f"budget: expected at least one answer per candidate, got {budget}")
    idx = np.broadcast_to(np.arange(n_cand), (m, n_cand))
    return _argmax(rng, ask(idx, n))


def sequential_halving(ask: Ask, n_cand: int, budget: int, m: int, rng) -> np.ndarray:
    """Karnin et al. (2013), Algorithm 1: R = ⌈log₂ C⌉ rounds; in round r each of the
    ``|S_r|`` candidates left gets ``⌊budget / (|S_r| R)⌋`` answers and the ``⌈|S_r| / 2⌉`` with
    the most correct go on. Answers do not carry over between rounds. Returns the kept
    candidate of each of M rounds (M,)."""
    rounds = max(1, int(np.ceil(np.log2(n_cand))))
    alive = np.broadcast_to(np.arange(n_cand), (m, n_cand))
    while alive.shape[1] > 1:
        n = budget // (alive.shape[1] * rounds)
        if n < 1:
            raise ValueError(f"budget: {budget} answers leave a round with none per candidate")
        correct = ask(alive, n)
        keep = -(-alive.shape[1] // 2)
        order = np.argsort(-(correct + rng.uniform(0, 1e-9, correct.shape)), axis=-1)
        alive = np.take_along_axis(alive, order[:, :keep], axis=-1)
    return alive[:, 0]


def binomial_ask(scores: np.ndarray, rng: np.random.Generator) -> Ask:
    """The simulated people: candidate c's answers are correct with probability
    ``scores[c]`` (the module docstring's s_f), independently."""
    scores = np.asarray(scores, np.float64)

    def ask(idx, n):
        return rng.binomial(n, scores[idx]).astype(np.float64)

    return ask


def _rows(doc: dict) -> dict:
    """(population, seed, answers) -> {family: row} of the random-pick rows."""
    out: dict = {}
    for p in doc["populations"]:
        for r in p["rows"]:
            if r["strategy"] == "random":
                key = (p["population"], r["seed"], r["answers"])
                out.setdefault(key, {})[r["family"]] = r
    return out


def expected_gain(
    fam_rows: dict, rule: str, budget: int, seed: int, draws: int = DRAWS
) -> tuple[float, float]:
    """The mean gain kept of ``rule``'s choice over ``draws`` simulated rounds of
    ``budget`` answers among one run's plans (``fam_rows``: family -> row), and how often
    it kept the candidate of the largest gain."""
    rng = np.random.default_rng(seed)
    if rule == "cross_top2":
        cross = fam_rows[PICK_CROSS]["cross_scores"]
        names = sorted(cross, key=lambda f: -cross[f])[:2]
        choose = uniform_round
    elif rule == "two_picks":
        names, choose = [PICK, PICK_CROSS], uniform_round
    else:
        names = sorted(f for f in fam_rows if f != PICK_CROSS)
        choose = {"uniform": uniform_round, "halving": sequential_halving}[rule]
    score = np.array([fam_rows[f]["score"] for f in names])
    gain = np.array([fam_rows[f]["gain_kept"] for f in names])
    chosen = choose(binomial_ask(score, rng), len(names), budget, draws, rng)
    best = max(r["gain_kept"] for f, r in fam_rows.items() if f != PICK_CROSS)
    return float(gain[chosen].mean()), float(np.mean(gain[chosen] >= best - 1e-12))


def answers_needed(score: float, span: float, d: float = DETECT) -> float:
    """Answers per candidate to tell two candidates ``d`` of the gain apart (module
    docstring): n = (z_{0.975} + z_{0.8})² · 2 s(1 − s) / (d Δ)², at score s and
    Δ = oracle − straight.

    >>> round(answers_needed(0.5, 0.1, 0.1))  # 2.8016² · 0.5 / 0.01²
    39244
    """
    return Z**2 * 2 * score * (1 - score) / (d * span) ** 2


def analyse(doc: dict, draws: int = DRAWS) -> dict:
    """Every rule at the loop's budgets (T with T/2 also a size) and, from the fits at the
    largest such T/2, along rounds of :data:`EXTRA` answers (beyond the budget too)."""
    rows = _rows(doc)
    sizes = sorted({a for _, _, a in rows})
    pops = [p["population"] for p in doc["populations"]]
    seeds = {q: sorted({s for p, s, _ in rows if p == q}) for q in pops}
    budgets = [t for t in sizes if t // 2 in sizes and t % 2 == 0]
    if not budgets:
        raise ValueError(f"results: expected two sizes T/2 and T, got sizes {sizes}")

    def per_pop(fn) -> dict[str, float]:
        return {q: statistics.fmean(fn(q, sd) for sd in seeds[q]) for q in pops}

    at_budget = {}
    for t in budgets:
        s = t // 2
        cell = {
            rule: per_pop(
                lambda q, sd, rule=rule, s=s, t=t: expected_gain(
                    rows[q, sd, s], rule, t - s, 11 * sd + t, draws
                )[0]
            )
            for rule in RULES
            if rule in ("uniform", "halving")
            or all({PICK, PICK_CROSS} <= set(rows[q, sd, s]) for q in pops for sd in seeds[q])
        }
        for f in (PICK_CROSS, PICK):
            if all(f in rows[q, sd, t] for q in pops for sd in seeds[q]):
                cell[f] = per_pop(lambda q, sd, f=f, t=t: rows[q, sd, t][f]["gain_kept"])
        cell["best_at_half"] = per_pop(
            lambda q, sd, s=s: max(r["gain_kept"] for f, r in rows[q, sd, s].items())
        )
        cell["best_at_full"] = per_pop(
            lambda q, sd, t=t: max(r["gain_kept"] for f, r in rows[q, sd, t].items())
        )
        at_budget[t] = cell
    s = budgets[-1] // 2
    curve = {}
    for rule in ("uniform", "halving"):
        curve[rule] = {}
        for e in EXTRA:
            res = {
                (q, sd): expected_gain(rows[q, sd, s], rule, e, 13 * sd + e, draws)
                for q in pops
                for sd in seeds[q]
            }
            curve[rule][e] = {
                "gain": per_pop(lambda q, sd, res=res: res[q, sd][0]),
                "best_rate": statistics.fmean(b for _, b in res.values()),
            }
    need = {}
    for p in doc["populations"]:
        q, c = p["population"], p["comparison"]
        best = statistics.fmean(
            max(r["score"] for f, r in rows[q, sd, s].items() if f != PICK_CROSS) for sd in seeds[q]
        )
        need[q] = answers_needed(best, c["oracle"]["score"] - c["straight"]["score"])
    return {
        "preset": doc.get("preset"),
        "populations": pops,
        "seeds": seeds,
        "budgets": budgets,
        "fit_size": s,
        "at_budget": {str(t): v for t, v in at_budget.items()},
        "curve": {r: {str(e): v for e, v in c.items()} for r, c in curve.items()},
        "answers_needed": need,
        "draws": draws,
    }


def _stats(per: dict[str, float]) -> tuple[float, float, float]:
    v = list(per.values())
    return statistics.median(v), min(v), statistics.fmean(v)


def _cell(per: dict[str, float]) -> str:
    return " / ".join(f"{100 * x:.0f} %" for x in _stats(per))


def report(res: dict, source: str) -> str:
    """The document: the rules at the loop's budgets, the curve beyond, the power."""
    title = {
        **RULE_TITLES,
        PICK_CROSS: FAMILY_TITLES[PICK_CROSS].replace("**", "") + ", every answer to fit",
        PICK: FAMILY_TITLES[PICK].replace("**", "") + ", every answer to fit",
        "best_at_half": "the oracle's best candidate, fitted on T/2 (a ceiling no rule has)",
        "best_at_full": "the oracle's best candidate, fitted on T (the picks' ceiling)",
    }
    budgets = res["budgets"]
    lines = [
        f"# Does an evaluation round pay? ({res['preset']} preset)",
        "",
        f"From `{source}` (random picks; populations {', '.join(res['populations'])}), by "
        "`python -m slotv_jax.experiments.people_loop.evaluation_round`. Every number is a "
        "model of people. With T answers in all, the candidates are fitted on T/2 and the "
        "other T/2 answers ask fresh participants about each candidate's plans "
        "(`slotv_jax/experiments/people_loop/evaluation_round.py` says why the round can be "
        f"simulated from the recorded scores; {res['draws']:,} simulated rounds per run).",
        "",
        "## At the loop's budgets",
        "",
        "Gain kept over the populations, median / worst / mean (each population the mean "
        "over its seeds):",
        "",
        "| rule | " + " | ".join(f"T = {t:,} (fits on {t // 2:,})" for t in budgets) + " |",
        "|---|" + "---|" * len(budgets),
    ]
    names = [k for k in (*RULES, PICK_CROSS, PICK, "best_at_half", "best_at_full")
             if all(k in res["at_budget"][str(t)] for t in budgets)]  # fmt: skip
    for k in names:
        cells = [_cell(res["at_budget"][str(t)][k]) for t in budgets]
        lines.append(f"| {title[k]} | " + " | ".join(cells) + " |")
    t = str(budgets[-1])
    lines += [
        "",
        f"Per population at T = {budgets[-1]:,}:",
        "",
        "| population | " + " | ".join(title[k] for k in names) + " | answers per candidate "
        f"to tell {DETECT:.0%} of the gain apart |",
        "|---|" + "---|" * (len(names) + 1),
    ]
    for q in res["populations"]:
        cells = [f"{100 * res['at_budget'][t][k][q]:.0f} %" for k in names]
        lines.append(f"| {q} | " + " | ".join(cells) + f" | {res['answers_needed'][q]:,.0f} |")
    s = res["fit_size"]
    lines += [
        "",
        f"## Rounds beyond the budget (fits on {s:,} answers)",
        "",
        "| answers in the round | "
        + " | ".join(f"{RULE_TITLES[r]}: median / worst / mean" for r in res["curve"])
        + " | kept the best candidate (halving) |",
        "|---|" + "---|" * (len(res["curve"]) + 1),
    ]
    for e in res["curve"]["halving"]:
        cells = [_cell(res["curve"][r][e]["gain"]) for r in res["curve"]]
        rate = res["curve"]["halving"][e]["best_rate"]
        lines.append(f"| {int(e):,} | " + " | ".join(cells) + f" | {100 * rate:.0f} % |")
    return "\n".join(lines) + "\n"


def plot(res: dict, path: Path) -> None:
    """Median and worst gain kept against the round's answers, beside the pick by plans."""
    plt = figures.pyplot()
    fig, ax = plt.subplots(figsize=(10.5, 4.5))
    s = res["fit_size"]
    for rule, color in (("uniform", "tab:blue"), ("halving", "tab:green")):
        e = [int(x) for x in res["curve"][rule]]
        med = [_stats(res["curve"][rule][str(x)]["gain"])[0] for x in e]
        low = [_stats(res["curve"][rule][str(x)]["gain"])[1] for x in e]
        ax.plot(e, med, "-o", color=color, ms=3, label=f"{RULE_TITLES[rule]}: median")
        ax.plot(e, low, ":o", color=color, ms=3, label=f"{RULE_TITLES[rule]}: worst")
    top = res["at_budget"][str(2 * s)]
    for k, color, label in (
        (PICK_CROSS, "darkorange", f"pick by plans, {2 * s:,} answers to fit"),
        (PICK, "tab:gray", f"pick (the pool), {2 * s:,} answers to fit"),
        ("best_at_half", "k", f"the oracle's best candidate on {s:,} (ceiling)"),
    ):
        if k in top:
            med, low, _ = _stats(top[k])
            ax.axhline(med, color=color, lw=1, label=f"{label}: median")
            ax.axhline(low, color=color, lw=1, ls=":", label=f"{label}: worst")
    ax.axvline(s, color="grey", lw=0.5, label=f"a round of {s:,}: {2 * s:,} answers in all")
    ax.set_xscale("log")
    ax.set_xlabel(f"answers in the evaluation round (beside the {s:,} that fit the candidates)")
    ax.set_ylabel("gain kept over the populations")
    ax.set_title(f"An evaluation round of the candidates' plans ({res['preset']} preset)")
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    fig.tight_layout()
    figures.save(fig, path, dpi=120)


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.people_loop.evaluation_round",
        description=__doc__.split("\n")[0],
    )
    ap.add_argument("results", help="a people loop's *_results.json")
    ap.add_argument("--out", default=str(command.DEFAULT_OUT), help="folder of the record")
    ap.add_argument("--draws", type=int, default=DRAWS, help="simulated rounds per run")
    args = ap.parse_args(argv)
    if not 1 <= args.draws <= 1_000_000:
        raise ValueError(f"--draws: expected 1..1000000, got {args.draws}")
    src = Path(args.results)
    if not src.is_file():
        raise ValueError(f"results: {src} is not a file")
    doc = json.loads(src.read_text())
    if not isinstance(doc, dict) or "populations" not in doc:
        raise ValueError(f"results: {src} is not a people loop's results document")
    stem = f"evaluation_round_{doc.get('preset', 'quick')}"
    names = [f"{stem}.md", f"{stem}.png", f"{stem}.json"]
    fileio.check_not_input(Path(args.out) / names[2], {"results": src})
    ours = {names[2]: lambda p: fileio.is_json_object_with(p, ["budgets", "at_budget"])}
    fileio.check_output_files(args.out, names, ours=ours, beside=names[2])
    res = analyse(doc, args.draws)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fileio.write_text(out / names[2], json.dumps(res, indent=1))
    fileio.write_text(out / names[0], report(res, str(src)))
    plot(res, out / names[1])
    print(f"evaluation round: {out / names[0]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
