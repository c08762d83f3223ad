"""Property tests (hypothesis) at the public boundary: the labelers and ``label_all`` on
generated motions and on generated bad input, ``study.read_tables`` on generated tables
(valid ones round-trip; one corrupted field is reported with its file and line), and
``load_observer`` on checkpoints with one file truncated or removed. The profile in
conftest.py makes them derandomised and bounded."""

from __future__ import annotations

import csv
import io
import shutil
import tempfile
from pathlib import Path

import jax
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import slotv_jax
from slotv_jax import study
from slotv_jax.observers import labelers as L
from slotv_jax.observers import labelling
from slotv_jax.training import checkpoint
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

# ------------------------------------------------------------------ labelers

coord = st.floats(-1.0, 1.0, allow_nan=False, width=32)


@st.composite
def motions(draw, T=None):
    """A motion of T points in the workspace in front of the observer camera, 1-8 goals on
    the table (pairwise apart), and the betas."""
    T = draw(st.sampled_from([2, 9])) if T is None else T
    u = np.array(draw(st.lists(st.tuples(coord, coord, coord), min_size=T, max_size=T)))
    xyz = np.array([0.5, 0.0, 0.3]) + u * np.array([0.3, 0.5, 0.25])
    k = draw(st.integers(1, 8))
    g = np.array(draw(st.lists(st.tuples(coord, coord), min_size=k, max_size=k)))
    goals = np.zeros((8, 3))
    goals[:k] = np.c_[0.5 + 0.25 * g[:, 0], 0.45 * g[:, 1], np.full(k, 0.025)]
    d = np.linalg.norm(goals[:k, None] - goals[None, :k], axis=-1) + np.eye(k)
    assume(d.min() > 1e-3)
    beta = draw(st.floats(0.1, 30.0))
    return xyz, goals, np.arange(8) < k, beta


def call(name, xyz, goals, mask, **kw):
    if name == "nikolaidis":
        return L.nikolaidis(xyz, goals, mask, "observer", **kw)
    return L.LABELERS[name](xyz, goals, mask, **kw)


@settings(max_examples=16)
@given(m=motions(), name=st.sampled_from(L.LABELER_NAMES))
def test_labelers_give_probabilities_over_the_real_goals(m, name):
    xyz, goals, mask, beta = m
    y = np.asarray(call(name, xyz, goals, mask, beta=beta), np.float64)
    assert y.shape == (8,) and np.all(np.isfinite(y)) and np.all(y >= 0)
    assert np.all(y[~mask] == 0)
    assert abs(y[mask].sum() - 1) < 1e-5


@settings(max_examples=6)
@given(ms=st.lists(motions(T=12), min_size=3, max_size=3))
def test_label_all_matches_the_single_labelers(ms):
    xyz = np.stack([m[0] for m in ms])
    goals = np.stack([m[1] for m in ms])
    mask = np.stack([m[2] for m in ms])
    y = labelling.label_all(xyz, goals, mask, progress=False)
    for name in L.LABELER_NAMES:
        for i in range(3):
            want = np.asarray(call(name, xyz[i], goals[i], mask[i]))
            np.testing.assert_allclose(y[name][i], want, atol=2e-5)


def _mutate(kind, xyz, goals, mask, beta, i):
    """One bad input, and the argument the error must name first."""
    xyz, goals, mask = xyz.copy(), goals.copy(), mask.copy()
    k = int(mask.sum())
    if kind == "nan":
        xyz[i % len(xyz), i % 3] = np.nan
        return ("xyz", xyz, goals, mask, beta)
    if kind == "complex":
        return ("xyz", xyz + 1j, goals, mask, beta)
    if kind == "shape":
        return ("xyz", xyz[:, :2], goals, mask, beta)
    if kind == "duplicate goal":
        assume(k >= 2)
        goals[1] = goals[0]
        return ("goals", xyz, goals, mask, beta)
    if kind == "mask value 2":
        m = mask.astype(int)
        m[0] = 2
        return ("goal_mask", xyz, goals, m, beta)
    if kind == "empty mask":
        return ("goal_mask", xyz, goals, np.zeros(8, bool), beta)
    bad_beta = {"beta text": "5", "beta <= 0": -abs(beta), "beta nan": np.float64(np.nan),
                "beta bool": True, "beta complex": 1 + 2j}[kind]  # fmt: skip
    return ("beta", xyz, goals, mask, bad_beta)


