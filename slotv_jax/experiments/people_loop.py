"""From people's answers to motion people read: the whole loop, run and measured as one.

    python -m slotv_jax.experiments.people_loop                    # quick preset, CPU
    python -m slotv_jax.experiments.people_loop --preset paper     # the paper's MLP, a GPU
    python -m slotv_jax.experiments.people_loop --population homogeneous   # the sanity row

The people are simulated: a :class:`slotv_jax.observers.population.Population` (the
``default`` one: three viewpoints, three inference rules, log-normal temperatures, a
recency-weighted memory and lapses; or ``homogeneous``: everyone the dataset's Dragan
labeler; or a JSON file of the same fields). Every result below is a result on that
model of people, and says which.

Protocol, per population, seed and strategy (every step the library's public path):

1. **Ask.** Stimuli are dataset motions (the ``train`` split's first ``pool``) shown up to
   each stop time τ in ``taus`` (:func:`slotv_jax.asking.selection.make_pool`). Each asked
   stimulus gets ``per_stimulus`` answers, each from a fresh participant of the population
   (:func:`slotv_jax.observers.population.sample_guesses`; a stimulus gets the same answers
   under every strategy of a seed). Round 0 is drawn at random; after it, ``random`` keeps
   drawing at random and an active strategy (``margin``, ``error``, …) picks by an
   ensemble of ``select_family`` observers trained on the answers so far
   (:class:`slotv_jax.asking.selection.Selector`, warm-started from round to round).
2. **Learn.** After each size in ``sizes`` (answers), every family is fitted on the
   answers so far, prefixes included: the paper MLP, SLOT-V+ and the dragan and viewpoint
   archetypes by the count likelihood of the guesses (a fresh fit of ``epochs`` passes,
   at least ``min_updates`` updates); Dragan's and Nikolaidis' labelers by their β alone
   (:func:`slotv_jax.answers.crossval.fit_beta`): the baselines a researcher would use
   without slotv_jax.
3. **Plan.** Every fitted observer plans the held-out problems (scenes of
   ``position_test`` and ``goal_count_test``, which no round showed; every real goal a
   target) with the prefix objective, the mean over τ of log P(target | ξ_{0:τ})
   (:class:`slotv_jax.planning.PlannerConfig` ``taus``); so does the population itself
   (the oracle: its exact P_pop); the straight line is the floor. One compiled planner
   serves every observer (a ``lax.switch`` over families).
4. **Evaluate.** Each plan's score is the population's mean P_pop(target | ξ_{0:τ}) over
   the study's τ, averaged over problems; beside it an evaluation study of fresh
   participants (``eval_participants`` guesses per plan and τ): accuracy with a 95 %
   Wilson interval. **Gain kept** = (plan − straight) / (oracle − straight).

Writes ``OUT/people_loop[_paper]_results.json`` (``summary``: rows {population, family,
strategy, answers, gain_kept (mean over seeds), seeds}; the per-seed rows; the whole-motion
against prefix comparison; config, environment, timing), the Markdown report and figures
rendered from it (:mod:`slotv_jax.experiments.people_loop_report`). A rerun with another
``--population`` adds its rows to the same document; one already there is kept.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.asking import selection, simulated
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments import people_loop_report as report_lib
from slotv_jax.observers import population as population_lib
from slotv_jax.observers.common import mask_logits, masked_log
from slotv_jax.observers.prefix import prefix_labels
from slotv_jax.planning import evaluation
from slotv_jax.runs import command
from slotv_jax.training import config as train_config

LEARNED = ("mlp", "slotv_plus", "dragan_archetype", "viewpoint_archetype")
FITTED = {"dragan_fitted": "dragan", "nikolaidis_fitted": "nikolaidis"}  # family -> labeler
FAMILIES = LEARNED + tuple(FITTED)
CAMERA = "observer"  # the viewpoint of the fitted Nikolaidis baseline (the dataset's)


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """One people-loop experiment (module docstring)."""

    preset: str
    data: data_lib.DataConfig
    train_preset: str  # slotv_jax.training.config preset of the learned families
    planner: planning.PlannerConfig  # its taus: the prefix objective (the study's τ)
    sizes: tuple[int, ...] = (250, 500, 1000, 2000, 4000, 8000)  # answers after each round
    taus: tuple[float, ...] = (0.4, 0.7, 1.0)  # the study's stop times
    per_stimulus: int = 5  # answers (fresh participants) per asked stimulus
    strategies: tuple[str, ...] = ("random", "margin", "error")
    families: tuple[str, ...] = FAMILIES
    select_family: str = "slotv_plus"  # the ensemble that active strategies ask
    members: int = 4  # its size E
    select_epochs: float = 2.0  # its warm-start passes over the answers per round
    pool: int = 2000  # motions of the train split (× len(taus) candidates)
    subset: int = 1000  # candidates an active strategy scores per round
    epochs: float = 20.0  # passes over the answer rows of each family's fit
    min_updates: int = 300  # at least this many updates per fit
    block: int = 100  # updates per compiled call
    problems: int = 12  # held-out planning problems
    eval_participants: int = 20  # evaluation study: guesses per plan and τ
    seeds: int = 2
    first_seed: int = 0
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides of the MLP families

    def __post_init__(self):
        s, per = self.sizes, self.per_stimulus
        if len(s) < 1 or list(s) != sorted(set(s)) or s[0] < per:
            raise ValueError(f"sizes: expected increasing answer counts >= per_stimulus, got {s}")
        if any(x % per for x in s):
            raise ValueError(f"sizes: expected multiples of per_stimulus ({per}), got {s}")
        if not (isinstance(per, int) and per >= 1):
            raise ValueError(f"per_stimulus: expected an int >= 1, got {per!r}")
        if tuple(sorted(set(self.taus))) != tuple(self.taus) or not all(
            0 < t <= 1 for t in self.taus
        ):
            raise ValueError(f"taus: expected increasing stop times in (0, 1], got {self.taus}")
        if self.planner.taus is None or tuple(self.planner.taus) != tuple(self.taus):
            raise ValueError("planner: expected the prefix objective at the study's taus")
        bad = [x for x in self.strategies if x not in selection.STRATEGIES]
        if (
            bad
            or "random" not in self.strategies
            or len(set(self.strategies)) < len(self.strategies)
        ):
            raise ValueError(
                f"strategies: expected 'random' and distinct names of {selection.STRATEGIES}, "
                f"got {list(self.strategies)}"
            )
        bad = [f for f in self.families if f not in FAMILIES]
        if bad or not self.families:
            raise ValueError(f"families: expected names of {FAMILIES}, got {list(self.families)}")
        if self.select_family not in LEARNED:
            raise ValueError(
                f"select_family: expected one of {LEARNED}, got {self.select_family!r}"
            )
        if s[-1] // per > self.pool * len(self.taus):
            raise ValueError(
                f"sizes: {s[-1] // per} stimuli asked, the pool holds {self.pool} motions × "
                f"{len(self.taus)} stop times"
            )
        k_max = max([s[0] // per] + [(b - a) // per for a, b in itertools.pairwise(s)])
        if self.subset < 2 * k_max and set(self.strategies) != {"random"}:
            raise ValueError(
                f"subset: expected >= twice the largest round ({k_max}), got {self.subset}"
            )
        for f in (
            "members",
            "pool",
            "min_updates",
            "block",
            "problems",
            "eval_participants",
            "seeds",
        ):
            v = getattr(self, f)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"{f}: expected an int >= 1, got {v!r}")
        if not (self.epochs > 0 and self.select_epochs > 0):
            raise ValueError("epochs, select_epochs: expected > 0")

    def train_config(self, family: str) -> train_config.TrainConfig:
        """The TrainConfig that fits ``family`` (a learned one) on answers."""
        if family in ("dragan_archetype", "viewpoint_archetype"):
            model = family.split("_")[0]
            return train_config.archetype(self.train_preset, model, train_size=None)
        cfg = train_config.preset(self.train_preset, "slotv", train_size=None)
        if family == "slotv_plus":
            cfg = dataclasses.replace(cfg, start_term=True, time_weight=True)
        elif family != "mlp":
            raise ValueError(f"family: expected one of {LEARNED}, got {family!r}")
        return train_config.apply_overrides(cfg, self.overrides)

    def updates(self, rows: int, batch: int, epochs: float, least: int) -> int:
        """Updates of a fit on ``rows`` answer rows: ``epochs`` passes, at least ``least``,
        rounded up to whole blocks."""
        u = max(least, math.ceil(epochs * rows / batch))
        return self.block * math.ceil(u / self.block)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["train"] = {f: self.train_config(f).to_dict() for f in LEARNED if f in self.families}
        return json.loads(json.dumps(d))


def quick() -> LoopConfig:
    """CPU preset: the quick dataset and networks (64/32), 2 seeds, 12 problems, 50-point
    plans of 30 steps."""
    taus = (0.4, 0.7, 1.0)
    return LoopConfig(
        "quick",
        data_lib.quick(),
        "quick",
        planning.PlannerConfig(n_points=50, iters=30, taus=taus),
        taus=taus,
        subset=2000,
    )


def paper() -> LoopConfig:
    """GPU preset: the paper's networks and dataset distribution (12,000 training motions, of
    which the pool takes 10,000, and the held-out scenes), 3 seeds, 100 problems, the
    default planner (100 points, 50 steps)."""
    taus = (0.4, 0.7, 1.0)
    return LoopConfig(
        "paper",
        dataclasses.replace(data_lib.paper(), n_train=12_000, n_eval=1_000, n_new_scenes=20),
        "paper",
        planning.PlannerConfig(taus=taus),
        taus=taus,
        pool=10000,
        subset=4000,
        problems=100,
        eval_participants=40,
        seeds=3,
        epochs=30.0,
        min_updates=1000,
        block=250,
    )


def tiny() -> LoopConfig:
    """The tests' preset: seconds on a CPU."""
    taus = (0.5, 1.0)
    d = data_lib.DataConfig(
        preset="tiny", n_train=120, n_eval=40, n_train_scenes=12, n_new_scenes=2, chunk_size=256
    )
    return LoopConfig(
        "tiny",
        d,
        "quick",
        planning.PlannerConfig(n_points=20, iters=3, taus=taus),
        sizes=(20, 40),
        taus=taus,
        per_stimulus=2,
        strategies=("random", "margin"),
        families=("mlp", "dragan_archetype", "dragan_fitted"),
        select_family="mlp",
        members=2,
        pool=60,
        subset=40,
        epochs=2.0,
        min_updates=20,
        block=10,
        problems=3,
        eval_participants=4,
        seeds=1,
        overrides=("hidden=16,8",),
    )


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


