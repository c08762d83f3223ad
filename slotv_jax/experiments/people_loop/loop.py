"""The loop for one population and its seeds (the package docstring's protocol): the
planner's observers in one compiled switch, the simulated study on the pool, the fits,
the plans and their evaluation by the population.

Read from :func:`run_population` down: its stages are named objects and functions of this
module, each size in the order learn, plan, judge, evaluate, ask:

- :class:`SimulatedStudy`: the pool (with the plan motions of rounds of plans), each run's
  rows and the population's answers (``first_round``, ``ask``, ``write_plans``, ``stimuli``);
- :class:`ActiveAsker`: the active strategies' ensemble and their picks;
- :func:`initial_params`, :func:`fit_family`, :func:`fitted_betas`: learn;
- :func:`pick_heldout`, :func:`pick_runs`: the pick's held-out predictions and pool;
- :func:`planner_for`, :func:`oracle_plans`: plan (one compiled program each);
- :func:`judge_plans`: every plan judged by every fit (the pick by plans, the trusted);
- :class:`Evaluation`, :func:`family_rows`: the held-out problems, the floor and oracles,
  and each family's rows;
- :class:`Timing`: the seconds of each stage, in the document.
"""

from __future__ import annotations

import contextlib
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
    CAUTIOUS,
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
from slotv_jax.planning import caution, evaluation
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
    if CAUTIOUS in cfg.families:
        out[CAUTIOUS] = lambda p: caution.lower_bound_observer(
            jax.vmap(lambda q: out[PICK]({**q, "pick_w": p["pick_w"]}))(p["ensemble"]),
            cfg.caution,
        )
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
    got = evaluation.even_problems(scenes, names, cfg.problems, "the held-out scenes")
    return {k: got[k] for k in ("goals", "goal_mask", "target")}


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
    are never a source). Made once per process, config, sources and camera: the people of
    the suite, none of them a source, share one."""
    tc = cfg.train_config(READER)
    pos, rot = (np.asarray(a, np.float32).round(6).tobytes() for a in (camera.pos, camera.rot))
    key = (cfg.data, cfg.pool, cfg.taus, tc, prior.source_names((people_name,)), pos, rot)
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
    held-out row's counts set to 0 (:func:`fit_family`); the labelers fit β per fold.
    Returns the predictions and the folds' fits (each learned family's parameters and
    ``beta`` (R·K, len(FITTED)), run-major: row i·K + f is run i's fit without fold f)."""
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
    fits = {"beta": np.ones((n_r * k, len(FITTED)), np.float32)}
    for fam in cfg.candidates:
        if fam in TRAINED:
            tc = cfg.train_config(fam)
            params = fit_family(cfg, fam, pool, cand_k, counts_k, n_rows, seeds_k, inits)
            fits[fam] = params
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
                    fits["beta"][i * k + f, list(FITTED).index(fam)] = beta
                    lp[i, te] = simulated.labeler_log_probs(
                        pool, cfg.taus, cand[i, :n_rows][te], lab, beta, CAMERA
                    )
            out[fam] = lp
    return out, fits


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
    cfg: LoopConfig, pool, cand, counts, n_rows: int, runs, inits=None, *, with_fits=False
):
    """What the pick reads of every run, from its answers alone: folds by motion and every
    candidate's out-of-fold predictions (:func:`heldout_logp`). Returns each run's
    (log p (F, n_rows, G) in the order of ``cfg.candidates``, goal mask (n_rows, G)); with
    ``with_fits``, also the folds' fits (:func:`heldout_logp`'s second value)."""
    run_seeds = [sd for _, sd in runs]
    traj = np.asarray(pool.traj)
    fold = np.stack(
        [
            pooling.fold_of(traj[cand[i, :n_rows]], cfg.pick_folds, 7_000 + sd)
            for i, sd in enumerate(run_seeds)
        ]
    )
    logp, fits = heldout_logp(cfg, pool, cand, counts, n_rows, run_seeds, fold, inits)
    g = counts.shape[-1]
    heldout = [
        (
            np.stack([logp[f][i] for f in cfg.candidates]),
            np.asarray(pool.goal_mask)[traj[cand[i, :n_rows]], :g],
        )
        for i in range(len(runs))
    ]
    return (heldout, fits) if with_fits else heldout


