"""The ``stimuli``, ``serve``, ``export`` and ``simulate`` commands of the study CLI."""

from __future__ import annotations

import argparse
import asyncio
import collections
import secrets
import sys
import time
from pathlib import Path

import httpx

from slotv_jax.core import validation
from slotv_jax.core.fileio import check_not_input
from slotv_jax.webstudy import client, limits, make_stimuli
from slotv_jax.webstudy import export as export_lib
from slotv_jax.webstudy.database import SYNC, connect
from slotv_jax.webstudy.server import LOOPBACK_HOSTS, make_app
from slotv_jax.webstudy.service import StudyService


def _add_web_commands(sub) -> None:
    serve = sub.add_parser("serve", help="run the study server (participant page at /)")
    serve.add_argument("--stimuli", required=True, help="the study folder (stimulus sets)")
    serve.add_argument("--db", required=True, help="SQLite file of the answers (created if new)")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on")
    serve.add_argument("--port", type=int, default=8000)
    serve.add_argument("--allowed-hosts", default=None,
                       help="comma-separated Host names participants use (default: the "
                       "loopback names on a loopback --host, else any)")  # fmt: skip
    serve.add_argument("--sync", default="full", choices=SYNC,
                       help="full: each answer on disk before the reply (survives power "
                       "loss); normal: faster, survives a crashed server")  # fmt: skip
    d = limits.Limits()
    serve.add_argument("--client-timeout", type=float, default=d.client_timeout,
                       help="seconds a client has to send a whole request, or to read on when "
                       f"it stops taking a reply (default {d.client_timeout:g})")  # fmt: skip
    serve.add_argument("--keep-alive", type=float, default=d.keep_alive,
                       help="seconds a connection may stay idle between requests (default "
                       f"{d.keep_alive:g})")  # fmt: skip
    serve.add_argument("--max-connections", type=int, default=d.max_connections,
                       help="open connections at most; one more closes the one that has "
                       "waited longest on its client, or gets 503 when all are busy "
                       f"(default {d.max_connections})")  # fmt: skip
    exp = sub.add_parser("export", help="answers -> CSV tables that `study import` reads")
    exp.add_argument("--db", required=True, help="the server's SQLite file")
    exp.add_argument("--out", required=True, help="folder for answers/trajectories/goals.csv")
    exp.add_argument("--drop-failed-attention", action="store_true",
                     help="leave out participants who failed an attention check")  # fmt: skip
    exp.add_argument("--overwrite", action="store_true", help="replace earlier exported files")
    sim = sub.add_parser("simulate", help="simulated participants take a running study")
    sim.add_argument("--url", default="http://127.0.0.1:8000", help="the study server")
    sim.add_argument("--stimuli", required=True, help="the study folder the server serves")
    sim.add_argument("--participants", type=int, default=20)
    sim.add_argument("--labeler", default=None, choices=("dragan", "effdist", "fastapp"),
                     help="the simulated participants answer like this observer (default: "
                     "dragan)")  # fmt: skip
    sim.add_argument("--population", default=None,
                     help="or: they are people of this population (default, homogeneous or a "
                     "population JSON file; see README), each with their own draw")  # fmt: skip
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--first", type=int, default=0,
                     help="number of the first participant: ids sim-FIRST, ... and, with "
                     "--population, their draws (a later crowd on the same server starts "
                     "after the earlier one's)")  # fmt: skip
    sim.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the server")


def serve_main(args: argparse.Namespace) -> int:
    """Check the inputs, print the URLs and the admin token, and serve until stopped."""
    stimdir, db = Path(args.stimuli), Path(args.db)
    if not stimdir.is_dir():
        raise ValueError(f"--stimuli {stimdir}: expected a folder written by `study stimuli`")
    if not db.parent.is_dir():
        raise ValueError(f"--db {db}: the folder {db.parent} does not exist")
    if not 0 < args.port < 65536:
        raise ValueError(f"--port {args.port}: expected 1..65535")
    bounds = limits.Limits(args.client_timeout, args.keep_alive, args.max_connections)
    limits.check_file_limit(bounds)
    if args.allowed_hosts is not None:
        hosts = [h.strip() for h in args.allowed_hosts.split(",") if h.strip()]
        if not hosts:
            raise ValueError(f"--allowed-hosts {args.allowed_hosts!r}: expected host names")
    elif args.host in LOOPBACK_HOSTS:
        hosts = list(LOOPBACK_HOSTS)
    else:
        hosts = ["*"]
        print(f"note: any Host header is answered on {args.host}; pass --allowed-hosts "
              "with the name participants use", flush=True)  # fmt: skip
    sock = limits.bind(args.host, args.port)  # a port in use: refused before the --db is made
    try:
        service = StudyService(stimdir, connect(db, sync=args.sync))
        token = secrets.token_urlsafe(24)
        app = make_app(service, token, hosts)
        url = f"http://{args.host}:{args.port}"
        print(f"study: {url}/  (rounds {', '.join(map(str, sorted(service.sets)))})")
        print(f"admin: {url}/admin")
        print(f"admin token: {token}", flush=True)
        server = limits.make_server(app, args.host, args.port, bounds, log_level="warning",
                                    access_log=False)  # fmt: skip
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # Ctrl-C, after uvicorn's graceful shutdown (as uvicorn.run)
        pass
    finally:
        sock.close()
    return 0


