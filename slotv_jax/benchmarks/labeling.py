"""Labelling throughput: a per-trajectory NumPy loop against batched, jitted JAX on the CPU.

    python -m slotv_jax.benchmarks.labeling [--n 160000] [--numpy-n 1000] [--repeats 5]

For each labeler, in one run on the same synthetic trajectories:

- **NumPy loop**: the way a researcher would write it, one trajectory at a time,
  vectorised over points and goals within the trajectory (float64), timed on the
  first ``--numpy-n`` trajectories and reported per trajectory;
- **JAX**: :func:`slotv_jax.labelers.label_all` with that one labeler, over all
  ``--n`` trajectories from host NumPy arrays (chunking, validation flags and
  copies back included), after compilation;

and the ratio, by wall clock (best of ``--repeats``) and by CPU time of the process
(steadier when other jobs share the machine). Then all four labelers together over
all ``--n`` trajectories (the SPEC target: 160,000 trajectories of 100 points in
<= 2 s on a 2-core CPU), and the largest difference between the NumPy and JAX labels
as a sanity check.

Synthetic data: piecewise-linear paths from the home TCP position through two
random via points to one of 2–8 random cubes, 100 points, float32.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time

import numpy as np

import slotv_jax
from slotv_jax import labelers as L
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.scene import camera as scene_camera

HOME = np.array([0.3069, 0.0, 0.4869])  # TCP(q_home), SPEC §1


def synthetic(n: int, T: int = 100, seed: int = 0):
    """``xyz (n, T, 3)``, ``goals (n, 8, 3)``, ``goal_mask (n, 8)`` (float32, bool).

    C-contiguous arrays, like those of a dataset read with ``np.load``.
    """
    rng = np.random.default_rng(seed)
    n_goals = rng.integers(2, 9, n)
    mask = np.arange(8)[None] < n_goals[:, None]
    goals = np.zeros((n, 8, 3))
    goals[..., 0] = rng.uniform(0.30, 0.70, (n, 8))
    goals[..., 1] = rng.uniform(-0.45, 0.45, (n, 8))
    goals[..., 2] = 0.025
    goals[~mask] = 0.0
    target = goals[np.arange(n), rng.integers(0, n_goals)]
    via = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4], (n, 2, 3))
    knots = np.concatenate([np.broadcast_to(HOME, (n, 1, 3)), via, target[:, None]], axis=1)
    s = np.linspace(0.0, 3.0, T)
    seg = np.minimum(s.astype(int), 2)
    frac = (s - seg)[None, :, None]
    xyz = knots[:, seg] * (1 - frac) + knots[:, seg + 1] * frac
    return np.ascontiguousarray(xyz, np.float32), goals.astype(np.float32), mask


# --------------------------------------------------- the NumPy researcher baseline


def _softmax(s):
    e = np.exp(s - s.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def np_dragan(xyz, goals, mask, beta=5.0):
    g = goals[mask]
    t = np.linspace(0, 1, len(xyz))
    d = np.linalg.norm(xyz[:, None, :] - g[None, :, :], axis=-1)  # (T, K)
    p = _softmax(beta * (d[0] - d))  # P(goal | motion so far), per point
    y = np.trapezoid(p * (1 - t)[:, None], t, axis=0) / np.trapezoid(1 - t, t)
    out = np.zeros(len(goals))
    out[mask] = y
    return out


def np_nikolaidis(xyz, goals, mask, cam_pos, cam_rot, beta=7.5):
    def proj(p):
        pc = (p - cam_pos) @ cam_rot
        return pc[:, :2] / -pc[:, 2:]

    return np_dragan(proj(xyz), proj(goals), mask, beta)


def np_effdist(xyz, goals, mask, beta=5.0):
    g = goals[mask]
    d = np.linalg.norm(xyz[:, None, :] - g[None, :, :], axis=-1)
    out = np.zeros(len(goals))
    out[mask] = _softmax(-beta * d.mean(axis=0))
    return out


def np_fastapp(xyz, goals, mask, beta=5.0):
    g = goals[mask]
    t = np.linspace(0, 1, len(xyz))
    d = np.linalg.norm(xyz[:, None, :] - g[None, :, :], axis=-1)
    approach = d[:-1] - d[1:]  # (T-1, K): distance gained per step
    w = 1 - t[1:]
    s = beta * (w @ approach) / np.sum(w * np.diff(t))
    out = np.zeros(len(goals))
    out[mask] = _softmax(s)
    return out


# ------------------------------------------------------------------- benchmark


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m slotv_jax.benchmarks.labeling", description=__doc__)
    p.add_argument("--n", type=int, default=160_000, help="trajectories for JAX")
    p.add_argument("--T", type=int, default=100, help="points per trajectory")
    p.add_argument("--numpy-n", type=int, default=1000, help="trajectories for the NumPy loop")
    p.add_argument("--chunk-size", type=int, default=L.DEFAULT_CHUNK)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)

    import jax
    import jaxlib

    print(slotv_jax.XLA_CONFIG.summary())
    print(
        f"# {datetime.date.today()}  {cpu_model()}, {os.cpu_count()} cores, load average "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}\n"
        f"# python {platform.python_version()}, jax {jax.__version__}, jaxlib "
        f"{jaxlib.__version__}, numpy {np.__version__}, backend {jax.default_backend()}\n"
        f"# {args.n} trajectories of {args.T} points, chunk {args.chunk_size}, "
        f"{args.repeats} repeats; NumPy loop on {args.numpy_n} trajectories (float64)"
    )
    xyz, goals, mask = synthetic(args.n, args.T)
    cam = scene_camera("observer")
    cam_pos, cam_rot = np.asarray(cam.pos, np.float64), np.asarray(cam.rot, np.float64)
    numpy_fns = {
        "dragan": np_dragan,
        "nikolaidis": lambda x, g, m: np_nikolaidis(x, g, m, cam_pos, cam_rot),
        "effdist": np_effdist,
        "fastapp": np_fastapp,
    }
    kw = dict(chunk_size=args.chunk_size, progress=False)
    m = min(args.numpy_n, args.n)
    x64, g64 = xyz[:m].astype(np.float64), goals[:m].astype(np.float64)
    warm = (xyz[: 2 * args.chunk_size], goals[: 2 * args.chunk_size], mask[: 2 * args.chunk_size])

    def measure(*fs):
        """Best and median wall time and best process CPU time of each of ``fs``, over the
        repeats. The functions take turns within each repeat, so that a change in the
        machine's speed during the run (other jobs on the host) reaches all of them."""
        walls, cpus, outs = [[] for _ in fs], [[] for _ in fs], [None] * len(fs)
        for _ in range(args.repeats):
            for i, f in enumerate(fs):
                w0, c0 = time.perf_counter(), time.process_time()
                outs[i] = f()
                walls[i].append(time.perf_counter() - w0)
                cpus[i].append(time.process_time() - c0)
        return [
            (out, min(w), float(np.median(w)), min(c))
            for out, w, c in zip(outs, walls, cpus, strict=True)
        ]

    print(
        "\nthroughput in trajectories per second: wall clock (best of the repeats) and per "
        "CPU-second of this process\n(the CPU figure is steadier on a shared machine; XLA "
        "may use both cores, so JAX's CPU-based rate is the conservative one)"
    )
    head = f"{'labeler':<11} {'numpy':>9} {'jax':>11} {'ratio':>6} {'jax med':>11}"
    print(f"{head}   {'numpy':>9} {'jax':>11} {'ratio':>6}  {'max |Δy|':>8}")
    print(f"{'':<11} {'wall':>9} {'wall':>11} {'':>6} {'wall':>11}   {'cpu':>9} {'cpu':>11}")
    ratios = {}
    for name in L.LABELER_NAMES:
        f_np = numpy_fns[name]
        L.label_all(*warm, labelers=(name,), **kw)  # compile
        (y_np, np_wall, _, np_cpu), (_, wall, wall_med, cpu) = measure(
            lambda f=f_np: np.stack([f(x64[i], g64[i], mask[i]) for i in range(m)]),
            lambda n=name: L.label_all(xyz, goals, mask, labelers=(n,), **kw),
        )
        y_jax = L.label_all(xyz[:m], goals[:m], mask[:m], labelers=(name,), **kw)[name]
        r_wall = (args.n / wall) / (m / np_wall)
        r_cpu = (args.n / cpu) / (m / np_cpu)
        ratios[name] = (r_wall, r_cpu)
        print(
            f"{name:<11} {m / np_wall:>9,.0f} {args.n / wall:>11,.0f} {r_wall:>5.0f}x "
            f"{args.n / wall_med:>11,.0f}   {m / np_cpu:>9,.0f} {args.n / cpu:>11,.0f} "
            f"{r_cpu:>5.0f}x  {np.abs(y_jax - y_np).max():>8.1e}",
            flush=True,
        )

    L.label_all(*warm, **kw)  # compile the four-label kernel
    ((_, wall, wall_med, cpu),) = measure(lambda: L.label_all(xyz, goals, mask, **kw))
    print(
        f"\nall four labelers, {args.n:,} trajectories of {args.T} points (after compilation): "
        f"{wall:.3f} s best, {wall_med:.3f} s median wall, {cpu:.3f} s CPU "
        "(target <= 2 s for 160,000)"
    )
    print(
        "ratio to the NumPy loop (wall / cpu): "
        + ", ".join(f"{k} {a:.0f}x / {b:.0f}x" for k, (a, b) in ratios.items())
        + " (target >= 100x each)"
    )
    print(f"# load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