def ensemble(cfg: LoopConfig, params: dict, fits: dict) -> dict:
    """The cautious pick's members of every run (each leaf (R, K + 1, ...)): the fits
    without each of the K folds (:func:`pick_heldout`'s fits), then the fits on every
    answer (``params``: each learned candidate's parameters and ``beta``)."""
    k = cfg.pick_folds
    names = [f for f in cfg.candidates if f in TRAINED] + ["beta"]

    def join(folds, full):
        folds = jnp.reshape(folds, (-1, k, *folds.shape[1:]))
        return jnp.concatenate([folds, jnp.asarray(full)[:, None]], axis=1)

    return {f: jax.tree.map(join, fits[f], params[f]) for f in names}


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


# ------------------------------------------------------------------ the loop's stages


class Timing(dict):
    """Seconds spent in each stage of the loop, ``with timing("fit"): ...`` adding to
    ``fit_s``."""

    STAGES = ("answers", "fit", "beta", "select", "pretrain", "pick", "plan", "judge", "eval",
              "study_plan")  # fmt: skip

    def __init__(self):
        super().__init__({f"{s}_s": 0.0 for s in self.STAGES})
        self._start = time.perf_counter()

    @contextlib.contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self[f"{stage}_s"] += time.perf_counter() - t0

    def done(self) -> dict:
        """Every stage's seconds and ``total_s``, rounded."""
        return {**{k: round(v, 2) for k, v in self.items()},
                "total_s": round(time.perf_counter() - self._start, 2)}  # fmt: skip


