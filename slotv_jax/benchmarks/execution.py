"""Execution speed: plans timed and checked for a Franka Panda, against the motions' own time.

    python -m slotv_jax.benchmarks.execution [--n 1000] [--workers 0] [--json FILE]

The plans are the recorded ones (``experiments/planning_paper_plans.npz`` and
``experiments/people_loop_paper_plans.npz``: 121 plans, every planner and problem), taken in
turn until ``--n`` (1,000: each about 8 times). For each plan, in one process, the stages of
:func:`slotv_jax.execution.execute` are timed apart: the timing (TOPP-RA, the jerk bound,
the 1 mm path check), the limit checks at 1 kHz, the collision check, the dynamics (MuJoCo
physics at 1 kHz). Printed side by side in one run:

- per plan: each stage, the whole, and the motion's own duration; the **real-time factor**,
  the motions' total duration over the total time to time and check them (target: ≥ 100);
- the timing alone against timing and checks;
- baselines of two choices: contacts at every 1 kHz sample against the swept-distance bound
  that certifies most of them (:mod:`slotv_jax.execution.checks`), and the TCP poses of the
  1 kHz samples by MuJoCo C in a loop against MJX (``jit(vmap)``, compiled once for a fixed
  batch) on the same samples (the checks use the C API);
- with ``--workers W`` > 0, the same plans over W processes (each plan in one): throughput.

Wall-clock times; the load average before and after is printed (the machine may be shared).
"""

from __future__ import annotations

import concurrent.futures as futures
import datetime
import json
import multiprocessing
import os
import platform
import sys
import time
from importlib import metadata
from pathlib import Path

import jax
import mujoco
import numpy as np

from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli, fileio
from slotv_jax.execution import checks, models, timing
from slotv_jax.planning.plans import load_plans
from slotv_jax.robot import kinematics

FILES = ("experiments/planning_paper_plans.npz", "experiments/people_loop_paper_plans.npz")
STAGES = ("timing", "limits", "collisions", "dynamics")
MJX_BATCH = 4096  # samples per MJX call (a plan's 1 kHz samples, padded)


def recorded_plans(files=FILES) -> list[tuple]:
    """(q, goals, goal_mask, target) of every finite plan of ``files``."""
    out = []
    for f in files:
        z = load_plans(f)
        for k in range(len(z["names"])):
            for p in range(z["q"].shape[1]):
                if np.isfinite(z["q"][k, p]).all():
                    out.append(
                        (z["q"][k, p], z["goals"][p], z["goal_mask"][p], int(z["target"][p]))
                    )
    return out


def _clock() -> tuple[float, float]:
    return time.perf_counter(), time.process_time()


def stages(plan) -> dict:
    """Seconds of each stage on one plan (wall clock, and ``cpu_``: this process's CPU
    time), and the motion's duration (s)."""
    q, goals, mask, target = plan
    cfg = timing.TimingConfig()
    c0 = _clock()
    traj = timing.time_plan(q, cfg)
    c1 = _clock()
    checks.limit_checks(traj, cfg.limits)
    c2 = _clock()
    found, _ = checks.collision_check(traj, goals, mask, target)
    c3 = _clock()
    checks.dynamics_check(traj, cfg.limits)
    c4 = _clock()
    out = {"duration": traj.duration, "samples": len(traj.t),
           "contact_samples": found["contact_samples"]}  # fmt: skip
    for name, a, b in zip(STAGES, (c0, c1, c2, c3), (c1, c2, c3, c4), strict=True):
        out[name], out[f"cpu_{name}"] = b[0] - a[0], b[1] - a[1]
    return out


def _every_sample(plan) -> float:
    """Seconds to compute the contacts at every 1 kHz sample of the plan (the baseline)."""
    q, goals, mask, target = plan
    traj = timing.time_plan(q)
    con = checks._Contacts(goals, mask, target)
    t = time.perf_counter()
    for qi in traj.q:
        con.clearance(qi)
    return time.perf_counter() - t


def _poses_c_vs_mjx(plans, repeats: int = 3) -> dict:
    """TCP poses of the 1 kHz samples: MuJoCo C loop vs MJX ``jit(vmap)`` (one fixed batch)."""
    fk = jax.jit(jax.vmap(kinematics.tcp_pose))
    pad = np.tile(kinematics.Q_HOME, (MJX_BATCH, 1)).astype(np.float32)
    t = time.perf_counter()
    jax.block_until_ready(fk(pad))
    compile_s = time.perf_counter() - t
    c_s = mjx_s = 0.0
    n = 0
    for q, *_ in plans:
        traj = timing.time_plan(q)
        x = traj.q[:MJX_BATCH]
        n += len(x)
        best_c = best_j = np.inf
        for _ in range(repeats):
            t = time.perf_counter()
            models.tcp_poses(x)
            best_c = min(best_c, time.perf_counter() - t)
            t = time.perf_counter()
            batch = pad.copy()
            batch[: len(x)] = x
            jax.block_until_ready(fk(batch))
            best_j = min(best_j, time.perf_counter() - t)
        c_s += best_c
        mjx_s += best_j
    return {"samples": n, "c_s": c_s, "mjx_s": mjx_s, "mjx_compile_s": compile_s}