def export_main(args: argparse.Namespace) -> int:
    """Write the exported tables (never over earlier files without ``--overwrite``)."""
    db, out = Path(args.db), Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: expected a folder")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: the folder {out.parent} does not exist")
    for n in export_lib.TABLES:
        check_not_input(out / f"{n}.csv", {"--db": db})
    there = [n for n in export_lib.TABLES if (out / f"{n}.csv").exists()]
    if there and not args.overwrite:
        raise ValueError(f"--out {out}: {there[0]}.csv exists (add --overwrite to replace it)")
    storage = connect(db, create=False)  # a missing, empty or damaged file: refused
    n = export_lib.export_tables(storage, out, drop_failed_attention=args.drop_failed_attention)
    kinds = collections.Counter(a["kind"] for a in storage.answers())
    dropped = kinds["trial"] - n["answers"]  # --drop-failed-attention
    print(
        f"wrote {out}: {n['answers']} answers to {n['trajectories']} trajectories "
        f"from {n['participants']} participants (the stimuli's answers; left out: "
        f"{kinds['attention']} attention checks, {kinds['practice']} practice trials"
        + (f", {dropped} answers of participants who failed a check" if dropped else "")
        + ")",
        file=sys.stdout,
    )
    return 0


def simulate_main(args: argparse.Namespace) -> int:
    """Run simulated participants against a running server and report what they did."""
    if not 1 <= args.participants <= 10_000:
        raise ValueError(f"--participants {args.participants}: expected 1..10000")
    if args.first < 0:
        raise ValueError(f"--first {args.first}: expected an integer >= 0")
    validation.check_seeds("--seed", args.seed)
    # participant i draws from fold_in(key(seed), i), which takes i < 2**32 as a seed does
    validation.check_seeds("--first", args.first, args.participants, count_name="--participants")
    if not args.url.startswith(("http://", "https://")):
        raise ValueError(f"--url {args.url}: expected http://HOST:PORT")
    if args.population is not None and args.labeler is not None:
        raise ValueError("--labeler, --population: expected one of them, got both")
    if args.population is not None:
        guess = client.PopulationGuesser(args.stimuli, args.population, seed=args.seed)
    else:
        guess = client.LabelerGuesser(args.stimuli, args.labeler or "dragan", seed=args.seed)
    deadline = time.monotonic() + args.wait
    while True:  # the server may still be starting
        try:
            httpx.get(args.url + "/healthz", timeout=5).raise_for_status()
            break
        except httpx.HTTPError as e:
            if time.monotonic() > deadline:
                raise ValueError(f"--url {args.url}: no study server there ({e})") from None
            time.sleep(0.25)
    kinds: collections.Counter = collections.Counter()

    def counted(g: client.Guesser) -> client.Guesser:  # the guesser, counting trial kinds
        def answer(state: dict, still: bytes) -> str:
            kinds[guess.stimuli.find(still)[0]["kind"]] += 1
            return g(state, still)

        return answer

    crowd = (client.Crowd(lambda i: counted(guess.participant(i)))
             if hasattr(guess, "participant") else counted(guess))  # fmt: skip
    try:
        res = asyncio.run(
            client.run_crowd(args.url, args.participants, crowd, timeout=600, first=args.first)
        )
    except client.Refused as e:
        if e.status == 409 and e.path == "/api/start":  # an earlier crowd's id
            last = args.first + args.participants - 1
            raise ValueError(
                f"--first {args.first}: participant {e.participant} already exists on the "
                f"server ({e.status} {e.reason}: it has answered); this crowd's ids are "
                f"sim-{args.first} ... sim-{last}: choose another --first, past the ids of "
                "the crowds before it"
            ) from None
        raise ValueError(f"--url {args.url}: {e}") from None
    except TimeoutError as e:  # the server stopped answering mid-run
        raise ValueError(f"--url {args.url}: {e}") from None
    done = sum(r.code is not None for r in res)
    # every guess was acknowledged: a post that fails raises out of run_crowd
    print(f"{done} of {len(res)} simulated participants finished, "
          f"{sum(len(r.answers) for r in res)} answers ({kinds['trial']} on the stimuli, "
          f"{kinds['attention']} attention checks, {kinds['practice']} practice trials; "
          "export keeps those on the stimuli)")  # fmt: skip
    return 0


COMMANDS = {"stimuli": make_stimuli.stimuli_main, "serve": serve_main,
            "export": export_main, "simulate": simulate_main}  # fmt: skip


def add_commands(sub) -> None:
    """Add ``stimuli``, ``serve``, ``export`` and ``simulate`` to the study CLI's subparsers."""
    make_stimuli.add_command(sub)
    _add_web_commands(sub)