# ------------------------------------------------------------------ the observers


def labeler_prefix(name: str, beta, xyz, goals, goal_mask, seen):
    """log y of labeler ``name`` at a traced ``beta`` on the first ``seen`` points
    (:func:`slotv_jax.observers.prefix.prefix_labels`, as the labelers' prefix observers)."""
    y = prefix_labels(name, xyz, goals, goal_mask, seen, beta=beta, camera=CAMERA)
    return masked_log(y, goal_mask)


def branches(cfg: LoopConfig, pop) -> tuple[tuple[str, ...], tuple]:
    """The planner's observers as prefix functions ``f(params, xyz, goals, mask, seen) ->
    logits``: the population (``oracle``; ``oracle_whole`` scores the whole motion whatever
    τ, so its plan is the whole-motion objective's), then each family. ``params`` is a dict
    with each learned family's parameters and ``beta`` (the two fitted temperatures)."""
    obs = population_lib.population_observer(pop)
    names = ["oracle", "oracle_whole"]
    fns = [
        lambda p, x, g, m, s: obs.prefix(x, g, m, s),
        lambda p, x, g, m, s: obs(x, g, m),
    ]
    for f in cfg.families:
        names.append(f)
        if f in FITTED:
            j = list(FITTED).index(f)
            fns.append(
                lambda p, x, g, m, s, lab=FITTED[f], j=j: labeler_prefix(
                    lab, p["beta"][j], x, g, m, s
                )
            )
        else:
            sel = selection.make_selector(cfg.train_config(f), 1, 1)
            fns.append(
                lambda p, x, g, m, s, f=f, sel=sel: mask_logits(
                    selection.candidate_scores(sel.base.model(p[f]), x, g, m, s), m
                )
            )
    return tuple(names), tuple(fns)


