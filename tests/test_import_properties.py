"""Property tests (hypothesis) of the study import (:func:`slotv_jax.study.read_tables`).

For small generated tables (trajectories, goals, answers; CSV or JSON) with one column
renamed, duplicated or retyped, the import either reads exactly what was written (the
Study's arrays against the generated values, through an independent re-derivation of the
documented rules) or raises a ValueError whose message names the file, the line (CSV) or
item (JSON), and the field; it never warns. The profile in ``conftest.py`` derandomises
every test (the same examples on every run).
"""

from __future__ import annotations

import csv
import io
import json
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slotv_jax.core.validation import SAME_POSITION
from slotv_jax.study import read_tables

ROLES = ("trajectories", "goals", "answers")
# the documented layout (read_tables' docstring): (required, optional) columns per table
COLUMNS = {
    "trajectories": (("trajectory", "x", "y", "z"), ("t",)),
    "goals": (("goal", "x", "y", "z"), ("trajectory",)),
    "answers": (("trajectory", "guess"), ("tau", "participant", "condition", "count")),
}
# columns of the answers table that ``study export`` records and the import does not read
RECORDED = {"confidence", "response_ms", "stimulus", "round", "position", "reloads", "answered"}
FILES = {"trajectories": "traj", "goals": "goals", "answers": "answers"}
TAU_RTOL = 1e-9  # the documented tolerance: τ within 1e-9 of the duration of t_i sees t_i
NAME = st.text(alphabet="abcdefgh0123_", min_size=1, max_size=3)

# --------------------------------------------------------------- generated tables


def _apart(points) -> bool:
    """Goals the importer takes as distinct: at least SAME_POSITION apart as stored (float32),
    so that a table is refused for the one bad cell a test puts in, not for its goals."""
    p = np.asarray(points, np.float32).astype(np.float64)
    d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(len(p))
    return bool((d >= SAME_POSITION).all())


@st.composite
def tables(draw) -> dict:
    """Tables as Python values: {role: {"columns": [...], "rows": [{col: value|None}]}}.
    ``None`` is a blank cell (CSV) or a missing key / null (JSON)."""
    n = draw(st.integers(1, 3))
    ids = draw(st.lists(NAME, min_size=n, max_size=n, unique=True))
    has_t = draw(st.booleans())
    coord = st.floats(-2.0, 2.0, allow_nan=False)
    traj_rows, times = [], {}
    for tid in ids:
        length = draw(st.integers(2, 4))
        if has_t:
            t0 = draw(st.floats(-5.0, 5.0))
            steps = draw(st.lists(st.floats(1e-3, 10.0), min_size=length - 1, max_size=length - 1))
            ts = [t0]
            for d in steps:
                ts.append(ts[-1] + d)
        else:
            ts = [i / (length - 1) for i in range(length)]
        times[tid] = ts
        for i in range(length):
            row = {"trajectory": tid, "x": draw(coord), "y": draw(coord), "z": draw(coord)}
            if has_t:
                row["t"] = ts[i]
            traj_rows.append(row)
    traj_cols = ["trajectory", "x", "y", "z"] + (["t"] if has_t else [])

    per_traj = draw(st.booleans())
    owners = ids if per_traj else [None]
    goal_rows, goal_names = [], {}
    pos = st.tuples(*[st.floats(-2.0, 2.0, width=32)] * 3)  # distinct as stored (float32)
    for owner in owners:
        k = draw(st.integers(1, 3))
        names = draw(st.lists(NAME, min_size=k, max_size=k, unique=True))
        where = draw(st.lists(pos, min_size=k, max_size=k, unique=True).filter(_apart))
        goal_names[owner] = names
        for name, (x, y, z) in zip(names, where, strict=True):
            row = {"goal": name, "x": x, "y": y, "z": z}
            if per_traj:
                row["trajectory"] = owner
            goal_rows.append(row)
    goal_cols = (["trajectory"] if per_traj else []) + ["goal", "x", "y", "z"]

    has = {c: draw(st.booleans()) for c in ("tau", "participant", "condition", "count")}
    answer_rows = []
    for tid in ids:
        for _ in range(draw(st.integers(1, 2))):
            names = goal_names[tid if per_traj else None]
            row = {"trajectory": tid, "guess": draw(st.sampled_from(names))}
            if has["tau"]:
                j = draw(st.integers(0, len(times[tid]) - 1))
                row["tau"] = None if j == 0 else times[tid][j]  # blank: the whole motion
            if has["participant"]:
                row["participant"] = draw(st.none() | st.sampled_from(["p1", "p2", "p3"]))
            if has["condition"]:
                row["condition"] = draw(st.sampled_from(["front", "side"]))
            if has["count"]:
                row["count"] = draw(st.none() | st.integers(1, 5))
            answer_rows.append(row)
    answer_cols = ["trajectory", "guess"] + [c for c, h in has.items() if h]
    draw(st.randoms()).shuffle(answer_rows)
    return {
        "trajectories": {"columns": traj_cols, "rows": traj_rows},
        "goals": {"columns": goal_cols, "rows": goal_rows},
        "answers": {"columns": answer_cols, "rows": answer_rows},
    }


