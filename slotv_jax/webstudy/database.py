"""Where a study's answers live: a small storage interface and its SQLite implementation.

The web layer talks only to :class:`Storage` (a ``Protocol``), so another SQL database
can replace SQLite by implementing its dozen methods; the SQL below keeps to what
PostgreSQL also accepts (``INSERT ... ON CONFLICT DO NOTHING``, no SQLite-only types).

Durability
----------
SQLite runs in WAL mode and every answer is committed in its own transaction before
:meth:`Storage.answer` returns. With ``sync="full"`` (the default, SQLite's
``synchronous=FULL``) the commit waits for the disk (an fsync, 6 ms on the test VM), so
no acknowledged answer is lost even by a power cut; with ``sync="normal"`` it does not
wait, and an acknowledged answer survives a crashed or ``kill -9``-ed server but may be
lost by a power cut or a crash of the operating system (SQLite's WAL documentation).
Each thread has its own connection; writers take the database lock at
``BEGIN IMMEDIATE`` and wait up to ``busy_timeout`` for it, readers never wait (WAL).

Tables
------
``rounds`` (round, manifest JSON), ``trajectories`` (id, points JSON [[t, x, y, z], ...]),
``goals`` (trajectory, slot, goal name, x, y, z), ``stimuli`` (round, id, trajectory, τ,
camera, kind, target, goal names), ``participants`` (sha256 of the token, the external
participant / study / session ids, the seed of their draw, timestamps, completion code,
``starts``: how many times the participant was issued a token),
``trials`` (participant, position in their order, stimulus), ``answers`` (trial, guess,
confidence, response time; the trial is the primary key, so an answer is stored once).

>>> db = SQLiteStorage("study.db")                 # doctest: +SKIP
>>> db.progress()["answers"]                       # doctest: +SKIP
0
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Protocol

from slotv_jax.webstudy.design import Stimulus

SCHEMA_VERSION = 2  # 2: participants.starts
SYNC = ("full", "normal")  # SQLite's synchronous setting (see Durability)
ACTIVE_SECONDS = 3600.0  # an unfinished participant seen this recently still holds trials
PENDING_SECONDS = 600.0  # ... and one with no answer yet (e.g. a lost start) this long
_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS rounds (
    round INTEGER PRIMARY KEY, manifest TEXT NOT NULL, loaded REAL NOT NULL);
CREATE TABLE IF NOT EXISTS trajectories (trajectory TEXT PRIMARY KEY, points TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS goals (
    trajectory TEXT NOT NULL REFERENCES trajectories, slot INTEGER NOT NULL,
    goal TEXT NOT NULL, x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
    PRIMARY KEY (trajectory, slot));
CREATE TABLE IF NOT EXISTS stimuli (
    stimulus INTEGER PRIMARY KEY, round INTEGER NOT NULL REFERENCES rounds, id TEXT NOT NULL,
    trajectory TEXT NOT NULL REFERENCES trajectories, tau REAL NOT NULL, camera TEXT NOT NULL,
    kind TEXT NOT NULL, target TEXT, goals TEXT NOT NULL, UNIQUE (round, id));
CREATE TABLE IF NOT EXISTS participants (
    participant INTEGER PRIMARY KEY, token_sha256 TEXT NOT NULL UNIQUE,
    external_id TEXT, study_id TEXT, session_id TEXT, round INTEGER NOT NULL,
    seed INTEGER NOT NULL, created REAL NOT NULL, last_seen REAL NOT NULL,
    finished REAL, completion_code TEXT NOT NULL, user_agent TEXT,
    starts INTEGER NOT NULL DEFAULT 1);
CREATE UNIQUE INDEX IF NOT EXISTS participants_external
    ON participants (external_id, study_id);
CREATE TABLE IF NOT EXISTS trials (
    trial INTEGER PRIMARY KEY, participant INTEGER NOT NULL REFERENCES participants,
    position INTEGER NOT NULL, stimulus INTEGER NOT NULL REFERENCES stimuli,
    shown INTEGER NOT NULL DEFAULT 0, UNIQUE (participant, position));
CREATE TABLE IF NOT EXISTS answers (
    trial INTEGER PRIMARY KEY REFERENCES trials, guess TEXT NOT NULL, confidence INTEGER,
    response_ms REAL NOT NULL, answered REAL NOT NULL);
"""


