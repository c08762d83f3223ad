"""Observers learned from people: study data, training on goal guesses, cross-validation.

In a legibility study participants watch a motion, often stopped part-way, and guess
the goal (Dragan et al., HRI 2013; Wallkötter et al. 2022, §III-A and §VI). This module
stores such answers, trains SLOT-V and T-REX on them, and cross-validates the result
against the hand-crafted observers.

The study format
----------------
One ``.npz`` file (read with ``allow_pickle=False``; written atomically) holding:

==========================  =============  =============================================
array                       shape, dtype   meaning
==========================  =============  =============================================
``format``                  () str         ``"slotv_jax.study/1"``
``xyz``                     (N, T, 3) f32  trajectory points (m), padded after ``length``
``length``                  (N,) i32       points of each trajectory, 2 ≤ length ≤ T
``t`` (optional)            (N, T) f64     time stamps (any unit), strictly increasing
``goals``                   (N, 8, 3) f32  goals (m) per trajectory, or (8, 3) shared
``goal_mask``               (N, 8) bool    real goal slots (1-8, first), or (8,) shared
``goal_names`` (optional)   (N, 8) or (8,) goal names (str, '' on padded slots)
``trajectory_ids``          (N,) str       the trajectories' ids in the source tables
``answer_trajectory``       (A,) i32       trajectory of each answer row
``answer_tau``              (A,) f64       the participant saw points with t_i ≤ τ
``counts``                  (A, 8) f64     guesses per goal slot (integers ≥ 0)
``answer_condition`` (opt)  (A,) i32       index into ``conditions`` (viewpoint, ...)
``conditions`` (optional)   (C,) str       condition names
==========================  =============  =============================================

An *answer row* is one (trajectory, τ, condition) shown to one or more participants:
``counts[a, k]`` of them guessed goal k. Instead of ``counts`` a file may hold
``probs (A, 8)`` and ``n_answers (A,)`` (the share of each goal and the number of
participants); then counts = probs · n_answers, which need not be integers. τ is in the
unit of ``t`` (normalised time t_i = i / (length − 1) when there is no ``t``); a row sees
the points with t_i ≤ τ, at least two of them; τ = t_{length−1} is the whole motion.

Importing study tables
----------------------
``python -m slotv_jax.study import --trajectories T --goals G --answers A --out study.npz``
reads three tables, each a CSV file with a header (UTF-8; a spreadsheet's byte-order
mark is fine) or a JSON list of objects with the same keys (one object per row):

- trajectories: ``trajectory, x, y, z`` and optionally ``t``; one row per point, in
  time order within each trajectory (any T ≥ 2; trajectories may differ in length);
  ``t`` is all-or-nothing: every point of every trajectory has one, or the column is
  left out;
- goals: ``goal, x, y, z`` (shared by every trajectory) or ``trajectory, goal, x, y, z``
  (per trajectory); 1-8 goals each, slots in order of appearance;
- answers: ``trajectory, guess`` (a goal name) and optionally ``tau`` (empty: the whole
  motion), ``participant``, ``condition`` and ``count`` (how many participants gave this
  answer; default 1). One row per answer.

Every error is a ``ValueError`` naming the file, the line (CSV) or item (JSON) or array
row, and the field.

Training
--------
The observer's probability of goal k for answer row a is p_ak = softmax_k(s_a), with
the scores integrated only over the points the participant saw (L_a of them):

- SLOT-V:  s_ak = (1/L_a) Σ_{i<L_a} V(p_i, g_k)  (the mean of V over the seen points);
- T-REX:   s_ak = Σ_{i<L_a} r(p_i, g_k)  (the return of the seen points; the guess is a
  Plackett-Luce first choice among the goals' returns, the K-goal form of T-REX's
  Bradley-Terry preference σ(R₂ − R₁), Brown et al. 2019).

The loss is the multinomial negative log-likelihood of the counts, per answer::

    L = −Σ_a Σ_k c_ak log p_ak / Σ_a n_a,     n_a = Σ_k c_ak,

i.e. the cross-entropy against the answer shares c_a / n_a weighted by n_a. Minibatches
of B rows use −Σ_{a∈batch} Σ_k c_ak log p_ak / (B · n̄), n̄ the mean answers per row, an
unbiased estimate of L (with one answer per row, the plain cross-entropy against one-hot
labels). Points after τ never reach the network (they are replaced by the first point
and weighted 0), so they change neither the loss nor its gradient.

>>> study = load_study("study.npz")                                   # doctest: +SKIP
>>> cfg = config.quick("slotv")
>>> state = train_study(cfg, study, jax.random.key(0))                # doctest: +SKIP
>>> cross_validate(cfg, study, folds=5)["slotv"]["nll_per_answer"]    # doctest: +SKIP
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import io
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P
from jaxtyping import Array, Bool, Float, Int
from tqdm.auto import tqdm

from slotv_jax import checkpoint, cli, fileio, labelers, models, scene, validation
from slotv_jax import config as config_lib
from slotv_jax import train as train_lib
from slotv_jax.config import TrainConfig
from slotv_jax.fileio import atomic_write, write_text
from slotv_jax.validation import G_MAX

FORMAT = "slotv_jax.study/1"
TAU_RTOL = 1e-9  # τ within this fraction of the motion's duration of t_i counts as t_i
PROB_FLOOR = 1e-12  # labeler probabilities are floored here in log-likelihoods (float32)
BETA_RANGE = 100.0  # β is fitted within [β₀ / BETA_RANGE, β₀ · BETA_RANGE]

# ============================================================== the format


@dataclasses.dataclass(frozen=True)
class Study:
    """A validated study: N trajectories (padded to T points) and A answer rows.

    Build it with :func:`make_study`, :func:`load_study` or :func:`read_tables`; they check
    every field (the constructor itself does not).
    """

    xyz: np.ndarray  # (N, T, 3) float32: points (m); zeros after length[n]
    length: np.ndarray  # (N,) int32: points of each trajectory, >= 2
    goals: np.ndarray  # (N, 8, 3) float32: goals (m); zeros on padded slots
    goal_mask: np.ndarray  # (N, 8) bool: real goal slots, real goals first
    answer_trajectory: np.ndarray  # (A,) int32: trajectory of each answer row
    answer_tau: np.ndarray  # (A,) float64: seen points are those with t_i <= tau
    counts: np.ndarray  # (A, 8) float64: guesses per goal slot
    t: np.ndarray | None = None  # (N, T) float64: time stamps (None: i / (length − 1))
    answer_condition: np.ndarray | None = None  # (A,) int32: index into conditions
    conditions: tuple[str, ...] = ()  # condition names
    trajectory_ids: tuple[str, ...] = ()  # (N,) ids from the source tables
    goal_names: np.ndarray | None = None  # (N, 8) str array ('' on padding; numpy.str_ items)
    shared_goals: bool = False  # every trajectory has the same goals (stored once)

    @property
    def n_trajectories(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def n_rows(self) -> int:
        """Answer rows (trajectory × τ × condition)."""
        return int(self.counts.shape[0])

    @property
    def n_answers(self) -> float:
        """Total answers (participants' guesses)."""
        return float(self.counts.sum())

    def times(self) -> np.ndarray:
        """(N, T) float64 time of every point (normalised i / (length − 1) without ``t``)."""
        if self.t is not None:
            return self.t
        i = np.arange(self.xyz.shape[1], dtype=np.float64)
        return i[None, :] / (self.length[:, None] - 1.0)

    def seen(self) -> np.ndarray:
        """(A,) int32: points each answer row's participants saw (t_i ≤ τ, i < length)."""
        return _seen_points(self.times(), self.length, self.answer_trajectory, self.answer_tau)

    def full_tau(self) -> np.ndarray:
        """(N,) float64: τ of the whole motion (the time of the last point)."""
        return self.times()[np.arange(self.n_trajectories), self.length - 1]

    def select_rows(self, rows) -> Study:
        """The answer rows ``rows`` (index or boolean mask); trajectories without a row left
        are dropped and the rest renumbered."""
        rows = np.asarray(rows)
        if rows.dtype == bool:
            rows = np.flatnonzero(rows)
        keep = np.unique(self.answer_trajectory[rows])
        new_index = np.full(self.n_trajectories, -1, np.int32)
        new_index[keep] = np.arange(keep.size, dtype=np.int32)
        per = {
            "xyz": self.xyz[keep],
            "length": self.length[keep],
            "goals": self.goals[keep],
            "goal_mask": self.goal_mask[keep],
            "t": None if self.t is None else self.t[keep],
            "goal_names": None if self.goal_names is None else self.goal_names[keep],
            "trajectory_ids": tuple(self.trajectory_ids[i] for i in keep)
            if self.trajectory_ids
            else (),
        }
        cond = None if self.answer_condition is None else self.answer_condition[rows]
        return dataclasses.replace(
            self,
            **per,
            answer_trajectory=new_index[self.answer_trajectory[rows]],
            answer_tau=self.answer_tau[rows],
            counts=self.counts[rows],
            answer_condition=cond,
        )

    def select_trajectories(self, idx) -> Study:
        """The answer rows of the trajectories ``idx`` (index array)."""
        return self.select_rows(np.isin(self.answer_trajectory, np.asarray(idx)))

    def select_condition(self, name: str) -> Study:
        """The answer rows of condition ``name``."""
        if name not in self.conditions or self.answer_condition is None:
            raise ValueError(f"condition: expected one of {list(self.conditions)}, got {name!r}")
        return self.select_rows(self.answer_condition == self.conditions.index(name))

    def summary(self) -> str:
        """One paragraph: sizes, goals, prefixes, conditions."""
        n_goals = self.goal_mask.sum(-1)
        seen = self.seen()
        full = seen == self.length[self.answer_trajectory]
        per_row = self.counts.sum(-1)
        lines = [
            f"{self.n_trajectories} trajectories of {self.length.min()}-{self.length.max()} "
            f"points{' with time stamps' if self.t is not None else ''}; "
            f"{'shared' if self.shared_goals else 'per-trajectory'} goals, "
            f"{n_goals.min()}-{n_goals.max()} per trajectory",
            f"{self.n_rows} answer rows ({int(full.sum())} whole motions, "
            f"{int((~full).sum())} prefixes), {self.n_answers:g} answers "
            f"({per_row.min():g}-{per_row.max():g} per row)",
        ]
        if self.conditions:
            c = np.bincount(self.answer_condition, minlength=len(self.conditions))
            lines.append(
                "conditions: "
                + ", ".join(f"{n} ({k} rows)" for n, k in zip(self.conditions, c, strict=True))
            )
        return "\n".join(lines)


def _seen_points(times, length, traj, tau) -> np.ndarray:
    t = times[traj]  # (A, T)
    t0 = t[:, 0]
    t_end = t[np.arange(t.shape[0]), length[traj] - 1]
    tol = TAU_RTOL * (t_end - t0)
    inside = (t <= (tau + tol)[:, None]) & (np.arange(t.shape[1]) < length[traj][:, None])
    return inside.sum(-1).astype(np.int32)


class _Where:
    """Names a place in an input: the file, and a line/item/row and field."""

    def __init__(self, source: str):
        self.source = source

    def __call__(self, field: str, row: str | int | None = None) -> str:
        where = self.source
        if row is not None:
            where += f", {row if isinstance(row, str) else f'row {row}'}"
        return f"{where}, field {field!r}"


def make_study(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"] | Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "N 8"] | Bool[np.ndarray, "8"],
    answer_trajectory: Int[np.ndarray, " A"],
    counts: Float[np.ndarray, "A 8"] | None = None,
    *,
    length: Int[np.ndarray, " N"] | None = None,
    answer_tau: Float[np.ndarray, " A"] | None = None,
    probs: Float[np.ndarray, "A 8"] | None = None,
    n_answers: Float[np.ndarray, " A"] | None = None,
    t: Float[np.ndarray, "N T"] | None = None,
    answer_condition: Int[np.ndarray, " A"] | None = None,
    conditions: Sequence[str] = (),
    trajectory_ids: Sequence[str] = (),
    goal_names=None,
    source: str = "study",
) -> Study:
    """A validated :class:`Study` from arrays (see the module docstring for the fields).

    ``length`` defaults to T for every trajectory; ``answer_tau`` to the whole motion.
    Give ``counts`` (integers ≥ 0) or ``probs`` with ``n_answers``. Raises ValueError,
    naming ``source``, the field and the row, on: ragged arrays that disagree, T < 2,
    NaN/inf, more than 8 or no goals, goals on one position, negative or non-integer
    counts, answers for padded goals, rows or trajectories with no answers, τ outside the
    motion (or seeing fewer than 2 points), unknown trajectory or condition indices.

    >>> import numpy as np
    >>> xyz = np.linspace([0.3, 0.0, 0.5], [0.5, 0.2, 0.0], 50)[None]
    >>> goals = np.zeros((8, 3)); goals[:2] = [[0.5, 0.2, 0.0], [0.5, -0.2, 0.0]]
    >>> s = make_study(xyz, goals, np.arange(8) < 2, [0], [[7, 1, 0, 0, 0, 0, 0, 0]])
    >>> s.n_answers, int(s.seen()[0])
    (8.0, 50)
    """
    w = _Where(source)
    xyz = _float_array(xyz, "xyz", w, np.float32)
    if xyz.ndim != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"{w('xyz')}: expected shape (N, T, 3), got {xyz.shape}")
    n, t_max = xyz.shape[:2]
    if n < 1:
        raise ValueError(f"{w('xyz')}: expected at least 1 trajectory")
    if length is None:
        length = np.full(n, t_max)
    length = _int_array(length, "length", w)
    _check_rows("length", length, (n,), w, "one per trajectory of 'xyz'")
    bad = np.flatnonzero(length < 2)
    if bad.size:
        raise ValueError(
            f"{w('length', int(bad[0]))}: expected at least 2 points (T >= 2), "
            f"got {int(length[bad[0]])}"
        )
    bad = np.flatnonzero(length > t_max)
    if bad.size:
        raise ValueError(
            f"{w('length', int(bad[0]))}: {int(length[bad[0]])} points, but 'xyz' holds only "
            f"{t_max} per trajectory (ragged arrays disagree)"
        )
    real = np.arange(t_max)[None, :] < length[:, None]  # (N, T)
    _check_finite_where(xyz, real[..., None], "xyz", w)
    xyz = np.where(real[..., None], xyz, 0.0).astype(np.float32)

    if t is not None:
        t = _float_array(t, "t", w, np.float64)
        _check_rows("t", t, (n, t_max), w, "the shape of 'xyz' without its last axis")
        _check_finite_where(t, real, "t", w)
        t = np.where(real, t, 0.0)
        steps = np.diff(t, axis=1) > 0
        bad = np.argwhere(~steps & real[:, 1:])
        if bad.size:
            i, j = (int(v) for v in bad[0])
            raise ValueError(
                f"{w('t', i)}: expected strictly increasing time stamps, "
                f"t[{j + 1}] = {t[i, j + 1]!r} <= t[{j}] = {t[i, j]!r}"
            )

    goals = _float_array(goals, "goals", w, np.float32)
    goal_mask = np.asarray(goal_mask)
    shared = goals.ndim == 2
    if shared:
        _check_rows("goals", goals, (G_MAX, 3), w, f"({G_MAX}, 3) shared or (N, {G_MAX}, 3)")
        _check_rows("goal_mask", goal_mask, (G_MAX,), w, f"({G_MAX},) like shared 'goals'")
        goals = np.broadcast_to(goals, (n, G_MAX, 3))
        goal_mask = np.broadcast_to(goal_mask, (n, G_MAX))
    else:
        _check_rows("goals", goals, (n, G_MAX, 3), w, f"(N, {G_MAX}, 3), one per trajectory")
        _check_rows("goal_mask", goal_mask, (n, G_MAX), w, f"(N, {G_MAX})")
    if goal_mask.dtype != bool:
        if not np.all((goal_mask == 0) | (goal_mask == 1)):
            raise ValueError(f"{w('goal_mask')}: expected booleans (or 0/1)")
        goal_mask = goal_mask.astype(bool)
    for i in range(n):
        m = goal_mask[i]
        if not m.any():
            raise ValueError(f"{w('goal_mask', i)}: expected 1-{G_MAX} real goals, found none")
        if m.sum() < G_MAX and m[int(m.sum()) :].any():
            raise ValueError(f"{w('goal_mask', i)}: expected the real goals in the first slots")
    _check_finite_where(goals, goal_mask[..., None], "goals", w)
    d = np.linalg.norm(goals[:, :, None].astype(np.float64) - goals[:, None], axis=-1)
    same = np.argwhere(goal_mask[:, :, None] & goal_mask[:, None] & (d < 1e-9))
    same = same[same[:, 1] < same[:, 2]]
    if same.size:
        i, a, b = (int(v) for v in same[0])
        raise ValueError(f"{w('goals', i)}: real goal slots {a} and {b} share one position")
    goals = np.where(goal_mask[..., None], goals, 0.0).astype(np.float32)
    if goal_names is not None:
        goal_names = np.asarray(goal_names, str)
        goal_names = np.broadcast_to(goal_names, (n, G_MAX)) if shared else goal_names
        _check_rows("goal_names", goal_names, (n, G_MAX), w, "the shape of 'goal_mask'")

    traj = _int_array(answer_trajectory, "answer_trajectory", w)
    if traj.ndim != 1:
        raise ValueError(f"{w('answer_trajectory')}: expected shape (A,), got {traj.shape}")
    a_rows = traj.shape[0]
    bad = np.flatnonzero((traj < 0) | (traj >= n))
    if bad.size:
        raise ValueError(
            f"{w('answer_trajectory', int(bad[0]))}: unknown trajectory {int(traj[bad[0]])} "
            f"(expected 0..{n - 1})"
        )
    if counts is None:
        if probs is None or n_answers is None:
            raise ValueError(f"{w('counts')}: give 'counts', or 'probs' with 'n_answers'")
        probs = _float_array(probs, "probs", w, np.float64)
        _check_rows("probs", probs, (a_rows, G_MAX), w, "(A, 8), one per answer row")
        _check_finite_where(probs, np.ones(probs.shape, bool), "probs", w)
        n_answers = _float_array(n_answers, "n_answers", w, np.float64)
        _check_rows("n_answers", n_answers, (a_rows,), w, "one per answer row")
        _check_finite_where(n_answers, np.ones(a_rows, bool), "n_answers", w)
        bad = np.flatnonzero(~(n_answers > 0))
        if bad.size:
            raise ValueError(f"{w('n_answers', int(bad[0]))}: expected a number > 0")
        _check_counts(probs, "probs", w, integer=False)
        sums = probs.sum(-1)
        bad = np.flatnonzero(np.abs(sums - 1.0) > 1e-4)
        if bad.size:
            raise ValueError(
                f"{w('probs', int(bad[0]))}: expected shares summing to 1, got {sums[bad[0]]:.6g}"
            )
        counts = probs * n_answers[:, None]
        count_field = "probs"
    else:
        counts = _float_array(counts, "counts", w, np.float64)
        _check_rows("counts", counts, (a_rows, G_MAX), w, "(A, 8), one per answer row")
        _check_finite_where(counts, np.ones(counts.shape, bool), "counts", w)
        _check_counts(counts, "counts", w, integer=True)
        count_field = "counts"
    padded = np.argwhere((counts > 0) & ~goal_mask[traj])
    if padded.size:
        a, k = (int(v) for v in padded[0])
        raise ValueError(
            f"{w(count_field, a)}: {counts[a, k]:g} answers for padded goal slot {k} "
            f"(trajectory {int(traj[a])} has {int(goal_mask[traj[a]].sum())} goals)"
        )
    empty = np.flatnonzero(counts.sum(-1) <= 0)
    if empty.size:
        raise ValueError(f"{w(count_field, int(empty[0]))}: an answer row with no answers")
    no_answers = np.setdiff1d(np.arange(n), traj)
    if no_answers.size:
        i = int(no_answers[0])
        name = f" ({trajectory_ids[i]!r})" if trajectory_ids else ""
        raise ValueError(
            f"{w('answer_trajectory')}: trajectory {i}{name} has no answers "
            f"({no_answers.size} trajectories without answers)"
        )

    times = t if t is not None else np.arange(t_max)[None, :] / (length[:, None] - 1.0)
    full = times[np.arange(n), length - 1]
    if answer_tau is None:
        tau = full[traj].astype(np.float64)
    else:
        tau = _float_array(answer_tau, "answer_tau", w, np.float64)
        _check_rows("answer_tau", tau, (a_rows,), w, "one per answer row")
        _check_finite_where(tau, np.ones(a_rows, bool), "answer_tau", w)
    seen = _seen_points(times, length, traj, tau)
    tol = TAU_RTOL * (full - times[:, 0])
    bad = np.flatnonzero((tau > full[traj] + tol[traj]) | (seen < 2))
    if bad.size:
        a = int(bad[0])
        i = int(traj[a])
        raise ValueError(
            f"{w('answer_tau', a)}: tau = {float(tau[a])!r} is outside the motion of trajectory "
            f"{i}: expected {float(times[i, 1])!r} <= tau <= {float(full[i])!r} (at least 2 "
            "points seen, "
            "at most the whole motion)"
        )

    cond = None
    conditions = tuple(str(c) for c in conditions)
    if answer_condition is not None:
        cond = _int_array(answer_condition, "answer_condition", w)
        _check_rows("answer_condition", cond, (a_rows,), w, "one per answer row")
        bad = np.flatnonzero((cond < 0) | (cond >= len(conditions)))
        if bad.size:
            raise ValueError(
                f"{w('answer_condition', int(bad[0]))}: unknown condition {int(cond[bad[0]])} "
                f"(expected an index into 'conditions', {len(conditions)} names)"
            )
    elif conditions:
        raise ValueError(f"{w('conditions')}: names given without 'answer_condition'")
    trajectory_ids = tuple(str(s) for s in trajectory_ids)
    if trajectory_ids and len(trajectory_ids) != n:
        raise ValueError(
            f"{w('trajectory_ids')}: expected {n} ids (one per trajectory), "
            f"got {len(trajectory_ids)}"
        )
    return Study(
        xyz=xyz,
        length=length.astype(np.int32),
        goals=np.ascontiguousarray(goals),
        goal_mask=np.ascontiguousarray(goal_mask),
        answer_trajectory=traj.astype(np.int32),
        answer_tau=tau,
        counts=counts,
        t=t,
        answer_condition=None if cond is None else cond.astype(np.int32),
        conditions=conditions,
        trajectory_ids=trajectory_ids or tuple(str(i) for i in range(n)),
        goal_names=None if goal_names is None else np.ascontiguousarray(goal_names),
        shared_goals=bool(shared),
    )