def _cell(v) -> str:
    return "" if v is None else repr(v) if isinstance(v, float) else str(v)


def write(tabs: dict, folder: Path, fmt: str) -> dict[str, Path]:
    """Write each table; a column listed twice in "columns" is written twice (values from
    "dup", else the row's own). JSON objects are written by hand so a key may repeat."""
    paths = {}
    for role, tab in tabs.items():
        path = folder / f"{FILES[role]}.{fmt}"
        cols, dup = tab["columns"], tab.get("dup", {})
        if fmt == "csv":
            buf = io.StringIO()
            w = csv.writer(buf, lineterminator="\n")
            w.writerow(cols)
            for i, row in enumerate(tab["rows"]):
                cells, seen = [], set()
                for c in cols:
                    v = dup.get(i, row.get(c)) if c in seen else row.get(c)
                    seen.add(c)
                    cells.append(_cell(v))
                w.writerow(cells)
            path.write_text(buf.getvalue())
        else:
            items = []
            for i, row in enumerate(tab["rows"]):
                pairs, seen = [], set()
                for c in cols:
                    if c not in row:
                        continue  # a blank optional cell: the key left out
                    v = dup.get(i, row[c]) if c in seen else row[c]
                    seen.add(c)
                    pairs.append(f"{json.dumps(c)}: {json.dumps(v)}")
                items.append("{" + ", ".join(pairs) + "}")
            path.write_text("[\n" + ",\n".join(items) + "\n]\n")
        paths[role] = path
    return paths


# ---------------------------------------------------------- the documented reading


class Refused(Exception):
    """The tables break a documented rule: the import must name (role, row, field)."""


