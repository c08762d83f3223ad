"""``python -m slotv_jax.execution``: time, check and export a plan for a Franka arm.

``export`` takes one planner's plan of one problem from a plans file
(:mod:`slotv_jax.planning.plans`), times it (:mod:`slotv_jax.execution.timing`), checks it
(:mod:`slotv_jax.execution.checks`) and writes it for a controller
(:mod:`slotv_jax.execution.export`)::

    python -m slotv_jax.execution export --plans experiments/planning_paper_plans.npz \\
        --problem 0 --planner slotv --format csv --out motion.csv
    python -m slotv_jax.execution export --plans ... --format ros --robot fr3 --out goal.yaml

``check`` times and checks every plan of a plans file (or ``--planner``, ``--problem``) and
prints one line each: its duration, or why the robot would not run it.

Every argument and the output are checked before any work: a bad one is one line
``error: ...`` and exit code 2. A plan the robot would not run is written nowhere; its one
line ``refused: t = ... s: ...`` names the first time and the joint and limit, or the
colliding pair, and the exit code is 1.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from slotv_jax.core import cli, fileio
from slotv_jax.execution.export import DEFAULT_RATES, FORMATS, write_trajectory
from slotv_jax.execution.limits import DEFAULT_SPEED, ROBOTS, check_speed
from slotv_jax.execution.models import CLEARANCE_HORIZON
from slotv_jax.execution.run import execute
from slotv_jax.execution.timing import TimingConfig, check_plan, rate_step
from slotv_jax.planning.plans import load_plans

EXIT_REFUSED = 1


def add_timing_args(p: argparse.ArgumentParser, *, instead: str | None = None) -> None:
    """The flags that time a motion for a Franka arm, spelled once for every command:
    ``--speed`` and ``--robot``; with ``instead`` (what timing replaces, in a command that
    may show motions untimed), also ``--timed``, and then the two apply only with it
    (:func:`timing_from_args`)."""
    with_timed = "with --timed: " if instead else ""
    if instead:
        p.add_argument("--timed", action="store_true",
                       help="each motion at a Franka arm's speed (its published limits times "
                       f"--speed) instead of {instead}")  # fmt: skip
    p.add_argument("--speed", type=float, default=None if instead else DEFAULT_SPEED,
                   help=f"{with_timed}fraction of the velocity, acceleration and jerk limits, "
                   f"in (0, 1] (default {DEFAULT_SPEED})")  # fmt: skip
    p.add_argument("--robot", default=None if instead else "fer", choices=sorted(ROBOTS),
                   help=f"{with_timed}whose limits: fer (the Panda, default) or fr3")  # fmt: skip


def timing_from_args(args: argparse.Namespace) -> TimingConfig | None:
    """The timing :func:`add_timing_args`'s flags ask for (None: ``--timed`` left out);
    ``cli.InputError`` naming the flag for a speed outside (0, 1], or for ``--speed`` or
    ``--robot`` without ``--timed``."""
    if not getattr(args, "timed", True):
        for flag in ("speed", "robot"):
            if getattr(args, flag) is not None:
                raise cli.InputError(f"--{flag}: only with --timed")
        return None
    try:
        speed = check_speed(DEFAULT_SPEED if args.speed is None else args.speed)
    except ValueError as e:
        raise cli.InputError(f"--{e}") from None
    return TimingConfig(speed=speed, robot=args.robot or "fer")


def _parser() -> argparse.ArgumentParser:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.execution",
        description="Time a plan for a Franka arm within its published limits, check it "
        "(joint and Cartesian limits at 1 kHz, collisions, dynamics) and export it.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    for name, text in (("export", "time, check and write one plan"),
                       ("check", "time and check plans, one line each")):  # fmt: skip
        s = sub.add_parser(name, help=text, description=text)
        s.add_argument("--plans", required=True, type=Path, help="a plans file (plans.npz)")
        s.add_argument("--problem", type=int, help="the problem's index" + (
            "" if name == "export" else " (default: all)"), required=name == "export")  # fmt: skip
        s.add_argument("--planner", help="the planner's name" + (
            "" if name == "export" else " (default: all)"), required=name == "export")  # fmt: skip
        add_timing_args(s)
        if name == "export":
            s.add_argument("--format", required=True, choices=sorted(FORMATS),
                           help="csv or npz (t, q, dq, ddq) or ros (a FollowJointTrajectory "
                           "goal as YAML)")  # fmt: skip
            s.add_argument("--rate", type=int, default=None,
                           help="samples per second, a divisor of 1000 (default: 1000 for csv "
                           f"and npz, {DEFAULT_RATES['ros']} for ros)")  # fmt: skip
            s.add_argument("--out", required=True, type=Path,
                           help="the file to write (.csv, .npz or .yaml)")  # fmt: skip
            s.add_argument("--overwrite", action="store_true", help="replace an existing --out")
        else:
            s.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _rows(args, plans) -> list[tuple[int, int]]:
    """(planner index, problem index) pairs the command names, checked."""
    names = [str(n) for n in plans["names"]]
    n_problems = plans["q"].shape[1]
    if args.planner is not None and args.planner not in names:
        raise cli.InputError(f"--planner: expected one of {names}, got {args.planner!r}")
    if args.problem is not None and not 0 <= args.problem < n_problems:
        raise cli.InputError(f"--problem: expected an index in 0..{n_problems - 1}, "
                             f"got {args.problem}")  # fmt: skip
    ks = [names.index(args.planner)] if args.planner is not None else range(len(names))
    ps = [args.problem] if args.problem is not None else range(n_problems)
    return [(k, p) for k in ks for p in ps]


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """Check every input and the output, then time, check and export (or report)."""
    args = _parser().parse_args(argv)
    config = timing_from_args(args)
    if args.command == "export":
        if args.rate is not None:
            try:
                rate_step(args.rate)
            except ValueError as e:
                raise cli.InputError(f"--{e}") from None
        fileio.check_not_input(args.out, {"--plans": args.plans})
        fileio.check_output_file(args.out, overwrite=args.overwrite, suffix=FORMATS[args.format])
    plans = load_plans(args.plans)
    rows = _rows(args, plans)
    names = [str(n) for n in plans["names"]]
    for k, p in rows:  # every plan is a plan: finite, within the robot's joint limits
        where = f"--plans {args.plans}: q[{names[k]}, problem {p}]"
        try:
            check_plan(plans["q"][k, p], config.limits, where)
        except ValueError as e:
            if args.command == "export" or "not finite" not in str(e):
                raise cli.InputError(str(e)) from None
    if args.command == "export":
        return _export(args, plans, rows[0], config)
    return _check(args, plans, rows, config)


def _execute(plans, k, p, config):
    return execute(plans["q"][k, p], plans["goals"][p], plans["goal_mask"][p],
                   int(plans["target"][p]), config)  # fmt: skip


def _export(args, plans, row, config) -> int:
    k, p = row
    e = _execute(plans, k, p, config)
    if not e.ok:
        print(f"refused: {e.refusal}", file=sys.stderr)
        return EXIT_REFUSED
    source = {"plans": args.plans.name, "planner": args.planner, "problem": p}
    # the output rule passed --out's nearest existing folder as writable: what is missing of
    # its folder is made, as every command that writes a file does (only now: a refused
    # plan leaves nothing behind)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    n = write_trajectory(args.out, e.trajectory, args.format, args.rate, source)
    c, t = e.checks, e.trajectory
    near = "" if c.clearance < CLEARANCE_HORIZON else "> "
    print(
        f"wrote {args.out}: {n} samples, {t.duration:.3f} s ({args.robot.upper()}, speed "
        f"{config.speed:g}); peak |dq| {np.max(c.peak_dq / config.limits.dq_max):.2f} of its "
        f"limit, least clearance {near}{c.clearance * 1e3:.1f} mm, TCP within "
        f"{t.deviation.max() * 1e3:.2f} mm of the planned path"
    )
    return 0


def _check(args, plans, rows, config) -> int:
    names = [str(n) for n in plans["names"]]
    refused = 0
    for k, p in tqdm(rows, disable=args.quiet or len(rows) < 2, unit="plan"):
        label = f"{names[k]} problem {p}"
        if not np.isfinite(plans["q"][k, p]).all():
            print(f"{label}: no plan (NaN)")
            continue
        e = _execute(plans, k, p, config)
        if e.ok:
            print(f"{label}: ok, {e.trajectory.duration:.3f} s")
        else:
            refused += 1
            print(f"{label}: refused: {e.refusal}")
    return EXIT_REFUSED if refused else 0
