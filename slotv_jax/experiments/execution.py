"""Every recorded plan on a real Panda: timed, checked, exported or refused (:ref:`concepts-pick`).

    python -m slotv_jax.experiments.execution                 # the two recorded plans files
    python -m slotv_jax.experiments.execution --plans F [F ...] --speed 0.3 --robot fer

Each plan of each planner and problem in the plans files goes through
:func:`slotv_jax.execution.execute`: timed under the robot's published limits times the speed
scale (TOPP-RA, bounded jerk, at rest at both ends, the TCP within 1 mm of the planned path),
then checked at 1 kHz (joint and Cartesian limits, collisions, MuJoCo dynamics). Writes
``OUT/execution_results.json`` (one record per plan, a summary per planner, the run's
machine, versions and date) and, from it alone, ``OUT/execution.md`` and ``OUT/execution.png``
(:mod:`slotv_jax.experiments.execution_report`; ``--report`` renders them again).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from slotv_jax import execution
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.execution.limits import DEFAULT_SPEED, ROBOTS, SOURCE, check_speed
from slotv_jax.execution.models import CLEARANCE_HORIZON
from slotv_jax.execution.timing import backward_differences, check_plan
from slotv_jax.experiments.execution_report import plot, report
from slotv_jax.planning.plans import load_plans
from slotv_jax.runs import command, record

PROG = "python -m slotv_jax.experiments.execution"
STEM = "execution"
RESULTS = f"{STEM}_results.json"
PLANS = ("experiments/planning_paper_plans.npz", "experiments/people_loop_paper_plans.npz")
METRICS = ("peak_dq", "peak_ddq", "peak_dddq", "peak_tau", "peak_dtau", "peak_tcp_speed",
           "deviation", "tracking", "tcp_tracking")  # fmt: skip
PROFILE_BIN = 10  # samples (10 ms) per point of the example's profile (the largest in each)


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment."""
    return fileio.is_json_object_with(path, ("config", "plans", "summary"))


def summarise(plans: list[dict]) -> list[dict]:
    """Per plans file and planner: counts, and over its executed plans the duration (mean,
    range), the largest of each peak fraction, deviation and tracking error, and the least
    clearance (m; None: all beyond the contact horizon)."""
    out = []
    keys = list(dict.fromkeys((p["file"], p["planner"]) for p in plans))
    for f, name in keys:
        rows = [p for p in plans if (p["file"], p["planner"]) == (f, name)]
        ok = [p for p in rows if p.get("ok")]
        s = {"file": f, "planner": name, "plans": len(rows), "exported": len(ok),
             "refused": sum(p.get("refusal") is not None for p in rows),
             "no_plan": sum(p.get("no_plan", False) for p in rows)}  # fmt: skip
        if ok:
            d = [p["duration"] for p in ok]
            clear = [p["clearance"] for p in ok if p["clearance"] is not None]
            s.update(duration_mean=round(float(np.mean(d)), 3), duration_min=min(d),
                     duration_max=max(d), clearance=min(clear) if clear else None,
                     **{m: max(p[m] for p in ok) for m in METRICS})  # fmt: skip
        out.append(s)
    return out


def _profile(e: execution.Execution) -> dict:
    """The example plan's joint velocity, acceleration and jerk as fractions of the limits,
    the largest in each 10 ms (the figure)."""
    t, lim = e.trajectory, e.trajectory.config.limits
    out = {"t": [], "dq": [], "ddq": [], "dddq": []}
    for name, d, m in zip(("dq", "ddq", "dddq"), backward_differences(t.q),
                          (lim.dq_max, lim.ddq_max, lim.dddq_max), strict=True):  # fmt: skip
        r = np.abs(d[: len(t.q)]) / m
        n = len(r) // PROFILE_BIN * PROFILE_BIN
        out[name] = np.round(r[:n].reshape(-1, PROFILE_BIN, 7).max(1), 4).T.tolist()
    out["t"] = [round(float(v), 3) for v in t.t[:n:PROFILE_BIN]]
    return out