def _float_array(x, name, w, dtype) -> np.ndarray:
    try:
        a = np.asarray(x)
    except ValueError as e:  # ragged nested lists
        raise ValueError(f"{w(name)}: expected a rectangular array of numbers ({e})") from e
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{w(name)}: expected numbers, got dtype {a.dtype}")
    return a.astype(dtype)


def _int_array(x, name, w) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype.kind == "f":
        bad = np.flatnonzero(~np.isfinite(a) | (a != np.round(a)))
        if bad.size:
            raise ValueError(f"{w(name, int(bad[0]))}: expected an integer, got {a.flat[bad[0]]}")
    elif a.dtype.kind not in "biu":
        raise ValueError(f"{w(name)}: expected integers, got dtype {a.dtype}")
    return a.astype(np.int64)


def _check_rows(name, a, shape, w, what) -> None:
    if np.shape(a) != tuple(shape):
        raise ValueError(
            f"{w(name)}: expected shape {tuple(shape)} ({what}), got {np.shape(a)} "
            "(arrays disagree)"
        )


def _check_finite_where(a, where, name, w) -> None:
    bad = np.argwhere(~np.isfinite(a) & np.broadcast_to(where, a.shape))
    if bad.size:
        idx = tuple(int(v) for v in bad[0])
        raise ValueError(
            f"{w(name, idx[0])}: expected finite values, found {a[idx]} at index {list(idx)}"
        )