KINDS = ["nan", "complex", "shape", "duplicate goal", "mask value 2", "empty mask",
         "beta text", "beta <= 0", "beta nan", "beta bool", "beta complex"]  # fmt: skip


@settings(max_examples=30)
@given(
    m=motions(),
    kind=st.sampled_from(KINDS),
    name=st.sampled_from(L.LABELER_NAMES),
    i=st.integers(0, 100),
)
def test_bad_input_is_named(m, kind, name, i):
    arg, xyz, goals, mask, beta = _mutate(kind, *m, i)
    with pytest.raises(ValueError) as e:
        call(name, xyz, goals, mask, beta=beta)
    assert str(e.value).startswith(f"{arg}:"), str(e.value)
    assert "np.float64" not in str(e.value)
    # label_all says the same at its boundary, with the labeler's beta argument (a NaN
    # point it finds from the labels, after compiling: tested in test_labelers.py)
    if kind not in ("shape", "nan"):
        b = {"beta_" + name: beta}
        with pytest.raises(ValueError) as e:
            labelling.label_all(xyz[None], goals, mask, labelers=name, progress=False, **b)
        assert str(e.value).startswith("beta_" + name if arg == "beta" else arg), str(e.value)


# ------------------------------------------------------------------ study tables

name_text = st.text(st.characters(categories=["L", "N"]), min_size=1, max_size=6)


@st.composite
def study_tables(draw):
    """Rows of the three tables of a valid study (strings, as in a CSV)."""
    n = draw(st.integers(1, 4))
    has_t = draw(st.booleans())
    goal_names = draw(st.lists(name_text, min_size=1, max_size=8, unique=True))
    k = len(goal_names)
    gx = draw(st.lists(st.integers(0, 400), min_size=k, max_size=k, unique=True))
    goals = [{"goal": g, "x": "0.5", "y": repr(-0.4 + 0.002 * x), "z": "0.025"}
             for g, x in zip(goal_names, gx, strict=True)]  # fmt: skip
    points, lengths = [], []
    for i in range(n):
        T = draw(st.integers(2, 6))
        lengths.append(T)
        for j in range(T):
            row = {"trajectory": f"tr{i}", "x": repr(draw(coord)), "y": repr(draw(coord)),
                   "z": repr(draw(coord))}  # fmt: skip
            if has_t:
                row["t"] = repr(0.5 * j)
            points.append(row)
    answers = []
    for j in range(n + draw(st.integers(0, 6))):  # every trajectory is answered
        i = j if j < n else draw(st.integers(0, n - 1))
        seen = draw(st.integers(2, lengths[i]))
        tau = (0.5 * (seen - 1)) if has_t else (seen - 1) / (lengths[i] - 1)
        answers.append({"trajectory": f"tr{i}", "guess": draw(st.sampled_from(goal_names)),
                        "tau": draw(st.sampled_from(["", repr(tau)])),
                        "count": str(draw(st.integers(int(j < n), 3)))})  # fmt: skip
    return points, goals, answers


def write_csv(path: Path, rows: list[dict], bom: bool = False) -> list[bytes]:
    f = io.StringIO(newline="")
    w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    data = ("\ufeff" if bom else "") + f.getvalue()
    path.write_bytes(data.encode())
    return data.encode().split(b"\n")


def read(tables, d: Path, bom=False):
    paths = [d / n for n in ("trajectories.csv", "goals.csv", "answers.csv")]
    for p, rows in zip(paths, tables, strict=True):
        write_csv(p, rows, bom)
    return paths, study.read_tables(*paths)[0]


@settings(max_examples=25)
@given(tables=study_tables(), bom=st.booleans())
def test_valid_tables_round_trip(tables, bom):
    points, goals, answers = tables
    with tempfile.TemporaryDirectory() as d:
        _, s = read(tables, Path(d), bom)
        path = study.save_study(Path(d) / "s.npz", s)
        again = study.load_study(path)
    for got in (s, again):
        ids = list(got.trajectory_ids)
        for i, tid in enumerate(ids):
            rows = [r for r in points if r["trajectory"] == tid]
            assert got.length[i] == len(rows)
            want = np.array([[float(r[c]) for c in "xyz"] for r in rows], np.float32)
            np.testing.assert_array_equal(got.xyz[i, : len(rows)], want)
            names = [str(x) for x in got.goal_names[i][got.goal_mask[i]]]
            assert names == [g["goal"] for g in goals]
            total = sum(int(a["count"]) for a in answers if a["trajectory"] == tid)
            assert got.counts[got.answer_trajectory == i].sum() == total


