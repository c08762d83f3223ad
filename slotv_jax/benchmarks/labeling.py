"""Labelling throughput: a per-trajectory NumPy loop against the public labelers, jitted.

    python -m slotv_jax.benchmarks.labeling [--n 160000] [--numpy-n 1000] [--repeats 5]

For each labeler, in one run on the same synthetic trajectories, side by side:

- **NumPy loop**: the way a researcher would write it, one trajectory at a time,
  vectorised over points and goals within the trajectory (float64), timed on the
  first ``--numpy-n`` trajectories and reported per trajectory;
- **public**: ``jax.jit(jax.vmap(labeler))`` called on all ``--n`` trajectories at once,
  as a user writes it, on JAX arrays (put on the device once, before timing), labels
  back as NumPy; and, as *public, numpy in*, on the host NumPy arrays (the call then
  copies 190 MB of trajectories into a new XLA buffer each time);
- **label_all**: :func:`slotv_jax.labelers.label_all` with that one labeler (chunks,
  validation and copies back included), on the same JAX arrays and on the host NumPy
  arrays, each compared with the public path given the same input (like for like);

all after compilation, taking turns within each of ``--repeats`` repeats (so that all
see the same machine state), best of the repeats. Then all four labelers together,
both ways (the public way: one jitted function of the four), and the largest
difference between the NumPy and JAX labels as a sanity check. The last column is the
public path compiled with XLA's default vector width (``compiler_options`` of
``jax.jit``), against the package's ``--xla_cpu_prefer_vector_width=512``
(:mod:`slotv_jax.core.xla`), in the same run. Targets (issue 17):
public >= 80x the NumPy loop for each labeler, all four <= 1 s for 160,000 and
``label_all`` within 1.3x of the public path.

Synthetic data: piecewise-linear paths from the home TCP position through two
random via points to one of 2–8 random cubes, 100 points, float32.
"""

from __future__ import annotations

import datetime
import functools
import os
import platform
import sys
import time

import jax
import jaxlib
import numpy as np

import slotv_jax
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli
from slotv_jax.observers import labelers as L
from slotv_jax.observers import labelling
from slotv_jax.world.scene import camera as scene_camera

HOME = np.array([0.3069, 0.0, 0.4869])  # TCP(q_home), :ref:`concepts-robot`


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


VECTOR_WIDTH = "xla_cpu_prefer_vector_width"