def _check_counts(c, name, w, *, integer: bool) -> None:
    bad = np.argwhere(c < 0)
    if bad.size:
        a, k = (int(v) for v in bad[0])
        raise ValueError(f"{w(name, a)}: expected values >= 0, got {c[a, k]:g} for slot {k}")
    if integer:
        bad = np.argwhere(c != np.round(c))
        if bad.size:
            a, k = (int(v) for v in bad[0])
            raise ValueError(
                f"{w(name, a)}: expected whole numbers of answers, got {c[a, k]!r} for slot {k}"
            )


# ---------------------------------------------------------------- file I/O


def save_study(path: str | os.PathLike, study: Study) -> Path:
    """Write ``study`` as one ``.npz`` (atomically: a reader never sees a partial file)."""
    path = Path(path)
    n = study.n_trajectories
    arrays: dict[str, np.ndarray] = {
        "format": np.array(FORMAT),
        "xyz": study.xyz.astype(np.float32),
        "length": study.length.astype(np.int32),
        "goals": (study.goals[0] if study.shared_goals else study.goals).astype(np.float32),
        "goal_mask": study.goal_mask[0] if study.shared_goals else study.goal_mask,
        "trajectory_ids": np.array(study.trajectory_ids or [str(i) for i in range(n)], str),
        "answer_trajectory": study.answer_trajectory.astype(np.int32),
        "answer_tau": study.answer_tau.astype(np.float64),
        "counts": study.counts.astype(np.float64),
    }
    if study.t is not None:
        arrays["t"] = study.t.astype(np.float64)
    if study.goal_names is not None:
        arrays["goal_names"] = study.goal_names[0] if study.shared_goals else study.goal_names
    if study.answer_condition is not None:
        arrays["answer_condition"] = study.answer_condition.astype(np.int32)
        arrays["conditions"] = np.array(study.conditions, str)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
    return path


_NPZ_FIELDS = {
    "xyz", "length", "t", "goals", "goal_mask", "goal_names", "trajectory_ids",
    "answer_trajectory", "answer_tau", "counts", "probs", "n_answers", "answer_condition",
    "conditions", "format",
}  # fmt: skip


