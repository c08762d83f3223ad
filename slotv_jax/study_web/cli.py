"""The ``stimuli``, ``serve`` and ``export`` subcommands of ``python -m slotv_jax.study``."""

from __future__ import annotations

import argparse
import secrets
import sys
from pathlib import Path

import uvicorn

from slotv_jax.study_web import export as export_lib
from slotv_jax.study_web.server import make_app
from slotv_jax.study_web.service import StudyService
from slotv_jax.study_web.storage import connect


def add_commands(sub) -> None:
    """Add ``serve`` and ``export`` to the study CLI's subparsers."""
    serve = sub.add_parser("serve", help="run the study server (participant page at /)")
    serve.add_argument("--stimuli", required=True, help="the study folder (stimulus sets)")
    serve.add_argument("--db", required=True, help="SQLite file of the answers (created if new)")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on")
    serve.add_argument("--port", type=int, default=8000)
    exp = sub.add_parser("export", help="answers -> CSV tables that `study import` reads")
    exp.add_argument("--db", required=True, help="the server's SQLite file")
    exp.add_argument("--out", required=True, help="folder for answers/trajectories/goals.csv")
    exp.add_argument("--drop-failed-attention", action="store_true",
                     help="leave out participants who failed an attention check")  # fmt: skip
    exp.add_argument("--overwrite", action="store_true", help="replace earlier exported files")


def serve_main(args: argparse.Namespace) -> int:
    """Check the inputs, print the URLs and the admin token, and serve until stopped."""
    stimdir, db = Path(args.stimuli), Path(args.db)
    if not stimdir.is_dir():
        raise ValueError(f"--stimuli {stimdir}: expected a folder written by `study stimuli`")
    if not db.parent.is_dir():
        raise ValueError(f"--db {db}: the folder {db.parent} does not exist")
    if not 0 < args.port < 65536:
        raise ValueError(f"--port {args.port}: expected 1..65535")
    service = StudyService(stimdir, connect(db))
    token = secrets.token_urlsafe(24)
    app = make_app(service, token)
    url = f"http://{args.host}:{args.port}"
    print(f"study: {url}/  (rounds {', '.join(map(str, sorted(service.sets)))})")
    print(f"admin: {url}/admin")
    print(f"admin token: {token}", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning", access_log=False)
    return 0


def export_main(args: argparse.Namespace) -> int:
    """Write the exported tables (never over earlier files without ``--overwrite``)."""
    db, out = Path(args.db), Path(args.out)
    if not db.is_file():
        raise ValueError(f"--db {db}: no such file")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: expected a folder")
    if not out.parent.is_dir():
        raise ValueError(f"--out {out}: the folder {out.parent} does not exist")
    there = [n for n in export_lib.TABLES if (out / f"{n}.csv").exists()]
    if there and not args.overwrite:
        raise ValueError(f"--out {out}: {there[0]}.csv exists (add --overwrite to replace it)")
    n = export_lib.export_tables(connect(db), out, drop_failed_attention=args.drop_failed_attention)
    print(
        f"wrote {out}: {n['answers']} answers to {n['trajectories']} trajectories "
        f"from {n['participants']} participants",
        file=sys.stdout,
    )
    return 0


def main(argv=None) -> int:
    """``stimuli``, ``serve`` and ``export`` on their own (until they join the study CLI)."""
    from slotv_jax.study_web import make_stimuli

    ap = argparse.ArgumentParser(prog="python -m slotv_jax.study")
    sub = ap.add_subparsers(dest="command", required=True)
    add_commands(sub)
    make_stimuli.add_command(sub)
    args = ap.parse_args(argv)
    run = {"serve": serve_main, "export": export_main, "stimuli": make_stimuli.stimuli_main}
    return run[args.command](args)
