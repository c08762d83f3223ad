"""Rounds of plans: after the first round of dataset motions, a share of every later
round's stimuli are the planner's own motions.

An observer fitted on answers about random dataset motions is asked, when it plans, about
motions unlike any of them: the planner climbs where the fit is least constrained. Asking
people about the optimiser's own outputs is how a learned reward is kept honest (Christiano
et al. 2017; Sadigh et al. 2017; Ross et al. 2011, DAgger). So, with ``plan_share`` > 0
(:class:`~slotv_jax.experiments.people_loop.config.LoopConfig`), after each size but the
last every run plans the *study problems* with each candidate family and with the pick
(every real goal of the ``train`` split's scenes, cut evenly to ``problems``: scenes the
study may show, never those of the held-out evaluation problems), and the next round asks
``round(plan_share · k)`` of its ``k`` stimuli about those plans, each up to one of the
study's stop times. The plans are drawn without replacement, the families in turn, so every
family's plans and every problem are asked about; the rest of the round are dataset
motions (drawn as the run's strategy draws them). Every answer, of every round, counts in
the budget ``sizes``.

Plans join the pool as motions of their own (:class:`PlanSlots`): the pool holds, after
the dataset's motions, one block of motions for each (run, later round), written once, just
before the round that asks about them, so a stimulus' answers never change once drawn.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from jaxtyping import Float

from slotv_jax.asking import selection
from slotv_jax.planning import evaluation

STUDY_SPLIT = "train"  # the scenes a study may show: the dataset's training scenes


def study_problems(problems: int, splits) -> dict[str, np.ndarray]:
    """Every (scene, real goal) of the ``train`` split's scenes
    (:func:`slotv_jax.planning.evaluation.scene_problems`), cut evenly to ``problems``:
    goals (P, 8, 3), goal_mask (P, 8), target (P,) and scene (P,: the train split's
    scene index). The study's own problems, which rounds of plans ask about."""
    s = splits[STUDY_SPLIT]
    scenes = {STUDY_SPLIT: (s.scene_goals, s.scene_mask)}
    got = evaluation.even_problems(scenes, [STUDY_SPLIT], problems, "the study's scenes")
    return {k: got[k] for k in ("goals", "goal_mask", "target", "scene")}


def resample_time(xyz: Float[np.ndarray, "*B n 3"], t: int) -> Float[np.ndarray, "*B t 3"]:
    """Paths sampled at ``n`` uniform times resampled to ``t`` uniform times by linear
    interpolation in time, ξ'(i / (t − 1)) = ξ(s) at s = i (n − 1) / (t − 1) (not by arc
    length: when a point is reached is what an observer of a prefix sees)."""
    xyz = np.asarray(xyz, np.float32)
    n = xyz.shape[-2]
    if n == t:
        return xyz
    s = np.linspace(0.0, n - 1, t)
    lo = np.minimum(np.floor(s).astype(int), n - 2)
    w = (s - lo)[:, None].astype(np.float32)
    return xyz[..., lo, :] * (1 - w) + xyz[..., lo + 1, :] * w


@dataclasses.dataclass(frozen=True)
class PlanSlots:
    """Where the plans of each (run, later round) live in the pool: motions ``start +
    ((run · rounds + round) · F + f) · P + p`` for family f of ``families`` and study
    problem p (P problems, one scene each)."""

    start: int  # the first plan motion (the dataset's motions come first)
    families: tuple[str, ...]  # the planned families, in order
    scenes: tuple[int, ...]  # each study problem's scene (the train split's index)
    runs: int
    rounds: int  # later rounds (those that may ask about plans)
    n_taus: int  # candidates per motion

    @property
    def problems(self) -> int:
        """P, the study problems planned per family."""
        return len(self.scenes)

    @property
    def per_block(self) -> int:
        return len(self.families) * self.problems

    @property
    def motions(self) -> int:
        return self.runs * self.rounds * self.per_block

    def block(self, run: int, rnd: int) -> np.ndarray:
        """The motions of ``run``'s plans asked about in later round ``rnd`` (0-based)."""
        first = self.start + (run * self.rounds + rnd) * self.per_block
        return np.arange(first, first + self.per_block)

    def describe(self, motion: int) -> tuple[str, int] | None:
        """(family, study problem) of a plan motion; None for a dataset motion."""
        if motion < self.start:
            return None
        off = (motion - self.start) % self.per_block
        return self.families[off // self.problems], off % self.problems

    def draw(self, run: int, rnd: int, k: int, rng: np.random.Generator) -> np.ndarray:
        """``k`` candidates of the block's plans, without replacement, the families in
        turn (each family's candidates shuffled: every problem and stop time of it before
        any again)."""
        cap = self.per_block * self.n_taus
        if not 0 <= k <= cap:
            raise ValueError(f"k: expected 0..{cap} plan stimuli for a round, got {k}")
        motions = self.block(run, rnd).reshape(len(self.families), self.problems)
        per_family = [
            rng.permutation((m[:, None] * self.n_taus + np.arange(self.n_taus)).ravel())
            for m in motions
        ]
        interleaved = np.stack(per_family, 1).ravel()  # family 0, 1, …, then again
        return interleaved[:k].astype(np.int32)


def extend_pool(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N G 3"],
    mask: np.ndarray,
    taus: Sequence[float],
    slots: PlanSlots,
    study: dict[str, np.ndarray],
    placeholder: Float[np.ndarray, "P T 3"],
) -> selection.Pool:
    """The pool of the dataset's motions followed by ``slots``' plan motions: each holds
    its study problem's goals and, until its plans are written (:func:`write_plans`), the
    problem's ``placeholder`` path (the straight line), which no round asks about."""
    g = goals.shape[1]
    reps = slots.motions // slots.problems
    pg = np.tile(study["goals"][:, :g], (reps, 1, 1))
    pm = np.tile(study["goal_mask"][:, :g], (reps, 1))
    px = np.tile(placeholder, (reps, 1, 1))
    return selection.make_pool(
        np.concatenate([xyz, px]), np.concatenate([goals, pg]), np.concatenate([mask, pm]), taus
    )


def write_plans(
    pool: selection.Pool, slots: PlanSlots, run: int, rnd: int, plans: dict[str, np.ndarray]
) -> selection.Pool:
    """``pool`` with ``run``'s plans for later round ``rnd`` written into its block
    (``plans``: family -> paths (P, n, 3), resampled in time to the pool's T)."""
    t = pool.xyz.shape[1]
    new = np.concatenate([resample_time(plans[f], t) for f in slots.families])
    xyz = pool.xyz.at[slots.block(run, rnd)].set(new)
    return pool._replace(xyz=xyz)
