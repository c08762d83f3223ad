"""The kinematics (jax, the MJCF's chain) on the CPU, with and without slotv_jax's XLA setting,
against MuJoCo C.

    python -m slotv_jax.benchmarks.kinematics [--batch 1024] [--traj-batch 1024] [--repeats 5]

XLA reads ``XLA_FLAGS`` once, when its first backend starts, so each variant runs
in a fresh interpreter (a worker subprocess of this module):

- **with**: ``import slotv_jax`` appends ``--xla_cpu_use_fusion_emitters=false``
  (see :mod:`slotv_jax.core.xla`);
- **without**: ``SLOTV_JAX_XLA_FLAGS=0``, XLA's defaults.

Each worker measures, on the same random in-limit configurations (float32 for
the kinematics, float64 for MuJoCo C):

1. a Python loop of MuJoCo C ``mj_kinematics`` on the same MJCF: poses/s (it does not
   use XLA, so its two columns show the machine's noise);
2. single call, ``jit(tcp_position)`` on one configuration: µs per call (median,
   synchronised with ``block_until_ready``);
3. batched, ``jit(vmap(tcp_pose))``: poses/s at a small batch (both variants, like
   for like) and at ``--batch`` (the "with" variant only);
4. full trajectory generation, ``jit(vmap(sample_trajectory))`` in 250 scenes
   (sampling, arc-length resampling, warm-started path IK, executed FK), with
   ``TrajectoryConfig()``: trajectories/s at one per call (both variants) and at
   ``--traj-batch`` (the "with" variant only). Every draw counts, rejected or not.

Without the setting the kinematics is slow (tens of ms per kinematics call, and batching
makes it slower per pose), so that variant uses a small batch and few repeats; the
``--slow-*`` options set them, and ``--skip-slow-trajectories`` saves its longest
part (compiling and running one trajectory, 1–2 minutes). Rates are the best of the
repeats by wall clock, and per CPU-second of the worker process (steadier when
other jobs share the machine); the load average is printed before and after.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shlex
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import jaxlib
import mujoco
import numpy as np

import slotv_jax
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli, validation
from slotv_jax.core.xla import OPT_OUT_VAR, SETTINGS
from slotv_jax.robot import kinematics as K
from slotv_jax.world import scene as S
from slotv_jax.world import trajectories as T

RESULT_TAG = "KINEMATICS_BENCHMARK_RESULT "
N_SCENES = 250
SCENE_GOAL_COUNTS = (2, 3, 5, 6)


# --------------------------------------------------------------------------- worker


def _timed(f, n: int, repeats: int) -> dict:
    """Rates of ``f()`` (which synchronises and does ``n`` units of work) over ``repeats``."""
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return {
        "n": n,
        "per_s": n / min(wall),
        "per_s_median": n / float(np.median(wall)),
        "per_cpu_s": n / max(min(cpu), 1e-9),
    }


def _mujoco_c(qs: np.ndarray, repeats: int) -> dict:

    model = mujoco.MjModel.from_xml_path(str(K.PANDA_XML))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, K.TCP_SITE)
    out = np.empty((len(qs), 3))

    def loop():
        for i, q in enumerate(qs):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            out[i] = data.site_xpos[site]

    return _timed(loop, len(qs), repeats)


def _mjx_single(qs: np.ndarray, calls: int) -> dict:

    f = jax.jit(K.tcp_position)
    q = [jnp.asarray(x, jnp.float32) for x in qs[:calls]]
    t0 = time.perf_counter()
    f(q[0]).block_until_ready()
    compile_s = time.perf_counter() - t0
    wall, c0 = [], time.process_time()
    for x in q:
        t0 = time.perf_counter()
        f(x).block_until_ready()
        wall.append(time.perf_counter() - t0)
    return {
        "calls": len(q),
        "us_per_call": 1e6 * float(np.median(wall)),
        "cpu_us_per_call": 1e6 * (time.process_time() - c0) / len(q),
        "compile_s": compile_s,
    }


def _mjx_batched(qs: np.ndarray, batch: int, repeats: int) -> dict:

    f = jax.jit(jax.vmap(K.tcp_pose))
    x = jnp.asarray(qs[:batch], jnp.float32)
    t0 = time.perf_counter()
    jax.block_until_ready(f(x))
    compile_s = time.perf_counter() - t0
    return {
        "batch": batch,
        "compile_s": compile_s,
        **_timed(lambda: jax.block_until_ready(f(x)), batch, repeats),
    }


def _trajectories(batch: int, repeats: int, seed: int) -> dict:

    cfg = T.TrajectoryConfig()
    k_scene, k_count, k_traj = jax.random.split(jax.random.key(seed), 3)
    counts = jax.vmap(lambda k: S.sample_goal_count(k, SCENE_GOAL_COUNTS))(
        jax.random.split(k_count, N_SCENES)
    )
    scenes = jax.jit(jax.vmap(S.sample_scene))(jax.random.split(k_scene, N_SCENES), counts)

    @jax.jit
    def generate(keys):
        pick = lambda k: jax.random.randint(jax.random.fold_in(k, 0), (), 0, N_SCENES)  # noqa: E731
        picked = jax.tree.map(lambda a: a[jax.vmap(pick)(keys)], scenes)
        return jax.vmap(lambda k, s: T.sample_trajectory(jax.random.fold_in(k, 1), s, cfg))(
            keys, picked
        )

    calls = iter(jax.random.split(k_traj, (repeats + 1, batch)))
    t0 = time.perf_counter()
    residuals = [np.asarray(generate(next(calls)).residual)]
    compile_s = time.perf_counter() - t0

    def run():
        residuals.append(np.asarray(generate(next(calls)).residual))  # synchronises

    rates = _timed(run, batch, repeats)
    res = np.concatenate(residuals)
    return {
        "batch": batch,
        "compile_s": compile_s,
        **rates,
        "ik": f"iters={cfg.ik.iters}, refine_iters={cfg.ik.refine_iters}",
        "draws": len(res),
        "rejected": float(np.mean(res > cfg.max_residual)),
        "max_residual_m": float(res.max()),
    }


def worker(args: argparse.Namespace) -> dict:
    """Measure one variant in this interpreter (XLA's setting is whatever it started with)."""
    summary = slotv_jax.XLA_CONFIG.summary()
    xla_flags = os.environ.get("XLA_FLAGS", "")

    fast = args.worker == "with"
    t0 = time.perf_counter()

    def log(msg):
        print(
            f"[{args.worker} {time.perf_counter() - t0:5.0f} s] {msg}", file=sys.stderr, flush=True
        )

    qs = np.random.default_rng(args.seed).uniform(K.Q_MIN, K.Q_MAX, (max(args.batch, args.c_n), 7))
    out = {
        "variant": args.worker,
        "xla_config": summary,
        "xla_flags": xla_flags,
        "versions": {
            "python": platform.python_version(),
            "jax": jax.__version__,
            "jaxlib": jaxlib.__version__,
            "mujoco": mujoco.__version__,
            "backend": jax.default_backend(),
        },
    }
    log("MuJoCo C loop")
    out["c"] = _mujoco_c(qs[: args.c_n], args.repeats)
    log("single call")
    out["single"] = _mjx_single(qs, args.single_calls if fast else args.slow_single_calls)
    log(f"batched, batch {args.slow_batch}")
    out["batched_small"] = _mjx_batched(
        qs, args.slow_batch, args.repeats if fast else args.slow_repeats
    )
    if fast:
        log(f"batched, batch {args.batch}")
        out["batched"] = _mjx_batched(qs, args.batch, args.repeats)
    if fast or not args.skip_slow_trajectories:
        log("trajectories, 1 per call")
        out["traj_one"] = _trajectories(
            1, args.traj_repeats if fast else args.slow_traj_repeats, args.seed
        )
    if fast:
        log(f"trajectories, batch {args.traj_batch}")
        out["traj"] = _trajectories(args.traj_batch, args.traj_repeats, args.seed)
    log("done")
    return out


# --------------------------------------------------------------------------- driver


def _load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def _variant_env(variant: str) -> dict[str, str]:
    """A worker's environment: the user's, minus any flag slotv_jax sets and opt-out."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = " ".join(
        f for f in shlex.split(env.get("XLA_FLAGS", "")) if not any(name in f for name in SETTINGS)
    )
    env.pop(OPT_OUT_VAR, None)
    if variant == "without":
        env[OPT_OUT_VAR] = "0"
    return env


def _run_worker(variant: str, argv: list[str]) -> dict:
    cmd = [sys.executable, "-m", "slotv_jax.benchmarks.kinematics", "--worker", variant, *argv]
    proc = subprocess.run(
        cmd, env=_variant_env(variant), stdout=subprocess.PIPE, text=True, check=True
    )
    for line in proc.stdout.splitlines():
        if line.startswith(RESULT_TAG):
            return json.loads(line[len(RESULT_TAG) :])
    raise RuntimeError(f"the {variant!r} worker printed no result:\n{proc.stdout}")


def _get(d: dict, *path):
    for k in path:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _table(title: str, rows: list[tuple]) -> None:
    print(f"\n{title:<46} {'with':>12} {'without':>12} {'ratio':>9}")
    for name, w, wo, fmt, higher_is_better in rows:
        ratio = ""
        if w is not None and wo is not None:
            r = w / wo if higher_is_better else wo / w
            ratio = f"{r:,.1f}x" if r < 10 else f"{r:,.0f}x"
        cells = [f"{x:{fmt}}" if x is not None else "—" for x in (w, wo)]
        print(f"{name:<46} {cells[0]:>12} {cells[1]:>12} {ratio:>9}")


def report(w: dict, wo: dict, wall_s: float) -> None:
    v = w["versions"]
    print(
        f"# {datetime.date.today()}  {cpu_model()}, {os.cpu_count()} cores\n"
        f"# python {v['python']}, jax {v['jax']}, jaxlib {v['jaxlib']}, "
        f"mujoco {v['mujoco']}, backend {v['backend']}\n"
        f"# with:    {w['xla_config']}\n#          XLA_FLAGS={w['xla_flags']!r}\n"
        f"# without: {wo['xla_config']}\n#          XLA_FLAGS={wo['xla_flags']!r}"
    )
    small, big, tb = w["batched_small"]["batch"], w["batched"]["batch"], w["traj"]["batch"]
    rate_rows = [
        ("MuJoCo C mj_kinematics loop, poses/s", ("c",)),
        (f"jit(vmap(tcp_pose)) B={small}, poses/s", ("batched_small",)),
        (f"jit(vmap(tcp_pose)) B={big}, poses/s", ("batched",)),
        ("trajectories/s, 1 per call", ("traj_one",)),
        (f"trajectories/s, B={tb}", ("traj",)),
    ]

    def rates(key: str) -> list[tuple]:
        return [
            (name, _get(w, *p, key), _get(wo, *p, key), ",.2f" if "1 per" in name else ",.0f", True)
            for name, p in rate_rows
        ]

    _table("wall clock (best of the repeats)", rates("per_s"))
    _table(
        "latency and compile time",
        [
            (
                "single call jit(tcp_position), µs",
                w["single"]["us_per_call"],
                wo["single"]["us_per_call"],
                ",.0f",
                False,
            ),
            (
                f"compile jit(vmap(tcp_pose)) B={small}, s",
                w["batched_small"]["compile_s"],
                wo["batched_small"]["compile_s"],
                ".1f",
                False,
            ),
            (
                "compile the trajectory generator (B=1), s",
                w["traj_one"]["compile_s"],
                _get(wo, "traj_one", "compile_s"),
                ".1f",
                False,
            ),
        ],
    )
    _table("per CPU-second of the worker process", rates("per_cpu_s"))
    c, cw = w["c"]["per_s"], wo["c"]["per_s"]
    t = w["traj"]
    print(
        f"\nwith the setting: B={big} / MuJoCo C loop = {w['batched']['per_s'] / c:.2f}x "
        f"(per CPU-s {w['batched']['per_cpu_s'] / w['c']['per_cpu_s']:.2f}x); one call "
        f"takes {w['single']['us_per_call'] * c / 1e6:.0f}x one C call\n"
        f"without it:       B={small} / MuJoCo C loop = "
        f"{wo['batched_small']['per_s'] / cw:.1e}x\n"
        f"trajectory generator: IK {t['ik']}, 100 points; {100 * t['rejected']:.2f}% of "
        f"{t['draws']} draws over 2 mm (max residual {1e3 * t['max_residual_m']:.3f} mm)\n"
        f"medians (with, wall): C {w['c']['per_s_median']:,.0f} poses/s, B={big} "
        f"{w['batched']['per_s_median']:,.0f} poses/s, trajectories B={tb} "
        f"{t['per_s_median']:,.0f}/s"
    )
    print(f"# load average after: {_load()}; whole run {wall_s:.0f} s")


@cli.command
def main(argv: list[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.benchmarks.kinematics",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--batch", type=int, default=1024, help="FK batch (with the setting)")
    p.add_argument("--traj-batch", type=int, default=1024, help="trajectories per call (with)")
    p.add_argument("--c-n", type=int, default=20_000, help="configurations for the C loop")
    p.add_argument("--single-calls", type=int, default=500, help="single calls (with)")
    p.add_argument("--repeats", type=int, default=5, help="repeats of the FK measurements")
    p.add_argument("--traj-repeats", type=int, default=3, help="repeats of trajectory batches")
    p.add_argument("--slow-batch", type=int, default=16, help="small FK batch, both variants")
    p.add_argument("--slow-single-calls", type=int, default=10, help="single calls (without)")
    p.add_argument("--slow-repeats", type=int, default=2, help="FK repeats (without)")
    p.add_argument("--slow-traj-repeats", type=int, default=1, help="trajectory repeats (without)")
    p.add_argument(
        "--skip-slow-trajectories",
        action="store_true",
        help="skip trajectory generation without the setting (1-2 minutes)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--worker", choices=("with", "without"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    validation.check_seeds("--seed", args.seed)
    for name, value in vars(args).items():
        if isinstance(value, int) and not isinstance(value, bool) and name != "seed" and value < 1:
            p.error(f"--{name.replace('_', '-')}: expected >= 1, got {value}")

    if args.worker:
        print(RESULT_TAG + json.dumps(worker(args)), flush=True)
        return 0

    t0 = time.perf_counter()
    print(f"# load average before: {_load()}", flush=True)
    passthrough = sys.argv[1:] if argv is None else list(argv)
    results = {v: _run_worker(v, passthrough) for v in ("with", "without")}
    report(results["with"], results["without"], time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
