"""Evaluating a legible planner: problems from scenes, and plans scored by the true observer.

A *problem* is a scene and one of its real goals as the target, started from TCP(q_home)
(:func:`scene_problems`: every (scene, real goal) pair). A plan is scored by the
hand-crafted labeler that stands for the truth, at a given temperature
(:func:`true_labels`): its probability y_target of the goal the robot moves to, beside the
straight line's (the floor) and the oracle's, the planner that plans with that labeler
itself (the ceiling). The share of the oracle's gain a planner keeps,

    gain kept = (mean y_plan − mean y_straight) / (mean y_oracle − mean y_straight),

is the one number of a planner (Dragan & Srinivasa 2013 score legibility by the same
probability of the goal).

Where the truth is a population of simulated people (:mod:`slotv_jax.observers.population`)
and people see a motion stopped at times τ, a plan's score is the population's mean
P_pop(target | ξ_{0:τ}) over the stop times, beside an evaluation study of fresh
participants (:func:`population_scorer`, :func:`population_scores`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import labelers, labelling, zoo
from slotv_jax.observers import people as people_lib
from slotv_jax.observers import population as population_lib
from slotv_jax.observers.common import seen_points


def scene_problems(
    scenes: Mapping[str, tuple[np.ndarray, np.ndarray]], splits: Sequence[str]
) -> dict[str, np.ndarray]:
    """Every (scene, real goal slot) pair of ``scenes`` (``{split: (goals (S, 8, 3),
    goal_mask (S, 8))}``), the ``splits`` in order: goals (P, 8, 3), goal_mask (P, 8),
    target (P,), split (P,: index into ``splits``) and scene (P,: index within it)."""
    rows = {"goals": [], "goal_mask": [], "target": [], "split": [], "scene": []}
    for si, s in enumerate(splits):
        goals, mask = scenes[s]
        for e in range(goals.shape[0]):
            for k in np.flatnonzero(mask[e]):
                rows["goals"].append(goals[e])
                rows["goal_mask"].append(mask[e])
                rows["target"].append(k)
                rows["split"].append(si)
                rows["scene"].append(e)
    return {
        "goals": np.asarray(rows["goals"], np.float32),
        "goal_mask": np.asarray(rows["goal_mask"], bool),
        "target": np.asarray(rows["target"], np.int32),
        "split": np.asarray(rows["split"], np.int32),
        "scene": np.asarray(rows["scene"], np.int32),
    }


def even_problems(
    scenes: Mapping[str, tuple[np.ndarray, np.ndarray]], splits: Sequence[str], n: int, what: str
) -> dict[str, np.ndarray]:
    """:func:`scene_problems` of ``scenes`` cut evenly to ``n`` (rows round(i (P − 1) / (n − 1))):
    goals, goal_mask, target, split and scene. ``what`` names the scenes in the error when
    they hold fewer than ``n`` problems."""
    every = scene_problems(scenes, splits)
    total = every["target"].size
    if total < n:
        raise ValueError(f"problems: {what} have {total}, asked for {n}")
    pick = np.linspace(0, total - 1, n).round().astype(int)
    return {k: v[pick] for k, v in every.items()}


def true_labels(
    labeler: str,
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    *,
    beta: float | None = None,
    camera: str = "observer",
) -> Float[np.ndarray, "N 8"]:
    """The labels of planned paths ``xyz`` under the hand-crafted ``labeler`` at ``beta``
    (default: :data:`slotv_jax.labelers.DEFAULT_BETAS`, the datasets'), float32, compiled
    and batched (:func:`slotv_jax.labelers.label_all`)."""
    beta = labelers.DEFAULT_BETAS[labeler] if beta is None else beta
    kw = {f"beta_{labeler}": beta, "camera": camera, "labelers": (labeler,), "progress": False}
    return labelling.label_all(xyz, goals, goal_mask, **kw)[labeler]


def path_length(xyz: Float[np.ndarray, "... T 3"]) -> Float[np.ndarray, "..."]:
    """Length of each path, Σ_i ‖x_{i+1} − x_i‖ (m), in float64."""
    return np.linalg.norm(np.diff(np.asarray(xyz, np.float64), axis=-2), axis=-1).sum(-1)


def summarise(
    observer: str,
    labeler: str,
    y: Float[np.ndarray, " P"],
    y_straight: Float[np.ndarray, " P"],
    argmax_ok: Bool[np.ndarray, " P"],
    length_ratio: Float[np.ndarray, " P"],
    feasible: Bool[np.ndarray, " P"],
) -> dict:
    """One planner's row (:ref:`concepts-planning`'s ``planners``): its true y_target over the
    problems (mean, SD), how often the target is the labeler's argmax, the path length over the
    straight line's, feasibility, and the comparison with the straight line (mean gain, how
    often the plan lowered or raised y_target)."""
    y = np.asarray(y, np.float64)
    n = y.size
    return {
        "observer": observer,
        "labeler": labeler,
        "n": int(n),
        "mean_y_target": float(y.mean()),
        "sd_y_target": float(y.std(ddof=1)) if n > 1 else 0.0,
        "argmax_rate": float(np.mean(argmax_ok)),
        "length_ratio": float(np.mean(length_ratio)),
        "feasible_rate": float(np.mean(feasible)),
        "mean_gain": float(np.mean(y - y_straight)),
        "lowered_rate": float(np.mean(y < y_straight)),
        "raised_rate": float(np.mean(y > y_straight)),
    }


def plan_row(
    name: str,
    labeler: str,
    res,
    y_all: Float[np.ndarray, "P 8"],
    y_straight: Float[np.ndarray, " P"],
    len_straight: Float[np.ndarray, " P"],
    problems: Mapping[str, np.ndarray],
    splits: Sequence[str],
) -> dict:
    """:func:`summarise` of one planner's plans ``res`` (a batch of
    :class:`slotv_jax.planning.PlanResult`) with their true labels ``y_all``, plus what the
    planner itself saw (its own P(target) at the straight line and at its plan), the
    constraints of its worst plan and its mean y_target per split (``problems["split"]``
    indexes ``splits``)."""
    target = problems["target"]
    rows = np.arange(len(target))
    y = y_all[rows, target]
    d = res.diagnostics
    row = summarise(name, labeler, y, y_straight, y_all.argmax(-1) == target,
                    path_length(res.xyz) / len_straight, d.feasible)  # fmt: skip
    obj = np.asarray(d.objective)
    row["observer_p_target_straight"] = float(np.exp(obj[:, 0]).mean())
    row["observer_p_target_plan"] = float(np.exp(obj[rows, np.asarray(d.best_iter)]).mean())
    row["max_target_residual_m"] = float(np.max(d.target_residual))
    row["min_joint_margin_rad"] = float(np.min(d.joint_margin))
    row["min_table_clearance_m"] = float(np.min(d.table_clearance))
    row["max_cost_over_limit_m2"] = float(np.max(d.cost - d.cost_limit))
    row["by_split"] = {s: float(y[problems["split"] == i].mean()) for i, s in enumerate(splits)}
    return row


def gain_kept(mean_gain: float, oracle_gain: float) -> float | None:
    """The share of the oracle's gain over the straight line that a planner keeps (None
    where the oracle gains nothing)."""
    return mean_gain / oracle_gain if oracle_gain > 0 else None


def population_scorer(pop: people_lib.People, taus: Sequence[float], n_points: int, n_eval: int):
    """``score(keys (B,), xyz (B, T, 3), goals (B, 8, 3), mask (B, 8), target (B,)) ->
    (p (B, K), correct (B, K))``: the population's P_pop(target | ξ_{0:τ}) at each of the K
    stop times, and the fraction of ``n_eval`` fresh participants per (path, τ) who guessed
    the target (:func:`slotv_jax.observers.population.sample_guesses` with
    ``split(key, K)[τ]``). The programs take the population as an argument
    (:func:`slotv_jax.observers.population.quadrature`, ``sample_guesses_batch``): they
    compile once for every population. A zoo member (:mod:`slotv_jax.observers.zoo`) is
    scored the same way by its own P and its own people (a program per member)."""
    seen = jnp.asarray(seen_points(taus, n_points))
    if isinstance(pop, zoo.ZooMember):
        probs = functools.partial(_zoo_target_probs, pop)
    else:
        probs = functools.partial(_target_probs, population_lib.quadrature(pop))
    k = int(seen.shape[0])

    def score(keys, xyz, goals, mask, target):
        p = probs(xyz, goals, mask, target, seen)
        b = int(xyz.shape[0])
        keys = jax.vmap(lambda key: jax.random.split(key, k))(keys).reshape(-1)  # (B K,)
        each = lambda a: jnp.repeat(jnp.asarray(a), k, axis=0)  # noqa: E731
        guess = people_lib.guesses_batch(
            pop, keys, each(xyz), each(goals), each(mask), jnp.tile(seen, b), n_eval
        )
        correct = jnp.mean(guess == each(target)[:, None], axis=-1).reshape(b, k)
        return p, correct

    return score


@jax.jit
def _target_probs(quad, xyz, goals, mask, target, seen):
    """P_pop(target | ξ_{0:L}) (B, K) of B paths at the K ``seen`` points."""

    def one(x, g, m, tgt):
        return jax.vmap(lambda s: population_lib.population_probs(quad, x, g, m, s))(seen)[:, tgt]

    return jax.vmap(one)(xyz, goals, mask, target)


@functools.partial(jax.jit, static_argnums=0)
def _zoo_target_probs(member, xyz, goals, mask, target, seen):
    """A zoo member's P(target | ξ_{0:L}) (B, K) of B paths at the K ``seen`` points."""

    def one(x, g, m, tgt):
        return jax.vmap(lambda s: zoo.zoo_probs(member, x, g, m, s))(seen)[:, tgt]

    return jax.vmap(one)(xyz, goals, mask, target)


