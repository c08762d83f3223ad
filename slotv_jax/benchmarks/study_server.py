"""Load test of the study server: simulated participants answering concurrently over loopback.

    python -m slotv_jax.benchmarks.study_server [--participants 100] [--max-seconds 300]
    python -m slotv_jax.benchmarks.study_server --kill-during-starts [--participants 100]

A real server (``python -m slotv_jax.study serve`` in a subprocess: uvicorn, Starlette,
SQLite in WAL mode with ``synchronous=FULL``) on 127.0.0.1 serves a small rendered
stimulus set (10 motions at τ 0.5 and 1, two attention checks, a practice trial: 13
trials per participant). ``--participants`` simulated participants take the study at
once, each one an HTTP client that does what the page does: start, then per trial get
the clip and the still, and post the answer. Four runs side by side, each on a fresh
database and server:

- **paced**: each participant thinks 1-3 s (uniform) before each answer, a crowd far
  busier than a real one (people take 5-20 s per trial);
- **burst**: no thinking at all: every participant answers as fast as the server lets
  them, the worst case;

each with ``--sync full`` (the default: every answer on disk before the reply, an
fsync per answer) and ``--sync normal`` (survives a crashed server, not a power cut).

Reported per scenario: answers acknowledged, answers **lost** (acknowledged but not in
the database) and **doubled** (a trial with two stored answers, or a repeated
submission stored again; the answers table's primary key is the trial, so the count is
checked against the acknowledgements), answers/s, and the answer latency (the POST
round trip as the client sees it, p50/p95/p99/max). The clients run in this process
(asyncio + httpx) on the same 2 cores as the server, so the latency includes their
scheduling. Target (issue 28): 0 lost, 0 doubled, p95 ≤ 50 ms with 100 participants.
Everything is bounded: ``--max-seconds`` per scenario, then the run stops by itself.

``--kill-during-starts`` runs one other scenario (issue 36): the paced crowd with
``sync=full`` starts at once, and the server is killed with SIGKILL as soon as a
quarter of the participants are stored, then started again on the same database and
port. Participants whose start reply was lost send it again (as the page does) and must
resume their own row. Reported: participants stored at the kill, starts resumed (rows
issued twice), rows (one per participant), finished, answers, lost, doubled, the time
the server was down, the wall time; it passes when every participant finishes with
nothing lost or doubled and one row each.
"""

from __future__ import annotations

import asyncio
import datetime
import os
import platform
import random
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import starlette
import uvicorn

from slotv_jax import render  # render first: it picks MUJOCO_GL=egl before MuJoCo loads
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli
from slotv_jax.kinematics import Q_HOME
from slotv_jax.webstudy import client
from slotv_jax.webstudy.make_stimuli import SceneRenderer
from slotv_jax.webstudy.stimuli import cross_specs, write_stimulus_set

SERVE = [sys.executable, "-m", "slotv_jax.study", "serve"]