class SimulatedStudy:
    """The study of one population, every run (strategy, seed) side by side: the pool of
    stimuli (the dataset's motions, then the plan motions of rounds of plans:
    :mod:`~slotv_jax.experiments.people_loop.rounds`), each run's rows asked so far
    (``cand (R, cap)``, ``counts (R, cap, G)``, the first ``n_rows`` filled) and the
    population's answers, drawn once per (seed, stimulus)."""

    def __init__(self, cfg: LoopConfig, pop, splits, seeds: Sequence[int]):
        self.cfg, self.pop = cfg, pop
        self.rows = [s // cfg.per_stimulus for s in cfg.sizes]  # rows after each size
        self.runs = [(st, sd) for st in cfg.strategies for sd in seeds]
        self.seeds = [sd for _, sd in self.runs]
        xyz, goals, mask = pool_motions(cfg, splits["train"])
        self.n_motion_c = xyz.shape[0] * len(cfg.taus)  # the dataset motions' candidates
        self.slots = self.study_straight = None
        if cfg.plan_share and len(self.rows) > 1:  # rounds of plans: the pool's plan motions
            study = rounds.study_problems(cfg.problems, splits)
            self.study_straight = planning.straight_lines(
                study["goals"], study["goal_mask"], study["target"], cfg=cfg.planner
            )
            self.slots = rounds.PlanSlots(
                xyz.shape[0], cfg.planned, tuple(study["scene"].tolist()), len(self.runs),
                len(self.rows) - 1, len(cfg.taus),
            )  # fmt: skip
            lines = rounds.resample_time(np.asarray(self.study_straight.xyz), xyz.shape[1])
            self.pool = rounds.extend_pool(xyz, goals, mask, cfg.taus, self.slots, study, lines)
        else:
            self.pool = selection.make_pool(xyz, goals, mask, cfg.taus)
        n_r, cap, g = len(self.runs), self.rows[-1], int(self.pool.goals.shape[1])
        self.cand = np.zeros((n_r, cap), np.int32)
        self.counts = np.zeros((n_r, cap, g), np.float32)
        self.asked = np.zeros((n_r, int(self.pool.traj.shape[0])), bool)
        self.heard: dict[int, dict[int, np.ndarray]] = {sd: {} for sd in seeds}

    def ask(self, i: int, start: int, new: np.ndarray) -> None:
        """Run ``i``'s rows ``start, start + 1, …`` are the candidates ``new``, answered by
        ``per_stimulus`` fresh participants each
        (:func:`~slotv_jax.asking.simulated.population_answers`: a stimulus gets the same
        answers under every strategy of a seed)."""
        sd = self.runs[i][1]
        todo = np.asarray([c for c in new if c not in self.heard[sd]], np.int32)
        if todo.size:
            got = simulated.population_answers(self.pop, sd, self.pool, todo, self.cfg.per_stimulus)
            for c, k in zip(todo, got, strict=True):
                self.heard[sd][int(c)] = k
        self.cand[i, start : start + new.size] = new
        self.counts[i, start : start + new.size] = [self.heard[sd][int(c)] for c in new]
        self.asked[i, new] = True

    def first_round(self) -> None:
        """Round 0: the same random draw of dataset motions for every strategy of a seed."""
        for i, (_, sd) in enumerate(self.runs):
            rng = np.random.default_rng([sd, 1])
            self.ask(i, 0, rng.choice(self.n_motion_c, self.rows[0], replace=False))

    def free(self, i: int) -> np.ndarray:
        """The dataset motions' candidates run ``i`` has not asked about."""
        return np.flatnonzero(~self.asked[i, : self.n_motion_c])

    def write_plans(self, planner, params, r: int) -> None:
        """Rounds of plans: every run's plans of the study problems, by each candidate
        family and the pick, written into the pool for the round after size ``r``."""
        made = {  # (R, P, n, 3) per family
            f: np.asarray(planner.plan_problems(params, self.study_straight, family=f).xyz)
            for f in self.slots.families
        }
        for i in range(len(self.runs)):
            own = {f: v[i] for f, v in made.items()}
            self.pool = rounds.write_plans(self.pool, self.slots, i, r, own)

    def stimuli(self, split) -> list[dict]:
        """What each run asked about, row by row: the scene of the ``train`` split it showed
        (a dataset motion's own, or a plan's study problem's), and for a plan its family
        ("" for a dataset motion)."""
        traj = np.asarray(self.pool.traj)
        out = []
        for i, (st, sd) in enumerate(self.runs):
            scene, family = [], []
            for c in self.cand[i]:
                m = int(traj[c])
                what = None if self.slots is None else self.slots.describe(m)
                scene.append(int(split.env_id[m]) if what is None else self.slots.scenes[what[1]])
                family.append("" if what is None else what[0])
            out.append({"strategy": st, "seed": sd, "split": rounds.STUDY_SPLIT,
                        "scene": scene, "plan": family, "rows_per_size": self.rows})  # fmt: skip
        return out


class ActiveAsker:
    """The active strategies' ensemble of ``select_family`` observers (one per active run,
    warm-started from round to round) and the candidates each strategy picks from it."""

    def __init__(self, cfg: LoopConfig, study: SimulatedStudy):
        self.cfg, self.study = cfg, study
        self.active = [i for i, (st, _) in enumerate(study.runs) if st != "random"]
        self.tc = cfg.train_config(cfg.select_family)
        self.selector = selection.make_selector(self.tc, cfg.members, study.rows[-1])
        self.ens = None
        if self.active:
            keys = jnp.stack([jax.random.key(3_000 + study.runs[i][1]) for i in self.active])
            self.ens = jax.jit(jax.vmap(self.selector.init))(keys)

    def pick(self, r: int, n_rows: int, k: int) -> dict[int, np.ndarray]:
        """Each active run's ``k`` dataset-motion candidates after size ``r`` (``n_rows``
        rows answered): the ensemble fitted on the answers so far, then the strategy's
        choice among a random subset of the candidates not yet asked."""
        cfg, st_, picks = self.cfg, self.study, {}
        if not (self.active and k):
            return picks
        act = self.active
        pool, counts = selection.trim_goals(st_.pool, st_.counts[act])
        ans = selection.Answers(jnp.asarray(st_.cand[act]), jnp.asarray(counts),
                                jnp.full((len(act),), n_rows, jnp.int32))  # fmt: skip
        keys = jnp.stack([jax.random.key(5_000 + 31 * r + st_.runs[i][1]) for i in act])
        fit = simulated.fitter(self.selector, cfg.block)
        blocks = cfg.updates(n_rows, self.tc.batch_size, cfg.select_epochs, cfg.block) // cfg.block
        for j in range(blocks):
            step = jax.vmap(lambda kk, j=j: jax.random.fold_in(kk, j))(keys)
            self.ens, _ = fit(self.ens, pool, ans, step)
        for a, i in enumerate(act):
            st, sd = st_.runs[i]
            free = st_.free(i)
            sub = np.random.default_rng([sd, 2, r]).choice(
                free, min(cfg.subset, free.size), replace=False
            )
            member = jax.tree.map(lambda x, a=a: x[a], self.ens.params)
            logp = _scorer(self.selector)(member, st_.pool, jnp.asarray(sub))
            pick = selection.select(
                st, jax.random.fold_in(keys[a], 1), logp, jnp.ones(sub.size, bool), k
            )
            picks[i] = sub[np.asarray(pick)]
        return picks


def initial_params(cfg: LoopConfig, name: str, pop, split) -> dict:
    """θ₀ of every family that does not start from a random draw: the pre-trained ones from
    the labelers' labels (:func:`pretrained_params`), the motion reader from its prior
    without the people scored, filmed by their camera (:func:`reader_prior`)."""
    inits = {f: pretrained_params(cfg, f, split) for f in cfg.families if f in PRETRAINED}
    if READER in cfg.families:
        inits[READER] = reader_prior(cfg, split, name, people_lib.study_camera(pop))
    return inits


def fitted_betas(cfg: LoopConfig, study: SimulatedStudy, n_rows: int) -> np.ndarray:
    """Each run's β of Dragan's and Nikolaidis' labelers (R, len(FITTED)) on its first
    ``n_rows`` rows (:func:`slotv_jax.asking.simulated.fitted_betas`); 1 where none is fitted."""
    betas = np.ones((len(study.runs), len(FITTED)), np.float32)
    if any(f in FITTED for f in cfg.families):
        for i in range(len(study.runs)):
            betas[i] = simulated.fitted_betas(
                study.pool, cfg.taus, study.cand[i, :n_rows], study.counts[i, :n_rows],
                list(FITTED.values()), CAMERA,
            )  # fmt: skip
    return betas


def judge_plans(cfg: LoopConfig, params, plans, problems):
    """Every candidate's plans judged by every candidate's fit (:func:`judge_for`): each
    family's mean P(target) per run, and the pick by plans' choice
    (:func:`slotv_jax.answers.pick.cross_judged`)."""
    judged: dict[str, dict[str, np.ndarray]] = {}
    for g in cfg.candidates:
        judge_g = judge_for(cfg, g)
        for f in cfg.candidates:
            p_g = judge_g(params, plans[f].xyz, problems.goals, problems.goal_mask,
                          problems.target)  # fmt: skip
            judged.setdefault(f, {})[g] = np.asarray(p_g, np.float64).mean((1, 2))
    chosen, cross = cross_judged(judged, cfg.candidates)
    return judged, chosen, cross


class Evaluation:
    """The held-out problems, their straight lines, the population's scorer and each run's
    evaluation keys; the floor and the oracles, planned once."""

    def __init__(self, cfg: LoopConfig, pop, splits, runs):
        self.cfg, self.pop, n_r = cfg, pop, len(runs)
        self.prob = held_out_problems(cfg, splits)
        self.straight = planning.straight_lines(
            self.prob["goals"], self.prob["goal_mask"], self.prob["target"], cfg=cfg.planner
        )
        self.problems = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_r, *a.shape)), self.straight)
        self.scorer = evaluation.population_scorer(
            pop, cfg.taus, cfg.planner.n_points, cfg.eval_participants
        )
        self.keys = eval_keys(runs)
        self.floor: dict | None = None

    def scores(self, res) -> dict:
        return plan_scores(self.scorer, self.keys, res, self.problems)

    def plan_floor(self, example: dict) -> dict:
        """The straight line's, the oracle's and the whole-motion oracle's scores (once)."""
        if self.floor is None:
            n_r = self.problems.q.shape[0]
            self.floor = {"straight": self.scores(straight_as_plan(self.problems))}
            for o, res in oracle_plans(self.cfg.planner, self.pop, self.straight).items():
                res = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_r, *a.shape)), res)
                self.floor[o] = self.scores(res)
                example[o] = np.asarray(res.q[0, 0])
            example["straight"] = np.asarray(self.problems.q[0, 0])
        return self.floor

    def comparison(self) -> dict:
        return {
            o: {
                "score": float(self.floor[o]["score"][0]),
                "per_tau": self.floor[o]["per_tau"][0].round(6).tolist(),
                "accuracy": float(self.floor[o]["correct"][0]),
            }
            for o in ("straight", "oracle", "oracle_whole")
        }


