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
``goal_names`` (optional)   (N, 8), (8,)   goal names (str, '' on padded slots)
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

Any other column is refused (a misspelt ``cuont`` would otherwise be left out unseen;
``--ignore-columns`` leaves extra columns out on purpose), as is a column named twice, a
JSON ``true`` where a number goes, or a number beyond float32. Every error is a
``ValueError`` naming the file, the line (CSV) or item (JSON) or array row, and the field.

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
>>> from slotv_jax.training import config
>>> cfg = config.quick("slotv")
>>> state = train_study(cfg, study, jax.random.key(0))                # doctest: +SKIP
>>> cross_validate(cfg, study, folds=5)["slotv"]["nll_per_answer"]    # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from jaxtyping import Bool, Float, Int

from slotv_jax.core.validation import G_MAX, SAME_POSITION

# τ within this fraction of the motion's duration of t_i counts as t_i (one definition)
from slotv_jax.observers.common import TAU_RTOL

FORMAT = "slotv_jax.study/1"
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
    motion (or seeing fewer than 2 points), unknown trajectory or condition indices, and
    ``trajectory_ids`` that repeat an id.

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
    same = np.argwhere(goal_mask[:, :, None] & goal_mask[:, None] & (d < SAME_POSITION))
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
    first: dict[str, int] = {}
    for i, tid in enumerate(trajectory_ids):
        j = first.setdefault(tid, i)
        if j != i:  # answers name trajectories by id: two of one id are one too many
            raise ValueError(
                f"{w('trajectory_ids', i)}: {tid!r} is also the id of row {j}; expected "
                "distinct ids, one per trajectory"
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
    big = float(np.finfo(dtype).max)  # a finite value beyond it would become inf, with a warning
    wider = a.dtype.kind == "f" and float(np.finfo(a.dtype).max) > big  # else none can exceed
    over = np.argwhere(np.isfinite(a) & (np.abs(a) > big)) if wider else []
    if len(over):
        idx = tuple(int(v) for v in over[0])
        raise ValueError(
            f"{w(name, idx[0] if idx else None)}: expected magnitudes at most {big:.4g} "
            f"({np.dtype(dtype).name}), found {float(a[idx])!r} at index {list(idx)}"
        )
    return a.astype(dtype)


def _int_array(x, name, w) -> np.ndarray:
    a = np.asarray(x)
    if a.dtype.kind == "f":
        bad = np.flatnonzero(~(np.abs(a) < 2.0**62) | (a != np.round(a)))  # int64, no warning
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
