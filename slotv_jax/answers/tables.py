"""Importing a study from tables (trajectories, goals, answers; CSV or JSON) into the study
format (:mod:`slotv_jax.answers.format`), strictly: what is read is what was written, or a
ValueError names the file, the line (CSV) or item (JSON) and the field (:func:`read_tables`)."""

from __future__ import annotations

import csv
import dataclasses
import difflib
import io
import json
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from slotv_jax.answers.format import TAU_RTOL, Study, make_study
from slotv_jax.core import fileio
from slotv_jax.core.validation import FLOAT32_MAX, G_MAX, SAME_POSITION

# ------------------------------------------------------------ table import

# The columns of each table: (required, optional). Any other column is refused (a misspelt
# optional column would otherwise be silently left out), unless named in ``ignore_columns``.
COLUMNS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "trajectories": (("trajectory", "x", "y", "z"), ("t",)),
    "goals": (("goal", "x", "y", "z"), ("trajectory",)),
    "answers": (("trajectory", "guess"), ("tau", "participant", "condition", "count")),
}
# Columns accepted and not read: what ``study export`` records beside each answer for the
# analysis (slotv_jax.webstudy.export.ANSWER_COLUMNS), so its tables import unchanged.
RECORDED: dict[str, tuple[str, ...]] = {
    "answers": ("confidence", "response_ms", "stimulus", "round", "position", "reloads",
                "answered"),
}  # fmt: skip
# Coordinates, time stamps and τ must be finite in float32 (the study's and the networks'
# precision; their differences then stay finite in float64). Counts must be whole numbers
# that float32 holds exactly (training holds counts in float32): at most 2**24.
NUMBER_MAX = FLOAT32_MAX
COUNT_MAX = 2**24
ROLES = ("trajectories", "goals", "answers")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_NON_FINITE = re.compile(r"[+-]?(?:nan|inf|infinity)", re.ASCII | re.IGNORECASE)


@dataclasses.dataclass
class _Table:
    path: Path
    rows: list[dict[str, Any]]
    where: list[str]  # "line 5" (CSV) or "item 3" (JSON) per row
    columns: list[str]  # the columns read
    left_out: list[str]  # the columns there and not read (RECORDED, ignore_columns)

    def at(self, i: int, field: str) -> str:
        return f"{self.path.name}, {self.where[i]}, field {field!r}"


class _JsonObject(dict):
    """A JSON object that remembers its first duplicated key (``json`` keeps the last)."""

    duplicate: str | None = None


def _json_object(pairs: list[tuple[str, Any]]) -> _JsonObject:
    obj = _JsonObject()
    for k, v in pairs:
        if k in obj and obj.duplicate is None:
            obj.duplicate = k
        obj[k] = v
    return obj


def _unknown_column(path: Path, where: str, name: str, role: str) -> ValueError:
    required, optional = COLUMNS[role]
    known = (*required, *optional)
    close = [c for c in known if c.lower() == name.lower()] or difflib.get_close_matches(
        name, known, n=1, cutoff=0.6
    )
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    recorded = RECORDED.get(role, ())
    also = f", and, not read, {', '.join(recorded)}" if recorded else ""
    return ValueError(
        f"{path.name}, {where}, field {name!r}: unknown column{hint}; the {role} table's "
        f"columns are {', '.join(required)} and optionally {', '.join(optional)}{also} (to "
        f"keep other columns on purpose, pass --ignore-columns {name})"
    )


def _known(role: str, ignore: frozenset[str]) -> tuple[set[str], set[str]]:
    """(the columns read, every column accepted) of a table."""
    required, optional = COLUMNS[role]
    read = {*required, *optional} - ignore
    return read, {*read, *RECORDED.get(role, ()), *ignore}


def _split_columns(names: Sequence[str], read: set[str]) -> tuple[list[str], list[str]]:
    """The columns read and those left out, each once, in order of appearance."""
    names = list(dict.fromkeys(c for c in names if c != ""))
    return [c for c in names if c in read], [c for c in names if c not in read]