def run(
    files: Sequence[str], out: Path, *, speed: float, robot: str, progress: bool = True
) -> dict:
    """Execute every plan of ``files``; write and return the results document."""
    loaded = {f: load_plans(f) for f in files}
    cfg = execution.TimingConfig(speed=speed, robot=robot)
    for f, z in loaded.items():  # every plan a plan (NaN rows are no plan) before any work
        for k, name in enumerate(z["names"]):
            for p in range(z["q"].shape[1]):
                if np.isfinite(z["q"][k, p]).all():
                    check_plan(z["q"][k, p], cfg.limits, f"--plans {f}: {name}, problem {p}")
    todo = [(f, k, p) for f, z in loaded.items() for k in range(len(z["names"]))
            for p in range(z["q"].shape[1])]  # fmt: skip
    load, t0 = record.load_start(), time.perf_counter()
    plans, example, busy = [], None, 0.0
    for f, k, p in tqdm(todo, desc="plans", unit="plan", disable=not progress):
        z = loaded[f]
        row = {"file": Path(f).name, "planner": str(z["names"][k]), "problem": p}
        if not np.isfinite(z["q"][k, p]).all():
            plans.append({**row, "ok": False, "refusal": None, "no_plan": True})
            continue
        t1 = time.perf_counter()
        e = execution.execute(z["q"][k, p], z["goals"][p], z["goal_mask"][p],
                              int(z["target"][p]), cfg)  # fmt: skip
        busy += time.perf_counter() - t1
        plans.append({**row, **execution.summary(e)})
        if example is None and e.ok:
            example = {**row, **_profile(e)}
    lim = ROBOTS[robot]
    doc = {
        "config": {
            "files": list(files),
            "speed": speed,
            "robot": robot,
            "clearance_horizon": CLEARANCE_HORIZON,
            "timing": {k: getattr(cfg, k) for k in ("deviation", "refinements", "rounds", "grid")},
        },
        "limits": {
            "source": SOURCE,
            "robot": robot,
            "dq_max": lim.dq_max.tolist(),
            "ddq_max": lim.ddq_max.tolist(),
            "dddq_max": lim.dddq_max.tolist(),
            "tau_max": lim.tau_max.tolist(),
            "dtau_max": lim.dtau_max.tolist(),
        },
        "plans": plans,
        "summary": summarise(plans),
        "example": example,
        "environment": environment(),
        "machine": record.machine(),
        "date": record.utc_now(),
        "load": record.load_end(load),
        "timing": {
            "total_s": round(time.perf_counter() - t0, 2),
            "execute_s_per_plan": round(busy / max(1, len(plans)), 4),
        },
    }
    write_text(out / RESULTS, json.dumps(doc, indent=1) + "\n")
    return doc


def _render(doc: dict, out: Path, cmd: str) -> None:
    plot(doc, out / f"{STEM}.png")
    write_text(out / f"{STEM}.md", report(doc, cmd))


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    ap = cli.ArgumentParser(
        prog=PROG, description="Time, check and export every recorded plan for a Franka arm."
    )
    ap.add_argument("--plans", nargs="+", default=list(PLANS), help="plans files")
    ap.add_argument("--speed", type=float, default=DEFAULT_SPEED,
                    help=f"fraction of the velocity, acceleration and jerk limits (default "
                    f"{DEFAULT_SPEED})")  # fmt: skip
    ap.add_argument("--robot", default="fer", choices=sorted(ROBOTS))
    ap.add_argument("--out", type=Path, default=command.DEFAULT_OUT, help="output folder")
    ap.add_argument("--report", action="store_true",
                    help=f"only render {STEM}.md and {STEM}.png again from {RESULTS}")  # fmt: skip
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if args.report:

        def render(doc, cmd):
            _render(doc, args.out, cmd)

        return command.render_again(args.out, STEM, is_results, render, PROG, results=RESULTS)
    try:
        check_speed(args.speed)
    except ValueError as e:
        raise cli.InputError(f"--{e}") from None
    for f in args.plans:
        fileio.check_not_input(args.out / RESULTS, {"--plans": f})
    command.prepare_out(args.out, STEM, is_results, results=RESULTS)
    doc = run(args.plans, args.out, speed=args.speed, robot=args.robot,
              progress=not args.no_progress)  # fmt: skip
    _render(doc, args.out, record.command_line(PROG, argv).strip())
    n = len(doc["plans"])
    ok = sum(p.get("ok", False) for p in doc["plans"])
    print(f"{ok} of {n} plans exported, {n - ok} refused or no plan; wrote {args.out / STEM}.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