def family_rows(cfg, ev: Evaluation, name, runs, answers, f, res, extras) -> list[dict]:
    """One row per run of family ``f``'s plans ``res`` at ``answers``: score, gain kept,
    accuracy with its Wilson interval, feasibility, and run i's ``extras[i]``."""
    sc = ev.scores(res)
    lo, hi = ev.floor["straight"]["score"], ev.floor["oracle"]["score"]
    n_eval = cfg.problems * len(cfg.taus) * cfg.eval_participants
    out = []
    for i, (st, sd) in enumerate(runs):
        acc = float(sc["correct"][i])
        out.append({
            "population": name, "family": f, "strategy": st, "seed": sd, "answers": answers,
            "score": float(sc["score"][i]),
            "score_per_tau": sc["per_tau"][i].round(6).tolist(),
            "gain_kept": float((sc["score"][i] - lo[i]) / (hi[i] - lo[i])),
            "accuracy": acc,
            "accuracy_95": [round(v, 4) for v in evaluation.wilson(acc * n_eval, n_eval)],
            "feasible": float(np.mean(np.asarray(res.feasible[i]))),
            **extras[i],
        })  # fmt: skip
    return out


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
    document. ``on_size(rows)`` is called with the rows so far after each size.

    Each size: **learn** (every family fitted on the answers so far, the labelers' β, the
    pick's held-out predictions), **plan** (every family, the floor and oracles once),
    **judge** (every plan by every fit: the pick by plans, and the pick's trusted
    candidates), **evaluate** (each family's rows), then **ask** the next round (rounds of
    plans first write the plans of the study's problems)."""
    timing = Timing()
    study = SimulatedStudy(cfg, pop, splits, list(seeds))
    runs, run_seeds, n_r = study.runs, study.seeds, len(study.runs)
    with timing("answers"):
        study.first_round()
    with timing("pretrain"):  # the pre-trained families' θ₀ and the reader's prior
        inits = initial_params(cfg, name, pop, splits["train"])
    asker = ActiveAsker(cfg, study)
    ev = Evaluation(cfg, pop, splits, runs)
    out_rows, example = [], {}
    bar = tqdm(total=len(study.rows), desc=f"people loop ({name})", unit="size",
               disable=not progress)  # fmt: skip
    for r, n_rows in enumerate(study.rows):
        pool, cand, counts = study.pool, study.cand, study.counts
        with timing("fit"):  # learn: every family on the answers so far
            params = {
                f: fit_family(cfg, f, pool, cand, counts, n_rows, run_seeds, inits)
                for f in cfg.families
                if f in TRAINED
            }
        with timing("beta"):
            betas = fitted_betas(cfg, study, n_rows)
            params["beta"] = jnp.asarray(betas)
        w_all = None
        with timing("pick"):  # the held-out predictions; the pool by likelihood alone
            if PICK in cfg.families:
                heldout, fits = pick_heldout(
                    cfg, pool, cand, counts, n_rows, runs, inits, with_fits=True
                )
                w_all, _ = pick_runs(cfg, heldout, counts, n_rows)
                params["pick_w"] = jnp.asarray(w_all)
                if CAUTIOUS in cfg.families:
                    params["ensemble"] = ensemble(cfg, params, fits)
                del fits
        planner = planner_for(cfg, jax.tree.map(lambda a: a[0], params))

        with timing("plan"):  # plan: the floor and the oracles once, every family each size
            ev.plan_floor(example)
            plans = {
                f: planner.plan_problems(params, ev.straight, family=f)
                for f in cfg.families
                if f not in DERIVED  # made of the others' fits or plans
            }
            jax.block_until_ready(plans)
        judged: dict = {}
        with timing("judge"):  # every candidate's plans, judged by every fit
            if set(DERIVED) & set(cfg.families):
                judged, chosen, cross = judge_plans(cfg, params, plans, ev.problems)
        pick_reports = keep = None
        if PICK in cfg.families:  # the pool without the least-trusted candidate, planned
            with timing("pick"):
                keep = trusted(cross, *heldout_quality(heldout, counts, n_rows))
                w, pick_reports = pick_runs(cfg, heldout, counts, n_rows, keep)
                params["pick_w"] = jnp.asarray(w)
            with timing("plan"):
                for f in (PICK, CAUTIOUS):
                    if f in cfg.families:
                        plans[f] = jax.block_until_ready(
                            planner.plan_problems(params, ev.straight, family=f)
                        )

        with timing("eval"):  # evaluate: each family's rows, then the pick by plans'
            made: dict[tuple[str, int], dict] = {}
            for f in [f for f in cfg.families if f in plans]:
                extras = [
                    _family_fields(cfg, f, i, betas, pick_reports, keep, w_all, judged)
                    for i in range(n_r)
                ]
                got = family_rows(cfg, ev, name, runs, int(cfg.sizes[r]), f, plans[f], extras)
                for i, row in enumerate(got):
                    made[f, i] = row
                out_rows += got
                if r == len(study.rows) - 1:
                    example[f] = np.asarray(plans[f].q[0, 0])
            if PICK_CROSS in cfg.families:  # the pick by plans: the chosen family's plans
                own = ("beta", "heldout_nll", "judged_by")  # what the chosen family's row says
                for i in range(n_r):
                    f = cfg.candidates[chosen[i]]
                    row = {k: v for k, v in made[f, i].items() if k not in own}
                    row["family"], row["chosen"] = PICK_CROSS, f
                    row["cross_scores"] = dict(
                        zip(cfg.candidates, cross[i].round(6).tolist(), strict=True)
                    )
                    out_rows.append(row)
                if r == len(study.rows) - 1:
                    example[PICK_CROSS] = example[cfg.candidates[chosen[0]]]
        if on_size is not None:
            on_size(out_rows)
        bar.update(1)
        if r + 1 == len(study.rows):
            break

        # Ask: the next round, a share of it the plans of the study's problems.
        k = study.rows[r + 1] - n_rows
        k_plan = 0
        if study.slots is not None:
            with timing("study_plan"):
                k_plan = round(cfg.plan_share * k)
                study.write_plans(planner, params, r)
        k -= k_plan
        with timing("select"):
            picks = asker.pick(r, n_rows, k)
        with timing("answers"):
            for i, (st, sd) in enumerate(runs):
                if st == "random" or not k:
                    rng = np.random.default_rng([sd, 3, r])
                    picks[i] = rng.choice(study.free(i), k, replace=False)
                new = np.asarray(picks[i], np.int32)
                if k_plan:  # the plans of this run, drawn by its seed and round alone
                    rng = np.random.default_rng([sd, 4, r])
                    new = np.concatenate([new, study.slots.draw(i, r, k_plan, rng)])
                study.ask(i, n_rows, new)
    bar.close()
    return {
        "population": name,
        "population_config": people_lib.people_config(pop),
        "rows": out_rows,
        "comparison": ev.comparison(),
        "example": {
            "problem": {k: v[0].tolist() for k, v in ev.prob.items()},
            "q": {k: v.round(6).tolist() for k, v in example.items()},
        },
        "timing": timing.done(),
        "stimuli": study.stimuli(splits["train"]),
    }


def _family_fields(cfg, f, i, betas, pick_reports, keep, w_all, judged) -> dict:
    """What run ``i``'s row of family ``f`` says beyond its plans' scores: a labeler's β,
    what the answers alone say of it (its held-out NLL; the pick's pool), and each fit's
    P(target) of its plans."""
    row = {}
    if f in FITTED:
        row["beta"] = float(betas[i, list(FITTED).index(f)])
    if pick_reports is not None:
        rep = pick_reports[i]
        if f in (PICK, CAUTIOUS):
            row.update(_pick_fields(cfg, rep, keep[i], w_all[i]))
        else:
            row["heldout_nll"] = rep["heldout_nll"][rep["candidates"].index(f)]
    if f == CAUTIOUS:
        row["caution"], row["members"] = cfg.caution, cfg.pick_folds + 1
    if f in judged:
        row["judged_by"] = {g: round(float(v[i]), 6) for g, v in judged[f].items()}
    return row


def _pick_fields(cfg: LoopConfig, rep: dict, keep: np.ndarray, w_all: np.ndarray) -> dict:
    """What a pick row says of its pool: held-out NLL, weights (before and after leaving the
    least-trusted out), the pick, those left out, uniform guessing's NLL and ``poor_fit``."""
    return {
        "heldout_nll": rep["pool_nll"],
        "weights": dict(zip(rep["candidates"], rep["weights"], strict=True)),
        "picked": rep["pick"],
        "left_out": [cfg.candidates[j] for j in np.flatnonzero(~keep)],
        "uniform_nll": rep["uniform_nll"],
        "poor_fit": rep["poor_fit"],
        "weights_likelihood": dict(zip(rep["candidates"], w_all.round(6).tolist(), strict=True)),
    }


_SCORERS: dict = {}


def _scorer(sel):
    if sel not in _SCORERS:
        _SCORERS[sel] = jax.jit(lambda p, pool, c: sel.log_probs(p, pool, c))
    return _SCORERS[sel]


def straight_as_plan(problems: planning.Problem):
    """The straight lines in the shape of a plan (``xyz``)."""
    return planning.PlanResult(problems.xyz, problems.q, None)
