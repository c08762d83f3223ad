"""The study server killed with ``kill -9`` mid-study loses no acknowledged answer."""

from __future__ import annotations

import asyncio
import sqlite3
import threading
import time

from study_fixtures import ServerProcess, write_dot_set

from slotv_jax.webstudy import client


def _stored(db) -> dict[tuple[str, int], str]:
    """(external id, position) -> guess, read straight from the SQLite file."""
    con = sqlite3.connect(db)
    rows = con.execute(
        "SELECT p.external_id, t.position, a.guess FROM answers a "
        "JOIN trials t ON t.trial = a.trial JOIN participants p ON p.participant = t.participant"
    ).fetchall()
    con.close()
    return {(e, pos): g for e, pos, g in rows}


def test_kill9_mid_study_loses_nothing(tmp_path):
    stim, db = tmp_path / "stim", tmp_path / "study.db"
    write_dot_set(stim, n=4, taus=(0.5, 1.0))  # 6 trials each: practice, 4, 1 check
    server = ServerProcess(stim, db)
    port = server.port
    log: list = []
    results: dict = {}

    def crowd():
        async def one(i):
            r, _ = await client.run_participant(
                server.url, client.uniform_guesser(i), ids={"PROLIFIC_PID": f"p{i}"},
                think=lambda: 0.03, timeout=90, log=log,
            )  # fmt: skip
            results[i] = r

        async def main():
            await asyncio.gather(*(one(i) for i in range(3)))

        asyncio.run(main())

    th = threading.Thread(target=crowd)
    try:
        th.start()
        deadline = time.monotonic() + 60
        while len(log) < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
        server.kill9()
        acked = list(log)  # every answer the server acknowledged before it died
        assert 5 <= len(acked) < 18, "the kill should land mid-study"
        time.sleep(0.3)  # participants keep retrying while the server is down
        server = ServerProcess(stim, db, port)
        stored = _stored(db)
        for pid, pos, guess in acked:
            assert stored[(pid, pos)] == guess
        th.join(90)
        assert not th.is_alive()
    finally:
        server.stop()
    # every participant went on to the end; each answer is stored once, as acknowledged
    assert sorted(results) == [0, 1, 2]
    assert all(r.code is not None and len(r.answers) == 6 for r in results.values())
    stored = _stored(db)
    assert len(stored) == 18
    assert {(pid, pos): g for pid, pos, g in log} == stored
