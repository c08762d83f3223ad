"""Every command as a user runs it: a file in the way survives byte for byte, an unwritable
``--out`` fails in seconds before any work, and input errors are one line ``error: ...``
with exit code 2 (:ref:`concepts-commands`). Each run is a fresh ``python -m`` process; every case
here fails before JAX does any work, so a run costs about its import time."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from docs_pages import pages

ROOT = Path(__file__).resolve().parents[1]
FAST_S = 30.0  # an import of JAX on a busy 2-core machine, not a dataset, labels or training


def run(*argv: str, cwd: Path) -> tuple[int, str, float]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    env.pop("SLOTV_JAX_TRACEBACK", None)
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", *argv], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    return r.returncode, r.stderr, time.perf_counter() - t0


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` (hidden ones too) with its bytes (None for a directory)."""
    return {
        str(p.relative_to(root)): None if p.is_dir() else p.read_bytes()
        for p in sorted(root.rglob("*"))
    }


def assert_one_line_error(rc: int, err: str, *pieces: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert rc == 2, (rc, err)
    assert len(lines) == 1 and "Traceback" not in err, err
    for piece in pieces:
        assert piece in lines[0], (piece, lines[0])


TRAIN = ("slotv_jax.train", "--data", "nodata", "--labeler", "dragan", "--method", "slotv")


@pytest.mark.slow
def test_train_never_replaces_what_it_did_not_write(tmp_path):
    user_dir = tmp_path / "results"
    user_dir.mkdir()
    (user_dir / "thesis.tex").write_bytes(b"\x00my only copy\xff")
    (tmp_path / "notes.txt").write_bytes(b"do not lose me\n")
    ckpt = tmp_path / "ckpt"  # a checkpoint of ours (its marker files)
    (ckpt / "state").mkdir(parents=True)
    (ckpt / "config.json").write_text('{"format": "slotv_jax.checkpoint/1"}')
    before = snapshot(tmp_path)

    rc, err, _ = run(*TRAIN, "--out", "results", cwd=tmp_path)
    assert_one_line_error(rc, err, "--out results", "did not write")
    rc, err, _ = run(*TRAIN, "--out", "notes.txt", "--overwrite", cwd=tmp_path)
    assert_one_line_error(rc, err, "--out notes.txt", "is a file")
    rc, err, _ = run(*TRAIN, "--out", "ckpt", cwd=tmp_path)
    assert_one_line_error(rc, err, "--out ckpt", "--resume", "--overwrite")
    rc, err, secs = run(*TRAIN, "--out", "/proc/ckpt", cwd=tmp_path)  # root cannot write here
    assert_one_line_error(rc, err, "--out /proc/ckpt", "cannot write in /proc")
    assert secs < FAST_S, secs
    assert snapshot(tmp_path) == before  # byte for byte, and no hidden leftovers


@pytest.mark.parametrize(
    "argv",
    [
        (*TRAIN, "--out", "{bad}/ckpt"),
        ("slotv_jax.data", "--preset", "quick", "--out", "{bad}/data"),
        ("slotv_jax.labelers", "--in", "nothing.npz", "--out", "{bad}/labels.npz"),
        ("slotv_jax.study", "import", "--trajectories", "t.csv", "--goals", "g.csv",
         "--answers", "a.csv", "--out", "{bad}/study.npz"),
        ("slotv_jax.experiments.table1", "--preset", "quick", "--out", "{bad}/t1"),
    ],
    ids=["train", "data", "labelers", "study-import", "table1"],
)  # fmt: skip
def test_unwritable_out_fails_in_seconds_before_any_work(tmp_path, argv):
    # chmod does not stop root (CI runs as root); a regular file as the parent does
    (tmp_path / "afile").write_text("x")
    rc, err, secs = run(*(a.replace("{bad}", "afile") for a in argv), cwd=tmp_path)
    assert_one_line_error(rc, err, "--out", "is a file, not a directory")
    assert secs < FAST_S, secs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]  # nothing generated