_KEY_TABLES = {"meta", "trials", "answers"}  # a study's database has these (every version)

_MIGRATIONS = {  # schema version -> the statements that take it to the next one
    1: ("ALTER TABLE participants ADD COLUMN starts INTEGER NOT NULL DEFAULT 1",),
}


class Conflict(Exception):
    """The request contradicts what is stored (e.g. an external id that already answered)."""


class Storage(Protocol):
    """What the study server needs from a database (see the module docstring)."""

    def load_round(
        self, round_: int, manifest: dict, trajectories: dict[str, list], goals: dict[str, list]
    ) -> bool: ...
    def manifest(self, round_: int) -> dict | None: ...
    def rounds(self) -> list[int]: ...
    def create_participant(
        self,
        token_sha256: str,
        ids: dict[str, str | None],
        plan: Callable[[list[Stimulus], dict[int, int], int], list[int]],
        seed: int,
        code: str,
        *,
        resume: bool = False,
    ) -> int: ...
    def set_token(self, participant: int, token_sha256: str) -> bool: ...
    def participant(self, token_sha256: str) -> dict | None: ...
    def trials(self, participant: int) -> list[dict]: ...
    def mark_shown(self, participant: int, position: int) -> None: ...
    def answer(
        self,
        participant: int,
        position: int,
        guess: str,
        confidence: int | None,
        response_ms: float,
    ) -> tuple[bool, dict]: ...
    def progress(self) -> dict: ...
    def answers(self) -> list[dict]: ...
    def participants(self) -> list[dict]: ...
    def trajectory_tables(self) -> tuple[dict[str, list], dict[str, list]]: ...


def check_database(path: str | Path, *, create: bool = True) -> None:
    """Refuse a ``--db`` that is not a healthy study database, touching nothing.

    The file is opened read-only (``immutable`` when no ``-wal`` file beside it holds
    changes, so SQLite writes no ``-wal``/``-shm`` file either) and SQLite's own
    ``PRAGMA quick_check`` and schema are asked. Accepted: a study server's database, or,
    with ``create``, a file that does not exist yet or an empty SQLite database (the study
    tables are then created in it). Refused, with a :class:`ValueError` naming ``--db`` and
    what the file is: a folder, a file that is not SQLite (a CSV, say), a damaged or
    truncated database, or the database of something else (tables, but not a study's).

    >>> check_database("notadb.csv")  # doctest: +SKIP
    ValueError: --db notadb.csv: not a SQLite database (SQLite: file is not a database) ...
    """
    path = Path(path)
    expected = "expected the study server's SQLite file"
    if not path.exists():
        if create:
            return
        raise ValueError(f"--db {path}: no such file ({expected})")
    if path.is_dir():
        raise ValueError(f"--db {path}: a folder, {expected}")
    if not path.is_file():
        raise ValueError(f"--db {path}: not a regular file, {expected}")
    wal = Path(f"{path}-wal")
    mode = "ro" if wal.exists() else "ro&immutable=1"
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode={mode}", uri=True)
        try:
            check = [r[0] for r in con.execute("PRAGMA quick_check").fetchall()]
            tables = {
                r[0] for r in con.execute("SELECT name FROM sqlite_schema WHERE type = 'table'")
            }
        finally:
            con.close()
    except sqlite3.DatabaseError as e:
        what = {
            "SQLITE_NOTADB": "not a SQLite database",
            "SQLITE_CORRUPT": "a damaged (e.g. truncated) SQLite database",
        }.get(getattr(e, "sqlite_errorname", ""), "a file SQLite cannot read")
        raise ValueError(f"--db {path}: {what} (SQLite: {e}); {expected}") from None
    if check != ["ok"]:
        raise ValueError(
            f"--db {path}: a damaged SQLite database (quick_check: {check[0]}); {expected}"
        )
    if tables and not _KEY_TABLES <= tables:
        raise ValueError(
            f"--db {path}: a SQLite database of something else (tables "
            f"{', '.join(sorted(tables)[:5])}), not a study's; {expected}"
        )
    if not tables and not create:
        raise ValueError(f"--db {path}: an empty SQLite database, no study's tables; {expected}")


