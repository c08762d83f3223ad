"""Tests for slotv_jax.study: the format's round trip, table import, every validation error,
the count likelihood against a float64 NumPy reference, prefix masking, simulated
participants, β fitting, training through the CLI, and the README's example."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from docs_pages import marked_block
from flax import nnx

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax import study
from slotv_jax.observers import models
from slotv_jax.study import cli as study_cli
from slotv_jax.train import cli as train_cli
from slotv_jax.training import checkpoint, losses, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

REL_TOL = 2e-5  # float32 loss against the float64 reference
ROOT = Path(__file__).resolve().parents[1]


def synthetic(n=40, t=30, seed=0, goals_per=(2, 3, 4)):
    """Paths from the home TCP through one via point to a goal on the table (NumPy)."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((n, 8, 3), np.float32)
    mask = np.zeros((n, 8), bool)
    xyz = np.zeros((n, t, 3), np.float32)
    for i in range(n):
        k = int(rng.choice(goals_per))
        y = np.linspace(-0.4, 0.4, k) + rng.uniform(-0.03, 0.03, k)
        g = np.c_[rng.uniform(0.3, 0.7, k), y, np.full(k, 0.025)]
        goals[i, :k], mask[i, :k] = g, True
        via = [rng.uniform(0.25, 0.7), rng.uniform(-0.5, 0.5), rng.uniform(0.1, 0.4)]
        s = np.linspace(0, 1, t // 2)[:, None]
        xyz[i, : t // 2] = np.array([0.31, 0.0, 0.49]) * (1 - s) + np.array(via) * s
        s = np.linspace(0, 1, t - t // 2)[:, None]
        xyz[i, t // 2 :] = np.array(via) * (1 - s) + g[rng.integers(k)] * s
    return xyz, goals, mask


@pytest.fixture(scope="module")
def small():
    """A study with ragged lengths, time stamps, prefixes, conditions and goal names."""
    xyz, goals, mask = synthetic(12, 20)
    length = np.array([20, 15, 8, 20, 2, 12, 20, 20, 9, 20, 16, 20])
    t = np.cumsum(np.full((12, 20), 0.1), axis=1)
    traj = np.array([0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 11])
    counts = np.zeros((14, 8))
    for a, k in enumerate(traj):
        counts[a, : mask[k].sum()] = np.arange(mask[k].sum()) + a % 3
    tau = t[traj, length[traj] - 1].copy()
    tau[0], tau[13] = t[0, 4], t[11, 1]  # prefixes: 5 and 2 points seen
    return study.make_study(
        xyz, goals, mask, traj, counts, length=length, answer_tau=tau, t=t,
        answer_condition=np.arange(14) % 2, conditions=("front", "side"),
        trajectory_ids=[f"tr{i}" for i in range(12)],
        goal_names=np.where(mask, np.array([f"g{k}" for k in range(8)]), ""),
    )  # fmt: skip


# ---------------------------------------------------------------- format


def test_round_trip(small, tmp_path):
    path = study.save_study(tmp_path / "s.npz", small)
    back = study.load_study(path)
    for f in ("xyz", "length", "goals", "goal_mask", "answer_trajectory", "answer_tau",
              "counts", "t", "answer_condition", "goal_names"):  # fmt: skip
        np.testing.assert_array_equal(getattr(back, f), getattr(small, f), err_msg=f)
    assert back.conditions == small.conditions and back.trajectory_ids == small.trajectory_ids
    np.testing.assert_array_equal(back.seen(), [5, 20, 15, 8, 20, 2, 12, 20, 20, 9, 20, 16, 20, 2])
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        assert all(z[k].dtype != object for k in z.files)
    # shared goals are stored once and come back identical
    xyz, goals, mask = synthetic(3, 10)
    shared = study.make_study(xyz, goals[0], mask[0], [0, 1, 2], np.eye(8)[[0, 1, 0]])
    back = study.load_study(study.save_study(tmp_path / "shared.npz", shared))
    with np.load(tmp_path / "shared.npz") as z:
        assert z["goals"].shape == (8, 3)
    np.testing.assert_array_equal(back.goals, np.broadcast_to(goals[0], (3, 8, 3)))


def test_probs_with_participant_count(tmp_path):
    xyz, goals, mask = synthetic(2, 10, goals_per=(2,))
    probs = np.zeros((2, 8))
    probs[:, :2] = [[0.25, 0.75], [0.5, 0.5]]
    path = tmp_path / "p.npz"
    np.savez(path, format=np.array(study.FORMAT), xyz=xyz, goals=goals, goal_mask=mask,
             answer_trajectory=np.array([0, 1]), probs=probs,
             n_answers=np.array([8.0, 3.0]))  # fmt: skip
    s = study.load_study(path)
    np.testing.assert_allclose(s.counts[:, :2], [[2.0, 6.0], [1.5, 1.5]])


TRAJ_CSV = """trajectory,t,x,y,z
a,0.0,0.31,0.00,0.49
a,0.5,0.40,0.12,0.30
a,1.0,0.50,0.20,0.03
b,0.0,0.31,0.00,0.49
b,2.0,0.55,-0.15,0.10
"""
GOALS_CSV = "goal,x,y,z\nleft,0.50,0.25,0.025\nright,0.55,-0.20,0.025\n"
ANSWERS_CSV = """trajectory,tau,guess,participant,condition,count
a,0.5,left,p1,front,
a,0.5,right,p2,front,
a,0.5,left,p3,front,
a,,left,p1,front,2
b,,right,p1,side,
"""


def _write_tables(tmp_path, traj=TRAJ_CSV, goals=GOALS_CSV, answers=ANSWERS_CSV):
    paths = []
    for name, text in (("traj.csv", traj), ("goals.csv", goals), ("answers.csv", answers)):
        (tmp_path / name).write_text(text)
        paths.append(tmp_path / name)
    return paths


def test_csv_and_json_import(tmp_path):
    s, rep = study.read_tables(*_write_tables(tmp_path))
    assert s.trajectory_ids == ("a", "b") and s.conditions == ("front", "side")
    np.testing.assert_array_equal(s.length, [3, 2])
    np.testing.assert_array_equal(s.answer_trajectory, [0, 0, 1])
    np.testing.assert_array_equal(s.answer_tau, [0.5, 1.0, 2.0])
    np.testing.assert_array_equal(s.counts[:, :2], [[2, 1], [2, 0], [0, 1]])
    np.testing.assert_array_equal(s.seen(), [2, 3, 2])
    np.testing.assert_array_equal(s.answer_condition, [0, 0, 1])
    np.testing.assert_allclose(s.xyz[0, 1], [0.40, 0.12, 0.30], rtol=1e-6)
    assert (rep.answer_rows, rep.participants, rep.taus) == (5, 3, 1)
    assert "3 participants" in rep.describe(s)
    # the same tables as JSON lists of objects give the same study
    tables = []
    for name, text in (("traj", TRAJ_CSV), ("goals", GOALS_CSV), ("answers", ANSWERS_CSV)):
        lines = text.strip().splitlines()
        keys = lines[0].split(",")
        rows = [dict(zip(keys, ln.split(","), strict=True)) for ln in lines[1:]]
        tables.append(tmp_path / f"{name}.json")
        tables[-1].write_text(json.dumps(rows))
    sj, _ = study.read_tables(*tables)
    np.testing.assert_array_equal(sj.counts, s.counts)
    np.testing.assert_array_equal(sj.xyz, s.xyz)
    # the import command reports what it read and writes a loadable file
    out = tmp_path / "s.npz"
    assert study_cli.main(["import", "--trajectories", str(tables[0]), "--goals", str(tables[1]),
                       "--answers", str(tables[2]), "--out", str(out)]) == 0  # fmt: skip
    np.testing.assert_array_equal(study.load_study(out).counts, s.counts)


# ------------------------------------------------------------ validation

CSV_ERRORS = [
    # (which table, old text, new text, expected message pieces)
    ("answers", "a,,left,p1,front,2", "a,,left,p1,front,-1",
     ["answers.csv", "line 5", "'count'", ">= 0"]),
    ("answers", "a,,left,p1,front,2", "a,,left,p1,front,1.5",
     ["answers.csv", "line 5", "'count'", "whole number"]),
    ("answers", "b,,right,p1,side,", "b,,middle,p1,side,",
     ["answers.csv", "line 6", "'guess'", "not a goal"]),
    ("answers", "b,,right,p1,side,", "a,,right,p1,side,",
     ["answers.csv", "'trajectory'", "'b'", "no answers"]),
    ("answers", "b,,right,p1,side,", "zz,,right,p1,side,",
     ["answers.csv", "line 6", "'trajectory'", "unknown trajectory id 'zz'"]),
    ("answers", "a,0.5,right,p2", "a,1.7,right,p2", ["answers.csv", "line 3", "'tau'", "outside"]),
    ("answers", "a,0.5,right,p2", "a,0.2,right,p2", ["answers.csv", "line 3", "'tau'", "outside"]),
    ("traj", "b,2.0,0.55,-0.15,0.10\n", "", ["traj.csv", "line 5", "'trajectory'", "T >= 2"]),
    ("traj", "a,0.5,0.40,0.12,0.30", "a,0.5,nan,0.12,0.30",
     ["traj.csv", "line 3", "'x'", "finite"]),
    ("traj", "a,1.0,0.50", "a,0.4,0.50", ["traj.csv", "line 4", "'t'", "increasing"]),
    ("goals", "right,0.55,-0.20,0.025\n",
     "right,0.55,-0.20,0.025\n" + "".join(f"g{i},0.3,{i / 10},0\n" for i in range(7)),
     ["goals.csv", "line 10", "'goal'", "more than 8"]),
]  # fmt: skip


@pytest.mark.parametrize("table, old, new, pieces", CSV_ERRORS)
def test_table_errors(tmp_path, table, old, new, pieces):
    texts = {"traj": TRAJ_CSV, "goals": GOALS_CSV, "answers": ANSWERS_CSV}
    assert old in texts[table]
    texts[table] = texts[table].replace(old, new)
    paths = _write_tables(tmp_path, texts["traj"], texts["goals"], texts["answers"])
    with pytest.raises(ValueError) as e:
        study.read_tables(*paths)
    for p in pieces:
        assert p in str(e.value), (p, str(e.value))


# --------------------------------------- strict import: what it reads is what was written

STRICT_ERRORS = [
    # a misspelt optional column was left out unseen: 900 answers became 1
    ("answers", "participant,condition,count", "participant,condition,cuont",
     ["answers.csv", "line 1", "'cuont'", "unknown column", "did you mean 'count'",
      "trajectory, guess", "--ignore-columns cuont"]),
    ("traj", "trajectory,t,x,y,z", "trajectory,T,x,y,z",
     ["traj.csv", "line 1", "'T'", "did you mean 't'"]),
    # a header naming a column twice: the second one silently won
    ("goals", "goal,x,y,z\nleft,0.50,0.25,0.025\nright,0.55,-0.20,0.025\n",
     "goal,x,y,z,x\nleft,0.50,0.25,0.025,0.9\nright,0.55,-0.20,0.025,0.1\n",
     ["goals.csv", "line 1", "'x'", "twice", "columns 2 and 5"]),
    # a column without a name may be empty (a spreadsheet's trailing comma), not hold values
    ("goals", "goal,x,y,z\nleft,0.50,0.25,0.025\n", "goal,x,y,z,\nleft,0.50,0.25,0.025,1\n",
     ["goals.csv", "line 2", "column 5", "without a name"]),
    # values float32 cannot hold: inf "at index [0, 1, 0]", two RuntimeWarnings, no line
    ("traj", "a,0.5,0.40,0.12,0.30", "a,0.5,1e300,0.12,0.30",
     ["traj.csv", "line 3", "'x'", "1e300", "at most 3.403e+38"]),
    ("goals", "right,0.55,-0.20,0.025", "right,0.55,-0.20,-4e38",
     ["goals.csv", "line 3", "'z'", "-4e38"]),
    ("traj", "a,0.5,0.40,0.12,0.30", "a,1e39,0.40,0.12,0.30", ["traj.csv", "line 3", "'t'"]),
    ("answers", "a,0.5,right,p2", "a,inf,right,p2", ["answers.csv", "line 3", "'tau'", "finite"]),
    ("answers", "a,,left,p1,front,2", "a,,left,p1,front,1e300",
     ["answers.csv", "line 5", "'count'", "16777216"]),
    # text float() takes but nobody means as a number
    ("traj", "a,0.5,0.40,0.12,0.30", "a,0.5,0.40,1_2,0.30",
     ["traj.csv", "line 3", "'y'", "expected a number, got '1_2'"]),
    ("traj", "a,0.5,0.40,0.12,0.30", "a,0.5,0.40,0.12,\u0663",
     ["traj.csv", "line 3", "'z'", "expected a number"]),
]  # fmt: skip


@pytest.mark.parametrize("table, old, new, pieces", STRICT_ERRORS)
def test_strict_import_errors(tmp_path, table, old, new, pieces):
    """Each of these was read without a word (or with a warning and no file line) before."""
    texts = {"traj": TRAJ_CSV, "goals": GOALS_CSV, "answers": ANSWERS_CSV}
    assert old in texts[table]
    texts[table] = texts[table].replace(old, new)
    paths = _write_tables(tmp_path, texts["traj"], texts["goals"], texts["answers"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing printed: no NumPy RuntimeWarning
        with pytest.raises(ValueError) as e:
            study.read_tables(*paths)
    for p in pieces:
        assert p in str(e.value), (p, str(e.value))


def test_the_columns_study_export_records_are_accepted_and_not_read(tmp_path):
    """``study export`` writes more columns than the import reads (confidence, response
    time, ...): its tables import unchanged, and the report names what was not read."""
    from slotv_jax.webstudy.export import ANSWER_COLUMNS

    extra = [c for c in ANSWER_COLUMNS if c not in ("trajectory", "tau", "guess",
                                                     "participant", "condition")]  # fmt: skip
    lines = ANSWERS_CSV.strip().splitlines()
    answers = "\n".join(
        [lines[0] + "," + ",".join(extra)] + [ln + ",7" * len(extra) for ln in lines[1:]]
    )
    s, rep = study.read_tables(*_write_tables(tmp_path, answers=answers + "\n"))
    np.testing.assert_array_equal(s.counts[:, :2], [[2, 1], [2, 0], [0, 1]])  # as without
    assert rep.left_out["answers"] == tuple(extra)
    assert f"5 rows, 3 participants, 1 distinct prefix time; not read: {', '.join(extra)}" in (
        rep.describe(s)
    )


def test_an_empty_column_without_a_name_is_no_column(tmp_path):
    """A spreadsheet's trailing commas: a column with no name and no values is left out."""
    goals = GOALS_CSV.replace("\n", ",\n")
    assert goals.startswith("goal,x,y,z,\nleft,0.50,0.25,0.025,\n")
    s, _ = study.read_tables(*_write_tables(tmp_path, goals=goals))
    (tmp_path / "ref").mkdir()
    ref, _ = study.read_tables(*_write_tables(tmp_path / "ref"))
    np.testing.assert_array_equal(s.goals, ref.goals)
    np.testing.assert_array_equal(s.counts, ref.counts)


def test_ignore_columns_keeps_extra_columns_on_purpose(tmp_path):
    answers = ANSWERS_CSV.replace("condition,count", "condition,count,notes").replace(
        "front,2", "front,2,slow"
    )
    paths = _write_tables(tmp_path, answers=answers)
    with pytest.raises(ValueError, match=r"line 1, field 'notes': unknown column"):
        study.read_tables(*paths)
    s, rep = study.read_tables(*paths, ignore_columns=["notes"])
    np.testing.assert_array_equal(s.counts[:, :2], [[2, 1], [2, 0], [0, 1]])  # as without
    assert rep.left_out == {"trajectories": (), "goals": (), "answers": ("notes",)}
    # an optional column left out on purpose: every answer counts 1
    s, _ = study.read_tables(*paths, ignore_columns=["notes", "count"])
    np.testing.assert_array_equal(s.counts[:, :2], [[2, 1], [1, 0], [0, 1]])
    with pytest.raises(ValueError, match=r"ignore_columns.*'guess' is a column the import needs"):
        study.read_tables(*paths, ignore_columns=["guess"])
    out = tmp_path / "s.npz"
    argv = ["import", "--trajectories", str(paths[0]), "--goals", str(paths[1]),
            "--answers", str(paths[2]), "--out", str(out), "--ignore-columns", "notes"]  # fmt: skip
    assert study_cli.main(argv) == 0
    np.testing.assert_array_equal(study.load_study(out).counts[:, :2], [[2, 1], [2, 0], [0, 1]])


def _json_tables(tmp_path, edit=None):
    tables = []
    for name, text in (("traj", TRAJ_CSV), ("goals", GOALS_CSV), ("answers", ANSWERS_CSV)):
        lines = text.strip().splitlines()
        keys = lines[0].split(",")
        rows = [dict(zip(keys, ln.split(","), strict=True)) for ln in lines[1:]]
        body = json.dumps(rows)
        tables.append(tmp_path / f"{name}.json")
        tables[-1].write_text(edit(name, body) if edit else body)
    return tables


@pytest.mark.parametrize(
    "table, old, new, pieces",
    [
        # JSON true was read as the number 1
        ("traj", '"x": "0.40"', '"x": true', ["traj.json", "item 1", "'x'", "got true"]),
        ("answers", '"count": "2"', '"count": true', ["answers.json", "item 3", "'count'"]),
        ("answers", '"tau": "0.5"', '"tau": false',
         ["answers.json", "item 0", "'tau'", "got false"]),
        ("goals", '"goal": "left"', '"goal": true', ["goals.json", "item 0", "'goal'"]),
        ("goals", '"goal": "left"', '"goal": ["left"]', ["goals.json", "item 0", "'goal'"]),
        ("traj", '"x": "0.40"', '"x": 1e400', ["traj.json", "item 1", "'x'", "finite"]),
        ("traj", '"x": "0.40"', '"x": ' + "9" * 400, ["traj.json", "item 1", "'x'"]),
        ("traj", '"x": "0.40"', '"x": NaN', ["traj.json", "item 1", "'x'", "finite"]),
        # a key given twice: the last one silently won
        ("goals", '"goal": "left"', '"goal": "left", "goal": "right"',
         ["goals.json", "item 0", "'goal'", "twice"]),
        ("traj", '{"trajectory": "a", "t": "0.0", "x": "0.31", "y": "0.00", "z": "0.49"}',
         '[1, 2]', ["traj.json", "item 0", "expected an object"]),
        ("answers", '"participant": "p1"', '"particpant": "p1"',
         ["answers.json", "item 0", "'particpant'", "did you mean 'participant'"]),
    ],
)  # fmt: skip
def test_strict_json_import(tmp_path, table, old, new, pieces):
    def edit(name, body):
        return body.replace(old, new, 1) if name == table else body

    assert old in json.dumps(_json_rows(table))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError) as e:
            study.read_tables(*_json_tables(tmp_path, edit))
    for p in pieces:
        assert p in str(e.value), (p, str(e.value))


def _json_rows(table):
    text = {"traj": TRAJ_CSV, "goals": GOALS_CSV, "answers": ANSWERS_CSV}[table]
    lines = text.strip().splitlines()
    return [dict(zip(lines[0].split(","), ln.split(","), strict=True)) for ln in lines[1:]]


def test_oversized_field_is_named_by_file_and_line(tmp_path):
    """A field beyond the csv module's limit (an unclosed quote, a binary file) was a raw
    ``_csv.Error`` traceback."""
    big = ANSWERS_CSV.replace("a,0.5,right,p2", 'a,0.5,"right' + "x" * 200_000)
    paths = _write_tables(tmp_path, answers=big)
    with pytest.raises(ValueError, match=r"answers\.csv, line 3: a field longer than 131072"):
        study.read_tables(*paths)


def _import_argv(paths, out):
    return ["import", "--trajectories", str(paths[0]), "--goals", str(paths[1]),
            "--answers", str(paths[2]), "--out", str(out)]  # fmt: skip


def _one_line_exit_2(argv, capsys, *pieces):
    with pytest.raises(SystemExit) as e:
        study_cli.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2, err
    assert err.count("\n") == 1 and err.startswith("error: "), err  # nothing else printed
    for p in pieces:
        assert p in err, (p, err)


def test_import_command_errors_are_one_line(tmp_path, capsys):
    paths = _write_tables(tmp_path, traj=TRAJ_CSV.replace("a,0.5,0.40", "a,0.5,1e300"))
    _one_line_exit_2(_import_argv(paths, tmp_path / "s.npz"), capsys,
                     "traj.csv, line 3, field 'x'")  # fmt: skip
    paths = _write_tables(tmp_path, answers=ANSWERS_CSV.replace(",count", ",cuont"))
    _one_line_exit_2(_import_argv(paths, tmp_path / "s.npz"), capsys,
                     "answers.csv, line 1, field 'cuont'")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["answers.csv", "goals.csv", "traj.csv"]


def test_import_never_writes_over_its_input(tmp_path, capsys):
    """``--answers a.csv --out a.csv --overwrite`` replaced the user's table with an .npz."""
    paths = _write_tables(tmp_path)
    before = {p: p.read_bytes() for p in paths}
    for k, p in enumerate(paths):
        flag = ("--trajectories", "--goals", "--answers")[k]
        _one_line_exit_2([*_import_argv(paths, p), "--overwrite"], capsys,
                         f"--out {p}: is the input {flag} {p}")  # fmt: skip
        # the same file by another name (a relative path through '..')
        other = tmp_path / "sub" / ".." / p.name
        _one_line_exit_2([*_import_argv(paths, other), "--overwrite"], capsys, "is the input")
    # an input named like a study file is still an input
    npz_named = tmp_path / "answers.npz"
    npz_named.write_bytes(paths[2].read_bytes())
    argv = [*_import_argv([*paths[:2], npz_named], npz_named), "--overwrite"]
    _one_line_exit_2(argv, capsys, "is the input --answers")
    assert {p: p.read_bytes() for p in paths} == before
    assert npz_named.read_bytes() == before[paths[2]]


def test_import_and_cv_refuse_an_out_of_another_format(tmp_path, capsys):
    """``--out out.csv`` wrote an .npz under a .csv name without a word."""
    paths = _write_tables(tmp_path)
    for name in ("out.csv", "out", "out.npz.json"):
        _one_line_exit_2(_import_argv(paths, tmp_path / name), capsys,
                         f"--out {tmp_path / name}: expected a name ending in .npz")  # fmt: skip
        assert not (tmp_path / name).exists()
    assert study_cli.main(_import_argv(paths, tmp_path / "out.NPZ")) == 0
    capsys.readouterr()
    s = tmp_path / "out.NPZ"
    _one_line_exit_2(["cv", str(s), "--out", str(tmp_path / "cv.npz")], capsys,
                     "expected a name ending in .json")  # fmt: skip
    _one_line_exit_2(["cv", str(s), "--out", str(s), "--overwrite"], capsys,
                     f"--out {s}: is the input study {s}")  # fmt: skip


def test_npz_value_beyond_float32_is_named(small, tmp_path):
    a = _arrays(small)
    a["xyz"] = a["xyz"].astype(np.float64)
    a["xyz"][2, 3, 1] = 1e300
    np.savez(tmp_path / "big.npz", **a)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError) as e:
            study.load_study(tmp_path / "big.npz")
    for p in ("big.npz", "row 2", "'xyz'", "1e+300", "[2, 3, 1]"):
        assert p in str(e.value), (p, str(e.value))


def _arrays(small):
    return {
        "format": np.array(study.FORMAT), "xyz": small.xyz, "length": small.length,
        "t": small.t, "goals": small.goals, "goal_mask": small.goal_mask,
        "answer_trajectory": small.answer_trajectory, "answer_tau": small.answer_tau,
        "counts": small.counts,
    }  # fmt: skip


def _bad_counts(a, v):
    a["counts"] = a["counts"].copy()
    a["counts"][3, 0] = v


def _padded(a):
    a["counts"] = a["counts"].copy()
    a["counts"][2, 7] = 1.0


def _nan(a):
    a["xyz"] = a["xyz"].copy()
    a["xyz"][4, 1, 2] = np.nan


def _short(a):
    a["length"] = a["length"].copy()
    a["length"][6] = 1


def _too_long(a):
    a["length"] = a["length"].copy()
    a["length"][6] = 21


def _rows(a):
    a["counts"] = a["counts"][:-1]


def _no_answers(a):
    keep = a["answer_trajectory"] != 7
    for k in ("answer_trajectory", "answer_tau", "counts"):
        a[k] = a[k][keep]


def _tau(a):
    a["answer_tau"] = a["answer_tau"].copy()
    a["answer_tau"][5] = 99.0


def _unknown(a):
    a["answer_trajectory"] = a["answer_trajectory"].copy()
    a["answer_trajectory"][9] = 12


def _nine_goals(a):
    a["goals"] = np.concatenate([a["goals"], a["goals"][:, :1]], axis=1)
    a["goal_mask"] = np.concatenate([a["goal_mask"], a["goal_mask"][:, :1]], axis=1)


NPZ_ERRORS = [
    (lambda a: _bad_counts(a, -2.0), ["'counts'", "row 3", ">= 0"]),
    (lambda a: _bad_counts(a, 0.5), ["'counts'", "row 3", "whole numbers"]),
    (_padded, ["'counts'", "row 2", "padded goal slot 7"]),
    (_nan, ["'xyz'", "row 4", "finite"]),
    (_short, ["'length'", "row 6", "T >= 2"]),
    (_too_long, ["'length'", "row 6", "disagree"]),
    (_rows, ["'counts'", "(13, 8)", "disagree"]),
    (_no_answers, ["'answer_trajectory'", "trajectory 7", "no answers"]),
    (_tau, ["'answer_tau'", "row 5", "outside the motion"]),
    (_unknown, ["'answer_trajectory'", "row 9", "unknown trajectory 12"]),
    (_nine_goals, ["'goals'", "(12, 8, 3)"]),
]


@pytest.mark.parametrize("edit, pieces", NPZ_ERRORS)
def test_npz_errors(small, tmp_path, edit, pieces):
    a = _arrays(small)
    edit(a)
    path = tmp_path / "bad.npz"
    np.savez(path, **a)
    with pytest.raises(ValueError) as e:
        study.load_study(path)
    for p in [str(path), *pieces]:
        assert p in str(e.value), (p, str(e.value))


def test_duplicate_trajectory_ids_are_refused_when_the_file_is_loaded(small, tmp_path, capsys):
    """Two trajectories of one id (answers name trajectories by id): `study show` and
    `study pick` refuse the file at once, naming it, the field and both rows (it passed
    both, and `study stimuli` refused it 25 s later naming no file); ids that only collide
    once made safe as stimulus ids are refused by `study stimuli` before its IK."""
    from slotv_jax.webstudy import make_stimuli

    ids = [f"tr{i}" for i in range(12)]
    path = tmp_path / "dup.npz"
    np.savez(path, **_arrays(small), trajectory_ids=np.array([*ids[:7], "tr3", *ids[8:]]))
    with pytest.raises(ValueError) as e:
        study.load_study(path)
    assert str(e.value) == (
        f"{path}, row 7, field 'trajectory_ids': 'tr3' is also the id of row 3; expected "
        "distinct ids, one per trajectory"
    )
    _one_line_exit_2(["show", str(path)], capsys, str(path), "'trajectory_ids'", "row 7")
    pick = ["pick", str(path), "--out", str(tmp_path / "pick"), "--candidates", "dragan,nikolaidis"]
    _one_line_exit_2([*pick, "--no-progress"], capsys, str(path), "row 7")
    assert not (tmp_path / "pick").exists()
    safe = tmp_path / "safe.npz"
    np.savez(safe, **_arrays(small), trajectory_ids=np.array(["a b", *ids[1:5], "a_b", *ids[6:]]))
    assert study.load_study(safe).trajectory_ids[5] == "a_b"  # distinct in the file
    with pytest.raises(ValueError, match=re.escape(f"--study {safe}: trajectory ids 'a b' and "
                                                   "'a_b' are both 'a_b'")):  # fmt: skip
        make_stimuli.motions_from_study(safe)


def test_corrupt_file(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match=r"x\.npz: not an \.npz file"):
        study.load_study(tmp_path / "x.npz")


# -------------------------------------------------------------- the loss


def _np_mlp(params, x, g):
    """V(x, g) in float64 from the model's parameters: ReLU layers, linear readout."""
    v = params["value"] if "value" in params else params["reward"]
    h = np.maximum((x - g) @ np.asarray(v["first"]["kernel"], np.float64)
                   + np.asarray(v["first"]["bias"], np.float64), 0)  # fmt: skip
    for layer in v["layers"].values():
        h = np.maximum(h @ np.asarray(layer["kernel"], np.float64)
                       + np.asarray(layer["bias"], np.float64), 0)  # fmt: skip
    return h @ np.asarray(v["readout"]["kernel"], np.float64)[:, 0]


def _np_loss(params, method, xyz, goals, mask, seen, counts, n_bar):
    """−Σ_a Σ_k c_ak log softmax_k(s_a) / (B n̄) in float64."""
    total = 0.0
    for b in range(len(xyz)):
        pts = np.asarray(xyz[b, : seen[b]], np.float64)
        s = np.array([_np_mlp(params, pts, np.asarray(goals[b, k], np.float64)).sum()
                      for k in range(goals.shape[1])])  # fmt: skip
        if method == "slotv":
            s = s / seen[b]
        s = np.where(mask[b], s, -np.inf)
        logp = s - s.max() - np.log(np.exp(s - s.max()).sum())
        total -= np.sum(np.where(counts[b] > 0, counts[b] * np.where(mask[b], logp, 0.0), 0.0))
    return total / (len(xyz) * n_bar)


def _model(method, seed=0):
    cfg = train_config.quick(method, hidden=(16, 8))
    return models.make_model(cfg, nnx.Rngs(params=seed))


def _plain(state):
    return jax.tree.map(np.asarray, nnx.to_pure_dict(state))


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_count_loss_matches_float64_reference(small, method):
    model = _model(method)
    d = study.study_data(small)
    tr = np.asarray(d.row_trajectory)
    args = (d.xyz[tr], d.goals[tr], d.goal_mask[tr], d.row_seen, d.counts)
    n_bar = float(np.asarray(d.counts).sum() / len(tr))
    got = float(nnx.jit(study.study_loss)(model, *args, n_bar))
    params = _plain(nnx.split(model)[1])
    want = _np_loss(params, method, *(np.asarray(a) for a in args), n_bar)
    assert abs(got - want) <= REL_TOL * abs(want)


def test_one_answer_per_row_is_plain_cross_entropy():
    xyz, goals, mask = synthetic(10, 25)
    rng = np.random.default_rng(1)
    guess = [int(rng.integers(mask[i].sum())) for i in range(10)]
    s = study.make_study(xyz, goals, mask, np.arange(10), np.eye(8)[guess])
    model = _model("slotv", seed=3)
    d = study.study_data(s)
    got = float(study.study_loss(model, d.xyz, d.goals, d.goal_mask, d.row_seen, d.counts, 1.0))
    # float64 NumPy: mean over trajectories of −log softmax(s)[guess], s_k = mean_i V(p_i, g_k)
    params = _plain(nnx.split(model)[1])
    ce = []
    for i in range(10):
        sc = np.array([_np_mlp(params, xyz[i].astype(np.float64), goals[i, k].astype(np.float64))
                       .mean() for k in range(8)])  # fmt: skip
        sc = np.where(mask[i], sc, -np.inf)
        ce.append(-(sc[guess[i]] - sc.max() - np.log(np.exp(sc - sc.max()).sum())))
    assert abs(got - np.mean(ce)) <= REL_TOL * np.mean(ce)
    # and the library's own SLOT-V loss with one-hot labels agrees
    onehot = jnp.asarray(np.eye(8)[guess][:, : d.goals.shape[1]], jnp.float32)
    plain = float(
        losses.slotv_loss(model, d.xyz, d.goals, d.goal_mask, onehot, backward="autodiff")
    )
    assert abs(got - plain) <= REL_TOL * plain


@pytest.mark.parametrize("method", ["slotv", "trex"])
def test_points_after_tau_change_nothing(small, method):
    prefix = small.select_rows(small.seen() < small.length[small.answer_trajectory])
    assert prefix.n_rows == 2
    d = study.study_data(prefix)
    tr = np.asarray(d.row_trajectory)
    model = _model(method)
    graph, params = nnx.split(model)
    seen = np.asarray(d.row_seen)

    @jax.jit
    def loss_and_grad(xyz):
        def f(p):
            return study.study_loss(nnx.merge(graph, p), xyz, d.goals[tr], d.goal_mask[tr],
                                    d.row_seen, d.counts, 1.0, backward="recompute")  # fmt: skip

        return jax.value_and_grad(f)(params)

    xyz = np.asarray(d.xyz[tr])
    moved = xyz.copy()
    for b in range(len(tr)):
        moved[b, seen[b] :] += np.random.default_rng(b).normal(0, 5.0, moved[b, seen[b] :].shape)
    l0, g0 = loss_and_grad(jnp.asarray(xyz))
    l1, g1 = loss_and_grad(jnp.asarray(moved))
    assert float(l0) == float(l1)
    for a, b in zip(jax.tree.leaves(g0), jax.tree.leaves(g1), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # and moving a seen point does change it (the test can fail)
    moved[0, 1] += 0.1
    assert float(loss_and_grad(jnp.asarray(moved))[0]) != float(l0)


# ------------------------------------------------------ simulation, β fit


def test_simulated_participants_follow_the_labeler():
    xyz, goals, mask = synthetic(30, 30)
    probs = study.prefix_labels(xyz, goals, mask, (0.5, 1.0), beta=10.0)
    key = jax.random.key(0)
    which, guess = study.simulate_guesses(key, probs, mask, 400, lapse=0.2)
    w5, g5 = study.simulate_guesses(key, probs, mask, 5, lapse=0.2)
    np.testing.assert_array_equal(which[:, :5], w5)  # nested participants
    np.testing.assert_array_equal(guess[:, :5], g5)
    p = 0.8 * probs + 0.2 * (mask / mask.sum(-1, keepdims=True))[:, None]
    expect = p[np.arange(30)[:, None], which].sum(1)  # (N, 8) expected counts
    got = np.zeros((30, 8))
    np.add.at(got, (np.arange(30)[:, None], guess), 1)
    sd = np.sqrt(expect * (1 - expect / 400)) + 1e-9
    assert np.all(np.abs(got - expect) <= 5 * sd + 1e-6)
    assert np.all(got[~mask] == 0)


def test_a_study_from_labels_is_the_limit_of_many_participants():
    """P = ∞: one row per (n, τ) holding the label itself; many simulated participants'
    normalised counts approach those rows (within 5 SD of the multinomial)."""
    xyz, goals, mask = synthetic(12, 30, seed=3)
    taus = (0.5, 1.0)
    probs = study.prefix_labels(xyz, goals, mask, taus, beta=10.0)
    s = study.study_from_labels(xyz, goals, mask, taus, probs)
    assert s.n_rows == 24 and s.answer_trajectory.tolist() == [n for n in range(12) for _ in taus]
    np.testing.assert_allclose(s.answer_tau, np.tile(taus, 12))
    np.testing.assert_allclose(s.counts, probs.reshape(24, 8), atol=1e-6)  # n_answers 1 a row
    which, guess = study.simulate_guesses(jax.random.key(0), probs, mask, 4000)
    many = study.study_from_guesses(xyz, goals, mask, taus, which, guess)
    assert many.answer_trajectory.tolist() == s.answer_trajectory.tolist()
    total = many.counts.sum(-1, keepdims=True)
    sd = np.sqrt(s.counts * (1 - s.counts) / total) + 1e-9
    assert np.all(np.abs(many.counts / total - s.counts) <= 5 * sd + 1e-6)
    with pytest.raises(ValueError, match=r"probs: expected \(12, 2, 8\)"):
        study.study_from_labels(xyz, goals, mask, taus, probs[:, :1])


def test_fit_beta_recovers_the_simulated_beta():
    xyz, goals, mask = synthetic(60, 30, seed=2)
    s = study.simulate_study(jax.random.key(1), xyz, goals, mask, 200, beta=12.0)
    beta, nll = study.fit_beta(s, "dragan")
    assert 12.0 / 1.25 < beta < 12.0 * 1.25
    y = study.labeler_probs(s, "dragan", beta=12.0)
    assert nll <= -np.sum(s.counts * np.log(np.maximum(y, 1e-12))) / s.counts.sum() + 1e-9


def test_cross_validation_reports_models_and_baselines():
    xyz, goals, mask = synthetic(24, 20, seed=4)
    s = study.simulate_study(jax.random.key(2), xyz, goals, mask, 3, beta=10.0)
    cfg = train_config.quick("slotv", hidden=(8, 4), epochs=1, batch_size=4, train_size=None)
    cv = study.cross_validate(cfg, s, folds=3, baselines=("dragan",), progress=False)
    assert set(cv) >= {"slotv", "uniform", "dragan"} and len(cv["per_fold"]) == 3
    assert sum(f["test_rows"] for f in cv["per_fold"]) == s.n_rows  # every row held out once
    n_goals = s.goal_mask[s.answer_trajectory].sum(-1)
    want = np.sum(s.counts.sum(-1) * np.log(n_goals)) / s.counts.sum()
    assert cv["uniform"]["nll_per_answer"] == pytest.approx(want, rel=1e-12)
    assert cv["uniform"]["accuracy"] == pytest.approx(np.mean(1 / n_goals))
    # β fitted on the training folds: the labeler that generated the answers beats uniform
    assert cv["dragan"]["nll_per_answer"] < cv["uniform"]["nll_per_answer"]
    assert "dragan" in study.cv_table(cv)


# ----------------------------------------------------------- CLI and README


def test_cli_training_then_load_observer(small, tmp_path, capsys):
    path = study.save_study(tmp_path / "s.npz", small)
    out = tmp_path / "ckpt"
    argv = ["--study", str(path), "--method", "slotv", "--out", str(out), "--epochs", "2",
            "--set", "hidden=16,8", "--no-progress"]  # fmt: skip
    assert train_cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "NLL per answer" in printed
    # 14 answer rows, fewer than the preset's batch of 32: the largest power of two that fits
    assert "the study has 14 answer rows" in printed and "using batch_size=8" in printed
    assert json.loads((out / "config.json").read_text())["config"]["batch_size"] == 8
    meta = json.loads((out / "config.json").read_text())["meta"]
    assert meta["study"] == str(path) and "train_metrics" in meta
    observer = slotv_jax.load_observer(out)
    _, state, _ = checkpoint.restore(out)
    model = nnx.merge(nnx.split(_model("slotv"))[0], state.params)
    n = 3
    xyz = small.xyz[n, : small.length[n]]
    logits = np.asarray(observer(xyz, small.goals[n], small.goal_mask[n]))
    assert np.all(np.isneginf(logits[~small.goal_mask[n]]))
    ref = study.prefix_scores(model, small.xyz[n], small.goals[n], jnp.asarray(small.length[n]))
    real = small.goal_mask[n]
    np.testing.assert_allclose(logits[real], np.asarray(ref)[real], rtol=1e-5, atol=1e-6)
    with pytest.raises(SystemExit):
        train_cli.main(["--study", str(path), "--labeler", "dragan", "--method", "slotv", "--out",
                    str(out)])  # fmt: skip


@pytest.mark.slow
def test_readme_example_runs(tmp_path):
    block = marked_block("docs/guides/study-data.md", "study-example", "bash")
    env = {"PYTHONPATH": str(ROOT), "PATH": str(Path(sys.executable).parent) + ":/usr/bin:/bin"}
    r = subprocess.run(["bash", "-e", "-c", block], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr[-3000:]
    assert "wrote my_study.npz" in r.stdout
    probs = [float(v) for v in re.findall(r"P\(\w+ \| motion a\) = ([0-9.]+)", r.stdout)]
    assert len(probs) == 3 and abs(sum(probs) - 1) < 2e-3


def test_study_trainer_matches_train_trials():
    """One answer row per trajectory holding the labeler's distribution (P = ∞, whole
    motions) is ordinary SLOT-V training: same initialisation, batches and loss, so
    study.train_study and train.train_trials reach the same parameters (float32 rounding
    only) and the same accuracy."""
    xyz, goals, mask = synthetic(48, 20, seed=4)
    rng = np.random.default_rng(5)
    logits = np.where(mask, rng.normal(0.0, 2.0, mask.shape), -np.inf)
    labels = np.exp(logits - logits.max(-1, keepdims=True))
    labels = (labels / labels.sum(-1, keepdims=True)).astype(np.float32)
    cfg = train_config.quick("slotv", hidden=(16, 8), batch_size=8, epochs=3, train_size=None)
    data = types.make_data(xyz, goals, mask, labels)
    st, _ = train.train_trials(cfg, data, [3], progress=False)
    s = study.make_study(xyz, goals, mask, np.arange(48), probs=labels, n_answers=np.ones(48))
    got = study.train_study(cfg, s, jax.random.key(3), progress=False)
    want = jax.tree.map(lambda x: x[0], st.params)
    for a, b in zip(jax.tree.leaves(got.params), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-5)
    assert int(got.epoch) == 3


def test_study_size_budget_and_needed():
    """Every cell gets the same update budget (at least ``updates``, less than one more
    epoch), both methods share the quick preset's batch and lr, and the N for 80 % is
    interpolated in log N (hand-computed: halfway between 1,000 and 10,000 is √10⁷)."""
    from slotv_jax.experiments import study_size

    cfg = study_size.quick()
    for steps in (1, 3, 31, 312, 5000):
        e = cfg.epochs_for(steps)
        assert e * steps >= cfg.updates and (e - 1) * steps < cfg.updates
    tcs = {m: cfg.train_config(m) for m in ("slotv", "trex")}
    assert tcs["slotv"].batch_size == tcs["trex"].batch_size == 32
    assert tcs["slotv"].learning_rate == tcs["trex"].learning_rate == 0.005
    summary = [
        {"method": "slotv", "participants": 5, "n": n, "mean": a}
        for n, a in ((100, 0.5), (1000, 0.7), (10000, 0.9))
    ] + [{"method": "trex", "participants": 0, "n": n, "mean": 0.85} for n in (100, 1000)]
    got = {r["method"]: r for r in study_size.needed(summary, 0.8)}
    assert got["slotv"]["n"] == pytest.approx(np.sqrt(1e7), rel=1e-9)
    assert got["slotv"]["answers"] == pytest.approx(5 * np.sqrt(1e7), rel=1e-9)
    assert got["trex"]["n"] == 100 and got["trex"]["at_most"]
    assert not got["slotv"]["falls_back"] and not got["trex"]["falls_back"]
    summary[-1]["mean"] = 0.75  # T-REX at N = 1,000 back below 80 %
    assert study_size.needed(summary, 0.8)[1]["falls_back"]