def make_plan_all(cfg: LoopConfig, fns):
    """``plan_all(index, params (R, ...), problems (R, P, ...)) -> PlanResult (R, P, ...)``:
    one compiled program for every observer (``lax.switch`` on an unbatched index)."""

    def plan_run(index, params, problems):
        def prefix(x, g, m, s):
            return jax.lax.switch(index, fns, params, x, g, m, s)

        def whole(x, g, m):
            return prefix(x, g, m, x.shape[0])

        whole.prefix = prefix
        return jax.vmap(lambda pr: planning.plan(whole, pr, cfg.planner))(problems)

    return jax.jit(jax.vmap(plan_run, in_axes=(None, 0, 0)))


_PLANNERS: dict = {}


def planner_for(cfg: LoopConfig, pop) -> tuple[tuple[str, ...], object]:
    """The observers' names and :func:`make_plan_all` of ``cfg`` and ``pop``, made once per
    process (a second run of the same config reuses the compiled program)."""
    key = (dataclasses.replace(cfg, seeds=1, first_seed=0), pop)  # seeds do not change it
    if key not in _PLANNERS:
        names, fns = branches(cfg, pop)
        _PLANNERS[key] = (names, make_plan_all(cfg, fns))
    return _PLANNERS[key]


# ------------------------------------------------------------------ the study