def load_study(path: str | os.PathLike) -> Study:
    """Read and validate a study ``.npz`` (no pickle). Raises ValueError naming the file,
    the field and the row on anything :func:`make_study` rejects, a corrupt file, or
    unknown or missing arrays."""
    path = Path(path)
    w = _Where(str(path))
    arrays = fileio.load_npz(path)  # names a missing, truncated or non-zip file
    fmt = str(arrays.pop("format", ""))
    if fmt != FORMAT:
        raise ValueError(f"{w('format')}: expected {FORMAT!r}, got {fmt!r}")
    unknown = sorted(set(arrays) - _NPZ_FIELDS)
    if unknown:
        raise ValueError(f"{w(unknown[0])}: unknown array (known: {sorted(_NPZ_FIELDS)})")
    for req in ("xyz", "goals", "goal_mask", "answer_trajectory"):
        if req not in arrays:
            raise ValueError(f"{w(req)}: missing")
    cond_names = arrays.pop("conditions", None)
    ids = arrays.pop("trajectory_ids", None)
    return make_study(
        arrays.pop("xyz"),
        arrays.pop("goals"),
        arrays.pop("goal_mask"),
        arrays.pop("answer_trajectory"),
        arrays.pop("counts", None),
        conditions=() if cond_names is None else [str(c) for c in cond_names],
        trajectory_ids=() if ids is None else [str(c) for c in ids],
        source=str(path),
        **arrays,
    )


# ------------------------------------------------------------ table import


@dataclasses.dataclass
class _Table:
    path: Path
    rows: list[dict[str, Any]]
    where: list[str]  # "line 5" (CSV) or "item 3" (JSON) per row
    columns: list[str]

    def at(self, i: int, field: str) -> str:
        return f"{self.path.name}, {self.where[i]}, field {field!r}"


def _read_table(path: str | os.PathLike, required: Sequence[str]) -> _Table:
    path = Path(path)
    if path.suffix.lower() == ".json":
        doc = fileio.read_json(path)  # names the file, line and column of bad JSON
        if not isinstance(doc, list) or not all(isinstance(r, dict) for r in doc):
            raise ValueError(f"{path.name}: expected a JSON list of objects (one per row)")
        rows = [{str(k): v for k, v in r.items()} for r in doc]
        where = [f"item {i}" for i in range(len(rows))]
        columns = sorted({k for r in rows for k in r})
    else:
        # UTF-8 (a spreadsheet's byte-order mark dropped); a bad byte is named by line
        with io.StringIO(fileio.read_text(path), newline="") as f:
            reader = csv.DictReader(f)
            columns = [c.strip() for c in (reader.fieldnames or [])]
            rows, where = [], []
            for r in reader:
                if None in r:
                    raise ValueError(
                        f"{path.name}, line {reader.line_num}: more values than header columns"
                    )
                if not any((v or "").strip() for v in r.values()):
                    continue  # blank line
                rows.append({k.strip(): (v or "").strip() for k, v in r.items()})
                where.append(f"line {reader.line_num}")
    missing = [c for c in required if c not in columns]
    if missing:
        raise ValueError(
            f"{path.name}, field {missing[0]!r}: missing column (found columns {columns})"
        )
    if not rows:
        raise ValueError(f"{path.name}: no rows")
    return _Table(path, rows, where, columns)


def _blank(v) -> bool:
    return v is None or (isinstance(v, str) and v.strip() == "")


def _number(tab: _Table, i: int, field: str, *, finite: bool = True) -> float:
    v = tab.rows[i].get(field)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{tab.at(i, field)}: expected a number, got {v!r}") from None
    if finite and not math.isfinite(x):
        raise ValueError(f"{tab.at(i, field)}: expected a finite number, got {v!r}")
    return x


def _text(tab: _Table, i: int, field: str) -> str:
    v = tab.rows[i].get(field)
    if _blank(v):
        raise ValueError(f"{tab.at(i, field)}: expected a value, got an empty one")
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    return str(v).strip()


@dataclasses.dataclass(frozen=True)
class ImportReport:
    """What :func:`read_tables` read (``str(report)`` is the import command's report)."""

    files: dict[str, str]  # role -> path
    point_rows: int
    goal_rows: int
    answer_rows: int
    participants: int  # distinct participant ids (0: column absent)
    taus: int  # distinct prefix times (whole motions not counted)

    def describe(self, study: Study) -> str:
        return "\n".join(
            [
                f"read {self.files['trajectories']}: {self.point_rows} points",
                f"read {self.files['goals']}: {self.goal_rows} goals",
                f"read {self.files['answers']}: {self.answer_rows} rows"
                + (f", {self.participants} participants" if self.participants else "")
                + (f", {self.taus} distinct prefix times" if self.taus else ""),
                study.summary(),
            ]
        )