def _read_csv(path: Path, role: str, ignore: frozenset[str]) -> _Table:
    # UTF-8 (a spreadsheet's byte-order mark dropped); a bad byte is named by line
    read, known = _known(role, ignore)
    with io.StringIO(fileio.read_text(path), newline="") as f:
        reader = csv.reader(f)
        header: list[str] | None = None
        head_line = 0
        rows, where = [], []
        line = 1  # the line on which the next record starts
        try:
            for record in reader:
                start, line = line, reader.line_num + 1
                if header is None:
                    if not record:
                        continue  # blank lines before the header
                    header, head_line = [c.strip() for c in record], start
                    for j, name in enumerate(header):
                        if name == "":
                            continue  # no name: it must hold no value (checked per row)
                        if name in header[:j]:
                            raise ValueError(
                                f"{path.name}, line {start}, field {name!r}: the header names "
                                f"this column twice (columns {header.index(name) + 1} and "
                                f"{j + 1}); expected each column once"
                            )
                        if name not in known:
                            raise _unknown_column(path, f"line {start}", name, role)
                    continue
                if len(record) > len(header):
                    raise ValueError(
                        f"{path.name}, line {start}, column {len(header) + 1}: more values "
                        f"({len(record)}) than header columns ({len(header)})"
                    )
                if not any(v.strip() for v in record):
                    continue  # blank line
                record = record + [""] * (len(header) - len(record))
                for j, v in enumerate(record):
                    if header[j] == "" and v.strip():
                        raise ValueError(
                            f"{path.name}, line {start}, column {j + 1}: a value ({v.strip()!r}) "
                            "in a column without a name in the header; name the column"
                        )
                rows.append({k: v.strip() for k, v in zip(header, record, strict=True)})
                where.append(f"line {start}")
        except csv.Error as e:
            limit = csv.field_size_limit()
            if "field limit" in str(e):
                raise ValueError(
                    f"{path.name}, line {line}: a field longer than {limit} characters (the "
                    f"csv module's limit), running to line {reader.line_num}; expected short "
                    'values (an unclosed quote (") makes the rest of the file one field)'
                ) from None
            raise ValueError(f"{path.name}, line {line}: not a valid CSV record ({e})") from None
    columns, left_out = _split_columns(header or [], read)
    rows = [{k: v for k, v in r.items() if k in read} for r in rows]
    _check_required(path, f"line {head_line or 1}", columns, role)
    return _Table(path, rows, where, columns, left_out)


def _read_json(path: Path, role: str, ignore: frozenset[str]) -> _Table:
    doc = fileio.read_json(path, object_pairs_hook=_json_object)  # names a broken line
    if not isinstance(doc, list):
        raise ValueError(f"{path.name}: expected a JSON list of objects (one per row)")
    if not doc:
        raise ValueError(f"{path.name}: no rows (an empty JSON list)")
    for i, r in enumerate(doc):
        if not isinstance(r, dict):
            raise ValueError(
                f"{path.name}, item {i}: expected an object (one row: column -> value), got "
                f"{json.dumps(r)[:40]}"
            )
    read, known = _known(role, ignore)
    for i, r in enumerate(doc):
        if r.duplicate is not None:
            raise ValueError(
                f"{path.name}, item {i}, field {r.duplicate!r}: the object gives this key "
                "twice; expected each key once"
            )
        for k in r:
            if k not in known:
                raise _unknown_column(path, f"item {i}", k, role)
    columns, left_out = _split_columns([k for r in doc for k in r], read)
    rows = [{k: v for k, v in r.items() if k in read} for r in doc]
    _check_required(path, "item 0", columns, role)
    return _Table(path, rows, [f"item {i}" for i in range(len(rows))], columns, left_out)


def _check_required(path: Path, where: str, columns: list[str], role: str) -> None:
    missing = [c for c in COLUMNS[role][0] if c not in columns]
    if missing:
        raise ValueError(
            f"{path.name}, {where}, field {missing[0]!r}: missing column; the {role} table "
            f"needs {', '.join(COLUMNS[role][0])} (found columns {columns})"
        )