def pool_motions(cfg: LoopConfig, split) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz (N, T, 3), goals (N, 8, 3), goal_mask (N, 8)) of the pool's motions."""
    n = min(cfg.pool, split.xyz.shape[0])
    if n < cfg.pool:
        raise ValueError(f"pool: the train split holds {n} motions, asked for {cfg.pool}")
    goals = split.scene_goals[split.env_id[:n]]
    mask = split.scene_mask[split.env_id[:n]]
    return np.asarray(split.xyz[:n], np.float32), goals, mask


def held_out_problems(cfg: LoopConfig, splits) -> dict[str, np.ndarray]:
    """Every (scene, real goal) of the held-out scenes (:func:`planning.evaluation.scene_problems`
    on ``position_test`` and ``goal_count_test``), cut evenly to ``cfg.problems``."""
    names = ("position_test", "goal_count_test")
    scenes = {s: (splits[s].scene_goals, splits[s].scene_mask) for s in names}
    every = evaluation.scene_problems(scenes, names)
    n = every["target"].size
    if n < cfg.problems:
        raise ValueError(f"problems: the held-out scenes have {n}, asked for {cfg.problems}")
    pick = np.linspace(0, n - 1, cfg.problems).round().astype(int)
    return {k: every[k][pick] for k in ("goals", "goal_mask", "target")}


def fit_family(cfg: LoopConfig, family: str, pool, cand, counts, rows: int, seeds) -> dict:
    """A fresh fit of ``family`` on each run's first ``rows`` answer rows
    (:func:`slotv_jax.asking.simulated.fit_runs`): parameters with a leading run axis."""
    tc = cfg.train_config(family)
    blocks = cfg.updates(rows, tc.batch_size, cfg.epochs, cfg.min_updates) // cfg.block
    return simulated.fit_runs(
        tc, pool, cand, counts, rows, _init_keys(family, seeds), blocks, cfg.block
    )


def _init_keys(family: str, seeds) -> jax.Array:
    return jnp.stack([jax.random.key(2_000 + 97 * sd + LEARNED.index(family)) for sd in seeds])


def initial_params(cfg: LoopConfig, seeds) -> dict:
    """Every family's parameters before any answer, one set per run (``seeds``: each run's
    seed), and β = 1 for the fitted labelers: the planner's ``params`` argument."""
    out = {}
    for f in cfg.families:
        if f in LEARNED:
            sel = selection.make_selector(cfg.train_config(f), 1, 1)
            ens = jax.vmap(sel.init)(_init_keys(f, seeds))
            out[f] = jax.tree.map(lambda x: x[:, 0], ens.params)
    out["beta"] = jnp.ones((len(list(seeds)), len(FITTED)), jnp.float32)
    return out


# ------------------------------------------------------------------ evaluation


def eval_keys(runs: Sequence[tuple[str, int]]) -> jax.Array:
    """One evaluation-study key per run, from its strategy and seed alone, so a seed's
    evaluation draws are the same whichever other seeds run beside it."""
    base = jax.random.key(4_000)
    return jnp.stack(
        [
            jax.random.fold_in(jax.random.fold_in(base, sd), selection.STRATEGIES.index(st))
            for st, sd in runs
        ]
    )


def plan_scores(scorer, keys: jax.Array, res, problems) -> dict:
    """:func:`slotv_jax.planning.evaluation.population_scores` of plans ``res``."""
    return evaluation.population_scores(
        scorer, keys, res.xyz, problems.goals, problems.goal_mask, problems.target
    )


# ------------------------------------------------------------------ the loop