def read_tables(
    trajectories: str | os.PathLike,
    goals: str | os.PathLike,
    answers: str | os.PathLike,
) -> tuple[Study, ImportReport]:
    """Import a study from three tables (CSV with a header, or a JSON list of objects).

    Layout (one row per point, goal and answer; see the module docstring):

    - ``trajectories``: ``trajectory, x, y, z[, t]``: points in time order per trajectory;
    - ``goals``: ``[trajectory,] goal, x, y, z``: shared goals, or goals per trajectory;
    - ``answers``: ``trajectory, guess[, tau, participant, condition, count]``.

    Answers with the same (trajectory, τ, condition) become one answer row of counts.
    Returns the validated :class:`Study` and an :class:`ImportReport`. Errors name the
    file, the line (CSV) or item (JSON), and the field.

    >>> study, report = read_tables("traj.csv", "goals.csv", "answers.csv")  # doctest: +SKIP
    >>> print(report.describe(study))  # doctest: +SKIP
    """
    tt = _read_table(trajectories, ("trajectory", "x", "y", "z"))
    gt = _read_table(goals, ("goal", "x", "y", "z"))
    at = _read_table(answers, ("trajectory", "guess"))

    # ---- trajectories
    has_t = "t" in tt.columns
    points: dict[str, list[tuple[list[float], float | None, int]]] = {}
    for i in range(len(tt.rows)):
        tid = _text(tt, i, "trajectory")
        p = [_number(tt, i, c) for c in ("x", "y", "z")]
        if has_t and _blank(tt.rows[i].get("t")):
            raise ValueError(
                f"{tt.at(i, 't')}: no time stamp; the column 't' is all-or-nothing: give t for "
                "every point of every trajectory, or leave the column out (points are then "
                "evenly spaced in time)"
            )
        ti = _number(tt, i, "t") if has_t else None
        pts = points.setdefault(tid, [])
        if has_t and pts and not ti > pts[-1][1]:
            raise ValueError(
                f"{tt.at(i, 't')}: expected time stamps increasing along trajectory "
                f"{tid!r}, got {ti!r} after {pts[-1][1]!r}"
            )
        pts.append((p, ti, i))
    ids = list(points)
    index = {tid: n for n, tid in enumerate(ids)}
    for tid, pts in points.items():
        if len(pts) < 2:
            raise ValueError(
                f"{tt.at(pts[0][2], 'trajectory')}: trajectory {tid!r} has {len(pts)} point; "
                "expected at least 2 (T >= 2)"
            )
    n = len(ids)
    length = np.array([len(points[k]) for k in ids], np.int32)
    xyz = np.zeros((n, int(length.max()), 3), np.float32)
    t = np.zeros((n, int(length.max())), np.float64) if has_t else None
    for k, tid in enumerate(ids):
        xyz[k, : length[k]] = [p for p, _, _ in points[tid]]
        if t is not None:
            t[k, : length[k]] = [ti for _, ti, _ in points[tid]]

    # ---- goals
    per_traj = "trajectory" in gt.columns
    gsets: dict[str | None, dict[str, tuple[list[float], int]]] = {}
    for i in range(len(gt.rows)):
        owner = _text(gt, i, "trajectory") if per_traj else None
        if owner is not None and owner not in index:
            raise ValueError(
                f"{gt.at(i, 'trajectory')}: unknown trajectory id {owner!r} (not in {tt.path.name})"
            )
        name = _text(gt, i, "goal")
        g = gsets.setdefault(owner, {})
        if name in g:
            raise ValueError(f"{gt.at(i, 'goal')}: goal {name!r} listed twice")
        if len(g) == G_MAX:
            raise ValueError(
                f"{gt.at(i, 'goal')}: more than {G_MAX} goals"
                + (f" for trajectory {owner!r}" if owner else "")
            )
        g[name] = ([_number(gt, i, c) for c in ("x", "y", "z")], i)
    goal_arr = np.zeros((n, G_MAX, 3), np.float32)
    mask = np.zeros((n, G_MAX), bool)
    names = np.full((n, G_MAX), "", dtype=object)
    for k, tid in enumerate(ids):
        g = gsets.get(None if not per_traj else tid)
        if g is None:
            raise ValueError(f"{gt.path.name}, field 'trajectory': no goals for trajectory {tid!r}")
        for s, (name, (pos, _)) in enumerate(g.items()):
            goal_arr[k, s], mask[k, s], names[k, s] = pos, True, name
    for g in gsets.values():
        pos = np.array([p for p, _ in g.values()], np.float64)
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos))
        if (d < 1e-9).any():
            j = int(np.argwhere(d < 1e-9)[0].max())
            row = list(g.values())[j][1]
            raise ValueError(f"{gt.at(row, 'x')}: two goals share one position")

    # ---- answers
    has = {c: c in at.columns for c in ("tau", "participant", "condition", "count")}
    times = t if t is not None else np.arange(xyz.shape[1])[None] / (length[:, None] - 1.0)
    full = times[np.arange(n), length - 1]
    groups: dict[tuple[int, float, str], np.ndarray] = {}
    participants: set[str] = set()
    taus: set[float] = set()
    conditions: list[str] = []
    for i in range(len(at.rows)):
        tid = _text(at, i, "trajectory")
        if tid not in index:
            raise ValueError(
                f"{at.at(i, 'trajectory')}: unknown trajectory id {tid!r} (not in {tt.path.name})"
            )
        k = index[tid]
        guess = _text(at, i, "guess")
        slots = [s for s in range(G_MAX) if mask[k, s] and names[k, s] == guess]
        if not slots:
            real = [str(x) for x in names[k][mask[k]]]
            raise ValueError(
                f"{at.at(i, 'guess')}: {guess!r} is not a goal of trajectory {tid!r} "
                f"(its goals: {', '.join(real)}); answers for padded or unknown goals"
            )
        if has["tau"] and not _blank(at.rows[i].get("tau")):
            tau = _number(at, i, "tau")
            seen = int(np.sum(times[k, : length[k]] <= tau + TAU_RTOL * (full[k] - times[k, 0])))
            if tau > full[k] + TAU_RTOL * (full[k] - times[k, 0]) or seen < 2:
                raise ValueError(
                    f"{at.at(i, 'tau')}: tau = {tau!r} is outside the motion of trajectory "
                    f"{tid!r}: expected {float(times[k, 1])!r} <= tau <= {float(full[k])!r} "
                    "(at least 2 points seen)"
                )
            if seen < length[k]:
                taus.add(tau)
            else:
                tau = float(full[k])
        else:
            tau = float(full[k])
        count = 1.0
        if has["count"] and not _blank(at.rows[i].get("count")):
            count = _number(at, i, "count")
            if count < 0 or count != round(count):
                raise ValueError(
                    f"{at.at(i, 'count')}: expected a whole number of answers >= 0, "
                    f"got {at.rows[i]['count']!r}"
                )
        cond = ""
        if has["condition"] and not _blank(at.rows[i].get("condition")):
            cond = _text(at, i, "condition")
            if cond not in conditions:
                conditions.append(cond)
        if has["participant"] and not _blank(at.rows[i].get("participant")):
            participants.add(_text(at, i, "participant"))
        row = groups.setdefault((k, float(tau), cond), np.zeros(G_MAX))
        row[slots[0]] += count
    for key in [key for key, c in groups.items() if c.sum() == 0]:
        del groups[key]
    answered = {k for k, _, _ in groups}
    for k, tid in enumerate(ids):
        if k not in answered:
            raise ValueError(
                f"{at.path.name}, field 'trajectory': trajectory {tid!r} (from "
                f"{tt.path.name}) has no answers"
            )
    keys = sorted(groups, key=lambda key: (key[0], key[2], key[1]))
    use_cond = has["condition"] and bool(conditions)
    if use_cond and "" in {key[2] for key in keys}:
        i = next(i for i in range(len(at.rows)) if _blank(at.rows[i].get("condition")))
        raise ValueError(
            f"{at.at(i, 'condition')}: expected a condition on every row (others have one)"
        )
    study = make_study(
        xyz,
        goal_arr[0] if not per_traj else goal_arr,
        mask[0] if not per_traj else mask,
        np.array([key[0] for key in keys], np.int32),
        np.stack([groups[key] for key in keys]),
        length=length,
        answer_tau=np.array([key[1] for key in keys]),
        t=t,
        answer_condition=np.array([conditions.index(key[2]) for key in keys], np.int32)
        if use_cond
        else None,
        conditions=conditions if use_cond else (),
        trajectory_ids=ids,
        goal_names=(names[0] if not per_traj else names).astype(str),
        source=f"{tt.path.name} + {gt.path.name} + {at.path.name}",
    )
    report = ImportReport(
        files={"trajectories": str(tt.path), "goals": str(gt.path), "answers": str(at.path)},
        point_rows=len(tt.rows),
        goal_rows=len(gt.rows),
        answer_rows=len(at.rows),
        participants=len(participants),
        taus=len(taus),
    )
    return study, report


# ================================================================= training


class StudyData(NamedTuple):
    """A study as device arrays for training (N trajectories, A answer rows, G goal slots)."""

    xyz: Float[Array, "N T 3"]  # points (m), zeros after each trajectory's length
    goals: Float[Array, "N G 3"]  # goals (m); G ≤ 8: slots no trajectory uses are cut
    goal_mask: Bool[Array, "N G"]  # real goal slots
    row_trajectory: Int[Array, " A"]  # trajectory of each answer row
    row_seen: Int[Array, " A"]  # points its participants saw (2 ≤ L ≤ length)
    counts: Float[Array, "A G"]  # guesses per goal slot


def study_data(study: Study) -> StudyData:
    """The training arrays of a :class:`Study` (goal slots after the last real one cut)."""
    g = max(1, int(np.max(np.where(study.goal_mask, np.arange(1, G_MAX + 1), 0))))
    return StudyData(
        jnp.asarray(study.xyz, jnp.float32),
        jnp.asarray(study.goals[:, :g], jnp.float32),
        jnp.asarray(study.goal_mask[:, :g], bool),
        jnp.asarray(study.answer_trajectory, jnp.int32),
        jnp.asarray(study.seen(), jnp.int32),
        jnp.asarray(study.counts[:, :g], jnp.float32),
    )


def prefix_scores(
    model: models.Model,
    xyz: Float[Array, "... T 3"],
    goals: Float[Array, "... G 3"],
    seen: Int[Array, "..."],
    *,
    backward: str = "autodiff",
) -> Float[Array, "... G"]:
    """Unmasked scores of the first ``seen`` points of each trajectory.

    SLOT-V: s_k = (1/L) Σ_{i<L} V(p_i, g_k); T-REX: s_k = Σ_{i<L} r(p_i, g_k), with
    L = ``seen``. A model with time weights u_i weights the seen points by them: SLOT-V's
    s_k is then Σ_{i<L} u_i V(p_i, g_k) / Σ_{i<L} u_i, T-REX's Σ_{i<L} u_i r(p_i, g_k); a
    model with the start term takes every value relative to f(p_0, g_k) (p_0 is always
    seen).
    Points i ≥ L are replaced by p_0 before the network and weighted 0, so their values
    reach neither the scores nor any gradient. With L = T this is
    ``model.scores`` (up to summation order).

    >>> m = models.SlotV((8, 4), rngs=nnx.Rngs(0))  # doctest: +SKIP
    >>> prefix_scores(m, xyz[None], goals[None], jnp.array([40]))  # doctest: +SKIP
    """
    t = xyz.shape[-2]
    vis = jnp.arange(t) < seen[..., None]  # (..., T)
    x = jnp.where(vis[..., None], xyz, xyz[..., :1, :])
    v = model.network.grid(x, goals, backward=backward)  # (..., T, G)
    if model.start_term:  # values relative to the start's (point 0 is always seen)
        v = v - v[..., :1, :]
    w = vis.astype(v.dtype)
    u = model.point_weights(t)  # time weights of mean 1 over the whole trajectory, or None
    if u is not None:
        w = w * u.astype(v.dtype)
    if model.method == "slotv":
        w = w / w.sum(-1, keepdims=True)
    return jnp.einsum("...tg,...t->...g", v, w, precision=jax.lax.Precision.HIGHEST)


def count_nll(
    scores: Float[Array, "B G"], goal_mask: Bool[Array, "B G"], counts: Float[Array, "B G"]
) -> Float[Array, " B"]:
    """Per row, −Σ_k c_k log softmax_k(s) over the real goals (the multinomial negative
    log-likelihood of the counts, without the constant multinomial coefficient)."""
    lse = jax.nn.logsumexp(models.mask_logits(scores, goal_mask), axis=-1, keepdims=True)
    return -jnp.sum(jnp.where(goal_mask, counts * (scores - lse), 0.0), axis=-1)


def study_loss(
    model: models.Model,
    xyz: Float[Array, "B T 3"],
    goals: Float[Array, "B G 3"],
    goal_mask: Bool[Array, "B G"],
    seen: Int[Array, " B"],
    counts: Float[Array, "B G"],
    answers_per_row: Float[Array, ""] | float,
    *,
    backward: str = "autodiff",
) -> Float[Array, ""]:
    """Minibatch estimate of the per-answer multinomial NLL (module docstring):

        L_batch = −Σ_b Σ_k c_bk log softmax_k(s_b) / (B · n̄),   n̄ = ``answers_per_row``

    With one answer per row (n̄ = 1) this is the mean cross-entropy against one-hot labels.
    """
    s = prefix_scores(model, xyz, goals, seen, backward=backward)
    return count_nll(s, goal_mask, counts).sum() / (xyz.shape[0] * answers_per_row)