BAD_VALUES = {  # (table, column) -> a value that is wrong there whatever the rest holds
    (0, "trajectory"): "", (0, "x"): "abc", (0, "y"): "nan", (0, "z"): "1e999",
    (0, "t"): "soon", (1, "goal"): "", (1, "x"): "?", (1, "z"): "inf",
    (2, "trajectory"): "no-such-trajectory", (2, "guess"): "no-such-goal",
    (2, "tau"): "late", (2, "count"): "-1",
}  # fmt: skip


@settings(max_examples=40)
@given(
    tables=study_tables(),
    table=st.integers(0, 2),
    pick=st.integers(0, 1000),
    how=st.sampled_from(["value", "not utf-8", "extra column"]),
)
def test_a_corrupted_field_is_named_by_file_and_line(tables, table, pick, how):
    tables = [list(map(dict, t)) for t in tables]
    rows = tables[table]
    r = pick % len(rows)
    cols = [c for c in rows[r] if (table, c) in BAD_VALUES]
    col = cols[pick % len(cols)]
    if how == "value":
        rows[r][col] = BAD_VALUES[(table, col)]
    with tempfile.TemporaryDirectory() as d:
        paths = [Path(d) / n for n in ("trajectories.csv", "goals.csv", "answers.csv")]
        for p, t in zip(paths, tables, strict=True):
            write_csv(p, t)
        lines = paths[table].read_bytes().split(b"\n")
        if how == "not utf-8":
            lines[r + 1] = lines[r + 1] + b"\xe9"  # Latin-1 'é' at the end of the row
        elif how == "extra column":
            lines[r + 1] = lines[r + 1] + b",1"
        paths[table].write_bytes(b"\n".join(lines))
        with pytest.raises(ValueError) as e:
            study.read_tables(*paths)
    msg = str(e.value)
    assert paths[table].name in msg and f"line {r + 2}" in msg, (how, col, msg)


# ------------------------------------------------------------------ checkpoints


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    cfg = train_config.quick("slotv", hidden=(8, 8), batch_size=16, epochs=1, train_size=None)
    state = train.make_train(cfg, progress=False).init(jax.random.key(3))
    path = checkpoint.save(tmp_path_factory.mktemp("ck") / "ck", cfg, state)
    files = sorted(str(p.relative_to(path)) for p in path.rglob("*") if p.is_file())
    rng = np.random.default_rng(0)
    x = (rng.uniform(0.2, 0.6, (10, 3)), rng.uniform(0.2, 0.6, (8, 3)), np.arange(8) < 3)
    return path, files, x, np.asarray(slotv_jax.load_observer(path)(*x))


@settings(max_examples=15)
@given(data=st.data())
def test_a_truncated_checkpoint_is_reported_or_loads_the_same(saved, data):
    path, files, x, want = saved
    name = data.draw(st.sampled_from(files))
    keep = data.draw(st.one_of(st.just(-1), st.floats(0.0, 0.99)))  # -1: the file is gone
    with tempfile.TemporaryDirectory() as d:
        ck = Path(d) / "ck"
        shutil.copytree(path, ck)
        f = ck / name
        if keep < 0:
            f.unlink()
        else:
            f.write_bytes(f.read_bytes()[: int(keep * f.stat().st_size)])
        try:
            got = np.asarray(slotv_jax.load_observer(ck)(*x))
        except (ValueError, FileNotFoundError) as e:
            assert str(ck) in str(e), str(e)
            return
    np.testing.assert_array_equal(got, want)  # never different numbers


def test_truncated_arrays_and_config_are_named(saved):
    path, files, _, _ = saved
    data = max(
        (f for f in files if f.startswith("state/d/")), key=lambda f: (path / f).stat().st_size
    )
    for name, piece in ((data, "stored arrays in state/ are truncated or corrupt"),
                        ("config.json", "config.json, line")):  # fmt: skip
        with tempfile.TemporaryDirectory() as d:
            ck = Path(d) / "ck"
            shutil.copytree(path, ck)
            raw = (ck / name).read_bytes()
            (ck / name).write_bytes(raw[: len(raw) // 2])
            with pytest.raises(ValueError, match=piece):
                slotv_jax.load_observer(ck)