def expected(tabs: dict) -> dict:
    """What the import must read, re-derived from the rules in ``read_tables``' docstring:
    points in order per trajectory (float32), goals by name (float32; at most 8, distinct
    names and positions), and answers summed per (trajectory, τ, condition), τ blank or
    seeing every point being the whole motion. Raises :class:`Refused` where a rule is
    broken (only reachable here once a column is left out on purpose)."""
    cols = {r: set(t["columns"]) for r, t in tabs.items()}
    points, times = {}, {}
    for row in tabs["trajectories"]["rows"]:
        points.setdefault(row["trajectory"], []).append([row["x"], row["y"], row["z"]])
        times.setdefault(row["trajectory"], []).append(row.get("t"))
    for tid, ts in times.items():
        n = len(ts)
        times[tid] = ts if "t" in cols["trajectories"] else [i / (n - 1) for i in range(n)]
    goals: dict = {}
    rows: dict = {}
    for i, row in enumerate(tabs["goals"]["rows"]):
        owner = row["trajectory"] if "trajectory" in cols["goals"] else None
        g = goals.setdefault(owner, {})
        if row["goal"] in g or len(g) == 8:
            raise Refused("goals", i, "goal")
        g[row["goal"]] = np.float32([row["x"], row["y"], row["z"]])
        rows[owner, row["goal"]] = i
    for owner, g in goals.items():
        names = list(g)
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                if np.array_equal(g[names[a]], g[names[b]]):
                    raise Refused("goals", rows[owner, names[b]], "x")
    answers: dict = {}
    participants = set()
    for i, row in enumerate(tabs["answers"]["rows"]):
        tid, ts = row["trajectory"], times[row["trajectory"]]
        full = ts[-1]
        tau = row.get("tau") if "tau" in cols["answers"] else None
        if tau is not None:
            tol = TAU_RTOL * (full - ts[0])
            seen = sum(t <= tau + tol for t in ts)
            if seen < 2 or tau > full + tol:
                raise Refused("answers", i, "tau")  # (t left out: τ on another clock)
            tau = full if seen == len(ts) else tau
        key = (tid, full if tau is None else tau, row.get("condition") or "")
        count = row.get("count") if "count" in cols["answers"] else None
        per_goal = answers.setdefault(key, {})
        per_goal[row["guess"]] = per_goal.get(row["guess"], 0) + (1 if count is None else count)
        if "participant" in cols["answers"] and row.get("participant") is not None:
            participants.add(row["participant"])
    return {
        "points": {k: np.float32(v) for k, v in points.items()},
        "times": times if "t" in cols["trajectories"] else None,
        "goals": {tid: goals[tid if None not in goals else None] for tid in points},
        "answers": answers,
        "participants": len(participants),
    }


def read_back(study, report) -> dict:
    """The same fields from the imported Study (its arrays, by id and by name)."""
    ids = study.trajectory_ids
    answers: dict = {}
    for a in range(study.n_rows):
        k = int(study.answer_trajectory[a])
        cond = "" if study.answer_condition is None else study.conditions[study.answer_condition[a]]
        key = (ids[k], float(study.answer_tau[a]), cond)
        assert key not in answers, key  # one answer row per (trajectory, τ, condition)
        answers[key] = {
            str(study.goal_names[k, s]): float(study.counts[a, s])
            for s in range(8)
            if study.counts[a, s] > 0
        }
    length = study.length
    return {
        "points": {tid: study.xyz[k, : length[k]] for k, tid in enumerate(ids)},
        "times": None
        if study.t is None
        else {tid: list(study.t[k, : length[k]]) for k, tid in enumerate(ids)},
        "goals": {
            tid: {
                str(study.goal_names[k, s]): study.goals[k, s]
                for s in range(8)
                if study.goal_mask[k, s]
            }
            for k, tid in enumerate(ids)
        },
        "answers": answers,
        "participants": report.participants,
    }


def assert_reads_exactly(paths, tabs, fmt, **kw) -> None:
    """The import reads what ``expected`` derives, or, where that refuses, names the place."""
    try:
        want = expected(tabs)
    except Refused as r:
        assert_names_place(paths, fmt, *r.args, **kw)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        study, report = read_tables(paths["trajectories"], paths["goals"], paths["answers"], **kw)
    got = read_back(study, report)
    assert list(got["points"]) == list(want["points"])  # ids in order of appearance
    for tid, p in want["points"].items():
        np.testing.assert_array_equal(got["points"][tid], p)
        assert got["points"][tid].dtype == np.float32
    assert got["times"] == want["times"]
    assert set(got["goals"]) == set(want["goals"])
    for tid, g in want["goals"].items():
        assert list(got["goals"][tid]) == list(g)  # slots in order of appearance
        for name, p in g.items():
            np.testing.assert_array_equal(got["goals"][tid][name], p)
    assert got["answers"] == want["answers"]
    assert got["participants"] == want["participants"]


