"""The loop for one population and its seeds (the package docstring's protocol): the
planner's observers in one compiled switch, the simulated study on the pool, the fits,
the plans and their evaluation by the population."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from slotv_jax import planning
from slotv_jax.answers import pooling, prior
from slotv_jax.answers.pick import cross_judged, trusted
from slotv_jax.asking import selection, simulated
from slotv_jax.core.shapes import bucket, pad_rows
from slotv_jax.experiments.people_loop import rounds
from slotv_jax.experiments.people_loop.config import (
    CAMERA,
    DERIVED,
    FITTED,
    LEARNED,
    PICK,
    PICK_CROSS,
    PRETRAINED,
    READER,
    TRAINED,
    LoopConfig,
)
from slotv_jax.observers import people as people_lib
from slotv_jax.observers import population as population_lib
from slotv_jax.observers import zoo
from slotv_jax.observers.common import mask_logits
from slotv_jax.observers.observer import Observer
from slotv_jax.planning import evaluation
from slotv_jax.training import trainer as train_lib
from slotv_jax.training import types as train_types

# ------------------------------------------------------------------ the observers


def builds(cfg: LoopConfig) -> dict:
    """The planner's observers, each built from one run's parameters ``p`` (a dict with
    each learned family's parameters, ``beta``, the two fitted temperatures, and
    ``pick_w``, the pick's pool weights): each family
    (:func:`slotv_jax.planning.make_family_planner`'s families). The pick is the
    log-linear pool of the other families (:func:`slotv_jax.answers.pooling.pool_observer`,
    what ``study pick --by pool`` writes): it reads their parameters and its weights,
    nothing of the population. Nothing here depends on the population, so one compiled
    program plans every population's fits
    (:func:`oracle_builds`: the population's own observers, a second program, which takes
    the population's quadrature as its parameters and so serves every population too)."""
    out = {f: _family_build(cfg, f) for f in cfg.candidates}
    if PICK in cfg.families:
        parts = [out[f] for f in cfg.candidates]
        out[PICK] = lambda p: pooling.pool_observer([b(p) for b in parts], p["pick_w"])
    return out


def oracle_builds() -> dict:
    """The population's observers, built from its quadrature
    (:func:`slotv_jax.observers.population.quadrature`, the parameters): ``oracle``, its
    exact P_pop, and ``oracle_whole``, which scores the whole motion whatever τ, so its plan
    is the whole-motion objective's. Every population's quadrature has one shape, so one
    compiled program plans every population's own plans."""
    obs = population_lib.quadrature_observer
    return {"oracle": obs, "oracle_whole": lambda q: _whole_motion(obs(q))}


def _family_build(cfg: LoopConfig, f: str):
    if f in FITTED:
        j = list(FITTED).index(f)
        return lambda p: planning.labeler_observer(FITTED[f], beta=p["beta"][j], camera=CAMERA)
    sel = selection.make_selector(cfg.train_config(f), 1, 1)
    return lambda p: _learned(sel, p[f])


def _whole_motion(obs):
    """``obs`` scoring the whole motion at every stop time."""
    return Observer(_whole_logits, _whole_prefix, params=obs, name="whole motion")


def _whole_logits(_, obs, x, g, m):
    return obs(x, g, m)


def _whole_prefix(_, obs, x, g, m, s):
    return obs(x, g, m)


def _learned(sel, params):
    """The observer of a fitted family as active selection scores it
    (:func:`slotv_jax.asking.selection.candidate_scores` of the prefix, masked)."""
    return Observer(_learned_logits, _learned_prefix, params=params, config=sel)


def _learned_prefix(sel, params, x, g, m, s):
    return mask_logits(selection.candidate_scores(sel.base.model(params), x, g, m, s), m)


def _learned_logits(sel, params, x, g, m):
    return _learned_prefix(sel, params, x, g, m, x.shape[0])


_PLANNERS: dict = {}


def planner_for(cfg: LoopConfig, example: dict):
    """:func:`slotv_jax.planning.make_family_planner` of :func:`builds` (``example``: one
    run's parameters), made once per process and config: every population and seed of a
    process reuses the compiled program (its compilation is most of a population's
    planning time on a GPU: experiments/BENCHMARKS.md)."""
    key = dataclasses.replace(cfg, seeds=1, first_seed=0)  # seeds do not change it
    if key not in _PLANNERS:
        _PLANNERS[key] = planning.make_family_planner(builds(cfg), example, cfg.planner)
    return _PLANNERS[key]


def oracle_planner(cfg: planning.PlannerConfig, quad):
    """The planner of :func:`oracle_builds` for quadratures shaped as ``quad`` (one
    parameter set a population: its plans are the same for every run), made once per
    process, planner settings and shape: every population of a process shares it."""
    key = (cfg, jax.tree.structure(quad), tuple(a.shape for a in jax.tree.leaves(quad)))
    if key not in _PLANNERS:
        _PLANNERS[key] = planning.make_family_planner(oracle_builds(), quad, cfg)
    return _PLANNERS[key]


def oracle_plans(cfg: planning.PlannerConfig, pop, straight) -> dict:
    """The people's own plans of the ``straight`` problems (each field ``(P, ...)``):
    ``oracle`` (their exact P at the stop times) and ``oracle_whole`` (the whole motion).
    A population plans through :func:`oracle_planner` (one program for every population);
    a zoo member through :func:`slotv_jax.planning.make_planner` of the member itself (a
    program per member, made once per process)."""
    if isinstance(pop, zoo.ZooMember):
        key = (cfg, pop)
        if key not in _PLANNERS:
            observers = {"oracle": pop, "oracle_whole": _whole_motion(pop)}
            _PLANNERS[key] = planning.make_planner(observers, cfg)
        return {o: _PLANNERS[key].plan_problems(straight, o) for o in ("oracle", "oracle_whole")}
    quad = population_lib.quadrature(pop)
    oracle = oracle_planner(cfg, quad)
    params = jax.tree.map(lambda a: a[None], quad)
    return {
        o: jax.tree.map(lambda a: a[0], oracle.plan_problems(params, straight, family=o))
        for o in ("oracle", "oracle_whole")
    }


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


def fit_family(
    cfg: LoopConfig, family: str, pool, cand, counts, rows: int, seeds, inits=None
) -> dict:
    """A fresh fit of ``family`` on each run's first ``rows`` answer rows
    (:func:`slotv_jax.asking.simulated.fit_runs`): parameters with a leading run axis. A
    pre-trained family starts from ``inits[family]`` (:func:`pretrained_params`) and draws
    the same minibatches as the family it starts (a paired comparison)."""
    tc = cfg.train_config(family)
    blocks = cfg.updates(rows, tc.batch_size, cfg.epochs, cfg.min_updates) // cfg.block
    init = None
    if family in PRETRAINED or family == READER:
        if not inits or family not in inits:
            raise ValueError(f"inits: expected the pre-trained parameters of {family!r}")
        init = inits[family]
    return simulated.fit_runs(
        tc, pool, cand, counts, rows, _init_keys(family, seeds), blocks, cfg.block, init
    )


def pretrained_params(cfg: LoopConfig, family: str, split):
    """θ₀ of the pre-trained ``family``: the observer of the family it starts, trained on
    the labels of the mixture of the dataset's labelers, y = (1/L) Σ_l y_l (the mean of
    their label distributions on each motion of ``split``), by the SLOT-V cross-entropy
    under its TrainConfig's own label protocol (train size, epochs, batch, optimiser;
    :func:`slotv_jax.training.train_trials`), seed 1000 + the family's index. Reads the
    labelers' labels only, never the population. Made once per process and config."""
    base = PRETRAINED[family]
    tc = cfg.train_config(family)
    key = (cfg.data, tc)
    if key not in _PRETRAINED:
        n = tc.n_used(len(split))
        labels = np.mean([np.asarray(split.labels[k][:n]) for k in sorted(split.labels)], 0)
        data = train_types.make_data(
            np.asarray(split.xyz[:n], np.float32),
            np.asarray(split.goals[:n], np.float32),
            np.asarray(split.goal_mask[:n], bool),
            labels.astype(np.float32),
        )
        state, _ = train_lib.train_trials(tc, data, [1_000 + LEARNED.index(base)], progress=False)
        _PRETRAINED[key] = jax.tree.map(lambda x: x[0], state.params)
    return _PRETRAINED[key]


_PRETRAINED: dict = {}


def reader_prior(cfg: LoopConfig, split, people_name: str, camera):
    """θ₀ of the motion reader for a study of the people called ``people_name``, filmed by
    ``camera``: its prior (:mod:`slotv_jax.answers.prior`) on every pool motion at every
    stop time, the zoo member ``people_name`` left out of the sources (the people scored
    are never a source). Made once per process, config, people and camera."""
    tc = cfg.train_config(READER)
    pos, rot = (np.asarray(a, np.float32).round(6).tobytes() for a in (camera.pos, camera.rot))
    key = (cfg.data, cfg.pool, cfg.taus, tc, people_name, pos, rot)
    if key not in _PRETRAINED:
        xyz, goals, mask = pool_motions(cfg, split)
        study = prior.prior_study(xyz, goals, mask, cfg.taus, exclude=(people_name,))
        _PRETRAINED[key] = prior.prior_params(tc, study, camera)
    return _PRETRAINED[key]


def _init_keys(family: str, seeds) -> jax.Array:
    """One key per run: from its seed (and, for a fold's fit, ``(seed, fold)``); a
    pre-trained family has the keys of the family it starts."""
    keys = []
    for sd in seeds:
        sd, fold = sd if isinstance(sd, tuple) else (sd, None)
        index = len(LEARNED) if family == READER else LEARNED.index(PRETRAINED.get(family, family))
        key = jax.random.key(2_000 + 97 * sd + index)
        keys.append(key if fold is None else jax.random.fold_in(key, 1 + fold))
    return jnp.stack(keys)


# ------------------------------------------------------------------ the pick


def heldout_logp(
    cfg: LoopConfig, pool, cand, counts, n_rows: int, run_seeds, fold: np.ndarray, inits=None
) -> dict[str, np.ndarray]:
    """Each candidate family's out-of-fold log-probabilities of each run's first ``n_rows``
    answer rows (R, n_rows, G): fitted on the other folds (``fold`` (R, n_rows), by motion),
    predicting the held-out fold. The learned families fit every (run, fold) at once, a
    held-out row's counts set to 0 (:func:`fit_family`); the labelers fit β per fold."""
    n_r, k = cand.shape[0], cfg.pick_folds
    keep = np.ones((n_r * k, cand.shape[1]), np.float32)
    for i in range(n_r):
        for f in range(k):
            keep[i * k + f, :n_rows] = fold[i] != f
    cand_k = np.repeat(cand, k, axis=0)
    counts_k = np.repeat(counts, k, axis=0) * keep[..., None]
    seeds_k = [(sd, f) for sd in run_seeds for f in range(k)]
    rows_pad = bucket(n_rows)
    out = {}
    for fam in cfg.candidates:
        if fam in TRAINED:
            tc = cfg.train_config(fam)
            params = fit_family(cfg, fam, pool, cand_k, counts_k, n_rows, seeds_k, inits)
            sel = selection.make_selector(tc, 1, 1)
            c = jnp.asarray(np.stack([pad_rows(c[:n_rows], rows_pad) for c in cand_k]))
            lp = np.asarray(_fold_scorer(sel)(params, pool, c))[:, :n_rows]  # (R·K, A, G)
            out[fam] = np.stack([lp[i * k + fold[i], np.arange(n_rows)] for i in range(n_r)])
        else:
            lab = FITTED[fam]
            lp = np.zeros((n_r, n_rows, counts.shape[-1]), np.float32)
            for i in range(n_r):
                for f in range(k):
                    tr, te = fold[i] != f, fold[i] == f
                    (beta,) = simulated.fitted_betas(
                        pool, cfg.taus, cand[i, :n_rows][tr], counts[i, :n_rows][tr], [lab],
                        CAMERA,
                    )  # fmt: skip
                    lp[i, te] = simulated.labeler_log_probs(
                        pool, cfg.taus, cand[i, :n_rows][te], lab, beta, CAMERA
                    )
            out[fam] = lp
    return out


_FOLD_SCORERS: dict = {}


def _fold_scorer(sel):
    """``(params (N, ...), pool, cand (N, A)) -> log p (N, A, G)``, one member per row."""
    if sel not in _FOLD_SCORERS:
        _FOLD_SCORERS[sel] = jax.jit(
            jax.vmap(
                lambda p, pool, c: sel.log_probs(jax.tree.map(lambda x: x[None], p), pool, c)[0],
                in_axes=(0, None, 0),
            )
        )
    return _FOLD_SCORERS[sel]


def pick_heldout(
    cfg: LoopConfig, pool, cand, counts, n_rows: int, runs, inits=None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """What the pick reads of every run, from its answers alone: folds by motion and every
    candidate's out-of-fold predictions (:func:`heldout_logp`). Returns each run's
    (log p (F, n_rows, G) in the order of ``cfg.candidates``, goal mask (n_rows, G))."""
    run_seeds = [sd for _, sd in runs]
    traj = np.asarray(pool.traj)
    fold = np.stack(
        [
            pooling.fold_of(traj[cand[i, :n_rows]], cfg.pick_folds, 7_000 + sd)
            for i, sd in enumerate(run_seeds)
        ]
    )
    logp = heldout_logp(cfg, pool, cand, counts, n_rows, run_seeds, fold, inits)
    g = counts.shape[-1]
    return [
        (
            np.stack([logp[f][i] for f in cfg.candidates]),
            np.asarray(pool.goal_mask)[traj[cand[i, :n_rows]], :g],
        )
        for i in range(len(runs))
    ]


def heldout_quality(heldout, counts, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Each run's candidates' held-out NLL per answer (R, F) and uniform guessing's (R,),
    from :func:`pick_heldout`'s predictions (:func:`slotv_jax.answers.pick.trusted`'s
    ``heldout`` and ``uniform``)."""
    nll, uni = zip(*(pooling.heldout_quality(lp, counts[i, :n_rows], mask)
                     for i, (lp, mask) in enumerate(heldout)), strict=True)  # fmt: skip
    return np.stack(nll), np.asarray(uni, np.float64)


def pick_runs(
    cfg: LoopConfig, heldout, counts, n_rows: int, keep: np.ndarray | None = None
) -> tuple[np.ndarray, list[dict]]:
    """The pool of every run (:func:`slotv_jax.answers.pooling.pick_report` of
    :func:`pick_heldout`'s predictions), weighing only ``keep``'s candidates (R, F; every
    one by default). Returns the weights (R, F) and each run's report."""
    weights, reports = [], []
    for i, (lp, mask) in enumerate(heldout):
        k = None if keep is None else keep[i]
        rep = pooling.pick_report(list(cfg.candidates), lp, counts[i, :n_rows], mask, k)
        weights.append(rep["weights"])
        reports.append(rep)
    return np.asarray(weights, np.float32), reports


# ------------------------------------------------------------------ the plans judged


def judge(build, taus: Sequence[float]):
    """``judge(params (R, ...), xyz (R, P, T, 3), goals (R, P, 8, 3), mask (R, P, 8),
    target (R, P)) -> (R, P, K)``: the observer ``build(params[r])`` of run r predicting
    P(target | ξ_{0:τ}) of run r's paths at each stop time τ of ``taus``
    (:func:`slotv_jax.planning.stop_log_probs`), the quantity that the evaluation scores
    with the population's P_pop (:func:`plan_scores`). Compiled."""

    def one_run(p, xyz, goals, mask, target):
        obs = build(p)
        return jax.vmap(lambda x, g, m, t: jnp.exp(planning.stop_log_probs(obs, x, g, m, t, taus)))(
            xyz, goals, mask, target
        )

    return jax.jit(jax.vmap(one_run))


_JUDGES: dict = {}


def judge_for(cfg: LoopConfig, family: str):
    """:func:`judge` of a candidate family's fit (built as for the planner, from the
    family's parameters alone: nothing of the population), made once per process."""
    key = (dataclasses.replace(cfg, seeds=1, first_seed=0), family)
    if key not in _JUDGES:
        _JUDGES[key] = judge(_family_build(cfg, family), cfg.taus)
    return _JUDGES[key]


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
            "pretrain_s": 0.0,
            "pick_s": 0.0,
            "plan_s": 0.0,
            "judge_s": 0.0,
            "eval_s": 0.0,
            "study_plan_s": 0.0,
        },
    )
    per = cfg.per_stimulus
    rows = [s // per for s in cfg.sizes]
    cap = rows[-1]
    seeds = list(seeds)
    runs = [(st, sd) for st in cfg.strategies for sd in seeds]
    n_r = len(runs)
    xyz, goals, mask = pool_motions(cfg, splits["train"])
    n_motion_c = xyz.shape[0] * len(cfg.taus)  # the dataset motions' candidates come first
    slots = None
    if cfg.plan_share:  # rounds of plans: the study's problems, and the pool's plan motions
        study = rounds.study_problems(cfg.problems, splits)
        study_straight = planning.straight_lines(
            study["goals"], study["goal_mask"], study["target"], cfg=cfg.planner
        )
        slots = rounds.PlanSlots(
            xyz.shape[0], cfg.planned, tuple(study["scene"].tolist()), n_r, len(rows) - 1,
            len(cfg.taus),
        )  # fmt: skip
        lines = rounds.resample_time(np.asarray(study_straight.xyz), xyz.shape[1])
        pool = rounds.extend_pool(xyz, goals, mask, cfg.taus, slots, study, lines)
    else:
        pool = selection.make_pool(xyz, goals, mask, cfg.taus)
    n_c, g = int(pool.traj.shape[0]), int(pool.goals.shape[1])
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
        ask(i, 0, np.random.default_rng([sd, 1]).choice(n_motion_c, rows[0], replace=False))
    timing["answers_s"] += time.perf_counter() - t0

    t0 = time.perf_counter()  # the pre-trained families' θ₀, from the labels alone
    inits = {f: pretrained_params(cfg, f, splits["train"]) for f in cfg.families if f in PRETRAINED}
    if READER in cfg.families:  # its prior, without the people scored, from their camera
        camera = people_lib.study_camera(pop)
        inits[READER] = reader_prior(cfg, splits["train"], name, camera)
    timing["pretrain_s"] += time.perf_counter() - t0

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
    straight = planning.straight_lines(
        prob["goals"], prob["goal_mask"], prob["target"], cfg=cfg.planner
    )
    problems = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_r, *a.shape)), straight)
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
            f: fit_family(cfg, f, pool, cand, counts, n_rows, run_seeds, inits)
            for f in cfg.families
            if f in TRAINED
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
        t0 = time.perf_counter()
        pick_reports = None
        if PICK in cfg.families:  # the held-out predictions; the pool by likelihood alone
            heldout = pick_heldout(cfg, pool, cand, counts, n_rows, runs, inits)
            w_all, _ = pick_runs(cfg, heldout, counts, n_rows)
            params["pick_w"] = jnp.asarray(w_all)
        timing["pick_s"] += time.perf_counter() - t0
        planner = planner_for(cfg, jax.tree.map(lambda a: a[0], params))

        # Plan and evaluate: the floor and the oracles once, every family at every size.
        t0 = time.perf_counter()
        if floor is None:
            floor = {
                "straight": plan_scores(scorer, keys_eval, straight_as_plan(problems), problems)
            }
            for o, res in oracle_plans(cfg.planner, pop, straight).items():
                res = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_r, *a.shape)), res)
                floor[o] = plan_scores(scorer, keys_eval, res, problems)
                example[o] = np.asarray(res.q[0, 0])
            example["straight"] = np.asarray(problems.q[0, 0])
        plans = {}
        for f in cfg.families:
            if f not in DERIVED:  # made of the others' fits or plans
                plans[f] = planner.plan_problems(params, straight, family=f)
        jax.block_until_ready(plans)
        timing["plan_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        judged: dict[str, dict[str, np.ndarray]] = {}
        if set(DERIVED) & set(cfg.families):  # every candidate's plans, judged by every fit
            for g in cfg.candidates:
                judge_g = judge_for(cfg, g)
                for f in cfg.candidates:
                    p_g = judge_g(params, plans[f].xyz, problems.goals, problems.goal_mask,
                                problems.target)  # fmt: skip
                    judged.setdefault(f, {})[g] = np.asarray(p_g, np.float64).mean((1, 2))
            chosen, cross = cross_judged(judged, cfg.candidates)
        timing["judge_s"] += time.perf_counter() - t0
        if PICK in cfg.families:  # the pool without the least-trusted candidate, planned
            t0 = time.perf_counter()
            keep = trusted(cross, *heldout_quality(heldout, counts, n_rows))
            w, pick_reports = pick_runs(cfg, heldout, counts, n_rows, keep)
            params["pick_w"] = jnp.asarray(w)
            timing["pick_s"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            plans[PICK] = jax.block_until_ready(
                planner.plan_problems(params, straight, family=PICK)
            )
            timing["plan_s"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        lo, hi = floor["straight"]["score"], floor["oracle"]["score"]
        n_eval = cfg.problems * len(cfg.taus) * cfg.eval_participants
        made: dict[tuple[str, int], dict] = {}
        for f in [f for f in cfg.families if f in plans]:
            res = plans[f]
            sc = plan_scores(scorer, keys_eval, res, problems)
            for i, (st, sd) in enumerate(runs):
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
                if pick_reports is not None:  # what the answers alone say of this family
                    rep = pick_reports[i]
                    if f == PICK:
                        row["heldout_nll"] = rep["pool_nll"]
                        row["weights"] = dict(zip(rep["candidates"], rep["weights"], strict=True))
                        row["picked"] = rep["pick"]
                        row["left_out"] = [cfg.candidates[j] for j in np.flatnonzero(~keep[i])]
                        row["uniform_nll"] = rep["uniform_nll"]
                        row["poor_fit"] = rep["poor_fit"]
                        row["weights_likelihood"] = dict(
                            zip(rep["candidates"], w_all[i].round(6).tolist(), strict=True)
                        )
                    else:
                        row["heldout_nll"] = rep["heldout_nll"][rep["candidates"].index(f)]
                if f in judged:  # each fit's P(target) of this family's plans
                    row["judged_by"] = {g: round(float(v[i]), 6) for g, v in judged[f].items()}
                made[f, i] = row
                out_rows.append(row)
            if r == len(rows) - 1:
                example[f] = np.asarray(res.q[0, 0])
        if PICK_CROSS in cfg.families:  # the pick by plans: the chosen family's plans
            own = ("beta", "heldout_nll", "judged_by")  # what the chosen family's row says of it
            for i in range(n_r):
                f = cfg.candidates[chosen[i]]
                row = {k: v for k, v in made[f, i].items() if k not in own}
                row["family"], row["chosen"] = PICK_CROSS, f
                row["cross_scores"] = dict(
                    zip(cfg.candidates, cross[i].round(6).tolist(), strict=True)
                )
                out_rows.append(row)
            if r == len(rows) - 1:
                example[PICK_CROSS] = example[cfg.candidates[chosen[0]]]
        timing["eval_s"] += time.perf_counter() - t0
        if on_size is not None:
            on_size(out_rows)
        bar.update(1)
        if r + 1 == len(rows):
            break

        # Ask: the next round's stimuli, a share of them the plans of the study's problems.
        k = rows[r + 1] - n_rows
        k_plan = 0
        if slots is not None:
            t0 = time.perf_counter()
            k_plan = round(cfg.plan_share * k)
            study_plans = {  # every candidate's plans and the pick's, of every run
                f: np.asarray(planner.plan_problems(params, study_straight, family=f).xyz)
                for f in slots.families
            }
            for i in range(n_r):
                own = {f: v[i] for f, v in study_plans.items()}
                pool = rounds.write_plans(pool, slots, i, r, own)
            timing["study_plan_s"] += time.perf_counter() - t0
        k -= k_plan
        t0 = time.perf_counter()
        picks = {}
        if active and k:
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
                free = np.flatnonzero(~asked[i, :n_motion_c])  # dataset motions only
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
            if st == "random" or not k:
                free = np.flatnonzero(~asked[i, :n_motion_c])
                picks[i] = np.random.default_rng([sd, 3, r]).choice(free, k, replace=False)
            new = np.asarray(picks[i], np.int32)
            if k_plan:  # the plans of this run, drawn by its seed and round alone
                rng = np.random.default_rng([sd, 4, r])
                new = np.concatenate([new, slots.draw(i, r, k_plan, rng)])
            ask(i, n_rows, new)
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
        "population_config": people_lib.people_config(pop),
        "rows": out_rows,
        "comparison": comparison,
        "example": {
            "problem": {k: v[0].tolist() for k, v in prob.items()},
            "q": {k: v.round(6).tolist() for k, v in example.items()},
        },
        "timing": {k: round(v, 2) for k, v in timing.items()},
        "stimuli": asked_stimuli(runs, cand, pool, slots, splits["train"], cfg),
    }


def asked_stimuli(runs, cand, pool, slots, split, cfg: LoopConfig) -> list[dict]:
    """What each run asked about, row by row: the scene of the ``train`` split it showed
    (a dataset motion's own, or a plan's study problem's), and for a plan its family (""
    for a dataset motion); with the answers each round added, and how many were plans."""
    traj = np.asarray(pool.traj)
    out = []
    for i, (st, sd) in enumerate(runs):
        scene, family = [], []
        for c in cand[i]:
            m = int(traj[c])
            what = None if slots is None else slots.describe(m)
            if what is None:
                scene.append(int(split.env_id[m]))
                family.append("")
            else:
                scene.append(slots.scenes[what[1]])
                family.append(what[0])
        out.append(
            {
                "strategy": st,
                "seed": sd,
                "split": rounds.STUDY_SPLIT,
                "scene": scene,
                "plan": family,
                "rows_per_size": [s // cfg.per_stimulus for s in cfg.sizes],
            }
        )
    return out


_SCORERS: dict = {}


def _scorer(sel):
    if sel not in _SCORERS:
        _SCORERS[sel] = jax.jit(lambda p, pool, c: sel.log_probs(p, pool, c))
    return _SCORERS[sel]


def straight_as_plan(problems: planning.Problem):
    """The straight lines in the shape of a plan (``xyz``)."""
    return planning.PlanResult(problems.xyz, problems.q, None)
