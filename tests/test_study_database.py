"""A ``--db`` that is not a healthy study database, and a ``--port`` in use: `study serve`,
`study export` and `study next` refuse them in one line, and leave the file and its folder
exactly as they were (no ``-wal``/``-shm`` beside it, no database created)."""

from __future__ import annotations

import hashlib
import re
import socket
import sqlite3
from pathlib import Path

import pytest
from study_fixtures import free_port, write_dot_set

from slotv_jax.study import cli as study_cli
from slotv_jax.study import rounds
from slotv_jax.webstudy.database import SQLiteStorage, check_database


def _study_db(path: Path) -> Path:
    """A study database with a round of 200 stimuli (a file of many pages), closed."""
    db = SQLiteStorage(path)
    n = 200
    manifest = {"stimuli": [{"id": f"s{i}", "trajectory": f"t{i}", "tau": 0.5, "camera": "c",
                             "kind": "trial", "goals": ["A"]} for i in range(n)]}  # fmt: skip
    trajectories = {f"t{i}": [[0.1 * k, 0.3, 0.0, 0.5] for k in range(40)] for i in range(n)}
    db.load_round(0, manifest, trajectories, {f"t{i}": [["A", 0.5, 0.1, 0.05]] for i in range(n)})
    db.close()
    return path


def _bad(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (a --db that is not a healthy study database, what the refusal says it is)."""
    tmp_path.mkdir(exist_ok=True)
    csv = tmp_path / "notadb.csv"
    csv.write_text("a,b,c\n1,2,3\n")
    whole = _study_db(tmp_path / "whole.db").read_bytes()
    assert len(whole) > 8 * 4096
    truncated = tmp_path / "truncated.db"
    truncated.write_bytes(whole[: len(whole) // 2])
    header = tmp_path / "header.db"
    header.write_bytes(whole[:60])
    folder = tmp_path / "folder.db"
    folder.mkdir()
    other = tmp_path / "other.db"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE notes (line TEXT)")
    con.commit()
    con.close()
    return {
        "csv": (csv, "not a SQLite database"),
        "truncated": (truncated, "a damaged (e.g. truncated) SQLite database"),
        "header": (header, "a damaged (e.g. truncated) SQLite database"),
        "folder": (folder, "a folder"),
        "other": (other, "a SQLite database of something else (tables notes)"),
    }


def _snapshot(folder: Path) -> dict[str, str | None]:
    """Every entry of ``folder`` with the sha256 of its bytes (None: a folder)."""
    return {
        p.name: None if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.iterdir())
    }


def _refused(argv, capsys, *pieces) -> None:
    with pytest.raises(SystemExit) as e:
        study_cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for piece in pieces:
        assert piece in err, (piece, err)


@pytest.mark.parametrize("command", ["serve", "export", "next"])
def test_a_db_that_is_not_a_study_database_is_refused_untouched(command, tmp_path, capsys):
    """A CSV, a truncated database, a folder or another program's database as ``--db``: one
    line naming --db and what the file is; not a byte of the folder changes."""
    bad = _bad(tmp_path / "in")  # _bad makes the folder's files
    stim = tmp_path / "stim"
    stim.mkdir()
    for name, (db, what) in bad.items():
        before = _snapshot(db.parent)
        if command == "serve":
            argv = ["serve", "--stimuli", stim, "--db", db, "--port", free_port()]
            _refused(argv, capsys, f"--db {db}: {what}")
        elif command == "export":
            _refused(
                ["export", "--db", db, "--out", tmp_path / "out"], capsys, f"--db {db}: {what}"
            )
            assert not (tmp_path / "out").exists()
        else:  # study next reads the answers so far from the --db first
            with pytest.raises(ValueError, match="^" + re.escape(f"--db {db}: {what}")):
                rounds.read_answers(db=db)
        assert _snapshot(db.parent) == before, name


def test_export_and_next_refuse_a_db_without_a_study(tmp_path, capsys):
    """The readers never create a database: a missing file or an empty SQLite file is
    refused (and stays empty), while a study's database is read."""
    empty = tmp_path / "empty.db"
    empty.write_bytes(b"")
    for db, what in [(empty, "an empty SQLite database"), (tmp_path / "no.db", "no such file")]:
        _refused(["export", "--db", db, "--out", tmp_path / "out"], capsys, f"--db {db}: {what}")
        with pytest.raises(ValueError, match="^" + re.escape(f"--db {db}: {what}")):
            rounds.read_answers(db=db)
    assert empty.read_bytes() == b"" and not (tmp_path / "no.db").exists()
    check_database(_study_db(tmp_path / "study.db"), create=False)  # a study's: accepted
    check_database(tmp_path / "new.db")  # serve creates a new one
    check_database(empty)  # ... or fills an empty one


def test_a_live_database_is_checked_without_disturbing_it(tmp_path):
    """A database a server holds open (its -wal beside it, answers not yet checkpointed) is
    read through the WAL: accepted, and the writer goes on."""
    path = _study_db(tmp_path / "live.db")
    writer = SQLiteStorage(path)
    writer.create_participant("sha", {}, lambda s, c, seed: [x.key for x in s[:3]], 0, "C")
    assert Path(f"{path}-wal").exists()
    check_database(path, create=False)
    assert SQLiteStorage(path).progress()["participants"][0]["trials"] == 3
    writer.answer(1, 0, "A", None, 10.0)
    writer.close()


def test_serve_refuses_a_port_in_use_before_making_the_db(tmp_path, capsys):
    """`serve --port P` with P taken: one line naming --port, exit 2, no --db created (it
    was created, then uvicorn's ``[Errno 98]``, exit 3)."""
    stim = tmp_path / "stim"
    write_dot_set(stim, n=2)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        db = tmp_path / "study.db"
        _refused(["serve", "--stimuli", stim, "--db", db, "--port", port], capsys,
                 f"--port {port}: already in use on 127.0.0.1")  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stim"]