def _read_table(path: str | os.PathLike, role: str, ignore: frozenset[str]) -> _Table:
    """One table, every column checked against :data:`COLUMNS` (``ignore``: dropped)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        tab = _read_json(path, role, ignore)
    else:
        tab = _read_csv(path, role, ignore)
    if not tab.rows:
        raise ValueError(f"{path.name}: no rows")
    return tab


def _blank(v) -> bool:
    return v is None or (isinstance(v, str) and v.strip() == "")


def _show(v) -> str:
    """A value as the user wrote it (JSON's true/false/null as such)."""
    if isinstance(v, bool) or v is None:
        return json.dumps(v)
    return repr(v)


def _number(tab: _Table, i: int, field: str, *, limit: float = NUMBER_MAX) -> float:
    """A finite number with ``|x| <= limit``: a JSON number or a decimal text (``1.5``,
    ``-2e-3``; not ``true``, ``1_000`` or another script's digits, which ``float`` takes)."""
    v = tab.rows[i].get(field)
    x = None
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        try:
            x = float(v)
        except OverflowError:  # a JSON integer beyond float64
            x = math.inf
    elif isinstance(v, str) and _NUMBER.fullmatch(v.strip()):
        x = float(v)
    elif isinstance(v, str) and _NON_FINITE.fullmatch(v.strip()):
        x = math.nan
    if x is None:
        kind = " (a JSON boolean)" if isinstance(v, bool) else ""
        raise ValueError(f"{tab.at(i, field)}: expected a number, got {_show(v)}{kind}")
    if not math.isfinite(x) or abs(x) > limit:
        raise ValueError(
            f"{tab.at(i, field)}: expected a finite number of magnitude at most {limit:.4g}, "
            f"got {_show(v)}"
        )
    return x


def _text(tab: _Table, i: int, field: str) -> str:
    """A name: a text, or a JSON number (``3`` and ``3.0`` read as ``"3"``)."""
    v = tab.rows[i].get(field)
    if _blank(v):
        raise ValueError(f"{tab.at(i, field)}: expected a value, got an empty one")
    ok = isinstance(v, str) or (
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    )
    if not ok:
        raise ValueError(f"{tab.at(i, field)}: expected a name (text or a number), got {_show(v)}")
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    return str(v).strip()


def _ignored(ignore_columns: Sequence[str]) -> frozenset[str]:
    ignore = frozenset(c.strip() for c in ignore_columns if c.strip())
    for c in sorted(ignore):
        roles = [role for role, (req, _) in COLUMNS.items() if c in req]
        if roles:
            raise ValueError(
                f"ignore_columns (--ignore-columns): {c!r} is a column the import needs (in "
                f"the {' and '.join(roles)} table); expected only columns to leave out"
            )
    return ignore


@dataclasses.dataclass(frozen=True)
class ImportReport:
    """What :func:`read_tables` read (``str(report)`` is the import command's report)."""

    files: dict[str, str]  # role -> path
    point_rows: int
    goal_rows: int
    answer_rows: int
    participants: int  # distinct participant ids (0: column absent)
    taus: int  # distinct prefix times (whole motions not counted)
    left_out: dict[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)  # not read

    def describe(self, study: Study) -> str:
        def unread(role):
            cols = self.left_out.get(role)
            return f"; not read: {', '.join(cols)}" if cols else ""

        return "\n".join(
            [
                f"read {self.files['trajectories']}: {self.point_rows} points"
                + unread("trajectories"),
                f"read {self.files['goals']}: {self.goal_rows} goals" + unread("goals"),
                f"read {self.files['answers']}: {self.answer_rows} rows"
                + (f", {self.participants} participants" if self.participants else "")
                + (
                    f", {self.taus} distinct prefix time{'s' * (self.taus != 1)}"
                    if self.taus
                    else ""
                )
                + unread("answers"),
                study.summary(),
            ]
        )


def read_tables(
    trajectories: str | os.PathLike,
    goals: str | os.PathLike,
    answers: str | os.PathLike,
    *,
    ignore_columns: Sequence[str] = (),
) -> tuple[Study, ImportReport]:
    """Import a study from three tables (CSV with a header, or a JSON list of objects).

    Layout (one row per point, goal and answer; see the module docstring):

    - ``trajectories``: ``trajectory, x, y, z[, t]``: points in time order per trajectory;
    - ``goals``: ``[trajectory,] goal, x, y, z``: shared goals, or goals per trajectory;
    - ``answers``: ``trajectory, guess[, tau, participant, condition, count]``.

    Answers with the same (trajectory, τ, condition) become one answer row of counts.
    Returns the validated :class:`Study` and an :class:`ImportReport`.

    The import is strict, so that what it reads is what was written: a column not in
    :data:`COLUMNS` (a misspelt ``cuont``) is refused unless named in ``ignore_columns``
    (then left out; the required columns cannot be) or in :data:`RECORDED` (what ``study
    export`` records beside each answer, accepted and not read; the report names both); a
    header or JSON object naming a column twice is refused; a number is a JSON number or a
    decimal text (not ``true``), finite, of magnitude at most :data:`NUMBER_MAX` (float32;
    a count at most :data:`COUNT_MAX`), so no value overflows when stored. Every error is a
    ValueError naming the file, the line (CSV) or item (JSON), and the field; nothing is
    printed.

    >>> study, report = read_tables("traj.csv", "goals.csv", "answers.csv")  # doctest: +SKIP
    >>> print(report.describe(study))  # doctest: +SKIP
    """
    ignore = _ignored(ignore_columns)
    tt = _read_table(trajectories, "trajectories", ignore)
    gt = _read_table(goals, "goals", ignore)
    at = _read_table(answers, "answers", ignore)

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
    for g in gsets.values():  # distinct as stored (float32)
        pos = np.array([p for p, _ in g.values()], np.float32).astype(np.float64)
        d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(len(pos))
        if (d < SAME_POSITION).any():
            j = int(np.argwhere(d < SAME_POSITION)[0].max())
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
            count = _number(at, i, "count", limit=math.inf)  # its own bound, below
            if count < 0 or count != round(count) or count > COUNT_MAX:
                raise ValueError(
                    f"{at.at(i, 'count')}: expected a whole number of answers >= 0 (at most "
                    f"{COUNT_MAX}, exact in float32), got {_show(at.rows[i]['count'])}"
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
        left_out={role: tuple(tab.left_out) for role, tab in zip(ROLES, (tt, gt, at), strict=True)},
    )
    return study, report