def stimulus_set(out: Path, n: int = 10) -> None:
    """``n`` joint-space motions from home (tables with goals under the motions' ends),
    rendered small: the server's work does not depend on the pictures."""
    rng = np.random.default_rng(0)
    m = n + 3
    home = np.asarray(Q_HOME, np.float64)
    s = np.linspace(0.0, 1.0, 20)[:, None]
    low, high = [-0.6, 0.2, -0.3, 0.3, -0.3, -0.2, -0.3], [0.6, 0.5, 0.3, 0.6, 0.3, 0.2, 0.3]
    q = np.stack([home + s * rng.uniform(low, high) for _ in range(m)]).astype(np.float32)
    r = SceneRenderer(size=(96, 64), fps=10, duration=1.0, hold=0.2)
    xyz = np.stack([r.renderer.tcp_path(qi) for qi in q]).astype(np.float32)
    goals = np.zeros((m, 8, 3), np.float32)
    goals[:, :3] = xyz[:, -1:] * [1, 1, 0] + np.array([[0, -0.25, 0.025], [0, 0, 0.025],
                                                      [0, 0.25, 0.025]])  # fmt: skip
    mask = np.zeros((m, 8), bool)
    mask[:, :3] = True
    specs = cross_specs(range(n), taus=(0.5, 1.0), cameras=render.CAMERAS[:1],
                        attention=[n, n + 1], practice=[n + 2])  # fmt: skip
    try:
        write_stimulus_set(out, q=q, xyz=xyz, goals=goals, goal_mask=mask,
                           ids=[f"m{i}" for i in range(m)], specs=specs, render=r,
                           targets=np.ones(m, int), progress=False)  # fmt: skip
    finally:
        r.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(stim: Path, db: Path, port: int, sync: str) -> subprocess.Popen:
    """``study serve`` in a subprocess, returned once it answers ``/healthz``."""
    url = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen([*SERVE, "--stimuli", str(stim), "--db", str(db), "--port",
                             str(port), "--sync", sync], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    for line in proc.stdout:
        if line.startswith("admin token:"):
            break
    deadline = time.monotonic() + 60
    while True:
        try:
            httpx.get(url + "/healthz", timeout=1).raise_for_status()
            return proc
        except httpx.HTTPError:
            if time.monotonic() > deadline or proc.poll() is not None:
                stop(proc)
                raise RuntimeError(f"server did not start: {proc.stderr.read()[-2000:]}") from None
            time.sleep(0.1)


def stop(proc: subprocess.Popen) -> None:
    """End a server of :func:`serve` (SIGTERM, then SIGKILL after 30 s)."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    proc.stdout.close()
    proc.stderr.close()


def _stored(db: Path) -> list[tuple[str, int, str]]:
    """(external id, position, guess) of every stored answer, read from the SQLite file."""
    con = sqlite3.connect(db)
    stored = con.execute(
        "SELECT p.external_id, t.position, a.guess FROM answers a "
        "JOIN trials t ON t.trial = a.trial JOIN participants p ON p.participant = t.participant"
    ).fetchall()
    con.close()
    return stored


def _figures(results: list, stored: list, wall: float) -> dict:
    """Answers, finished, lost, doubled, extra, rate and latency of a crowd's run."""
    acked = {(f"sim-{i}", pos, g) for i, r in enumerate(results) for pos, g in r.answers}
    keys = [(e, pos) for e, pos, _ in stored]
    lat = np.array([x for r in results for x in r.latencies]) * 1000
    return {
        "answers": len(acked),
        "finished": sum(r.code is not None for r in results),
        "lost": len(acked - set(stored)),
        "doubled": len(keys) - len(set(keys)) + sum(r.duplicates for r in results),
        "extra": len(set(stored) - acked),
        "rate": len(acked) / wall,
        "wall": wall,
        "p50": float(np.percentile(lat, 50)),
        "p95": float(np.percentile(lat, 95)),
        "p99": float(np.percentile(lat, 99)),
        "max": float(lat.max()),
    }


def scenario(stim: Path, db: Path, n: int, think, max_seconds: float, sync: str) -> dict:
    """One load run on a fresh server and database; the figures of the module docstring."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    proc = serve(stim, db, port, sync)
    try:
        t0 = time.perf_counter()
        results = asyncio.run(asyncio.wait_for(
            client.run_crowd(url, n, client.uniform_guesser(1), think=think,
                             timeout=max_seconds), max_seconds + 30))  # fmt: skip
        wall = time.perf_counter() - t0
    finally:
        stop(proc)
    return _figures(results, _stored(db), wall)


def kill_scenario(stim: Path, db: Path, n: int, think, max_seconds: float) -> dict:
    """The ``--kill-during-starts`` run (see the module docstring)."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    box: dict = {"proc": serve(stim, db, port, "full")}

    def rows() -> int:
        con = sqlite3.connect(db, timeout=5)
        try:
            return con.execute("SELECT COUNT(*) FROM participants").fetchone()[0]
        finally:
            con.close()

    def killer():
        try:
            deadline = time.monotonic() + max_seconds
            while rows() < max(1, n // 4) and time.monotonic() < deadline:
                time.sleep(0.001)
            os.kill(box["proc"].pid, signal.SIGKILL)
            box["proc"].wait(10)
            box["at_kill"] = rows()
            t = time.perf_counter()
            stop(box["proc"])
            box["proc"] = serve(stim, db, port, "full")
            box["down"] = time.perf_counter() - t
        except Exception as e:  # reported by the main thread
            box["error"] = e

    th = threading.Thread(target=killer)
    try:
        t0 = time.perf_counter()
        th.start()
        results = asyncio.run(asyncio.wait_for(
            client.run_crowd(url, n, client.uniform_guesser(1), think=think,
                             timeout=max_seconds), max_seconds + 30))  # fmt: skip
        wall = time.perf_counter() - t0
    finally:
        th.join(120)
        stop(box["proc"])
    if "error" in box:
        raise RuntimeError(f"the kill and restart failed: {box['error']}")
    con = sqlite3.connect(db)
    starts = [r[0] for r in con.execute("SELECT starts FROM participants")]
    con.close()
    out = _figures(results, _stored(db), wall)
    out.update(at_kill=box["at_kill"], resumed=sum(k == 2 for k in starts),
               reissued=sum(k > 2 for k in starts), rows=len(starts), down=box["down"])  # fmt: skip
    return out


def _parse(argv):
    ap = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.study_server",
                                 description=__doc__.splitlines()[0])  # fmt: skip
    ap.add_argument("--participants", type=int, default=100)
    ap.add_argument("--max-seconds", type=float, default=300.0, help="bound per scenario")
    ap.add_argument("--kill-during-starts", action="store_true",
                    help="only the kill -9 during the starts scenario (issue 36)")  # fmt: skip
    args = ap.parse_args(argv)
    if not 1 <= args.participants <= 2000:
        raise cli.InputError(f"--participants {args.participants}: expected 1..2000")
    if not args.max_seconds > 0:
        raise cli.InputError(f"--max-seconds {args.max_seconds}: expected seconds > 0")
    return args


@cli.command
def main(argv=None) -> int:
    args = _parse(argv)
    load = os.getloadavg()[0]
    print(f"# study server load test, {datetime.date.today()}, {cpu_model()}, "
          f"{os.cpu_count()} cores, load average {load:.1f} at the start")  # fmt: skip
    print(f"# Python {platform.python_version()}, Starlette {starlette.__version__}, "
          f"uvicorn {uvicorn.__version__}, SQLite {sqlite3.sqlite_version}, "
          f"httpx {httpx.__version__}")  # fmt: skip
    rng = random.Random(0)
    rows = []
    paced, burst = (lambda: rng.uniform(1.0, 3.0)), (lambda: 0.0)
    if args.kill_during_starts:
        with tempfile.TemporaryDirectory() as tmp:
            stimulus_set(Path(tmp) / "stim")
            r = kill_scenario(Path(tmp) / "stim", Path(tmp) / "kill.db", args.participants,
                              paced, args.max_seconds)  # fmt: skip
        print("\n| participants | stored at the kill | starts resumed | rows | finished "
              "| answers | lost | doubled | server down s | wall s |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|---|---|")
        print(f"| {args.participants} | {r['at_kill']} | {r['resumed']} | {r['rows']} "
              f"| {r['finished']}/{args.participants} | {r['answers']} | {r['lost']} "
              f"| {r['doubled']} | {r['down']:.1f} | {r['wall']:.1f} |")  # fmt: skip
        ok = (r["finished"] == r["rows"] == args.participants and r["reissued"] == 0
              and r["lost"] == r["doubled"] == r["extra"] == 0)  # fmt: skip
        print(f"\nevery participant finished, one row each, no answer lost or doubled: {ok}")
        return 0 if ok else 1
    with tempfile.TemporaryDirectory() as tmp:
        stim = Path(tmp) / "stim"
        stimulus_set(stim)
        runs = (("paced, sync=full (default)", paced, "full"),
                ("paced, sync=normal", paced, "normal"),
                ("burst, sync=full", burst, "full"),
                ("burst, sync=normal", burst, "normal"))  # fmt: skip
        for i, (name, think, sync) in enumerate(runs):
            db = Path(tmp) / f"run{i}.db"
            r = scenario(stim, db, args.participants, think, args.max_seconds, sync)
            rows.append((name, r))
            print(f"# {name}: done in {r['wall']:.1f} s, load average {os.getloadavg()[0]:.1f}",
                  flush=True)  # fmt: skip
    print()
    print("| scenario | participants finished | answers | lost | doubled | answers/s "
          "| p50 ms | p95 ms | p99 ms | max ms |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in rows:
        print(f"| {name} | {r['finished']}/{args.participants} | {r['answers']} | {r['lost']} "
              f"| {r['doubled']} | {r['rate']:.0f} | {r['p50']:.1f} | {r['p95']:.1f} "
              f"| {r['p99']:.1f} | {r['max']:.1f} |")  # fmt: skip
    ok = all(r["lost"] == 0 and r["doubled"] == 0 and r["extra"] == 0 for _, r in rows)
    print(f"\nno answer lost or doubled: {ok}; p95 of the paced crowd (default): "
          f"{rows[0][1]['p95']:.1f} ms")  # fmt: skip
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