@dataclasses.dataclass(frozen=True, eq=False)
class StudyTrainer:
    """Pure training on answer rows for one config (build with :func:`make_study_train`).

    An epoch shuffles the A answer rows (``jax.random.permutation`` of ``fold_in(key,
    epoch)``), drops the last partial batch and scans the updates; the optimiser, the
    initialisation and the state are those of :mod:`slotv_jax.train` (RMSprop for SLOT-V,
    Adam for T-REX), so checkpoints load with :func:`slotv_jax.load_observer`.
    """

    cfg: TrainConfig
    base: train_lib.Trainer  # init, optimiser, mesh and gradient implementation

    def init(self, key: jax.Array) -> train_lib.TrainState:
        return self.base.init(key)

    def _shard(self, x):
        return jax.lax.with_sharding_constraint(x, NamedSharding(self.base.mesh, P("data")))

    def steps_per_epoch(self, n_rows: int) -> int:
        return n_rows // self.cfg.batch_size

    def run(
        self, state: train_lib.TrainState, data: StudyData, *, epochs: int
    ) -> tuple[train_lib.TrainState, Float[Array, " E"]]:
        """``epochs`` more epochs from ``state`` (pure; jit it). Returns the new state and
        each epoch's mean training loss."""
        a_rows = data.counts.shape[0]
        bs = self.cfg.batch_size
        steps = self.steps_per_epoch(a_rows)
        if steps < 1:
            raise ValueError(
                f"study: {a_rows} answer rows give no full batch of {bs} "
                "(lower batch_size, e.g. --set batch_size=8)"
            )
        n_bar = data.counts.sum() / a_rows
        tx, backward = self.base.tx, self.base.backward

        def step(carry, idx):
            params, opt_state = carry
            idx = self._shard(idx)
            traj = data.row_trajectory[idx]
            batch = (
                self._shard(data.xyz[traj]),
                self._shard(data.goals[traj]),
                self._shard(data.goal_mask[traj]),
                self._shard(data.row_seen[idx]),
                self._shard(data.counts[idx]),
            )

            def f(p):
                return study_loss(self.base.model(p), *batch, n_bar, backward=backward)

            loss, grads = jax.value_and_grad(f)(params)
            updates, opt_state = tx.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state), loss

        def epoch_fn(carry, _):
            params, opt_state, epoch, key = carry
            perm = jax.random.permutation(jax.random.fold_in(key, epoch), a_rows)
            batches = perm[: steps * bs].reshape(steps, bs).astype(jnp.int32)
            (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), batches)
            return (params, opt_state, epoch + 1, key), losses.mean()

        (params, opt_state, epoch, key), losses = jax.lax.scan(
            epoch_fn, tuple(state), None, length=epochs
        )
        return train_lib.TrainState(params, opt_state, epoch, key), losses

    def train(self, key: jax.Array, data: StudyData) -> tuple[train_lib.TrainState, Array]:
        """Initialise from ``key`` and train ``cfg.epochs`` epochs (pure; jit it)."""
        return self.run(self.init(key), data, epochs=self.cfg.epochs)

    def scores(self, params, data: StudyData) -> Float[Array, "A G"]:
        """Masked scores (logits) of every answer row (pure; jit it)."""
        model = self.base.model(params)

        def one(traj, seen):
            return prefix_scores(model, data.xyz[traj], data.goals[traj], seen)

        s = jax.lax.map(lambda a: one(*a), (data.row_trajectory, data.row_seen), batch_size=256)
        return models.mask_logits(s, data.goal_mask[data.row_trajectory])


@functools.cache
def make_study_train(cfg: TrainConfig) -> StudyTrainer:
    """The :class:`StudyTrainer` of ``cfg`` (cached, so jitted calls reuse compilations)."""
    return StudyTrainer(cfg, train_lib.make_train(cfg, progress=False))


@functools.cache
def _jit_run(trainer: StudyTrainer, epochs: int):
    return jax.jit(functools.partial(trainer.run, epochs=epochs))


@functools.cache
def _jit_scores(trainer: StudyTrainer):
    return jax.jit(trainer.scores)


def train_study(
    cfg: TrainConfig,
    study: Study | StudyData,
    key: jax.Array,
    *,
    progress: bool = True,
    on_epoch: Callable[[train_lib.TrainState, float], None] | None = None,
    state: train_lib.TrainState | None = None,
) -> train_lib.TrainState:
    """Train ``cfg``'s model on a study's answers (one compiled call per epoch, a tqdm bar).

    ``cfg.train_size`` is ignored (every answer row is used). ``on_epoch(state, loss)`` is
    called after each epoch (e.g. to checkpoint). ``state`` resumes a run. Returns the final
    :class:`slotv_jax.types.TrainState`.
    """
    trainer = make_study_train(cfg)
    data = study_data(study) if isinstance(study, Study) else study
    data = trainer.base.replicate(data)
    state = trainer.init(key) if state is None else state
    # one compiled call per epoch when the caller looks at every epoch, else one for all
    chunk = 1 if on_epoch is not None else max(cfg.epochs - int(state.epoch), 1)
    run = _jit_run(trainer, chunk)
    bar = tqdm(
        total=cfg.epochs, initial=int(state.epoch), desc=f"{cfg.method} (study)", unit="epoch",
        disable=not progress, leave=False, file=sys.stderr,
    )  # fmt: skip
    while int(state.epoch) < cfg.epochs:
        state, losses = run(state, data)
        loss = float(losses[-1])
        if not math.isfinite(loss):
            raise ValueError(f"study training: the loss became {loss} at epoch {int(state.epoch)}")
        bar.update(chunk)
        bar.set_postfix(loss=f"{loss:.4f}")
        if on_epoch is not None:
            on_epoch(state, loss)
    bar.close()
    return state


# ============================================================== evaluation


def row_metrics(logits: np.ndarray, goal_mask: np.ndarray, counts: np.ndarray) -> dict:
    """Accuracy and likelihood of per-row goal logits (−∞ on padding) against counts.

    - ``accuracy``: fraction of rows whose argmax equals the modal answer (ties: the
      lowest slot, as SPEC §8 breaks them);
    - ``answer_accuracy``: fraction of all answers that equal the argmax;
    - ``nll_per_answer``: −Σ c log p / Σ c (nats).
    """
    logits = np.asarray(logits, np.float64)
    counts = np.asarray(counts, np.float64)
    mask = np.asarray(goal_mask, bool)
    z = np.where(mask, logits, -np.inf)
    z = z - z.max(-1, keepdims=True)
    logp = np.where(mask, z - np.log(np.exp(z).sum(-1, keepdims=True)), 0.0)
    pred = np.argmax(z, -1)
    mode = np.argmax(np.where(mask, counts, -np.inf), -1)
    rows = np.arange(len(counts))
    return {
        "accuracy": float(np.mean(pred == mode)),
        "answer_accuracy": float(counts[rows, pred].sum() / counts.sum()),
        "nll_per_answer": float(-np.sum(np.where(counts > 0, counts * logp, 0.0)) / counts.sum()),
        "rows": len(counts),
        "answers": float(counts.sum()),
    }


def model_metrics(cfg: TrainConfig, params, study: Study) -> dict:
    """:func:`row_metrics` of a trained model on every answer row of ``study``."""
    trainer = make_study_train(cfg)
    data = study_data(study)
    logits = np.asarray(_jit_scores(trainer)(params, trainer.base.replicate(data)))
    g = data.counts.shape[-1]
    return row_metrics(logits, study.goal_mask[study.answer_trajectory, :g], study.counts[:, :g])


@functools.cache
def _jit_labeler(name: str, camera: str, with_t: bool):
    cam = scene.camera(camera) if name == "nikolaidis" else None

    def one(xyz, goals, mask, beta, t):
        kw = {"beta": beta, "t": t if with_t else None}
        if name == "nikolaidis":
            return labelers.nikolaidis(xyz, goals, mask, cam, **kw)
        return labelers.LABELERS[name](xyz, goals, mask, **kw)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, 0)))


