"""Importing a study from CSV tables (trajectories, goals, answers) into the study format."""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slotv_jax.answers.format import TAU_RTOL, Study, make_study
from slotv_jax.core import fileio
from slotv_jax.core.validation import G_MAX

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
