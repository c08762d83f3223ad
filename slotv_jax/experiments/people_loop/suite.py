"""Which draws of the population hyper-distribution make the suite: a screen of the oracle's
gain over the straight line (``python -m slotv_jax.experiments.people_loop.suite``).

Gain kept is a ratio, (plan − straight) / (oracle − straight): where the oracle's plans
barely beat the straight line (a population that reads nothing from the motion, say), it
divides by almost nothing and measures noise. The suite keeps the first draws K = 0, 1, 2, …
of :func:`slotv_jax.observers.population.random_population` whose gain is large enough to
measure, by this rule, fixed before any people-loop result on a draw was seen:

    the oracle's plans beat the straight line by at least :data:`MIN_GAIN` = 0.05 in the
    population's mean P_pop(target | ξ_{0:τ}) over τ = 0.4, 0.7, 1 and the screening
    problems (every real goal of 8 scenes with 2, 3, 5 and 6 cubes drawn from fixed keys,
    planned as the quick people loop plans: 50 points, 30 steps).

0.05 is about half the default population's gain in the quick loop (0.47 − 0.35 at the
paper preset) and ten times the evaluation's resolution at the paper preset (P_pop is
exact; the studies' 12,000 guesses resolve about 0.01). Writes
``OUT/population_suite.md`` and ``population_suite.json`` (``--out experiments``: the record);
:data:`slotv_jax.observers.population.SUITE_DRAWS` holds the draws it chose.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from slotv_jax import planning
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.experiments.people_loop import loop
from slotv_jax.observers import population as population_lib
from slotv_jax.planning import evaluation
from slotv_jax.runs import command
from slotv_jax.world import scene

MIN_GAIN = 0.05  # the rule (module docstring)
SUITE_SIZE = 8  # draws the suite keeps
TAUS = (0.4, 0.7, 1.0)
PLANNER = planning.PlannerConfig(n_points=50, iters=30, taus=TAUS)
GOAL_COUNTS = (2, 3, 5, 6)


def screening_problems() -> dict[str, np.ndarray]:
    """Every real goal of 8 scenes (2 of each goal count in :data:`GOAL_COUNTS`), drawn from
    ``key(4_400 + i)``: goals (P, 8, 3), goal_mask (P, 8), target (P,)."""
    goals, masks = [], []
    for i, n in enumerate(GOAL_COUNTS * 2):
        s = scene.sample_scene(jax.random.key(4_400 + i), n)
        goals.append(np.asarray(s.goals))
        masks.append(np.asarray(s.goal_mask))
    every = evaluation.scene_problems({"screen": (np.stack(goals), np.stack(masks))}, ["screen"])
    return {k: every[k] for k in ("goals", "goal_mask", "target")}


def screen_one(pop: population_lib.Population, problems: dict) -> dict:
    """The straight line's and the oracle's mean P_pop(target | ξ_{0:τ}) on ``problems``."""
    quad = population_lib.quadrature(pop)
    planner = loop.oracle_planner(PLANNER, quad)  # one program for every draw
    g, m, t = (jnp.asarray(problems[k]) for k in ("goals", "goal_mask", "target"))
    straight = planner.straight_line(g, m, t)
    res = planner.plan_problems(jax.tree.map(lambda a: a[None], quad), straight, family="oracle")
    res = jax.tree.map(lambda a: a[0], res)
    scorer = evaluation.population_scorer(pop, TAUS, PLANNER.n_points, 1)
    keys = jax.random.split(jax.random.key(0), g.shape[0])
    lo = float(np.mean(np.asarray(scorer(keys, straight.xyz, g, m, t)[0])))
    hi = float(np.mean(np.asarray(scorer(keys, res.xyz, g, m, t)[0])))
    return {"straight": round(lo, 6), "oracle": round(hi, 6), "gain": round(hi - lo, 6)}


def screen(n: int = SUITE_SIZE, *, limit: int = 40, progress: bool = True) -> list[dict]:
    """Screen draws K = 0, 1, … until ``n`` pass the rule (at most ``limit`` draws)."""
    problems = screening_problems()
    out, kept = [], 0
    bar = tqdm(total=n, desc="screening draws", unit="kept", disable=not progress)
    for k in range(limit):
        pop = population_lib.random_population(k)
        row = {"k": k, **screen_one(pop, problems), "population": pop.to_dict()}
        row["kept"] = row["gain"] >= MIN_GAIN
        out.append(row)
        kept += row["kept"]
        bar.update(int(row["kept"]))
        if kept == n:
            break
    bar.close()
    return out


def report(rows: Sequence[dict], seconds: float) -> str:
    kept = [r["k"] for r in rows if r["kept"]]
    lines = [
        "# The population suite: which draws of the hyper-distribution are kept",
        "",
        "Every number here is a model of people (`slotv_jax.observers.population`; the "
        "hyper-distribution's table is in the README and in `random_population`'s docstring).",
        "",
        f"Rule, fixed before any result on a draw was seen: keep the first {SUITE_SIZE} draws "
        f"whose oracle beats the straight line by at least {MIN_GAIN} in mean "
        "P_pop(target | ξ_{0:τ}) over τ = 0.4, 0.7, 1 on the screening problems "
        "(`slotv_jax.experiments.people_loop.suite`).",
        "",
        f"Kept: {', '.join(f'random:{k}' for k in kept)} "
        f"(`SUITE_DRAWS` in `slotv_jax/observers/population.py`); screened in "
        f"{seconds / 60:.1f} min.",
        "",
        "| draw | viewpoints | rules | β₀ | σ_log | memory | lapse | straight | oracle | gain | "
        "kept |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = r["population"]
        mem = p["memory"] + (
            f" α∈[{p['alpha_range'][0]:.2f}, {p['alpha_range'][1]:.2f}]" if p["alpha_range"] else ""
        )
        lines.append(
            f"| random:{r['k']} | "
            + ", ".join(f"{k} {v:.2f}" for k, v in p["viewpoints"].items())
            + " | "
            + ", ".join(f"{k} {v:.2f}" for k, v in p["rules"].items())
            + " | "
            + ", ".join(f"{v:.3g}" for v in p["beta"].values())
            + f" | {p['beta_sigma_log']:.2f} | {mem} | {p['lapse']:.3f} | {r['straight']:.3f} | "
            f"{r['oracle']:.3f} | {r['gain']:.3f} | {'yes' if r['kept'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"


@cli.command()
def main(argv: Sequence[str] | None = None) -> int:
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.people_loop.suite", description=__doc__.split("\n")[0]
    )
    ap.add_argument("--out", default=str(command.DEFAULT_OUT), help="folder of the screen's record")
    ap.add_argument("--limit", type=int, default=40, help="draws screened at most")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if not 1 <= args.limit <= 1000:
        raise ValueError(f"--limit: expected 1..1000, got {args.limit}")
    out = Path(args.out)
    fileio.check_output_files(out, ["population_suite.json", "population_suite.md"])
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = screen(limit=args.limit, progress=not args.no_progress)
    seconds = time.perf_counter() - t0
    doc = {
        "rule": {"min_gain": MIN_GAIN, "suite_size": SUITE_SIZE, "taus": list(TAUS)},
        "planner": {"n_points": PLANNER.n_points, "iters": PLANNER.iters},
        "rows": rows,
        "kept": [r["k"] for r in rows if r["kept"]],
        "seconds": round(seconds, 1),
        "environment": environment(),
    }
    fileio.write_text(out / "population_suite.json", json.dumps(doc, indent=1))
    fileio.write_text(out / "population_suite.md", report(rows, seconds))
    print(f"suite: kept {doc['kept']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