def labeler_probs(
    study: Study, name: str, *, beta: float | None = None, camera: str = "observer"
) -> Float[np.ndarray, "A 8"]:
    """The hand-crafted observer ``name``'s goal distribution for every answer row, computed
    on the points the row's participants saw (``xyz[:L]``, and ``t[:L]`` if the study has
    time stamps). ``beta`` defaults to the labeler's SPEC value. Rows are grouped by L; each
    L compiles once per labeler (β is traced, so fitting it does not recompile).
    """
    if name not in labelers.LABELERS:
        raise ValueError(f"labeler: expected one of {list(labelers.LABELERS)}, got {name!r}")
    beta = labelers.DEFAULT_BETAS[name] if beta is None else float(beta)
    validation.check_positive("beta", beta)
    f = _jit_labeler(name, camera, study.t is not None)
    seen = study.seen()
    traj = study.answer_trajectory
    out = np.zeros((study.n_rows, G_MAX), np.float64)
    for L in np.unique(seen):
        rows = np.flatnonzero(seen == L)
        tr = traj[rows]
        t = study.t[tr, :L] if study.t is not None else np.zeros((len(rows), L))
        y = f(study.xyz[tr, :L], study.goals[tr], study.goal_mask[tr], jnp.float32(beta), t)
        out[rows] = np.asarray(y, np.float64)
    return out


def labeler_visible(study: Study, camera: str = "observer") -> bool:
    """Whether every point and real goal is in front of ``camera`` (Nikolaidis needs it)."""
    cam = scene.camera(camera)
    ok = jax.jit(jax.vmap(labelers.depth_ok, in_axes=(0, 0, 0, None)))(
        study.xyz, study.goals, study.goal_mask, cam
    )
    # padded points sit at the origin, which is in front of every scene camera
    return bool(np.all(np.asarray(ok)))


def _nll(probs: np.ndarray, counts: np.ndarray) -> float:
    logp = np.log(np.maximum(probs, PROB_FLOOR))
    return float(-np.sum(np.where(counts > 0, counts * logp, 0.0)) / counts.sum())


def fit_beta(
    study: Study, name: str, *, camera: str = "observer", tol: float = 1e-3
) -> tuple[float, float]:
    """β of labeler ``name`` that maximises the likelihood of ``study``'s counts.

    A 1-D search on log β within [β₀/100, β₀·100] (β₀ the SPEC default): a grid of 17
    points, then golden-section search (Kiefer 1953) on the bracket around the best grid
    point until it is ``tol`` wide in log β. Returns (β, NLL per answer at β).
    """
    b0 = labelers.DEFAULT_BETAS[name]
    lo, hi = math.log(b0 / BETA_RANGE), math.log(b0 * BETA_RANGE)
    cache: dict[float, float] = {}

    def nll(lb: float) -> float:
        if lb not in cache:
            cache[lb] = _nll(labeler_probs(study, name, beta=math.exp(lb), camera=camera),
                             study.counts)  # fmt: skip
        return cache[lb]

    grid = np.linspace(lo, hi, 17)
    vals = [nll(float(g)) for g in grid]
    j = int(np.argmin(vals))
    a, b = float(grid[max(j - 1, 0)]), float(grid[min(j + 1, len(grid) - 1)])
    r = (math.sqrt(5) - 1) / 2
    c, d = b - r * (b - a), a + r * (b - a)
    while b - a > tol:
        if nll(c) <= nll(d):
            b, d = d, c
            c = b - r * (b - a)
        else:
            a, c = c, d
            d = a + r * (b - a)
    best = min(cache, key=cache.get)
    return math.exp(best), cache[best]


def cross_validate(
    cfg: TrainConfig | Mapping[str, TrainConfig],
    study: Study,
    *,
    folds: int = 5,
    seed: int = 0,
    baselines: Sequence[str] = tuple(labelers.LABELER_NAMES),
    camera: str = "observer",
    progress: bool = True,
) -> dict:
    """k-fold cross-validation by trajectory (every answer row of a trajectory in one fold).

    For each fold, each config in ``cfg`` (one, or a mapping name -> config) trains on the
    other folds, and each hand-crafted labeler in ``baselines`` gets its β fitted on them
    (:func:`fit_beta`); all are scored on the held-out rows with :func:`row_metrics`. The
    uniform guess is scored too (its accuracy is the chance level, the mean of 1/n_goals).
    Returns {"folds", "per_fold": [...], "<name>": pooled metrics} where the pooled
    metrics weight each fold by its rows (accuracy) or answers (NLL, answer accuracy).
    Nikolaidis is skipped (with a note) if a point lies behind the camera.
    """
    cfgs = {cfg.method: cfg} if isinstance(cfg, TrainConfig) else dict(cfg)
    n = study.n_trajectories
    if not 2 <= folds <= n:
        raise ValueError(f"folds: expected 2 <= folds <= {n} (trajectories), got {folds}")
    base = list(baselines)
    notes = {}
    if "nikolaidis" in base and not labeler_visible(study, camera):
        base.remove("nikolaidis")
        notes["nikolaidis"] = f"skipped: a point or goal lies behind camera {camera!r}"
    order = np.random.default_rng(seed).permutation(n)
    fold_of = np.empty(n, np.int32)
    fold_of[order] = np.arange(n) % folds
    per_fold = []
    bar = tqdm(total=folds, desc="cross-validation", unit="fold", disable=not progress)
    for f in range(folds):
        tr_idx, te_idx = np.flatnonzero(fold_of != f), np.flatnonzero(fold_of == f)
        tr, te = study.select_trajectories(tr_idx), study.select_trajectories(te_idx)
        res: dict[str, Any] = {"fold": f, "train_rows": tr.n_rows, "test_rows": te.n_rows}
        for name, c in cfgs.items():
            state = train_study(c, tr, jax.random.key(seed * 1000 + f), progress=False)
            res[name] = model_metrics(c, state.params, te)
        uni = np.where(te.goal_mask[te.answer_trajectory], 0.0, -np.inf)
        res["uniform"] = row_metrics(uni, te.goal_mask[te.answer_trajectory], te.counts)
        res["uniform"]["accuracy"] = float(
            np.mean(1.0 / te.goal_mask[te.answer_trajectory].sum(-1))
        )
        for name in base:
            beta, _ = fit_beta(tr, name, camera=camera)
            y = labeler_probs(te, name, beta=beta, camera=camera)
            with np.errstate(divide="ignore"):
                logits = np.log(np.maximum(y, PROB_FLOOR))
            res[name] = {**row_metrics(logits, te.goal_mask[te.answer_trajectory], te.counts),
                         "beta": beta}  # fmt: skip
        per_fold.append(res)
        bar.update(1)
    bar.close()
    out: dict[str, Any] = {"folds": folds, "seed": seed, "per_fold": per_fold, "notes": notes}
    for name in [*cfgs, "uniform", *base]:
        rows = np.array([r[name]["rows"] for r in per_fold], np.float64)
        ans = np.array([r[name]["answers"] for r in per_fold], np.float64)
        pooled = {
            "accuracy": float(np.sum(rows * [r[name]["accuracy"] for r in per_fold]) / rows.sum()),
            "answer_accuracy": float(
                np.sum(ans * [r[name]["answer_accuracy"] for r in per_fold]) / ans.sum()
            ),
            "nll_per_answer": float(
                np.sum(ans * [r[name]["nll_per_answer"] for r in per_fold]) / ans.sum()
            ),
        }
        if "beta" in per_fold[0][name]:
            pooled["beta_per_fold"] = [r[name]["beta"] for r in per_fold]
        out[name] = pooled
    return out


def cv_table(cv: Mapping[str, Any]) -> str:
    """A Markdown table of :func:`cross_validate`'s pooled results."""
    lines = [
        f"{cv['folds']}-fold cross-validation by trajectory (held-out rows)",
        "",
        "| observer | accuracy (modal answer) | answer accuracy | NLL per answer (nats) | β |",
        "|---|---|---|---|---|",
    ]
    for name, r in cv.items():
        if not isinstance(r, dict) or "nll_per_answer" not in r:
            continue
        beta = r.get("beta_per_fold")
        b = "" if beta is None else f"{np.median(beta):.3g} (median of folds)"
        lines.append(
            f"| {name} | {r['accuracy']:.3f} | {r['answer_accuracy']:.3f} | "
            f"{r['nll_per_answer']:.4f} | {b} |"
        )
    for name, note in cv.get("notes", {}).items():
        lines.append(f"\n{name}: {note}")
    return "\n".join(lines)


# ============================================================== simulation


def prefix_labels(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    *,
    labeler: str = "dragan",
    beta: float | None = None,
    camera: str = "observer",
) -> Float[np.ndarray, "N K 8"]:
    """The labeler's distribution of each trajectory seen up to each normalised time τ
    (``taus``, K of them, in (0, 1]): :func:`labeler_probs` on every (trajectory, τ)."""
    taus = check_taus(taus)
    n = np.shape(xyz)[0]
    grid = make_study(
        xyz, goals, goal_mask, np.repeat(np.arange(n), taus.size),
        np.repeat(np.eye(G_MAX)[[0]], n * taus.size, axis=0),
        answer_tau=np.tile(taus, n), source="prefix_labels",
    )  # fmt: skip
    y = labeler_probs(grid, labeler, beta=beta, camera=camera)
    return y.reshape(n, taus.size, G_MAX)


def check_taus(taus) -> np.ndarray:
    taus = np.asarray(sorted({float(x) for x in taus}), np.float64)
    if taus.size == 0 or not (taus.min() > 0 and taus.max() <= 1):
        raise ValueError(f"taus: expected normalised times in (0, 1], got {taus.tolist()}")
    return taus