def test_file_outputs_are_replaced_only_with_overwrite(tmp_path):
    (tmp_path / "labels.npz").write_bytes(b"user data")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "readme.md").write_bytes(b"mine")
    before = snapshot(tmp_path)
    rc, err, _ = run("slotv_jax.labelers", "--in", "x.npz", "--out", "labels.npz", cwd=tmp_path)
    assert_one_line_error(rc, err, "labels.npz", "--overwrite")
    rc, err, _ = run("slotv_jax.data", "--out", "data", cwd=tmp_path)
    assert_one_line_error(rc, err, "--out data", "did not write")
    assert snapshot(tmp_path) == before


# ------------------------------------------------- in-process: input errors in one line


def test_input_errors_are_one_line_in_every_main(tmp_path, capsys):
    from slotv_jax.data import cli as data
    from slotv_jax.study import cli as study_cli
    from slotv_jax.train import cli as train_cli

    np.savez(tmp_path / "s.npz", x=np.arange(100.0))
    raw = (tmp_path / "s.npz").read_bytes()
    (tmp_path / "s.npz").write_bytes(raw[: len(raw) // 2])
    (tmp_path / "text.npz").write_text("trajectory,x,y,z\n")
    (tmp_path / "empty").mkdir()
    cases = [
        (study_cli.main, ["show", str(tmp_path / "s.npz")], "s.npz: truncated or corrupt"),
        (study_cli.main, ["show", str(tmp_path / "text.npz")], "not an .npz file (not a zip"),
        (study_cli.main, ["show", str(tmp_path / "nope.npz")], "nope.npz: no such file"),
        (data.main, ["--out", str(tmp_path / "empty"), "--relabel"], "no dataset splits"),
        (train_cli.main, ["--study", str(tmp_path / "s.npz"), "--method", "slotv", "--out",
                          str(tmp_path / "ck"), "--epochs", "0"], "--epochs: expected"),
        (train_cli.main, ["--study", str(tmp_path / "s.npz"), "--method", "slotv", "--out",
                          str(tmp_path / "ck")], "s.npz: truncated or corrupt"),
    ]  # fmt: skip
    for main, argv, piece in cases:
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and "error: " in err and piece in err, (argv, err)
        assert "Traceback" not in err
    assert not (tmp_path / "ck").exists()  # refused before a checkpoint was started


SEED_FLAGS = [  # (main's module, argv; a later input error that the old code met first)
    ("slotv_jax.train.cli", [*TRAIN[1:], "--out", "ck", "--seed", "SEED"]),
    ("slotv_jax.data.cli", ["--relabel", "--out", "empty", "--seed", "SEED"]),
    ("slotv_jax.study.cli", ["cv", "nope.npz", "--seed", "SEED"]),
    ("slotv_jax.study.cli", ["next", "--stimuli", "empty", "--data", "nodata", "--answers",
                             "a.csv", "--strategy", "random", "--n", "1", "--seed", "SEED"]),
    ("slotv_jax.study.cli", ["stimuli", "--npz", "nope.npz", "--out", "stim", "--seed", "SEED"]),
    ("slotv_jax.study.cli", ["simulate", "--stimuli", "empty", "--seed", "SEED"]),
    ("slotv_jax.experiments.planning.__main__", ["--n-scenes", "0", "--seed", "SEED"]),
    ("slotv_jax.experiments.hparam_search", ["--report-only", "--out", "empty", "--seed",
                                             "SEED"]),
    ("slotv_jax.experiments.people_loop.__main__", ["--population", "nope.json",
                                                    "--first-seed", "SEED"]),
    ("slotv_jax.experiments.active", ["--study-max", "0", "--first-seed", "SEED"]),
    ("slotv_jax.experiments.active_stream", ["--steps", "0", "--first-seed", "SEED"]),
    ("slotv_jax.benchmarks.kinematics", ["--batch", "0", "--seed", "SEED"]),
]  # fmt: skip


@pytest.mark.parametrize("seed", [2**32, 2**63, -1])
def test_every_seed_flag_is_range_checked_first(seed, tmp_path, capsys, monkeypatch):
    """Every command's --seed / --first-seed: 0..2**32 - 1 (jax.random.key keeps 32 bits:
    2**32 drew what 0 draws; 2**63 failed inside JAX after the dataset work). Out of range
    is one line naming the flag, exit code 2, before anything else is looked at."""
    import importlib

    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    for module, argv in SEED_FLAGS:
        main = importlib.import_module(module).main
        argv = [str(seed) if a == "SEED" else a for a in argv]
        flag = argv[argv.index(str(seed)) - 1]
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        want = f"error: {flag} {seed}: expected a seed in 0..4294967295 (2**32 - 1: "
        assert e.value.code == 2 and err.startswith(want) and err.count("\n") == 1, (module, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"]  # nothing written


def test_a_range_of_seeds_stays_below_2_to_the_32(tmp_path, capsys):
    """--first-seed with --seeds, and simulate's --first with --participants (participant i
    draws from fold_in(key(seed), i)): the last one must be a seed too."""
    from slotv_jax.experiments import active, active_stream, people_loop
    from slotv_jax.study import cli as study_cli

    for main, argv, want in (
        (active.main, ["--first-seed", str(2**32 - 2), "--seeds", "3", "--study-max", "0"],
         f"error: --first-seed {2**32 - 2}, --seeds 3: the last seed, 4294967296, is beyond "
         f"2**32 - 1 (4294967295); expected --first-seed at most {2**32 - 3}"),
        (study_cli.main, ["simulate", "--stimuli", str(tmp_path), "--first", str(2**32 - 5),
                          "--participants", "10"],
         f"error: --first {2**32 - 5}, --participants 10: the last seed, 4294967300, is "
         "beyond"),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.startswith(want) and err.count("\n") == 1, err
    # the configs check their own seeds (a preset's count with another first seed)
    for preset in (active.PRESETS["quick"], active_stream.PRESETS["quick"], people_loop.tiny):
        with pytest.raises(ValueError, match=r"^first_seed 4294967295, seeds \d+: the last seed"):
            dataclasses.replace(preset(), first_seed=2**32 - 1, seeds=2)


def test_study_table_messages(tmp_path):
    from slotv_jax import study

    (tmp_path / "t.csv").write_text(
        "trajectory,x,y,z,t\na,0,0,0,0\na,1,0,0,1\nb,0,1,0,\nb,1,1,0,1\n"
    )
    (tmp_path / "g.csv").write_text("goal,x,y,z\nleft,0.5,0.3,0\nright,0.5,-0.3,0\n")
    (tmp_path / "a.csv").write_text("trajectory,guess,tau\na,left,5\n")
    with pytest.raises(
        ValueError, match=r"t\.csv, line 4, field 't': no time stamp.*all-or-nothing"
    ):
        study.read_tables(tmp_path / "t.csv", tmp_path / "g.csv", tmp_path / "a.csv")
    xyz = np.zeros((1, 4, 3), np.float32)
    xyz[0, :, 0] = np.arange(4)
    goals = np.zeros((8, 3), np.float32)
    goals[1, 1] = 1
    with pytest.raises(ValueError, match=r"tau = 5\.0 is outside.* <= tau <= 1\.0") as e:
        study.make_study(xyz, goals, np.arange(8) < 2, [0], [[1, 0, 0, 0, 0, 0, 0, 0]],
                         answer_tau=[5.0])  # fmt: skip
    assert "np.float64" not in str(e.value)


# --------------------------------------------------------------------- Ctrl-C


def _commands() -> list[str]:
    """Every module of slotv_jax that defines a command's ``main``."""
    pkg = ROOT / "slotv_jax"
    return sorted(
        ".".join(p.relative_to(ROOT).with_suffix("").parts)
        for p in pkg.rglob("*.py")
        if "\ndef main(" in p.read_text()
    )


# the commands that keep their finished work and go on from it when rerun (README, Files)
RESUMES = {
    "slotv_jax.data.cli",
    *(f"slotv_jax.experiments.{m}" for m in ("table1", "fidelity", "explainable",
                                              "planning.__main__", "sample_efficiency",
                                              "hparam_search", "active", "active_stream")),
}  # fmt: skip


def test_a_preset_name_is_found_by_one_resolver_in_every_command(tmp_path, capsys, monkeypatch):
    """``--data quick`` run from a folder without ``data/``: every command that reads a
    dataset says the same, naming the absolute folder it looked in, before any work."""
    from slotv_jax.data import cli as data
    from slotv_jax.data import report
    from slotv_jax.render import cli as render
    from slotv_jax.study import cli as study_cli
    from slotv_jax.train import cli as train_cli

    monkeypatch.chdir(tmp_path)
    want = f"error: dataset 'quick': the quick preset's dataset is not in {tmp_path}/data/quick-"
    cases = [
        (train_cli.main, ["--labeler", "dragan", "--method", "slotv", "--out", "ck"]),
        (render.main, ["--split", "position_test", "--out", "a.png"]),
        (study_cli.main, ["stimuli", "--split", "trajectory_test", "--n", "2", "--out", "st"]),
        (data.main, ["--relabel", "--out", "d2", "--beta-dragan", "3"]),
        (report.main, ["--out", "r"]),
    ]
    for main, argv in cases:
        if main is study_cli.main:
            argv = [argv[0], "--data", "quick", *argv[1:]]
        else:
            argv = ["--data", "quick", *argv]
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code == 2 and len(err) == 1 and err[0].startswith(want), (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


def test_every_command_answers_ctrl_c_in_one_line(capsys, monkeypatch):
    """Every command's main goes through cli.command: Ctrl-C in it (here: while it parses
    its arguments) prints one line, saying so where rerunning resumes, and exits with 130."""
    import argparse
    import importlib

    from slotv_jax.core import cli

    def ctrl_c(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", ctrl_c)
    monkeypatch.delenv("SLOTV_JAX_TRACEBACK", raising=False)
    # cli.command collects garbage before its line (a command's process then exits): in a
    # test worker whose heap holds the suite's objects, 28 full collections took most of
    # this test's 20-50 s; the collection itself runs in the table1 Ctrl-C test below
    monkeypatch.setattr(cli.gc, "collect", lambda *a: 0)
    names = _commands()
    assert len(names) >= 20 and "slotv_jax.experiments.study_size.__main__" in names
    for name in names:
        main = importlib.import_module(name).main
        assert hasattr(main, "resumes"), f"{name}.main is not wrapped by cli.command"
        assert main.resumes is True or name not in RESUMES, name
        with pytest.raises(SystemExit) as e:
            main([])
        err = capsys.readouterr().err
        line = cli.INTERRUPTED_RESUMES if main.resumes is True else "interrupted"
        assert e.value.code == 130 and err == line + "\n", (name, err)

    @cli.command(resumes="rerun with --resume to continue")
    def main(argv=None):
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as e:
        main([])
    assert capsys.readouterr().err == "interrupted; rerun with --resume to continue\n"


CUT_SHORT = """
from slotv_jax.core import cli

class Bar:  # a progress bar that the Ctrl-C reaches before it has its position
    def __init__(self):
        raise KeyboardInterrupt

    def __del__(self):
        abs(self.pos)

@cli.command(resumes=True)
def main(argv=None):
    Bar()

main([])
"""


def test_ctrl_c_inside_an_object_s_construction_prints_only_the_line():
    """A Ctrl-C that lands inside an object's ``__init__`` (tqdm's, in a full-suite run of
    the table1 test below) leaves a half-built object whose finaliser fails as the frames
    are freed: its "Exception ignored in ... Traceback" is not printed; the line is."""
    from slotv_jax.core import cli

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("SLOTV_JAX_TRACEBACK", None)
    r = subprocess.run([sys.executable, "-c", CUT_SHORT], env=env, capture_output=True,
                       text=True, timeout=120, check=False)  # fmt: skip
    assert r.returncode == 130, r
    assert r.stderr.splitlines()[-1:] == [cli.INTERRUPTED_RESUMES], r.stderr
    assert "Traceback" not in r.stderr and "Exception ignored" not in r.stderr, r.stderr


FROM_A_TERMINAL = (
    "import os, signal, sys; signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); "
    "signal.signal(signal.SIGINT, signal.SIG_DFL); os.execv(sys.argv[1], sys.argv[1:])"
)  # then exec the command: SIGINT deliverable, as a shell gives a foreground command


def _sigint_state() -> str:
    """Whether this process blocks or ignores SIGINT (``/proc/self/status`` masks)."""
    with open("/proc/self/status") as f:
        masks = dict(line.split(":\t") for line in f if line.startswith(("SigBlk", "SigIgn")))
    bit = 1 << (signal.SIGINT - 1)
    return ", ".join(f"{k} SIGINT {bool(int(v, 16) & bit)}" for k, v in masks.items())


def test_every_command_refuses_a_flag_its_parser_refuses_in_one_line(capsys, monkeypatch):
    """A flag that argparse itself refuses (unknown, or a value not of its choices) is one
    line ``error: ...`` naming it and exit code 2 in every command, as the project's own
    input errors are, not argparse's usage block."""
    import importlib

    monkeypatch.delenv("SLOTV_JAX_TRACEBACK", raising=False)
    for name in _commands():
        main = importlib.import_module(name).main
        with pytest.raises(SystemExit) as e:
            main(["--no-such-flag"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.startswith("error: ") and err.count("\n") == 1, (
            name,
            err,
        )
        assert "--help)" in err and "usage:" not in err, (name, err)
    from slotv_jax.experiments.people_loop.__main__ import main

    with pytest.raises(SystemExit) as e:
        main(["--preset", "huge"])
    err = capsys.readouterr().err  # argparse quotes the choices in some Python versions
    assert err.startswith("error: argument --preset: invalid choice: 'huge' (choose from ")
    assert err.endswith(" (see python -m slotv_jax.experiments.people_loop --help)\n"), err
    assert e.value.code == 2 and err.count("\n") == 1


def test_a_swallowed_ctrl_c_still_ends_the_command_as_interrupted(capsys):
    """A SIGINT whose KeyboardInterrupt a library's bare ``except:`` swallows (JAX's compile
    path has such clauses, and a Ctrl-C pressed during a compilation surfaces right after
    it): the command does not report success but ends with 130 and the one line."""
    from slotv_jax.core import cli

    assert threading.current_thread() is threading.main_thread()  # where signals arrive

    @cli.command
    def main(argv=None):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(2)  # the handler raises KeyboardInterrupt here
        except:  # noqa: E722  (what the library does)
            pass
        return 0

    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(SystemExit) as e:
            main([])
    finally:
        signal.signal(signal.SIGINT, before)
    assert e.value.code == 130 and capsys.readouterr().err == "interrupted\n"


@pytest.mark.slow
def test_ctrl_c_in_table1_is_one_line_leaves_no_half_file_and_resumes(tmp_path):
    """SIGINT to the main job while it generates its dataset: exit 130, one line on stderr,
    no traceback, no temporary or half-written file; the same command then finishes."""
    argv = [sys.executable, "-m", "slotv_jax.experiments.table1", "--preset", "tiny",
            "--labelers", "dragan", "--methods", "slotv", "--trials", "1",
            "--out", "t1"]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    env.pop("SLOTV_JAX_TRACEBACK", None)
    # started as a shell starts a command at a terminal, whose Ctrl-C reaches it: SIGINT
    # unblocked and not ignored (a process inherits both, and this test worker's may differ:
    # in full-suite runs the job once ignored the signal and ran to its end)
    worker = _sigint_state()
    proc = subprocess.Popen([sys.executable, "-c", FROM_A_TERMINAL, *argv], cwd=tmp_path,
                            env=env, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while not list(tmp_path.glob("data/tiny-*/*.json")):  # working: a split is written
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no split written in 300 s"
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, (proc.returncode, worker, err[-3000:])
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", err)  # the progress bars' cursor moves
    lines = [ln.strip() for ln in re.split(r"[\r\n]", text) if ln.strip()]  # bars clear
    assert lines[-1] == "interrupted; rerun the same command to resume", err[-3000:]
    assert sum("interrupted" in ln for ln in lines) == 1, err[-3000:]
    files = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert not [p for p in files if p.name.endswith(".tmp")], files  # no half-written file
    from slotv_jax import data

    ddir = next(tmp_path.glob("data/tiny-*"))
    done = [p.stem for p in ddir.glob("*.json")]
    assert done and all((ddir / f"{n}.npz").is_file() for n in done)
    for n in done:  # what is there is whole: every checksum holds
        data.load_split(ddir, n)
    r = subprocess.run(argv, cwd=tmp_path, env=env, text=True, capture_output=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "dataset in data/tiny-" in r.stdout
    doc = json.loads((tmp_path / "t1" / "results.json").read_text())
    assert len(doc["cells"]) == 4  # dragan × slotv × 1 trial × the four test splits


def test_readme_commands_write_distinct_outputs():
    """Followed in order, no two commands of one page (README.md, each page of the manual)
    write the same --out (the second would be refused, or would replace the first's output
    with other settings)."""
    every: set[str] = set()
    for page in pages():
        outs: dict[str, str] = {}
        for block in re.findall(r"```bash\n(.*?)```", page.read_text(), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                m = re.search(r"python -m (\S+).*?--out (\S+)", line)
                if m:
                    assert m.group(2) not in outs, (page.name, line, outs.get(m.group(2)))
                    outs[m.group(2)] = line
        every |= set(outs)
    assert len(every) >= 15 and "ckpt/dragan" in every and "ckpt/dragan_plus" in every


@pytest.mark.parametrize(
    "module, document",
    [
        ("active", "runs/active_results.json"),
        ("active_stream", "runs/active_stream_results.json"),
        ("people_loop.__main__", "runs/people_loop_results.json"),
        ("study_size.__main__", "runs/study_size.json"),
    ],
)
def test_experiments_with_records_default_to_runs(module, document, tmp_path, monkeypatch, capsys):
    """active, active_stream, study_size and the people loop write NAME.md and its results
    into runs/ on their defaults (their records in experiments/ are rewritten only with
    --out experiments, where a rerun resumes the recorded document); --report where nothing
    ran yet names the document it looked for, in one line."""
    import importlib

    monkeypatch.chdir(tmp_path)
    main = importlib.import_module(f"slotv_jax.experiments.{module}").main
    with pytest.raises(SystemExit) as exit_:
        main(["--report"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert document in err and "no results document" in err and err.count("\n") == 1, err


@pytest.mark.parametrize(
    "coordinator, piece",
    [
        ("host0.invalid:12355", "cannot resolve host 'host0.invalid'"),
        ("host0", "expected HOST:PORT"),
        ("127.0.0.1:99999", "expected HOST:PORT"),
    ],
)
def test_a_coordinator_nobody_can_reach_is_one_line_at_once(coordinator, piece, tmp_path, capsys):
    """--coordinator with a host this machine cannot resolve (the README's multi-host
    example run on one machine): one line naming it, before jax.distributed waits its
    5 minutes and aborts with a C++ stack trace."""
    from slotv_jax.experiments import table1

    argv = ["--out", str(tmp_path / "t"), "--coordinator", coordinator,
            "--num-processes", "2", "--process-id", "0"]  # fmt: skip
    t0 = time.monotonic()
    with pytest.raises(SystemExit) as e:
        table1.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.startswith(f"error: --coordinator {coordinator}: "), err
    assert piece in err and err.count("\n") == 1 and time.monotonic() - t0 < 30


@pytest.mark.parametrize(
    "module, stem",
    [
        ("slotv_jax.experiments.active", "active"),
        ("slotv_jax.experiments.active_stream", "active_stream"),
        ("slotv_jax.experiments.study_size.__main__", "study_size"),
        ("slotv_jax.experiments.people_loop.__main__", "people_loop"),
    ],
)
def test_shared_folder_reports_replace_only_their_own(tmp_path, capsys, module, stem):
    """The experiments that write into a shared folder (default ``experiments/``) regenerate
    their report and figure only beside a results document of theirs: somebody's own
    ``<stem>.md`` (or a results document that is not theirs) is refused before any work
    and left as it was, and nothing else is written."""
    import importlib

    main = importlib.import_module(module).main
    results = "study_size.json" if stem == "study_size" else f"{stem}_results.json"
    for name, text, needle in (
        (f"{stem}.md", "my notes\n", f"{stem}.md exists beside no {results}"),
        (results, '{"mine": 1}', f"{results} exists and is not ours"),
    ):
        folder = tmp_path / name
        folder.mkdir()
        (folder / name).write_text(text)
        with pytest.raises(SystemExit) as e:
            main(["--out", str(folder), "--no-progress"])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0], err
        assert [p.name for p in folder.iterdir()] == [name]
        assert (folder / name).read_text() == text