def run_population(
    cfg: LoopConfig,
    name: str,
    pop,
    splits,
    seeds: Sequence[int],
    *,
    progress: bool = True,
    on_size=None,
) -> dict:
    """The whole loop for one population and ``seeds``; returns its rows, comparison and
    timings. Each seed's rows depend on that seed alone, so seeds run apart merge into one
    document. ``on_size(rows)`` is called with the rows so far after each size."""
    t_all, timing = (
        time.perf_counter(),
        {
            "answers_s": 0.0,
            "fit_s": 0.0,
            "beta_s": 0.0,
            "select_s": 0.0,
            "plan_s": 0.0,
            "eval_s": 0.0,
        },
    )
    xyz, goals, mask = pool_motions(cfg, splits["train"])
    pool = selection.make_pool(xyz, goals, mask, cfg.taus)
    n_c, per, g = int(pool.traj.shape[0]), cfg.per_stimulus, int(pool.goals.shape[1])
    rows = [s // per for s in cfg.sizes]
    cap = rows[-1]
    seeds = list(seeds)
    runs = [(st, sd) for st in cfg.strategies for sd in seeds]
    n_r = len(runs)
    run_seeds = [sd for _, sd in runs]
    cand = np.zeros((n_r, cap), np.int32)
    counts = np.zeros((n_r, cap, g), np.float32)
    asked = np.zeros((n_r, n_c), bool)
    heard: dict[int, dict[int, np.ndarray]] = {sd: {} for sd in seeds}

    def ask(i: int, start: int, new: np.ndarray) -> None:
        sd = runs[i][1]
        todo = np.asarray([c for c in new if c not in heard[sd]], np.int32)
        if todo.size:
            for c, k in zip(
                todo, simulated.population_answers(pop, sd, pool, todo, per), strict=True
            ):
                heard[sd][int(c)] = k
        cand[i, start : start + new.size] = new
        counts[i, start : start + new.size] = [heard[sd][int(c)] for c in new]
        asked[i, new] = True

    t0 = time.perf_counter()
    for i, (_, sd) in enumerate(runs):  # round 0: the same random draw for every strategy
        ask(i, 0, np.random.default_rng([sd, 1]).choice(n_c, rows[0], replace=False))
    timing["answers_s"] += time.perf_counter() - t0

    active = [i for i, (st, _) in enumerate(runs) if st != "random"]
    stc = cfg.train_config(cfg.select_family)
    selector = selection.make_selector(stc, cfg.members, cap)
    ens = None
    if active:
        ens = jax.jit(jax.vmap(selector.init))(
            jnp.stack([jax.random.key(3_000 + runs[i][1]) for i in active])
        )

    # The held-out problems, their straight lines, and the planner for every observer.
    prob = held_out_problems(cfg, splits)
    straight = jax.jit(
        jax.vmap(lambda gl, m, t: planning.straight_line(gl, m, t, cfg=cfg.planner))
    )(jnp.asarray(prob["goals"]), jnp.asarray(prob["goal_mask"]), jnp.asarray(prob["target"]))
    planning.check_problems(straight)
    problems = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_r, *a.shape)), straight)
    names, plan_all = planner_for(cfg, pop)
    scorer = evaluation.population_scorer(
        pop, cfg.taus, cfg.planner.n_points, cfg.eval_participants
    )
    keys_eval = eval_keys(runs)

    out_rows, floor, example = [], None, {}
    bar = tqdm(total=len(rows), desc=f"people loop ({name})", unit="size", disable=not progress)
    for r, n_rows in enumerate(rows):
        # Learn: every family on the answers so far.
        t0 = time.perf_counter()
        params = {
            f: fit_family(cfg, f, pool, cand, counts, n_rows, run_seeds)
            for f in cfg.families
            if f in LEARNED
        }
        timing["fit_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        betas = np.ones((n_r, len(FITTED)), np.float32)
        if any(f in FITTED for f in cfg.families):
            for i in range(n_r):
                betas[i] = simulated.fitted_betas(
                    pool,
                    cfg.taus,
                    cand[i, :n_rows],
                    counts[i, :n_rows],
                    list(FITTED.values()),
                    CAMERA,
                )
        params["beta"] = jnp.asarray(betas)
        timing["beta_s"] += time.perf_counter() - t0

        # Plan and evaluate: the floor and the oracles once, every family at every size.
        t0 = time.perf_counter()
        if floor is None:
            floor = {
                "straight": plan_scores(scorer, keys_eval, straight_as_plan(problems), problems)
            }
            for o in ("oracle", "oracle_whole"):
                res = plan_all(jnp.int32(names.index(o)), params, problems)
                floor[o] = plan_scores(scorer, keys_eval, res, problems)
                example[o] = np.asarray(res.q[0, 0])
            example["straight"] = np.asarray(problems.q[0, 0])
        plans = {}
        for f in cfg.families:
            plans[f] = plan_all(jnp.int32(names.index(f)), params, problems)
        jax.block_until_ready(plans)
        timing["plan_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        lo, hi = floor["straight"]["score"], floor["oracle"]["score"]
        for f, res in plans.items():
            sc = plan_scores(scorer, keys_eval, res, problems)
            for i, (st, sd) in enumerate(runs):
                n_eval = cfg.problems * len(cfg.taus) * cfg.eval_participants
                acc = float(sc["correct"][i])
                row = {
                    "population": name,
                    "family": f,
                    "strategy": st,
                    "seed": sd,
                    "answers": int(cfg.sizes[r]),
                    "score": float(sc["score"][i]),
                    "score_per_tau": sc["per_tau"][i].round(6).tolist(),
                    "gain_kept": float((sc["score"][i] - lo[i]) / (hi[i] - lo[i])),
                    "accuracy": acc,
                    "accuracy_95": [round(v, 4) for v in evaluation.wilson(acc * n_eval, n_eval)],
                    "feasible": float(np.mean(np.asarray(res.feasible[i]))),
                }
                if f in FITTED:
                    row["beta"] = float(betas[i, list(FITTED).index(f)])
                out_rows.append(row)
            if r == len(rows) - 1:
                example[f] = np.asarray(res.q[0, 0])
        timing["eval_s"] += time.perf_counter() - t0
        if on_size is not None:
            on_size(out_rows)
        bar.update(1)
        if r + 1 == len(rows):
            break

        # Ask: the next round's stimuli.
        k = rows[r + 1] - n_rows
        t0 = time.perf_counter()
        picks = {}
        if active:
            ans = selection.Answers(
                jnp.asarray(cand[active]),
                jnp.asarray(counts[active]),
                jnp.full((len(active),), n_rows, jnp.int32),
            )
            keys = jnp.stack([jax.random.key(5_000 + 31 * r + runs[i][1]) for i in active])
            fit = simulated.fitter(selector, cfg.block)
            for j in range(
                cfg.updates(n_rows, stc.batch_size, cfg.select_epochs, cfg.block) // cfg.block
            ):
                ens, _ = fit(
                    ens, pool, ans, jax.vmap(lambda kk, j=j: jax.random.fold_in(kk, j))(keys)
                )
            for a, i in enumerate(active):
                st, sd = runs[i]
                free = np.flatnonzero(~asked[i])
                sub = np.random.default_rng([sd, 2, r]).choice(
                    free, min(cfg.subset, free.size), replace=False
                )
                member = jax.tree.map(lambda x, a=a: x[a], ens.params)
                logp = _scorer(selector)(member, pool, jnp.asarray(sub))
                pick = selection.select(
                    st, jax.random.fold_in(keys[a], 1), logp, jnp.ones(sub.size, bool), k
                )
                picks[i] = sub[np.asarray(pick)]
        timing["select_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        for i, (st, sd) in enumerate(runs):
            if st == "random":
                free = np.flatnonzero(~asked[i])
                picks[i] = np.random.default_rng([sd, 3, r]).choice(free, k, replace=False)
            ask(i, n_rows, np.asarray(picks[i], np.int32))
        timing["answers_s"] += time.perf_counter() - t0
    bar.close()
    timing["total_s"] = time.perf_counter() - t_all
    comparison = {
        o: {
            "score": float(floor[o]["score"][0]),
            "per_tau": floor[o]["per_tau"][0].round(6).tolist(),
            "accuracy": float(floor[o]["correct"][0]),
        }
        for o in ("straight", "oracle", "oracle_whole")
    }
    return {
        "population": name,
        "population_config": pop.to_dict(),
        "rows": out_rows,
        "comparison": comparison,
        "example": {
            "problem": {k: v[0].tolist() for k, v in prob.items()},
            "q": {k: v.round(6).tolist() for k, v in example.items()},
        },
        "timing": {k: round(v, 2) for k, v in timing.items()},
    }


_SCORERS: dict = {}


def _scorer(sel):
    if sel not in _SCORERS:
        _SCORERS[sel] = jax.jit(lambda p, pool, c: sel.log_probs(p, pool, c))
    return _SCORERS[sel]


def straight_as_plan(problems: planning.Problem):
    """The straight lines in the shape of a plan (``xyz``)."""
    return planning.PlanResult(problems.xyz, problems.q, None)


# ------------------------------------------------------------------ the document


def summarise(rows: Sequence[dict]) -> list[dict]:
    """SPEC §12's ``summary``: gain kept per (population, family, strategy, answers), the
    mean over seeds (and the seeds)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["population"], r["family"], r["strategy"], r["answers"]), []).append(r)
    return [
        {
            "population": p,
            "family": f,
            "strategy": s,
            "answers": a,
            "gain_kept": round(float(np.mean([r["gain_kept"] for r in rs])), 6),
            "gain_kept_sd": round(float(np.std([r["gain_kept"] for r in rs])), 6),
            "accuracy": round(float(np.mean([r["accuracy"] for r in rs])), 6),
            "seeds": len(rs),
        }
        for (p, f, s, a), rs in groups.items()
    ]


def stem_of(preset: str) -> str:
    return "people_loop" if preset == "quick" else f"people_loop_{preset}"


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment (ours to extend)."""
    return fileio.is_json_object_with(path, ("preset", "config", "populations", "summary"))


SEED_FIELDS = ("seeds", "first_seed")  # which seeds ran: the rows say it, not the config


def run(
    cfg: LoopConfig,
    out: Path,
    populations: Sequence[str],
    *,
    cache: Path = Path("data"),
    progress: bool = True,
) -> dict:
    """Run the loop for every (population, seed) not yet in ``OUT/STEM_results.json``, write
    the document after each population, then the report. Seeds accumulate: a run with other
    seeds of the same config adds its rows (one GPU call per seed at the paper preset)."""
    stem = stem_of(cfg.preset)
    path = out / f"{stem}_results.json"
    conf = {k: v for k, v in cfg.to_json().items() if k not in SEED_FIELDS}
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc.get("config") != conf:
        doc = {"preset": cfg.preset, "config": conf, "populations": [], "summary": []}
    doc["populations"] = [p for p in doc["populations"] if not p.get("partial")]
    wanted = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    entries = {p["population"]: p for p in doc["populations"]}
    todo = {}
    for spec in populations:
        have = {r["seed"] for r in entries.get(population_name(spec), {}).get("rows", [])}
        if missing := [sd for sd in wanted if sd not in have]:
            todo[spec] = missing
    if not todo:  # say so: a recorded document makes the command return in seconds
        print(
            f"people loop: {path} already holds every population and seed asked for; nothing "
            "ran, the report is drawn again (other --seeds/--first-seed, --population or "
            "--out run more)",
            file=sys.stderr,
        )
    else:
        ddir = data_lib.dataset_dir(cache, cfg.data)
        splits = data_lib.generate_dataset(
            cfg.data,
            ddir,
            progress=progress,
            splits=("train", "position_test", "goal_count_test"),
        )
        doc["dataset"] = str(ddir)
    for spec, seeds in todo.items():
        pop, name = population_lib.get_population(spec), population_name(spec)

        def save_partial(rows, name=name):  # a run stopped mid-way keeps its finished sizes
            part = {"population": name, "partial": True, "rows": rows}
            write_text(path, json.dumps({**doc, "populations": [*doc["populations"], part]}))

        got = run_population(cfg, name, pop, splits, seeds, progress=progress, on_size=save_partial)
        record = {
            "seeds": seeds,
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "environment": environment(),
            "timing": got.pop("timing"),
        }
        if name in entries:  # the comparison and example do not depend on the seed
            entries[name]["rows"] += got["rows"]
            entries[name]["runs"].append(record)
        else:
            entries[name] = {**got, "runs": [record]}
            doc["populations"].append(entries[name])
        doc["summary"] = summarise([r for q in doc["populations"] for r in q["rows"]])
        write_text(path, json.dumps(doc, indent=1))
    report_lib.render(doc, out, stem)
    draw_example(doc, out, stem)
    return doc


def example_plans(doc: dict) -> dict[str, np.ndarray]:
    """The first population's example problem as a plans file of the planning experiment's
    format (``python -m slotv_jax.render --plans``): goals, goal_mask, target, names, q."""
    ex = doc["populations"][0]["example"]
    names = list(ex["q"])
    return {
        "goals": np.asarray(ex["problem"]["goals"], np.float32)[None],
        "goal_mask": np.asarray(ex["problem"]["goal_mask"], bool)[None],
        "target": np.asarray([ex["problem"]["target"]], np.int32),
        "names": np.asarray(names),
        "q": np.stack([np.asarray(ex["q"][n], np.float32) for n in names])[:, None],
    }


def draw_example(doc: dict, out: Path, stem: str) -> None:
    """Write ``STEM_plans.npz`` and draw ``STEM_render.png`` from it with the render command
    (in its own process: the loop itself needs no OpenGL); without OpenGL, say so in one
    line and go on."""
    plans = out / f"{stem}_plans.npz"
    fileio.atomic_write(plans, lambda f: np.savez_compressed(f, **example_plans(doc)))
    best = report_lib.best_family(doc, doc["populations"][0])
    cmd = [sys.executable, *report_lib.render_command(stem, out, best)[1:]]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["no output"])[-1]
        print(
            f"people loop: the example was not drawn ({last}); draw it with: "
            f"{' '.join(report_lib.render_command(stem, out, best))}",
            file=sys.stderr,
        )


def population_name(spec: str) -> str:
    """``default``, ``homogeneous``, or a JSON file's stem."""
    return spec if spec in population_lib.PRESETS else Path(spec).stem


# ------------------------------------------------------------------ command line


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m slotv_jax.experiments.people_loop",
        description="Simulated people's answers -> observers -> legible plans -> evaluation.",
    )
    ap.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    ap.add_argument(
        "--population",
        default="default",
        help="comma-separated: default, homogeneous, or population JSON files",
    )
    ap.add_argument(
        "--out", help="folder of the results and report (default: runs/people_loop_<preset>)"
    )
    ap.add_argument("--data-cache", default="data", help="where datasets are cached")
    ap.add_argument("--seeds", type=int, help="number of seeds (default: the preset's)")
    ap.add_argument("--first-seed", type=int, help="first seed (default 0)")
    ap.add_argument("--strategies", help="comma-separated (random first), e.g. random,margin")
    ap.add_argument("--families", help=f"comma-separated of {','.join(FAMILIES)}")
    ap.add_argument("--sizes", help="comma-separated answer counts, e.g. 250,500,1000")
    ap.add_argument("--problems", type=int, help="held-out planning problems")
    ap.add_argument("--report", action="store_true", help="only render the report again")
    return ap


def config_from(args: argparse.Namespace) -> LoopConfig:
    """The preset with the command line's overrides (checked by :class:`LoopConfig`)."""
    cfg = PRESETS[args.preset]()
    change = {}
    if args.seeds is not None:
        change["seeds"] = args.seeds
    if args.first_seed is not None:
        change["first_seed"] = args.first_seed
    if args.problems is not None:
        change["problems"] = args.problems
    for name in ("strategies", "families"):
        v = getattr(args, name)
        if v is not None:
            change[name] = tuple(x.strip() for x in v.split(",") if x.strip())
    if args.sizes is not None:
        try:
            change["sizes"] = tuple(int(x) for x in args.sizes.split(","))
        except ValueError:
            raise ValueError(
                f"--sizes: expected comma-separated integers, got {args.sizes!r}"
            ) from None
    return dataclasses.replace(cfg, **change)


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    cfg = config_from(args)
    specs = [p.strip() for p in args.population.split(",") if p.strip()]
    if not specs:
        raise ValueError("--population: expected at least one population")
    for p in specs:  # every population file is read and checked before any work
        population_lib.get_population(p)
    out = command.out_dir(args, "people_loop")
    stem = stem_of(cfg.preset)
    names = [f"{stem}{s}" for s in ("_results.json", ".md", ".png", "_plans.npz", "_render.png")]
    fileio.check_output_files(out, names, ours={names[0]: is_results})
    if args.report:
        path = out / names[0]
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no results document to render")
        doc = json.loads(path.read_text())
        report_lib.render(doc, out, stem)
        draw_example(doc, out, stem)
        return 0
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    run(cfg, out, specs, cache=Path(args.data_cache))
    print(
        f"people loop: {time.perf_counter() - t0:.0f} s; report {out / (stem + '.md')}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