def assert_names_place(paths, fmt, role, row, field, **kw) -> str:
    """The import raises a ValueError naming the file, the line/item and the field."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError) as e:
            read_tables(paths["trajectories"], paths["goals"], paths["answers"], **kw)
    where = f"line {row + 2}" if fmt == "csv" else f"item {row}"
    if row < 0:  # the header (CSV) or the first object with that key (JSON)
        where = "line 1" if fmt == "csv" else f"item {-row - 1}"
    place = f"{paths[role].name}, {where}, field {field!r}"
    assert place in str(e.value), (place, str(e.value))
    return str(e.value)


def _header(tab, fmt, column) -> int:
    """The header's place, as ``assert_names_place``'s row: -1 - (first item with the key)."""
    if fmt == "csv":
        return -1
    return -1 - next(i for i, r in enumerate(tab["rows"]) if column in r)


def _json_ready(tabs, fmt) -> dict:
    """In JSON a blank optional cell is a missing key; in CSV an empty cell."""
    if fmt == "json":
        for tab in tabs.values():
            tab["rows"] = [{k: v for k, v in r.items() if v is not None} for r in tab["rows"]]
    return tabs


FMT = st.sampled_from(["csv", "json"])


# ---------------------------------------------------------------------- the tests


@settings(max_examples=40)
@given(tabs=tables(), fmt=FMT)
def test_tables_as_written_are_read_exactly(tabs, fmt):
    tabs = _json_ready(tabs, fmt)
    with tempfile.TemporaryDirectory() as d:
        assert_reads_exactly(write(tabs, Path(d), fmt), tabs, fmt)


def _misspelt(draw, column: str) -> str:
    kind = draw(st.sampled_from(["swap", "drop", "add", "upper", "other"]))
    if kind == "swap" and len(column) > 1:
        i = draw(st.integers(0, len(column) - 2))
        return column[:i] + column[i + 1] + column[i] + column[i + 2 :]
    if kind == "drop" and len(column) > 1:
        i = draw(st.integers(0, len(column) - 1))
        return column[:i] + column[i + 1 :]
    if kind == "add":
        i = draw(st.integers(0, len(column)))
        return column[:i] + draw(st.sampled_from("aeiouxyz")) + column[i:]
    if kind == "upper":
        return column.upper()
    return draw(st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=8))


@settings(max_examples=80)
@given(tabs=tables(), fmt=FMT, data=st.data())
def test_a_renamed_column_is_refused_or_left_out_on_purpose(tabs, fmt, data):
    """A renamed (misspelt) column is refused by name; passed in ``ignore_columns`` it is
    left out, and the rest is read exactly (a required column then is missing)."""
    tabs = _json_ready(tabs, fmt)
    role = data.draw(st.sampled_from(ROLES))
    tab = tabs[role]
    column = data.draw(st.sampled_from(tab["columns"]))
    if fmt == "json" and not any(column in r for r in tab["rows"]):
        return  # an optional column left blank everywhere: in JSON it is not there at all
    new = _misspelt(data.draw, column)
    known = {c for req, opt in COLUMNS.values() for c in (*req, *opt)} | RECORDED
    if new in known or new.strip() != new:
        return  # another table's known column is refused by ignore_columns; tested below
    ignore = data.draw(st.booleans())
    tab["columns"] = [new if c == column else c for c in tab["columns"]]
    tab["rows"] = [{(new if k == column else k): v for k, v in r.items()} for r in tab["rows"]]
    kw = {"ignore_columns": [new]} if ignore else {}
    with tempfile.TemporaryDirectory() as d:
        paths = write(tabs, Path(d), fmt)
        if not ignore:
            msg = assert_names_place(paths, fmt, role, _header(tab, fmt, new), new)
            assert "unknown column" in msg and ", ".join(COLUMNS[role][0]) in msg
            return
        if column in COLUMNS[role][0]:  # a required column cannot be left out
            assert_names_place(paths, fmt, role, -1, column, **kw)
            return
        # an optional one is left out: the rest is read as if it had never been there
        # (without t, a written τ is on another clock; without the goals' owners, their
        # goals become one shared set)
        tab["columns"].remove(new)
        tab["rows"] = [{k: v for k, v in r.items() if k != new} for r in tab["rows"]]
        assert_reads_exactly(paths, tabs, fmt, **kw)


@settings(max_examples=60)
@given(tabs=tables(), fmt=FMT, data=st.data())
def test_a_duplicated_column_is_refused(tabs, fmt, data):
    """A header (or JSON object) naming a column twice is refused, whatever the second holds
    (the second copy used to win without a word)."""
    tabs = _json_ready(tabs, fmt)
    role = data.draw(st.sampled_from(ROLES))
    tab = tabs[role]
    column = data.draw(st.sampled_from(tab["columns"]))
    if fmt == "json" and not any(column in r for r in tab["rows"]):
        return
    if data.draw(st.booleans()):  # another value in the second copy of one row
        i = data.draw(st.integers(0, len(tab["rows"]) - 1))
        if column in tab["rows"][i]:
            tab["dup"] = {i: data.draw(st.sampled_from([9.5, 3, "zz"]))}
    at = data.draw(st.integers(0, len(tab["columns"])))
    tab["columns"] = [*tab["columns"][:at], column, *tab["columns"][at:]]
    with tempfile.TemporaryDirectory() as d:
        paths = write(tabs, Path(d), fmt)
        msg = assert_names_place(paths, fmt, role, _header(tab, fmt, column), column)
        assert "twice" in msg


NUMBER_FIELDS = {"x", "y", "z", "t", "tau", "count"}
# values that are not numbers, or not finite in float32, as CSV text and as JSON values
BAD_NUMBER_CSV = ["abc", "true", "1_0", "nan", "-Infinity", "inf", "1e300", "-1e39", "0x10",
                  "\u0661", "1,5", "--1", "1e", " "]  # fmt: skip
BAD_NUMBER_JSON = [True, False, "abc", [1.0], {"v": 1}, "nan", 1e300, -1e39, float("nan"),
                   float("inf"), "1_0", 10**400]  # fmt: skip
BAD_EXTRA = {"count": [1.5, -1, 2**24 + 1], "tau": [1e6, -1e6]}
BAD_TEXT_JSON = [True, False, [1], {"a": "b"}, float("nan")]


@settings(max_examples=150)
@given(tabs=tables(), fmt=FMT, data=st.data())
def test_a_retyped_value_is_named_by_place(tabs, fmt, data):
    """One cell of another type (a boolean, a word, a list, a value float32 cannot hold, an
    empty required name) is refused with its file, line/item and field."""
    tabs = _json_ready(tabs, fmt)
    role = data.draw(st.sampled_from(ROLES))
    tab = tabs[role]
    numbers = [c for c in tab["columns"] if c in NUMBER_FIELDS]
    # in CSV a name is retyped by leaving it empty: only the required names refuse that (a
    # blank participant is allowed, and a blank condition is tested in test_study)
    texts = [c for c in tab["columns"] if c not in NUMBER_FIELDS]
    if fmt == "csv":
        texts = [c for c in texts if c in COLUMNS[role][0]]
    column = data.draw(
        st.sampled_from(data.draw(st.sampled_from([k for k in (numbers, texts) if k])))
    )
    i = data.draw(st.integers(0, len(tab["rows"]) - 1))
    if column in NUMBER_FIELDS:
        bad = BAD_NUMBER_CSV if fmt == "csv" else BAD_NUMBER_JSON
        if column in ("tau", "count"):  # optional: a blank one is the default, not an error
            bad = [b for b in bad if b != " "] + BAD_EXTRA[column]
        value = data.draw(st.sampled_from(bad))
    else:
        value = data.draw(st.sampled_from(BAD_TEXT_JSON)) if fmt == "json" else ""
    tab["rows"][i] = {**tab["rows"][i], column: value}
    with tempfile.TemporaryDirectory() as d:
        paths = write(tabs, Path(d), fmt)
        assert_names_place(paths, fmt, role, i, column)