@cli.command
def main(argv=None) -> int:
    p = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.labeling", description=__doc__)
    p.add_argument("--n", type=int, default=160_000, help="trajectories for JAX")
    p.add_argument("--T", type=int, default=100, help="points per trajectory")
    p.add_argument("--numpy-n", type=int, default=1000, help="trajectories for the NumPy loop")
    p.add_argument("--chunk-size", type=int, help="label_all's chunk (default: its own)")
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)

    print(slotv_jax.XLA_CONFIG.summary())
    print(
        f"# {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC  {cpu_model()}, "
        f"{os.cpu_count()} cores, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n"
        f"# python {platform.python_version()}, jax {jax.__version__}, jaxlib "
        f"{jaxlib.__version__}, numpy {np.__version__}, backend {jax.default_backend()}\n"
        f"# {args.n} trajectories of {args.T} points, "
        f"label_all chunk {args.chunk_size or 'default'}, "
        f"{args.repeats} repeats; NumPy loop on {args.numpy_n} trajectories (float64)"
    )
    xyz, goals, mask = synthetic(args.n, args.T)
    cam = scene_camera("observer")
    cam_pos, cam_rot = np.asarray(cam.pos, np.float64), np.asarray(cam.rot, np.float64)
    b = L.DEFAULT_BETAS  # the public labelers' temperatures, where none is given
    numpy_fns = {
        "dragan": functools.partial(np_dragan, beta=b["dragan"]),
        "nikolaidis": lambda x, g, m: np_nikolaidis(x, g, m, cam_pos, cam_rot, b["nikolaidis"]),
        "effdist": functools.partial(np_effdist, beta=b["effdist"]),
        "fastapp": functools.partial(np_fastapp, beta=b["fastapp"]),
    }
    public = {n: functools.partial(L.LABELERS[n], camera=cam) for n in ["nikolaidis"]}
    public.update({n: L.LABELERS[n] for n in L.LABELER_NAMES if n != "nikolaidis"})
    kw = dict(chunk_size=args.chunk_size, progress=False)
    m = min(args.numpy_n, args.n)
    x64, g64 = xyz[:m].astype(np.float64), goals[:m].astype(np.float64)
    w = 2 * (args.chunk_size or L.CHUNK_LABELS)
    warm = (xyz[:w], goals[:w], mask[:w])

    def measure(*fs):
        """Last output, best wall time and best process CPU time of each of ``fs`` over
        the repeats. The functions take turns within each repeat, so that a change in
        the machine's speed during the run (other jobs on the host) reaches all of
        them. CPU time is steadier on a shared machine (JAX's counts both cores)."""
        walls, cpus, outs = [[] for _ in fs], [[] for _ in fs], [None] * len(fs)
        for _ in range(args.repeats):
            for i, f in enumerate(fs):
                t0, c0 = time.perf_counter(), time.process_time()
                outs[i] = f()
                walls[i].append(time.perf_counter() - t0)
                cpus[i].append(time.process_time() - c0)
        return [(o, min(w), min(c)) for o, w, c in zip(outs, walls, cpus, strict=True)]

    dev = [jax.numpy.asarray(a) for a in (xyz, goals, mask)]

    def host(f, arrays=(xyz, goals, mask)):
        """``f`` on ``arrays`` (default: the host arrays), labels back as NumPy."""
        return lambda: jax.tree.map(np.asarray, f(*arrays))

    print(
        "\nthroughput in trajectories per second (wall clock, best of the repeats); x: ratio to "
        "the NumPy loop; la/pub: label_all time over public time, like for like"
    )
    print(
        f"{'labeler':<11} {'numpy':>7} | {'JAX arrays in: public':>21} {'label_all':>15} "
        f"{'la/pub':>6} | {'NumPy arrays in: public':>23} {'label_all':>15} {'la/pub':>6} | "
        f"{'max |dy|':>8} | by CPU time: public, label_all (JAX in); la/pub (JAX, NumPy in) | "
        f"public, XLA's 256-bit vectors (JAX in): rate, speed-up of the package's setting"
    )
    ratios = {}
    for name in L.LABELER_NAMES:
        f_np, f_pub = numpy_fns[name], jax.jit(jax.vmap(public[name]))
        f_pub(xyz[:8], goals[:8], mask[:8])  # compile for a small batch: traces only
        run_pub, run_pub_np = host(f_pub, dev), host(f_pub)
        run_pub()  # compile for N
        # The same public path compiled with XLA's default vector width, for the record of
        # the --xla_cpu_prefer_vector_width=512 setting (slotv_jax.core.xla), in the same run.
        f_256 = jax.jit(jax.vmap(public[name]), compiler_options={VECTOR_WIDTH: 256})
        run_256 = host(f_256, dev)
        run_256()  # compile
        labelling.label_all(*warm, labelers=(name,), **kw)
        results = measure(
            lambda f=f_np: np.stack([f(x64[i], g64[i], mask[i]) for i in range(m)]),
            run_pub,
            lambda n=name: labelling.label_all(*dev, labelers=(n,), **kw),
            run_pub_np,
            lambda n=name: labelling.label_all(xyz, goals, mask, labelers=(n,), **kw),
            run_256,
        )
        (y_np, np_wall, np_cpu), (y_pub, pub_w, pub_c), (y_all, all_w, all_c) = results[:3]
        (_, pub_np_w, pub_np_c), (_, all_np_w, all_np_c), (_, w256, _) = results[3:]
        np_rate = m / np_wall
        np_n_cpu = np_cpu / m * args.n  # CPU time of the NumPy loop for all n

        def rate(wall, np_rate=np_rate):
            return f"{args.n / wall:>9,.0f} {args.n / wall / np_rate:>4.0f}x"

        ratios[name] = (args.n / pub_w / np_rate, args.n / all_w / np_rate)
        diff = max(np.abs(y_pub[:m] - y_np).max(), np.abs(y_all[name][:m] - y_np).max())
        print(
            f"{name:<11} {np_rate:>7,.0f} | {rate(pub_w):>21} {rate(all_w):>15} "
            f"{all_w / pub_w:>5.2f}x | {rate(pub_np_w):>23} {rate(all_np_w):>15} "
            f"{all_np_w / pub_np_w:>5.2f}x | {diff:>8.1e} | {np_n_cpu / pub_c:>4.0f}x "
            f"{np_n_cpu / all_c:>4.0f}x; {all_c / pub_c:.2f}x {all_np_c / pub_np_c:.2f}x | "
            f"{rate(w256)} {w256 / pub_w:.2f}x",
            flush=True,
        )

    four = jax.jit(jax.vmap(lambda x, g, m_: {n: f(x, g, m_) for n, f in public.items()}))
    host(four, dev)()  # compile
    labelling.label_all(*warm, **kw)
    each = [host(jax.jit(jax.vmap(f)), dev) for f in public.values()]
    for f in each:
        f()  # compile
    (_, four_wall, four_cpu), (_, each_wall, each_cpu), (_, all_wall, all_cpu), all_np = measure(
        host(four, dev),
        lambda: [f() for f in each],
        lambda: labelling.label_all(*dev, **kw),
        lambda: labelling.label_all(xyz, goals, mask, **kw),
    )
    print(
        f"\nall four labelers, {args.n:,} trajectories of {args.T} points (after compilation), "
        "wall (CPU) seconds:\n"
        f"  public, one jit of the four: {four_wall:.3f} ({four_cpu:.3f})\n"
        f"  public, one jit each:        {each_wall:.3f} ({each_cpu:.3f})\n"
        f"  label_all, JAX arrays in:    {all_wall:.3f} ({all_cpu:.3f}), "
        f"{all_wall / min(four_wall, each_wall):.2f}x the faster public way "
        "(targets <= 1 s, <= 1.3x)\n"
        f"  label_all, NumPy arrays in:  {all_np[1]:.3f} ({all_np[2]:.3f})"
    )
    print(
        "ratio to the NumPy loop (public / label_all): "
        + ", ".join(f"{k} {a:.0f}x / {b:.0f}x" for k, (a, b) in ratios.items())
        + " (target >= 80x each)"
    )
    print(f"# load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