def simulate_guesses(
    key: jax.Array,
    probs: Float[np.ndarray, "N K 8"],
    goal_mask: Bool[np.ndarray, "N 8"],
    participants: int,
    *,
    lapse: float = 0.0,
) -> tuple[Int[np.ndarray, "N P"], Int[np.ndarray, "N P"]]:
    """Simulated participants: participant j sees trajectory n at a τ drawn uniformly from
    the K of ``probs`` and guesses a goal from

        p = (1 − λ) · probs[n, τ] + λ · uniform over the real goals   (lapse rate λ).

    Returns ``(which_tau, guess)``, each (N, P). Participant j's draws come from
    ``fold_in(key, j)`` alone: the first P participants of a larger simulation are the
    participants of a smaller one.
    """
    if not (isinstance(participants, int | np.integer) and participants >= 1):
        raise ValueError(f"participants: expected an int >= 1, got {participants!r}")
    if not 0.0 <= lapse <= 1.0:
        raise ValueError(f"lapse: expected a rate in [0, 1], got {lapse!r}")
    probs = np.asarray(probs, np.float64)
    goal_mask = np.asarray(goal_mask, bool)
    n, k = probs.shape[:2]
    uniform = goal_mask / goal_mask.sum(-1, keepdims=True)
    p = (1 - lapse) * probs + lapse * uniform[:, None, :]
    which = np.zeros((n, participants), np.int64)
    u = np.zeros((n, participants))
    for j in range(participants):
        k_tau, k_guess = jax.random.split(jax.random.fold_in(key, j))
        which[:, j] = np.asarray(jax.random.randint(k_tau, (n,), 0, k))
        u[:, j] = np.asarray(jax.random.uniform(k_guess, (n,)), np.float64)
    cdf = np.cumsum(p[np.arange(n)[:, None], which], -1)  # (N, P, 8)
    real = goal_mask.sum(-1)[:, None]
    guess = np.minimum((u[..., None] >= cdf).sum(-1), real - 1)
    return which, guess


def study_from_guesses(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    taus: Sequence[float],
    which_tau: Int[np.ndarray, "N P"],
    guess: Int[np.ndarray, "N P"],
) -> Study:
    """Aggregate per-participant guesses into a :class:`Study` (one row per seen (n, τ))."""
    taus = check_taus(taus)
    n = np.shape(xyz)[0]
    counts = np.zeros((n, taus.size, G_MAX))
    np.add.at(counts, (np.arange(n)[:, None], which_tau, guess), 1.0)
    has = counts.sum(-1) > 0
    rows = np.argwhere(has)
    return make_study(
        xyz, goals, goal_mask, rows[:, 0], counts[has], answer_tau=taus[rows[:, 1]],
        source="simulated study",
    )  # fmt: skip


def simulate_study(
    key: jax.Array,
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    participants: int,
    *,
    labeler: str = "dragan",
    beta: float | None = None,
    taus: Sequence[float] = (1.0,),
    lapse: float = 0.0,
    camera: str = "observer",
) -> Study:
    """A simulated study: :func:`prefix_labels`, :func:`simulate_guesses` (P =
    ``participants`` per trajectory, each seeing it up to one τ of ``taus``), then
    :func:`study_from_guesses`."""
    probs = prefix_labels(xyz, goals, goal_mask, taus, labeler=labeler, beta=beta, camera=camera)
    which, guess = simulate_guesses(key, probs, goal_mask, participants, lapse=lapse)
    return study_from_guesses(xyz, goals, goal_mask, taus, which, guess)


# ===================================================================== CLI


def train_main(cfg: TrainConfig, args: argparse.Namespace) -> int:
    """``python -m slotv_jax.train --study FILE ...``: train on a study, checkpoint every
    epoch, optionally cross-validate (``--cv K``), and print the metrics. A study with
    fewer answer rows than the preset's batch trains with the largest power of two that
    fits (and says so), unless ``--set batch_size=N`` is given."""
    study = load_study(args.study)
    if args.condition is not None:
        study = study.select_condition(args.condition)
    cfg = dataclasses.replace(cfg, train_size=None)
    chosen = any(a.split("=", 1)[0].strip() == "batch_size" for a in getattr(args, "set", []))
    if not chosen and study.n_rows < cfg.batch_size:  # a small study: a batch that fits
        fit = 1 << (study.n_rows.bit_length() - 1)
        print(
            f"batch_size: the study has {study.n_rows} answer rows, fewer than the preset's "
            f"{cfg.batch_size}; using batch_size={fit} (--set batch_size=N to choose)"
        )
        cfg = dataclasses.replace(cfg, batch_size=fit)
    print(study.summary(), flush=True)
    print(f"config: {json.dumps(cfg.to_dict(), sort_keys=True)}", flush=True)
    out = Path(args.out)
    meta: dict[str, Any] = {"study": str(args.study), "condition": args.condition,
                            "seed": args.seed}  # fmt: skip
    state = None
    if args.resume and checkpoint.exists(out):
        _, state, old = checkpoint.restore(out, cfg)
        meta = {**old, **meta}
        print(f"resuming from {out} after epoch {int(state.epoch)}", flush=True)

    def save(st, loss):
        print(f"epoch {int(st.epoch)}/{cfg.epochs}: loss {loss:.4f}", flush=True)
        checkpoint.save(out, cfg, st, meta=meta)

    t0 = time.perf_counter()
    state = train_study(cfg, study, jax.random.key(args.seed), progress=not args.no_progress,
                        on_epoch=save, state=state)  # fmt: skip
    meta["train_seconds"] = round(time.perf_counter() - t0, 2)
    meta["train_metrics"] = model_metrics(cfg, state.params, study)
    print(f"training rows: accuracy {meta['train_metrics']['accuracy']:.4f}, NLL per answer "
          f"{meta['train_metrics']['nll_per_answer']:.4f}", flush=True)  # fmt: skip
    if args.cv:
        cv = cross_validate(cfg, study, folds=args.cv, seed=args.seed,
                            progress=not args.no_progress)  # fmt: skip
        meta["cross_validation"] = {k: v for k, v in cv.items() if k != "per_fold"}
        print(cv_table(cv), flush=True)
    checkpoint.save(out, cfg, state, meta=meta)
    print(json.dumps({"checkpoint": str(out), "train_seconds": meta["train_seconds"]}))
    return 0


def _parse_args(argv):
    ap = argparse.ArgumentParser(
        prog="python -m slotv_jax.study",
        description="Study data: import answer tables, show a study file, cross-validate.",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    imp = sub.add_parser("import", help="tables (CSV/JSON) -> one study .npz")
    imp.add_argument("--trajectories", required=True, help="trajectory,x,y,z[,t] per point")
    imp.add_argument("--goals", required=True, help="[trajectory,]goal,x,y,z per goal")
    imp.add_argument("--answers", required=True, help="trajectory,guess[,tau,participant,...]")
    imp.add_argument("--out", required=True, help="study file to write (.npz)")
    imp.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    show = sub.add_parser("show", help="validate a study file and summarise it")
    show.add_argument("study")
    cv = sub.add_parser("cv", help="k-fold cross-validation of SLOT-V/T-REX and baselines")
    cv.add_argument("study")
    cv.add_argument("--methods", default="slotv", help="comma-separated: slotv,trex")
    cv.add_argument("--preset", default="quick", choices=tuple(config_lib.PRESETS))
    cv.add_argument("--folds", type=int, default=5)
    cv.add_argument("--seed", type=int, default=0)
    cv.add_argument("--epochs", type=int, default=None)
    cv.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    cv.add_argument("--condition", default=None)
    cv.add_argument("--out", default=None, help="write the results as JSON here")
    cv.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    return ap.parse_args(argv)


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """CLI: ``import`` (report what was read), ``show``, ``cv``; input errors in one line."""
    args = _parse_args(argv)
    if getattr(args, "out", None) is not None:  # before any work
        fileio.check_output_file(args.out, overwrite=args.overwrite)
    if args.command == "import":
        study, report = read_tables(args.trajectories, args.goals, args.answers)
        save_study(args.out, study)
        print(report.describe(study))
        print(f"wrote {args.out}")
        return 0
    if args.command == "show":
        print(load_study(args.study).summary())
        return 0
    study = load_study(args.study)
    if args.condition is not None:
        study = study.select_condition(args.condition)
    cfgs = {}
    for m in args.methods.split(","):
        c = config_lib.preset(args.preset, m.strip(), train_size=None)
        if args.epochs is not None:
            c = dataclasses.replace(c, epochs=args.epochs)
        cfgs[m.strip()] = config_lib.apply_overrides(c, args.set)
    cv = cross_validate(cfgs, study, folds=args.folds, seed=args.seed)
    print(cv_table(cv))
    if args.out:
        write_text(args.out, json.dumps(cv, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