def population_scores(
    scorer,
    keys: jax.Array,
    xyz: Float[Array, "R P T 3"],
    goals: Float[Array, "R P 8 3"],
    goal_mask: Bool[Array, "R P 8"],
    target: Int[Array, "R P"],
) -> dict[str, np.ndarray]:
    """Runs × problems of paths scored by a :func:`population_scorer`, one key per run
    (each run's problems get ``split(key, P)``): ``score`` (R,) the mean P_pop over problems
    and τ, ``per_tau`` (R, K) and the evaluation study's ``correct`` (R,)."""
    r, n = xyz.shape[:2]
    flat = lambda a: a.reshape((-1, *a.shape[2:]))  # noqa: E731
    p, correct = scorer(
        jax.vmap(lambda k: jax.random.split(k, n))(keys).reshape(-1),
        flat(xyz),
        flat(goals),
        flat(goal_mask),
        flat(target),
    )
    p = np.asarray(p, np.float64).reshape(r, n, -1)
    correct = np.asarray(correct, np.float64).reshape(r, n, -1)
    return {"score": p.mean((1, 2)), "per_tau": p.mean(1), "correct": correct.mean((1, 2))}


def wilson(k: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The 95 % Wilson score interval of a proportion k / n (Wilson 1927):
    (p + z²/2n ± z √(p(1 − p)/n + z²/4n²)) / (1 + z²/n)."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    c = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    d = 1 + z * z / n
    return ((p + z * z / (2 * n) - c) / d, (p + z * z / (2 * n) + c) / d)