class SQLiteStorage:
    """:class:`Storage` on one SQLite file (WAL, one connection per thread).

    The file is checked first (:func:`check_database`): one that is not a healthy study
    database is refused before anything is written; ``create=False`` refuses a missing or
    empty one too (the readers: export, ``study next``).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        sync: str = "full",
        busy_timeout_ms: int = 30000,
        create: bool = True,
    ):
        if sync not in SYNC:
            raise ValueError(f"sync: expected one of {SYNC}, got {sync!r}")
        check_database(path, create=create)
        self.path = Path(path)
        self.sync = sync
        self.busy_timeout_ms = busy_timeout_ms
        self._local = threading.local()
        self._con().executescript(_SCHEMA)
        with self._tx() as db:
            row = db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
            if row is None:
                db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
                return
            version = int(row[0]) if row[0].isdigit() else row[0]
            while version in _MIGRATIONS:  # an older database: brought up to date in place
                for statement in _MIGRATIONS[version]:
                    db.execute(statement)
                version += 1
            if version != SCHEMA_VERSION:
                raise ValueError(
                    f"--db {self.path}: schema version {row[0]}, expected {SCHEMA_VERSION}"
                )
            db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (str(version),))

    # ------------------------------------------------------------ connections

    def _con(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None:
            con = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
            con.row_factory = sqlite3.Row
            con.execute(f"PRAGMA busy_timeout = {int(self.busy_timeout_ms)}")
            mode = con.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise ValueError(f"--db {self.path}: SQLite could not switch to WAL ({mode})")
            con.execute(f"PRAGMA synchronous = {self.sync.upper()}")
            con.execute("PRAGMA foreign_keys = ON")
            self._local.con = con
        return con

    @contextlib.contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        """One write transaction: ``BEGIN IMMEDIATE`` ... ``COMMIT`` (rolled back on error)."""
        con = self._con()
        con.execute("BEGIN IMMEDIATE")
        try:
            yield con
        except BaseException:
            con.execute("ROLLBACK")
            raise
        con.execute("COMMIT")

    def close(self) -> None:
        """Close this thread's connection."""
        con = getattr(self._local, "con", None)
        if con is not None:
            con.close()
            self._local.con = None

    # ---------------------------------------------------------------- rounds

    def load_round(
        self, round_: int, manifest: dict, trajectories: dict[str, list], goals: dict[str, list]
    ) -> bool:
        """Store a round's stimuli, trajectories and goals once; False if already stored.

        A trajectory id stored by an earlier round must have the same points and goals.
        """
        with self._tx() as db:
            if db.execute("SELECT 1 FROM rounds WHERE round = ?", (round_,)).fetchone():
                return False
            for tid, points in trajectories.items():
                old = db.execute(
                    "SELECT points FROM trajectories WHERE trajectory = ?", (tid,)
                ).fetchone()
                if old is None:
                    db.execute("INSERT INTO trajectories VALUES (?, ?)", (tid, json.dumps(points)))
                    db.executemany(
                        "INSERT INTO goals VALUES (?, ?, ?, ?, ?, ?)",
                        [(tid, s, g[0], *g[1:]) for s, g in enumerate(goals[tid])],
                    )
                    continue
                old_goals = db.execute(
                    "SELECT goal, x, y, z FROM goals WHERE trajectory = ? ORDER BY slot", (tid,)
                ).fetchall()
                if json.loads(old[0]) != points or [list(g) for g in old_goals] != goals[tid]:
                    raise ValueError(
                        f"round {round_}: trajectory {tid!r} differs from the one of the same "
                        "id in an earlier round"
                    )
            db.execute(
                "INSERT INTO rounds VALUES (?, ?, ?)", (round_, json.dumps(manifest), time.time())
            )
            db.executemany(
                "INSERT INTO stimuli (round, id, trajectory, tau, camera, kind, target, goals) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (round_, s["id"], s["trajectory"], s["tau"], s["camera"], s["kind"],
                     s.get("target"), json.dumps(s["goals"]))
                    for s in manifest["stimuli"]
                ],
            )  # fmt: skip
        return True

    def manifest(self, round_: int) -> dict | None:
        """The stored manifest of a round (``None``: not stored)."""
        row = self._con().execute("SELECT manifest FROM rounds WHERE round = ?", (round_,))
        row = row.fetchone()
        return json.loads(row[0]) if row else None

    def rounds(self) -> list[int]:
        """The stored rounds, in order."""
        rows = self._con().execute("SELECT round FROM rounds ORDER BY round").fetchall()
        return [r[0] for r in rows]

    # ---------------------------------------------------------- participants

    def create_participant(
        self,
        token_sha256: str,
        ids: dict[str, str | None],
        plan: Callable[[list[Stimulus], dict[int, int], int], list[int]],
        seed: int,
        code: str,
        *,
        resume: bool = False,
    ) -> int:
        """Create a participant with the trials ``plan(stimuli, counts, seed)`` draws.

        The stimuli are those of the newest round; ``counts`` holds each one's answers plus
        the unanswered trials of participants still active: seen in the last
        :data:`ACTIVE_SECONDS`, or in the last :data:`PENDING_SECONDS` for one without an
        answer yet (a start whose reply was lost and nobody resumed). One transaction, so
        concurrent participants see each other's draws.

        When the external (participant, study) ids already started: with ``resume`` and no
        answer stored for them, that participant is re-issued to ``token_sha256`` (the
        same row and trials; the token it held before stops working; ``starts`` counts
        the issues) and its number returned; otherwise :class:`Conflict`.
        """
        now = time.time()
        with self._tx() as db:
            row = db.execute("SELECT MAX(round) FROM rounds").fetchone()
            if row[0] is None:
                raise ValueError("no stimulus round is loaded")
            round_ = row[0]
            if ids.get("external_id"):
                old = db.execute(
                    "SELECT participant FROM participants WHERE external_id = ? AND study_id IS ?",
                    (ids["external_id"], ids.get("study_id")),
                ).fetchone()
                if old is not None:
                    answered = db.execute(
                        "SELECT 1 FROM trials t JOIN answers a ON a.trial = t.trial "
                        "WHERE t.participant = ? LIMIT 1",
                        (old[0],),
                    ).fetchone()
                    if answered or not resume:
                        raise Conflict("this participant id has already answered")
                    db.execute(
                        "UPDATE participants SET token_sha256 = ?, last_seen = ?, "
                        "starts = starts + 1 WHERE participant = ?",
                        (token_sha256, now, old[0]),
                    )
                    return int(old[0])
            stims = [
                Stimulus(r[0], r[1], r[2])
                for r in db.execute(
                    "SELECT stimulus, trajectory, kind FROM stimuli WHERE round = ? "
                    "ORDER BY stimulus",
                    (round_,),
                )
            ]
            counts = {
                r[0]: r[1]
                for r in db.execute(
                    "SELECT t.stimulus, COUNT(*) FROM trials t "
                    "JOIN participants p ON p.participant = t.participant "
                    "LEFT JOIN answers a ON a.trial = t.trial "
                    "WHERE a.trial IS NOT NULL OR (p.finished IS NULL AND (p.last_seen > ? "
                    "OR (p.last_seen > ? AND EXISTS (SELECT 1 FROM trials t2 JOIN answers a2 "
                    "ON a2.trial = t2.trial WHERE t2.participant = p.participant)))) "
                    "GROUP BY t.stimulus",
                    (now - PENDING_SECONDS, now - ACTIVE_SECONDS),
                )
            }
            order = plan(stims, counts, seed)
            cur = db.execute(
                "INSERT INTO participants (token_sha256, external_id, study_id, session_id, "
                "round, seed, created, last_seen, completion_code, user_agent) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (token_sha256, ids.get("external_id"), ids.get("study_id"),
                 ids.get("session_id"), round_, seed, now, now, code, ids.get("user_agent")),
            )  # fmt: skip
            pid = int(cur.lastrowid)
            db.executemany(
                "INSERT INTO trials (participant, position, stimulus) VALUES (?, ?, ?)",
                [(pid, i, s) for i, s in enumerate(order)],
            )
        return pid

    def set_token(self, participant: int, token_sha256: str) -> bool:
        """Give a participant a new token (the old one stops working); False: no such
        participant. The researcher's way to let someone go on in another browser."""
        with self._tx() as db:
            cur = db.execute(
                "UPDATE participants SET token_sha256 = ?, starts = starts + 1 "
                "WHERE participant = ?",
                (token_sha256, participant),
            )
        return cur.rowcount == 1

    def participant(self, token_sha256: str) -> dict | None:
        """The participant holding this token (``None``: no such participant)."""
        row = (
            self._con()
            .execute("SELECT * FROM participants WHERE token_sha256 = ?", (token_sha256,))
            .fetchone()
        )
        return dict(row) if row else None

    def trials(self, participant: int) -> list[dict]:
        """A participant's trials in their order, with stimulus and answer (if any)."""
        rows = (
            self._con()
            .execute(
                "SELECT t.trial, t.position, t.shown, s.stimulus, s.round, s.id, s.trajectory, "
                "s.tau, s.camera, s.kind, s.target, s.goals, a.guess, a.confidence, "
                "a.response_ms FROM trials t JOIN stimuli s ON s.stimulus = t.stimulus "
                "LEFT JOIN answers a ON a.trial = t.trial WHERE t.participant = ? "
                "ORDER BY t.position",
                (participant,),
            )
            .fetchall()
        )
        out = []
        for r in rows:
            d = dict(r)
            d["goals"] = json.loads(d["goals"])
            out.append(d)
        return out

    def mark_shown(self, participant: int, position: int) -> None:
        """Count one more showing of a trial by a reload of the page (``trials.shown``) and
        touch last_seen."""
        with self._tx() as db:
            db.execute(
                "UPDATE trials SET shown = shown + 1 WHERE participant = ? AND position = ?",
                (participant, position),
            )
            db.execute(
                "UPDATE participants SET last_seen = ? WHERE participant = ?",
                (time.time(), participant),
            )

    def answer(
        self,
        participant: int,
        position: int,
        guess: str,
        confidence: int | None,
        response_ms: float,
    ) -> tuple[bool, dict]:
        """Store the answer of a trial once, in its own transaction.

        Returns (stored, the stored answer): ``stored`` is False when the trial was already
        answered (a repeated submission), and the first answer is returned unchanged. The
        participant is marked finished when this was their last unanswered trial.
        """
        now = time.time()
        with self._tx() as db:
            row = db.execute(
                "SELECT trial FROM trials WHERE participant = ? AND position = ?",
                (participant, position),
            ).fetchone()
            if row is None:
                raise ValueError(f"participant {participant} has no trial {position}")
            cur = db.execute(
                "INSERT INTO answers VALUES (?, ?, ?, ?, ?) ON CONFLICT (trial) DO NOTHING",
                (row[0], guess, confidence, float(response_ms), now),
            )
            stored = cur.rowcount == 1
            ans = db.execute(
                "SELECT guess, confidence, response_ms FROM answers WHERE trial = ?", (row[0],)
            ).fetchone()
            db.execute(
                "UPDATE participants SET last_seen = ?, finished = CASE WHEN finished IS NULL "
                "AND NOT EXISTS (SELECT 1 FROM trials t LEFT JOIN answers a ON a.trial = t.trial "
                "WHERE t.participant = ? AND a.trial IS NULL) THEN ? ELSE finished END "
                "WHERE participant = ?",
                (now, participant, now, participant),
            )
        return stored, dict(ans)

    # ------------------------------------------------------------------ admin

    def progress(self) -> dict:
        """Answers per stimulus and per participant (the admin page's tables)."""
        con = self._con()
        stimuli = [
            dict(r)
            for r in con.execute(
                "SELECT s.round, s.id, s.trajectory, s.tau, s.camera, s.kind, "
                "COUNT(a.trial) AS answers, COUNT(t.trial) AS assigned FROM stimuli s "
                "LEFT JOIN trials t ON t.stimulus = s.stimulus "
                "LEFT JOIN answers a ON a.trial = t.trial "
                "GROUP BY s.stimulus ORDER BY s.round, s.id"
            )
        ]
        people = self.participants()
        return {
            "rounds": self.rounds(),
            "answers": sum(s["answers"] for s in stimuli),
            "stimuli": stimuli,
            "participants": people,
        }

    def participants(self) -> list[dict]:
        """Every participant: ids, timestamps, starts, answered trials, attention checks
        passed."""
        rows = self._con().execute(
            "SELECT p.participant, p.external_id, p.study_id, p.session_id, p.round, p.seed, "
            "p.created, p.last_seen, p.finished, p.completion_code, p.starts, "
            "COUNT(t.trial) AS trials, "
            "COUNT(a.trial) AS answered, "
            "SUM(CASE WHEN s.kind = 'attention' AND a.trial IS NOT NULL THEN 1 ELSE 0 END) "
            "AS attention_answered, "
            "SUM(CASE WHEN s.kind = 'attention' AND a.guess = s.target THEN 1 ELSE 0 END) "
            "AS attention_passed FROM participants p "
            "LEFT JOIN trials t ON t.participant = p.participant "
            "LEFT JOIN stimuli s ON s.stimulus = t.stimulus "
            "LEFT JOIN answers a ON a.trial = t.trial "
            "GROUP BY p.participant ORDER BY p.participant"
        )
        return [dict(r) for r in rows]

    def answers(self) -> list[dict]:
        """Every stored answer with its trial, stimulus and participant, in answer order."""
        rows = self._con().execute(
            "SELECT a.trial, t.participant, t.position, t.shown, s.round, s.id AS stimulus, "
            "s.trajectory, s.tau, s.camera, s.kind, s.target, a.guess, a.confidence, "
            "a.response_ms, a.answered FROM answers a JOIN trials t ON t.trial = a.trial "
            "JOIN stimuli s ON s.stimulus = t.stimulus ORDER BY a.answered, a.trial"
        )
        return [dict(r) for r in rows]

    def trajectory_tables(self) -> tuple[dict[str, list], dict[str, list]]:
        """Every stored trajectory's points [[t, x, y, z], ...] and goals [[name, x, y, z]]."""
        con = self._con()
        traj = {r[0]: json.loads(r[1]) for r in con.execute("SELECT * FROM trajectories")}
        goals: dict[str, list] = {}
        for r in con.execute("SELECT * FROM goals ORDER BY trajectory, slot"):
            goals.setdefault(r[0], []).append([r[2], r[3], r[4], r[5]])
        return traj, goals


def connect(url: str | Path, *, sync: str = "full", create: bool = True) -> Storage:
    """The storage behind ``--db``: a SQLite file (the only backend shipped), checked by
    :func:`check_database` (``create=False``: it must already be a study's)."""
    return SQLiteStorage(url, sync=sync, create=create)


def unanswered(trials: Sequence[dict]) -> dict | None:
    """The first trial without an answer (``None``: all answered)."""
    return next((t for t in trials if t["guess"] is None), None)