def _worker_init():
    timing.time_plan(recorded_plans()[0][0])  # loads the models, warms the caches


def run(n: int, workers: int, baseline_plans: int) -> dict:
    plans = recorded_plans()
    todo = [plans[i % len(plans)] for i in range(n)]
    stages(todo[0])  # warm up: the models are built once per process
    rows = [stages(p) for p in todo]
    res = {"n": n, "distinct": len(plans)}
    for k in (*STAGES, *(f"cpu_{s}" for s in STAGES), "duration", "samples", "contact_samples"):
        res[k] = float(np.sum([r[k] for r in rows]))
    for pre in ("", "cpu_"):
        res[f"{pre}checks"] = sum(res[f"{pre}{s}"] for s in STAGES[1:])
        res[f"{pre}total"] = res[f"{pre}timing"] + res[f"{pre}checks"]
    every = [_every_sample(p) for p in plans[:baseline_plans]]
    sweep = [stages(p)["collisions"] for p in plans[:baseline_plans]]
    res["contacts_every_sample_s"] = float(np.sum(every))
    res["contacts_sweep_s"] = float(np.sum(sweep))
    res["poses"] = _poses_c_vs_mjx(plans[:baseline_plans])
    if workers:
        ctx = multiprocessing.get_context("spawn")
        with futures.ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init) as ex:
            list(ex.map(stages, todo[:workers]))  # every worker started and warm
            t = time.perf_counter()
            got = list(ex.map(stages, todo, chunksize=4))
            res["pool_wall_s"] = time.perf_counter() - t
        res["pool_duration"] = float(np.sum([r["duration"] for r in got]))
    res["workers"] = workers
    return res


@cli.command
def main(argv=None) -> int:
    p = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.execution",
                                description=__doc__)  # fmt: skip
    p.add_argument("--n", type=int, default=1000, help="plans to time and check")
    p.add_argument("--workers", type=int, default=0, help="also over this many processes")
    p.add_argument("--baseline-plans", type=int, default=20,
                   help="plans for the two baselines (default 20)")  # fmt: skip
    p.add_argument("--json", type=Path, help="also write the results here")
    args = p.parse_args(argv)
    if args.json:
        fileio.check_output_files(args.json.parent, [args.json.name], what="--json")
    if args.n < 1 or args.workers < 0 or args.baseline_plans < 1:
        raise cli.InputError("--n >= 1, --workers >= 0 and --baseline-plans >= 1 expected")
    load0 = os.getloadavg()
    res = run(args.n, args.workers, args.baseline_plans)
    res.update(
        date=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        machine=f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()}",
        versions=f"Python {platform.python_version()}, mujoco {mujoco.__version__}, toppra "
        f"{metadata.version('toppra')}, NumPy {np.__version__}, jax {jax.__version__}",
        load_before=[round(v, 2) for v in load0],
        load_after=[round(v, 2) for v in os.getloadavg()],
    )
    n = res["n"]
    ms = {k: 1e3 * res[k] / n for k in res if k.split("cpu_")[-1] in (*STAGES, "checks", "total")}
    print(f"# execution benchmark: {n} plans ({res['distinct']} recorded, in turn), {res['date']}")
    print(f"# {res['machine']}; {res['versions']}")
    print(f"# load average before {res['load_before']}, after {res['load_after']}")
    print("| per plan | wall ms | CPU ms |\n|---|---|---|")
    for k in (*STAGES, "total"):
        name = "timing and checks" if k == "total" else k
        print(f"| {name} | {ms[k]:.2f} | {ms['cpu_' + k]:.2f} |")
    print(f"| the motion's own duration | {1e3 * res['duration'] / n:.0f} | |")
    rt, rt_cpu = res["duration"] / res["total"], res["duration"] / res["cpu_total"]
    print(f"real-time factor, timing and checks: {rt:.0f}x wall, {rt_cpu:.0f}x CPU (target >= "
          f"100x); timing alone: {res['duration'] / res['timing']:.0f}x wall, "
          f"{res['duration'] / res['cpu_timing']:.0f}x CPU; the checks take "
          f"{res['cpu_checks'] / res['cpu_total']:.0%} of the CPU time")  # fmt: skip
    every = res["contacts_every_sample_s"] / res["contacts_sweep_s"]
    print(f"contacts: {res['contact_samples'] / res['samples']:.0%} of the 1 kHz samples "
          f"computed; every sample instead: {every:.1f}x the time (on {args.baseline_plans} "
          "plans)")  # fmt: skip
    pz = res["poses"]
    c_us, j_us = (1e6 * pz[k] / pz["samples"] for k in ("c_s", "mjx_s"))
    print(f"TCP poses of {pz['samples']} samples: MuJoCo C loop {c_us:.2f} us/sample, MJX "
          f"jit(vmap) batch {MJX_BATCH} {j_us:.2f} us/sample ({j_us / c_us:.1f}x; compiled "
          f"once in {pz['mjx_compile_s']:.1f} s)")  # fmt: skip
    if res["workers"]:
        print(f"{res['workers']} processes: {n / res['pool_wall_s']:.0f} plans/s, real-time "
              f"factor {res['pool_duration'] / res['pool_wall_s']:.0f}x")  # fmt: skip
    if args.json:
        fileio.write_text(args.json, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
