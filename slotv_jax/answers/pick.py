"""The researcher's pick on a study file: ``python -m slotv_jax.study pick``.

Every candidate observer (the families of :data:`slotv_jax.training.config.FAMILIES` and
the hand-crafted labelers with a fitted β) is scored by the held-out likelihood of the
study's answers: K folds by motion, each candidate fitted on the other folds and
predicting the held-out one (:func:`out_of_fold`). The log-linear pool of the candidates
(:mod:`slotv_jax.answers.pooling`) weighs them by those predictions; the candidate of the
largest weight is the pick. Only the study's answers are read.

The people loop's family ``pick`` plans against the pool itself, less one candidate: the
one whose plans the other fits judge least legible (:func:`trusted`, from the judgments of
the pick by plans below); the held-out likelihood weighs the rest.

The pick *by plans* (:func:`pick_by_plans`, ``study pick --by plans``) judges the plans
instead: every candidate, fitted on every answer, plans the study's own scenes, each
candidate's plans are scored by the fits of the other candidates (:func:`cross_judged`),
and the best-judged candidate is the pick: the people loop's family ``pick_cross``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float
from tqdm.auto import tqdm

from slotv_jax import planning
from slotv_jax.answers import pooling, prior
from slotv_jax.answers.crossval import fit_beta, labeler_probs, labeler_visible
from slotv_jax.answers.fitting import answer_logits, study_trainer, train_study
from slotv_jax.answers.format import PROB_FLOOR, Study
from slotv_jax.planning import caution as caution_lib
from slotv_jax.planning import evaluation
from slotv_jax.training import checkpoint
from slotv_jax.training import config as train_config

LABELERS = ("dragan", "nikolaidis")  # the hand-crafted candidates (β fitted)
READER = "reader"  # the motion reader: it starts from its prior (:mod:`slotv_jax.answers.prior`)
CANDIDATES = (*train_config.FAMILIES, *LABELERS)
#: ``study pick``'s default candidates (``--candidates`` takes a subset): every candidate,
#: as the people loop's presets choose among every family.
DEFAULT_CANDIDATES = CANDIDATES
BY = ("likelihood", "plans", "pool")  # the rules of ``study pick --by``
#: The planner of the pick by plans, per training preset (the people loop's: 50 points and
#: 30 steps on a CPU, the default planner on a GPU).
PLANNERS = {"quick": {"n_points": 50, "iters": 30}, "paper": {}}
MAX_TAUS = 8  # the study's distinct stop times the planner's objective takes at most


def check_candidates(names: Sequence[str]) -> tuple[str, ...]:
    """Distinct names of :data:`CANDIDATES`, at least two (ValueError naming the flag)."""
    names = tuple(names)
    bad = [n for n in names if n not in CANDIDATES]
    if bad or len(set(names)) < len(names) or len(names) < 2:
        raise ValueError(
            f"--candidates: expected at least two distinct names of {list(CANDIDATES)}, "
            f"got {list(names)}"
        )
    return names


def check_visible(study: Study, names: Sequence[str], camera: str) -> None:
    """ValueError naming ``--candidates`` if Nikolaidis' labeler is a candidate and a point
    or goal of ``study`` is behind ``camera`` (its image is undefined there)."""
    if "nikolaidis" in names and not labeler_visible(study, camera):
        raise ValueError(
            f"--candidates: nikolaidis needs every point and goal in front of camera {camera!r}"
        )


def _log_probs(logits: np.ndarray, mask: np.ndarray) -> np.ndarray:
    z = np.where(mask, logits, -np.inf)
    z = z - z.max(-1, keepdims=True)
    return np.where(mask, z - np.log(np.exp(z).sum(-1, keepdims=True)), -np.inf)


def out_of_fold(
    study: Study,
    names: Sequence[str],
    *,
    preset: str = "quick",
    folds: int = 3,
    seed: int = 0,
    camera: str = "observer",
    progress: bool = True,
    with_fits: bool = False,
) -> tuple:
    """Each candidate's log-probabilities (F, A, G) of every answer row, predicted by its
    fit on the other folds (folds by motion, :func:`slotv_jax.answers.pooling.fold_of`);
    and the rows' folds (A,). Learned families train with ``preset``'s config; labelers get β
    by :func:`slotv_jax.answers.crossval.fit_beta`. With ``with_fits``, also each fold's
    fits, ``[{name: {"beta": β} or {"params": θ}}]`` (fold f's: fitted without fold f)."""
    names = check_candidates(names)
    start = starts(study, names, preset=preset, camera=camera)
    fold = pooling.fold_of(study.answer_trajectory, folds, seed)
    g = study.counts.shape[-1]
    mask = study.goal_mask[study.answer_trajectory, :g]
    out = np.full((len(names), study.n_rows, g), -np.inf, np.float32)
    bar = tqdm(total=folds * len(names), desc="held-out fits", disable=not progress)
    fold_fits: list[dict] = [{} for _ in range(folds)]
    for f in range(folds):
        rows = np.flatnonzero(fold == f)
        tr, te = study.select_rows(fold != f), study.select_rows(fold == f)
        for j, name in enumerate(names):
            if name in LABELERS:
                beta, _ = fit_beta(tr, name, camera=camera)
                fold_fits[f][name] = {"beta": beta}
                y = labeler_probs(te, name, beta=beta, camera=camera)[:, :g]
                with np.errstate(divide="ignore"):
                    lp = np.where(mask[rows], np.log(np.maximum(y, PROB_FLOOR)), -np.inf)
            else:
                cfg = fit_config(preset, name, tr.n_rows, camera)
                state = fit(cfg, tr, jax.random.key(seed * 1000 + f), start.get(name))
                fold_fits[f][name] = {"params": state.params}
                z = np.full((rows.size, g), -np.inf, np.float32)
                lg = answer_logits(cfg, state.params, te)  # the study's goal slots in use
                z[:, : lg.shape[-1]] = lg[:, :g]
                lp = _log_probs(z, mask[rows])
            out[j, rows] = lp
            bar.update(1)
    bar.close()
    return (out, fold, fold_fits) if with_fits else (out, fold)


def fit_config(
    preset: str, name: str, rows: int, camera: str = "observer"
) -> train_config.TrainConfig:
    """The family's config, with a batch that fits a small study (as ``study train``); the
    motion reader's with the study's ``camera``."""
    cfg = train_config.family(preset, name)
    if name == READER:
        cfg = dataclasses.replace(cfg, camera=camera)
    if rows < cfg.batch_size:
        cfg = train_config.apply_overrides(cfg, [f"batch_size={1 << (rows.bit_length() - 1)}"])
    return cfg


def starts(
    study: Study, names: Sequence[str], *, preset: str = "quick", camera: str = "observer"
) -> dict[str, object]:
    """θ₀ of the candidates that start from a prior: the motion reader's
    (:func:`slotv_jax.answers.prior.answered_prior`, the study's stimuli labelled by the
    prior's sources, never its answers), once per pick; the others start from a random draw."""
    if READER not in names:
        return {}
    cfg = fit_config(preset, READER, study.n_rows, camera)
    return {READER: prior.prior_params(cfg, prior.answered_prior(study))}


def fit(cfg: train_config.TrainConfig, study: Study, key: jax.Array, start=None):
    """``cfg``'s family fitted on ``study``'s answers
    (:func:`slotv_jax.answers.fitting.train_study`), from θ₀ = ``start`` (a prior, with a
    fresh optimiser state) or a random draw from ``key``."""
    state = None if start is None else study_trainer(cfg).init(key, start)
    return train_study(cfg, study, key, progress=False, state=state)


def pick_study(
    study: Study,
    names: Sequence[str] = DEFAULT_CANDIDATES,
    *,
    preset: str = "quick",
    folds: int = 3,
    seed: int = 0,
    camera: str = "observer",
    progress: bool = True,
    keep: Sequence[bool] | None = None,
) -> dict:
    """The pick of ``study``: :func:`out_of_fold` then
    :func:`slotv_jax.answers.pooling.pick_report` (each candidate's held-out NLL per answer,
    the pool's weights and NLL, ``pick`` the candidate of the largest weight); ``keep``:
    the candidates the pool may weigh (every one by default)."""
    names = check_candidates(names)
    check_folds(study, folds)
    check_visible(study, names, camera)
    logp, _ = out_of_fold(
        study, names, preset=preset, folds=folds, seed=seed, camera=camera, progress=progress
    )
    return _report(study, names, logp, keep, folds=folds, seed=seed, preset=preset)


def _report(study: Study, names, logp, keep, **meta) -> dict:
    """:func:`slotv_jax.answers.pooling.pick_report` of out-of-fold predictions ``logp``."""
    return {**pooling.pick_report(list(names), logp, *_counts(study), keep), **meta}


def _counts(study: Study) -> tuple[np.ndarray, np.ndarray]:
    """The answer rows' counts (A, G) and real goals (A, G), G the study's goal slots."""
    g = study.counts.shape[-1]
    return study.counts[:, :g], study.goal_mask[study.answer_trajectory, :g]


def check_folds(study: Study, folds: int) -> None:
    """ValueError naming ``--folds`` unless 2 <= folds <= the study's motions."""
    if not (isinstance(folds, int) and 2 <= folds <= study.n_trajectories):
        raise ValueError(
            f"--folds: expected 2 <= folds <= {study.n_trajectories} (motions), got {folds!r}"
        )


def pick_table(rep: dict) -> str:
    """A Markdown table of :func:`pick_study`'s report."""
    lines = [
        f"{rep['folds']}-fold held-out likelihood by motion; the pool's weights "
        "(log-linear, fitted on the held-out predictions)",
        "",
        "| candidate | held-out NLL per answer (nats) | weight |",
        "|---|---|---|",
    ]
    u = rep["uniform_nll"]
    for n, nll, w in zip(rep["candidates"], rep["heldout_nll"], rep["weights"], strict=True):
        mark = " **(pick)**" if n == rep["pick"] else ""
        if n in rep.get("left_out", ()):
            why = "no better than guessing" if nll >= u else "its plans judged least legible"
            mark += f" (left out: {why})"
        lines.append(f"| {n}{mark} | {nll:.4f} | {w:.3f} |")
    lines.append(f"| pool | {rep['pool_nll']:.4f} | |")
    lines.append(f"| uniform guessing | {u:.4f} | |")
    best = max(rep["quality"])
    lines += ["", f"the best fit closes {100 * best:.1f} % of uniform guessing's NLL"]
    if rep["poor_fit"]:
        lines[-1] += (
            f": **no candidate explains these answers well** (below "
            f"{100 * pooling.POOR_FIT:g} %); plans made against them rest on little: ask "
            "more, or about other motions, before trusting them"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------ the pick by plans


def cross_judged(
    judged: Mapping[str, Mapping[str, np.ndarray]], candidates: Sequence[str]
) -> tuple[np.ndarray, np.ndarray]:
    """The pick by plans. ``judged[f][g]`` (R,) is fit g's mean P(target | ξ_{0:τ}) of
    family f's plans (over problems and stop times); each candidate f is scored by the fits
    it was not planned against::

        S_f = (1 / (|C| − 1)) Σ_{g ∈ C, g ≠ f} judged[f][g],

    and the pick is argmax_f S_f, per run. A planner climbs wherever its own fit is too
    optimistic, so f's own judgment of its plans is left out: a plan counts as legible
    where fits that did not make it agree that it is (cross-validation of plans, as the
    folds of :mod:`slotv_jax.answers.pooling` are of fits). Returns the chosen index into
    ``candidates`` (R,) and the scores S ``(R, |C|)``.

    >>> j = {"a": {"a": np.array([0.9]), "b": np.array([0.4])},
    ...      "b": {"a": np.array([0.6]), "b": np.array([0.8])}}
    >>> idx, s = cross_judged(j, ["a", "b"])
    >>> idx.tolist(), s.round(2).tolist()
    ([1], [[0.4, 0.6]])
    """
    c = list(candidates)
    if len(c) < 2:
        raise ValueError(f"candidates: expected at least two, got {c}")
    s = np.stack(
        [np.mean([judged[f][g] for g in c if g != f], axis=0) for f in c], axis=-1
    )  # (R, C)
    return np.argmax(s, axis=-1), s


def trusted(
    scores: Float[np.ndarray, "R C"],
    heldout: Float[np.ndarray, "R C"] | None = None,
    uniform: Float[np.ndarray, " R"] | None = None,
) -> np.ndarray:
    """The candidates the pool may weigh (:func:`slotv_jax.answers.pooling.fit_pool_weights`'s
    ``keep``), per run: every candidate but the one whose plans the other fits judge least
    legible, ``argmin_f S_f`` of :func:`cross_judged`'s scores (R, C); with each
    candidate's held-out NLL per answer (``heldout`` (R, C)), never the best fit, and with
    uniform guessing's NLL (``uniform`` (R,)), none that is no better than guessing
    (``heldout ≥ uniform``) but the best. Returns (R, C) bool.

    A fit the planner can exploit, sharp where the answers did not constrain it, shows it
    in its own plans: they climb its error, and the fits that did not make them find them
    less legible (the pick by plans' S). In the pool that fit's error is scaled by its
    weight but still there to climb; leaving it out takes it away, whatever weight its
    held-out likelihood earned. The held-out likelihood then weighs the rest. But where
    the others are near-uniform fits, the sharp fit is the least judged because the others
    have learned nothing: so the best fit is kept (then none is left out), and a candidate
    that predicts held-out answers no better than guessing has no say.

    >>> trusted(np.array([[0.40, 0.31, 0.38]])).tolist()
    [[True, False, True]]
    >>> trusted(np.array([[0.40, 0.31, 0.38]]), np.array([[1.35, 1.20, 1.37]]),
    ...         np.array([1.355])).tolist()
    [[True, True, False]]
    """
    s = np.asarray(scores, np.float64)
    if s.ndim != 2 or s.shape[-1] < 2:
        raise ValueError(f"scores: expected (R, C) with C >= 2, got {s.shape}")
    keep = np.arange(s.shape[-1]) != np.argmin(s, axis=-1)[:, None]
    if heldout is None:
        if uniform is not None:
            raise ValueError("uniform: needs heldout, the candidates' held-out NLL")
        return keep
    h = np.asarray(heldout, np.float64)
    if h.shape != s.shape:
        raise ValueError(f"heldout: expected the scores' shape {s.shape}, got {h.shape}")
    best = np.arange(s.shape[-1]) == np.argmin(h, axis=-1)[:, None]
    if uniform is not None:
        u = np.asarray(uniform, np.float64)
        if u.shape != s.shape[:1]:
            raise ValueError(f"uniform: expected shape {s.shape[:1]}, got {u.shape}")
        keep &= h < u[:, None]
    return keep | best


def study_problems(study: Study, n: int) -> dict[str, np.ndarray]:
    """The study's own planning problems: every (scene, real goal) of its distinct goal sets
    (in order of first appearance; :func:`slotv_jax.planning.evaluation.scene_problems`),
    cut evenly to at most ``n``: goals (P, 8, 3), goal_mask (P, 8), target (P,)."""
    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"--problems: expected an int >= 1, got {n!r}")
    first: dict[bytes, int] = {}
    for i in range(study.n_trajectories):
        key = np.asarray(study.goals[i][study.goal_mask[i]], np.float32).round(5).tobytes()
        first.setdefault(key, i)
    idx = list(first.values())
    every = evaluation.scene_problems(
        {"study": (study.goals[idx], study.goal_mask[idx])}, ["study"]
    )
    m = every["target"].size
    keep = np.linspace(0, m - 1, min(n, m)).round().astype(int)
    return {k: every[k][keep] for k in ("goals", "goal_mask", "target")}


def study_taus(study: Study, rule: str = "plans") -> tuple[float, ...]:
    """The study's distinct stop times (its answers' τ), the planner's prefix objective
    (ValueError naming ``--by RULE``)."""
    taus = tuple(sorted({round(float(t), 6) for t in study.answer_tau}))
    outside = [t for t in taus if not 0 < t <= 1]
    if outside:
        why = (
            " (the study has time stamps t: its τ are in their unit, not fractions of the motion)"
            if study.t is not None
            else ""
        )
        raise ValueError(
            f"--by {rule}: expected the stop times τ of the study's answers in (0, 1], the "
            f"fraction of the motion seen, got {len(outside)} of its {len(taus)} outside: "
            f"{_few(outside)}{why}"
        )
    if len(taus) > MAX_TAUS:
        raise ValueError(
            f"--by {rule}: expected at most {MAX_TAUS} distinct stop times in the study's "
            f"answers (the planner's objective takes that many), got {len(taus)}: {_few(taus)}"
        )
    return taus


def _few(values: Sequence[float], n: int = 5) -> str:
    """The first ``n`` values, comma-separated, and how many more."""
    more = f", ... ({len(values) - n} more)" if len(values) > n else ""
    return ", ".join(f"{v:g}" for v in values[:n]) + more


def fit_candidates(
    study: Study,
    names: Sequence[str],
    *,
    preset: str = "quick",
    seed: int = 0,
    camera: str = "observer",
    progress: bool = True,
) -> dict[str, dict]:
    """Every candidate fitted on every answer: ``{name: {"observer", and "cfg" and "state"
    (a learned family, :func:`slotv_jax.answers.fitting.train_study`) or "beta" (a labeler,
    :func:`slotv_jax.answers.crossval.fit_beta`)}}``."""
    out = {}
    start = starts(study, names, preset=preset, camera=camera)
    for name in tqdm(names, desc="fits on every answer", disable=not progress):
        if name in LABELERS:
            beta, _ = fit_beta(study, name, camera=camera)
            obs = planning.labeler_observer(name, beta=beta, camera=camera)
            out[name] = {"observer": obs, "beta": beta}
        else:
            cfg = fit_config(preset, name, study.n_rows, camera)
            state = fit(cfg, study, jax.random.key(seed), start.get(name))
            obs = checkpoint.make_observer(cfg, state.params)
            out[name] = {"observer": obs, "cfg": cfg, "state": state}
    return out


def judge_plans(
    observers: Mapping[str, object],
    xyz: Mapping[str, Float[np.ndarray, "P T 3"]],
    problems: Mapping[str, np.ndarray],
    taus: Sequence[float],
) -> dict[str, dict[str, float]]:
    """``judged[f][g]``: observer g's mean P(target | ξ_{0:τ}) of f's plans ``xyz[f]``, over
    the problems and the stop times (:func:`slotv_jax.planning.stop_log_probs`)."""
    g_, m_, t_ = (jnp.asarray(problems[k]) for k in ("goals", "goal_mask", "target"))
    out: dict[str, dict[str, float]] = {f: {} for f in xyz}
    for g, obs in observers.items():
        judge = jax.jit(
            jax.vmap(lambda x, gl, m, t, obs=obs: planning.stop_log_probs(obs, x, gl, m, t, taus))
        )
        for f, x in xyz.items():
            lp = np.asarray(judge(jnp.asarray(x), g_, m_, t_), np.float64)
            out[f][g] = float(np.exp(lp).mean())
    return out


def pick_by_plans(
    study: Study,
    names: Sequence[str] = DEFAULT_CANDIDATES,
    *,
    preset: str = "quick",
    seed: int = 0,
    camera: str = "observer",
    problems: int = 12,
    progress: bool = True,
    rule: str = "plans",
) -> tuple[dict, dict[str, dict], dict[str, np.ndarray]]:
    """The pick by plans of ``study`` (``rule``: the ``--by`` its errors name): every
    candidate fitted on every answer (:func:`fit_candidates`) plans the study's own
    problems (:func:`study_problems`, from TCP(q_home), the prefix objective at the study's
    stop times, :data:`PLANNERS`), every plan is judged by every fit (:func:`judge_plans`)
    and the pick is :func:`cross_judged`'s. Reads the study's answers and scenes only.

    Returns the report (``candidates``, ``judged`` (C, C): row f, column g, ``scores``
    S_f, ``pick``, ``problems``, ``taus``, ``planner``), the fits, and the plans file's
    arrays (:mod:`slotv_jax.planning.plans`: the straight line, then every candidate)."""
    names = check_candidates(names)
    check_visible(study, names, camera)
    taus = study_taus(study, rule)
    prob = study_problems(study, problems)
    cfg = planning.PlannerConfig(**PLANNERS.get(preset, {}), taus=taus)
    # The problems' straight lines before any fit: an unreachable scene is refused first.
    try:
        straight = planning.straight_lines(prob["goals"], prob["goal_mask"], prob["target"],
                                           cfg=cfg)  # fmt: skip
    except ValueError as e:
        raise ValueError(f"--by {rule}: the study's scenes: {e}") from None
    fits = fit_candidates(study, names, preset=preset, seed=seed, camera=camera,
                          progress=progress)  # fmt: skip
    observers = {n: fits[n]["observer"] for n in names}
    planner = planning.make_planner(observers, cfg)
    plans = {}
    for n in tqdm(names, desc="plans", disable=not progress):
        plans[n] = planner.plan_problems(straight, observer=n)
    judged = judge_plans(observers, {n: np.asarray(r.xyz) for n, r in plans.items()}, prob, taus)
    idx, s = cross_judged({f: {k: np.array([v]) for k, v in r.items()} for f, r in judged.items()},
                          names)  # fmt: skip
    report = {
        "rule": "plans",
        "candidates": list(names),
        "judged": [[judged[f][k] for k in names] for f in names],
        "scores": s[0].tolist(),
        "pick": names[int(idx[0])],
        "problems": int(prob["target"].size),
        "taus": list(taus),
        "planner": {"n_points": cfg.n_points, "iters": cfg.iters},
        "preset": preset,
        "seed": seed,
    }
    arrays = {
        **prob,
        "names": np.array(["straight", *names]),
        "q": np.stack([np.asarray(straight.q)] + [np.asarray(plans[n].q) for n in names]),
        "xyz": np.stack([np.asarray(straight.xyz)] + [np.asarray(plans[n].xyz) for n in names]),
    }
    arrays["q"], arrays["xyz"] = arrays["q"].astype(np.float32), arrays["xyz"].astype(np.float32)
    return report, fits, arrays


def planner_words(preset: str) -> str:
    """The planner of :data:`PLANNERS` ``[preset]`` in words, "50 points, 30 iterations"."""
    cfg = planning.PlannerConfig(**PLANNERS[preset])
    return f"{cfg.n_points} points, {cfg.iters} iterations"


def planner_line(preset: str) -> str:
    """The line ``study pick --by plans|pool`` starts with: the planner ``preset`` plans
    with, and how to change it (another preset's planner)."""
    others = "; ".join(f"--preset {p}: {planner_words(p)}" for p in PLANNERS if p != preset)
    return f"planner: {planner_words(preset)} per plan (the {preset} preset's; {others})"


def plans_table(rep: dict) -> str:
    """A Markdown table of :func:`pick_by_plans`'s report."""
    lines = [
        f"each candidate's plans of {rep['problems']} problems of the study's scenes, judged by "
        f"every fit: mean P(target | motion up to τ) over τ = {', '.join(map(str, rep['taus']))}",
        "",
        "| candidate | judged by the other fits (S) | by its own fit |",
        "|---|---|---|",
    ]
    for i, (n, s) in enumerate(zip(rep["candidates"], rep["scores"], strict=True)):
        mark = " **(pick)**" if n == rep["pick"] else ""
        lines.append(f"| {n}{mark} | {s:.4f} | {rep['judged'][i][i]:.4f} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ the pool less one


def pick_pool(
    study: Study,
    names: Sequence[str] = DEFAULT_CANDIDATES,
    *,
    preset: str = "quick",
    folds: int = 3,
    seed: int = 0,
    camera: str = "observer",
    problems: int = 12,
    progress: bool = True,
    caution: float | None = None,
) -> tuple[dict, dict[str, dict], dict[str, np.ndarray], dict]:
    """The people loop's ``pick`` on a study: every candidate's plans judged by the other
    fits (:func:`pick_by_plans`), the candidate of the least-judged plans left out
    (:func:`trusted`), and the pool of the rest weighted by the held-out likelihood
    (:func:`pick_study` with ``keep``; ``pick`` names its largest weight); the pool is
    written by :func:`slotv_jax.answers.pool_file.save_pool`. Reads the study's answers
    and scenes only. Returns the pool's report (``rule``
    ``"pool"``, ``left_out``), the fits, the plans file's arrays (the straight line, every
    candidate's plans, then ``pool``: the plans made against the pool itself, what a
    researcher runs) and the report of the plans.

    ``caution`` κ (None: none): the plans file gets ``pool_cautious`` too, the pool planned
    for a lower confidence bound over its folds (:func:`cautious_pool`), and the report
    ``caution``."""
    names = check_candidates(names)
    check_folds(study, folds)
    if caution is not None:  # refused before any fit
        caution_lib.check_caution(caution)
    by_plans, fits, arrays = pick_by_plans(study, names, preset=preset, seed=seed, camera=camera,
                                           problems=problems, progress=progress,
                                           rule="pool")  # fmt: skip
    logp, _, fold_fits = out_of_fold(
        study, names, preset=preset, folds=folds, seed=seed, camera=camera, progress=progress,
        with_fits=True,
    )  # fmt: skip
    nll, uniform = pooling.heldout_quality(logp, *_counts(study))
    keep = trusted(np.asarray([by_plans["scores"]]), nll[None], np.asarray([uniform]))[0]
    rep = _report(study, names, logp, keep.tolist(), folds=folds, seed=seed, preset=preset)
    rep = {
        **rep,
        "rule": "pool",
        "left_out": [n for n, k in zip(names, keep, strict=True) if not k],
    }
    # The pool's own plans, against P_w ∝ Π_f P_f^{w_f} over the members of weight > 0
    # (none: save_pool refuses the pool, in its own words).
    kept = [i for i, w in enumerate(rep["weights"]) if w > 0]
    if not kept:
        return rep, fits, arrays, by_plans
    members = [names[i] for i in kept]
    weights = [rep["weights"][i] for i in kept]
    observers = {"pool": pooling.pool_observer([fits[n]["observer"] for n in members], weights)}
    if caution is not None:
        rep["caution"] = float(caution)
        observers["pool_cautious"] = cautious_pool(
            observers["pool"], fits, fold_fits, members, weights, caution, camera=camera
        )
    cfg = planning.PlannerConfig(**PLANNERS.get(preset, {}), taus=tuple(by_plans["taus"]))
    for name, obs in observers.items():
        got = planning.make_planner(obs, cfg)(
            arrays["goals"], arrays["goal_mask"], arrays["target"]
        )
        arrays = {
            **arrays,
            "names": np.append(arrays["names"], name),
            "q": np.concatenate([arrays["q"], np.asarray(got.q, np.float32)[None]]),
            "xyz": np.concatenate([arrays["xyz"], np.asarray(got.xyz, np.float32)[None]]),
        }
    return rep, fits, arrays, by_plans


def cautious_pool(
    pool,
    fits: Mapping[str, dict],
    fold_fits: Sequence[Mapping[str, dict]],
    members: Sequence[str],
    weights: Sequence[float],
    caution: float,
    *,
    camera: str = "observer",
):
    """The ``pool`` of ``members`` with ``weights`` (fitted on every answer,
    :func:`fit_candidates`) as a lower bound over K + 1 fits
    (:func:`slotv_jax.planning.caution.lower_bound_observer`, κ = ``caution``): the pools
    of each fold's fits (:func:`out_of_fold`'s, fitted without that fold), then ``pool``,
    stacked; what the people loop's ``pick_cautious``
    plans. A fold's learned fit takes the full fit's config (its network is the same; only
    the batch of its training differed)."""

    def member(name, fit):
        if name in LABELERS:
            return planning.labeler_observer(name, beta=fit["beta"], camera=camera)
        return checkpoint.make_observer(fits[name]["cfg"], fit["params"])

    pools = [
        pooling.pool_observer([member(n, ff[n]) for n in members], weights) for ff in fold_fits
    ] + [pool]
    stacked = jax.tree.map(lambda *p: jnp.stack([jnp.asarray(x) for x in p]), *pools)
    return caution_lib.lower_bound_observer(stacked, float(caution))
