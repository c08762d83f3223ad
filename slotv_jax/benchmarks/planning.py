"""Legible-planning throughput: batched JAX against a per-problem loop and SciPy L-BFGS.

    python -m slotv_jax.benchmarks.planning [--n 64] [--loop-n 8] [--scipy-n 2] [--repeats 3]
        [--populations default,homogeneous,random:0,random:1,random:2]

The same problems (random scenes of 2–8 cubes, a uniform real target, start TCP(q_home)),
the same objective (log y_target of the Dragan labeler, :ref:`concepts-dragan`) and the same number
of iterations, measured side by side in one run:

- **batched JAX**: :func:`slotv_jax.planning.make_planner` on all ``--n`` problems in one
  compiled call (straight-line IK, validation and planning included), after compilation;
- **JAX loop**: the same planner called once per problem (batch of 1), after compilation;
- **SciPy L-BFGS-B**: the way a researcher would write it without JAX: float64 NumPy
  forward kinematics (Franka's DH table, :ref:`concepts-robot`) and a NumPy Dragan labeler, the
  interior joint configurations as variables with the joint limits as L-BFGS-B bounds,
  the trust region and the table clearance as quadratic penalties, and SciPy's default
  finite-difference gradient (no autodiff in NumPy), ``maxiter`` = the planner's
  iterations; started from the same straight-line joints.

A second table compares the planner's path gradient (one iteration's forward kinematics
of ``n`` paths of T waypoints and its vector-Jacobian product) three ways in the same run:
:func:`slotv_jax.kinematics.fk_position`, whose derivative is the geometric Jacobian of
the chain's product (what the planner uses), reverse-mode autodiff through the same product
(:func:`slotv_jax.kinematics.tcp_state`), and autodiff through ``mjx.kinematics``
(:func:`slotv_jax.kinematics.mjx_tcp_state`, the baseline): compilation seconds, gradients
per second, and the largest difference from the baseline's gradient. Beside it, the
planner's first call (tracing and compiling its straight lines and its iterations, then
planning) and its later calls, with the chain's kinematics against ``mjx.kinematics``
put in its place (``unittest.mock.patch``, in the same run).

A third table (``--populations``) plans with each population's own observer (P_pop, the
people loop's oracle) for several populations: a program per population, the quadrature
closed over as constants (the code before efb346f), against one program that takes the
quadrature as an argument (what the loop does now): seconds for the first population and
the later ones, compilation included.

Printed: problems per second (best of ``--repeats`` for the JAX rows), the ratio to
SciPy, and the quality reached (the true Dragan y_target of the plans, float64, its
mean gain over the straight line, and the feasible fraction), so that speed is compared
at comparable results. SciPy is imported lazily (``pip install -e .[test]``).
"""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np

import slotv_jax
from slotv_jax import planning
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli
from slotv_jax.core.defaults import BETAS_V1
from slotv_jax.observers import population as population_lib
from slotv_jax.planning import evaluation
from slotv_jax.robot import kinematics
from slotv_jax.world import scene

# Franka's modified DH table (:ref:`concepts-robot`): a, d, alpha per joint; then the flange and the
# TCP.
_DH = np.array(
    [
        [0.0, 0.333, 0.0],
        [0.0, 0.0, -np.pi / 2],
        [0.0, 0.316, np.pi / 2],
        [0.0825, 0.0, np.pi / 2],
        [-0.0825, 0.384, -np.pi / 2],
        [0.0, 0.0, np.pi / 2],
        [0.088, 0.0, np.pi / 2],
    ]
)
# Both planners optimise and are scored by Dragan at the temperature of the recorded runs
# (experiments/BENCHMARKS.md), the first version's default.
BETA = BETAS_V1["dragan"]
_FLANGE_D = 0.107
_TCP_D = 0.1034


def sample_problems(n: int, seed: int = 0):
    """``goals (n, 8, 3)``, ``goal_mask (n, 8)``, ``target (n,)``: 2–8 cubes, a uniform target."""
    k_count, k_scene, k_target = jax.random.split(jax.random.key(seed), 3)
    counts = jax.vmap(lambda k: scene.sample_goal_count(k, (2, 3, 4, 5, 6, 8)))(
        jax.random.split(k_count, n)
    )
    s = jax.jit(jax.vmap(scene.sample_scene))(jax.random.split(k_scene, n), counts)
    target = jax.vmap(lambda k, c: jax.random.randint(k, (), 0, c))(
        jax.random.split(k_target, n), counts
    )
    return np.asarray(s.goals), np.asarray(s.goal_mask), np.asarray(target)


# ---------------------------------------------------- the NumPy/SciPy researcher baseline


def np_tcp(q: np.ndarray) -> np.ndarray:
    """TCP positions (T, 3) of joint configurations (T, 7) by the DH product, float64."""
    T = q.shape[0]
    m = np.broadcast_to(np.eye(4), (T, 4, 4)).copy()
    for (a, d, alpha), qi in zip(_DH, q.T, strict=True):
        ca, sa, cq, sq = np.cos(alpha), np.sin(alpha), np.cos(qi), np.sin(qi)
        step = np.zeros((T, 4, 4))
        step[:, 0] = np.stack([cq, -sq, np.zeros(T), np.full(T, a)], -1)
        step[:, 1] = np.stack([sq * ca, cq * ca, np.full(T, -sa), np.full(T, -sa * d)], -1)
        step[:, 2] = np.stack([sq * sa, cq * sa, np.full(T, ca), np.full(T, ca * d)], -1)
        step[:, 3, 3] = 1.0
        m = m @ step
    return m[:, :3, 3] + (_FLANGE_D + _TCP_D) * m[:, :3, 2]


def np_dragan(xyz: np.ndarray, goals: np.ndarray, mask: np.ndarray, beta: float = 5.0):
    """:ref:`concepts-dragan` in NumPy: y over the real goals (zeros elsewhere)."""
    g = goals[mask]
    t = np.linspace(0.0, 1.0, len(xyz))
    d = np.linalg.norm(xyz[:, None, :] - g[None], axis=-1)
    s = beta * (d[0] - d)
    p = np.exp(s - s.max(-1, keepdims=True))
    p /= p.sum(-1, keepdims=True)
    w = np.full(len(t), t[1] - t[0])
    w[[0, -1]] /= 2
    w *= 1 - t
    y = np.zeros(len(goals))
    y[mask] = (w / w.sum()) @ p
    return y


def scipy_plan(q0: np.ndarray, goals, mask, target, cfg: planning.PlannerConfig):
    """One problem with SciPy L-BFGS-B on the float64 NumPy objective (FD gradients)."""
    from scipy.optimize import minimize

    T = q0.shape[0]
    goal = goals[target]
    start, end = q0[0], q0[-1]

    def path(x):
        return np_tcp(np.concatenate([start[None], x.reshape(T - 2, 7), end[None]]))

    def cost(xyz):
        return 0.5 * (T - 1) * np.sum(np.diff(xyz, axis=0) ** 2)

    kappa = cost(path(q0[1:-1].ravel())) + cfg.budget

    def f(x):
        xyz = path(x)
        y = np_dragan(xyz, goals, mask, BETA)[target]
        far = np.linalg.norm(xyz - goal, axis=-1) >= cfg.exempt_radius
        short = np.maximum(cfg.clearance + cfg.clearance_margin - xyz[:, 2], 0.0)[far]
        over = max(cost(xyz) - kappa, 0.0)
        return -np.log(y) + cfg.table_weight * np.sum(short**2) + 1e4 * over**2

    bounds = list(
        zip(np.tile(kinematics.Q_MIN, T - 2), np.tile(kinematics.Q_MAX, T - 2), strict=True)
    )
    x0 = np.clip(q0[1:-1].ravel(), *np.array(bounds).T)
    r = minimize(f, x0, method="L-BFGS-B", bounds=bounds, options={"maxiter": cfg.iters})
    xyz = path(r.x)
    far = np.linalg.norm(xyz - goal, axis=-1) >= cfg.exempt_radius
    feasible = cost(xyz) <= kappa and np.all(xyz[far, 2] >= cfg.clearance)
    return xyz, bool(feasible)


# ------------------------------------------------------------------------ run


def quality(xyz, straight_xyz, goals, mask, target, feasible) -> str:
    def y_target(paths):
        rows = zip(paths, goals, mask, target, strict=True)
        return np.array(
            [np_dragan(np.asarray(x, np.float64), g, m, BETA)[t] for x, g, m, t in rows]
        )

    y, y0 = y_target(xyz), y_target(straight_xyz)
    return (
        f"y_target {y.mean():.3f} (gain {np.mean(y - y0):+.3f}, raised on "
        f"{np.mean(y > y0):.0%}), feasible {np.mean(feasible):.0%}"
    )


def path_gradient_rows(n: int, n_points: int, repeats: int) -> list[str]:
    """The path gradient, J(q)ᵀ ∂f/∂p over every waypoint, by ``fk_position``'s geometric
    Jacobian and by autodiff through the chain, against autodiff through MJX: markdown rows
    (compile s, gradients/s, max ``|Δ|`` from MJX's)."""
    qs = np.random.default_rng(1).uniform(kinematics.Q_MIN, kinematics.Q_MAX, (n, n_points, 7))
    qs = jnp.asarray(qs, jnp.float32)
    w = jnp.linspace(0.5, 1.5, 3, dtype=jnp.float32)
    ways = {
        "geometric Jacobian (fk_position)": kinematics.fk_position,
        "autodiff through the chain (tcp_state)": lambda q: kinematics.tcp_state(q).pos,
        "autodiff through mjx.kinematics": lambda q: kinematics.mjx_tcp_state(q).pos,
    }
    rows, grads = [], {}
    for name, fk in ways.items():

        def f(q, fk=fk):  # a smooth scalar of the path's positions
            return jnp.sum(jnp.sin(jax.vmap(fk)(q)) * w)

        t0 = time.perf_counter()
        g = jax.jit(jax.vmap(jax.grad(f))).lower(qs).compile()
        compile_s = time.perf_counter() - t0
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            grads[name] = np.asarray(jax.block_until_ready(g(qs)))
            best = min(best, time.perf_counter() - t0)
        rows.append((name, compile_s, n / best))
    base = rows[-1]
    out = ["| path gradient | compile s | gradients/s | × MJX autodiff (compile, rate) | "
           "largest |Δ| from MJX's |", "|---|---|---|---|---|"]  # fmt: skip
    for name, c, r in rows:
        diff = np.abs(grads[name] - grads[base[0]]).max()
        out.append(f"| {name} | {c:.2f} | {r:.3g} | {base[1] / c:.1f}×, {r / base[2]:.1f}× | "
                   f"{diff:.1e} |")  # fmt: skip
    out.append(f"\n{n} paths of {n_points} waypoints (float32)")
    return out


def planner_kinematics_rows(goals, mask, target, cfg: planning.PlannerConfig, repeats: int):
    """The planner's first call (tracing, compiling, planning) and its best later call on
    the same problems, with the chain's kinematics and with ``mjx.kinematics`` in its place:
    markdown rows and the largest difference of the plans' objectives."""
    obs = planning.labeler_observer("dragan", beta=BETA)
    rows, best_obj = [], {}
    ways = {"the chain (tcp_state)": kinematics.tcp_state,
            "mjx.kinematics (mjx_tcp_state)": kinematics.mjx_tcp_state}  # fmt: skip
    for name, fk in ways.items():
        jax.clear_caches()  # nothing compiled for one way is reused by the other
        with mock.patch.object(kinematics, "tcp_state", fk):
            planner = planning.make_planner(obs, cfg)
            t0 = time.perf_counter()
            res = jax.block_until_ready(planner(goals, mask, target))
            first = time.perf_counter() - t0
            later = np.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                jax.block_until_ready(planner(goals, mask, target))
                later = min(later, time.perf_counter() - t0)
        d = res.diagnostics
        best_obj[name] = np.asarray(d.objective)[np.arange(len(target)), np.asarray(d.best_iter)]
        rows.append((name, first, later))
    base = rows[-1]
    out = [f"| planner kinematics, {len(target)} problems | first call s | later call s | "
           "× MJX (first, later) |", "|---|---|---|---|"]  # fmt: skip
    for name, first, later in rows:
        out.append(f"| {name} | {first:.1f} | {later:.3f} | {base[1] / first:.1f}×, "
                   f"{base[2] / later:.1f}× |")  # fmt: skip
    diff = np.abs(np.subtract(*best_obj.values())).max()
    out.append(f"\nlargest |Δ best objective| {diff:.1e} (float32; the first call traces and "
               "compiles the straight lines and the planner)")  # fmt: skip
    return out


def population_rows(goals, mask, target, cfg: planning.PlannerConfig, specs) -> list[str]:
    """Plans with each population's own observer (P_pop at the prefix objective), the
    people loop's oracle, two ways in the same run: a program per population (the
    quadrature closed over as constants, as before efb346f) against one program for all
    (the quadrature as the planner's parameters, as the people loop's ``oracle_planner``):
    markdown rows of the seconds for the first and the later populations (compilation and
    planning) and the largest difference of the plans' P_pop scores."""
    cfg = planning.PlannerConfig(iters=cfg.iters, n_points=cfg.n_points, taus=(0.4, 0.7, 1.0))
    pops = [population_lib.get_population(s) for s in specs]
    keys = jax.random.split(jax.random.key(0), goals.shape[0])
    straight = planning.straight_lines(goals, mask, target, cfg=cfg)  # compiled before timing
    shared = None
    secs: dict[str, list[float]] = {}
    scores: dict[str, list[float]] = {}
    for way in ("a program per population (constants)", "one program (the quadrature an argument)"):
        for pop in pops:
            quad = population_lib.quadrature(pop)
            t0 = time.perf_counter()
            if way.startswith("one"):  # the people loop's oracle_planner, made once
                if shared is None:
                    shared = planning.make_family_planner(
                        population_lib.quadrature_observer, quad, cfg
                    )
                planner, params = shared, jax.tree.map(lambda a: a[None], quad)
            else:  # the loop before efb346f: the observer's quadrature a constant
                obs = population_lib.quadrature_observer(quad)
                planner = planning.make_family_planner(lambda p, obs=obs: obs, jnp.zeros(()), cfg)
                params = jnp.zeros((1,))
            xyz = jax.block_until_ready(planner.plan_problems(params, straight).xyz[0])
            secs.setdefault(way, []).append(time.perf_counter() - t0)
            scorer = evaluation.population_scorer(pop, cfg.taus, cfg.n_points, 1)
            p = np.asarray(scorer(keys, xyz, goals, mask, target)[0], np.float64).mean()
            scores.setdefault(way, []).append(p)
    base = next(iter(secs))
    out = [f"| P_pop planner, {len(pops)} populations × {goals.shape[0]} problems | first s | "
           "each later s | all s | × per population (all) |", "|---|---|---|---|---|"]  # fmt: skip
    for way, t in secs.items():
        later = f"{min(t[1:]):.1f}–{max(t[1:]):.1f}" if len(t) > 1 else "—"
        out.append(f"| {way} | {t[0]:.1f} | {later} | {sum(t):.1f} | "
                   f"{sum(secs[base]) / sum(t):.1f}× |")  # fmt: skip
    diff = np.abs(np.subtract(*scores.values())).max()
    out.append(f"\npopulations {', '.join(specs)}; compilation included, the straight lines "
               "compiled before; largest |Δ mean P_pop(target)| of the plans "
               f"{diff:.1e} (a local optimiser: the two programs round the gradient's sums "
               "differently)")  # fmt: skip
    return out


@cli.command
def main(argv=None) -> int:
    p = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.planning")
    p.add_argument("--n", type=int, default=64, help="problems of the batched call")
    p.add_argument("--loop-n", type=int, default=8, help="problems of the JAX loop")
    p.add_argument("--scipy-n", type=int, default=2, help="problems of the SciPy baseline")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--iters", type=int, default=planning.PlannerConfig().iters)
    p.add_argument("--populations", default="default,homogeneous,random:0,random:1,random:2",
                   help="comma-separated populations of the P_pop table")  # fmt: skip
    args = p.parse_args(argv)
    if min(args.n, args.loop_n, args.scipy_n, args.repeats, args.iters) < 1:
        p.error("--n, --loop-n, --scipy-n, --repeats and --iters must be >= 1")
    specs = [s for s in args.populations.split(",") if s]
    try:
        for s in specs:
            population_lib.get_population(s)
    except ValueError as e:
        p.error(f"--populations: {e}")
    if len(specs) < 2:
        p.error("--populations: expected at least two (the later ones share a program)")
    import scipy

    cfg = planning.PlannerConfig(iters=args.iters)
    print(slotv_jax.XLA_CONFIG.summary())
    print(f"{datetime.date.today()}  {cpu_model()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}; Python {platform.python_version()}, "
          f"jax {jax.__version__}, scipy {scipy.__version__}, numpy {np.__version__}")  # fmt: skip
    print(f"Dragan observer, {cfg.iters} iterations, {cfg.n_points} waypoints, "
          f"budget {cfg.budget} m²\n")  # fmt: skip
    goals, mask, target = sample_problems(max(args.n, args.loop_n, args.scipy_n))
    planner = planning.make_planner(planning.labeler_observer("dragan", beta=BETA), cfg)

    def timed(fn, repeats):
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn())
            best = min(best, time.perf_counter() - t0)
        return best, out

    n, ln, sn = args.n, args.loop_n, args.scipy_n
    t0 = time.perf_counter()
    jax.block_until_ready(planner(goals[:n], mask[:n], target[:n]))
    compile_batch = time.perf_counter() - t0
    t_batch, res = timed(lambda: planner(goals[:n], mask[:n], target[:n]), args.repeats)
    straight = planner.straight_line(goals[:n], mask[:n], target[:n])

    def loop():
        return [planner(goals[i : i + 1], mask[i : i + 1], target[i : i + 1]) for i in range(ln)]

    t0 = time.perf_counter()
    jax.block_until_ready(planner(goals[:1], mask[:1], target[:1]))
    compile_one = time.perf_counter() - t0
    t_loop, loop_res = timed(loop, args.repeats)

    q0 = np.asarray(straight.q, np.float64)
    t0 = time.perf_counter()
    sp = [scipy_plan(q0[i], goals[i].astype(np.float64), mask[i], int(target[i]), cfg)
          for i in range(sn)]  # fmt: skip
    t_scipy = time.perf_counter() - t0

    rate = {"batched JAX": n / t_batch, "JAX loop": ln / t_loop, "SciPy L-BFGS-B": sn / t_scipy}
    sx = np.asarray(straight.xyz)
    qual = {
        "batched JAX": quality(res.xyz, sx, goals[:n], mask[:n], target[:n], res.feasible),
        "JAX loop": quality(
            [r.xyz[0] for r in loop_res],
            sx[:ln],
            goals[:ln],
            mask[:ln],
            target[:ln],
            [bool(r.feasible[0]) for r in loop_res],
        ),
        "SciPy L-BFGS-B": quality(
            [x for x, _ in sp], sx[:sn], goals[:sn], mask[:sn], target[:sn], [f for _, f in sp]
        ),
    }
    counts = {"batched JAX": n, "JAX loop": ln, "SciPy L-BFGS-B": sn}
    print("| method | problems | problems/s | × SciPy | quality |\n|---|---|---|---|---|")
    for k, v in rate.items():
        print(f"| {k} | {counts[k]} | {v:.3g} | {v / rate['SciPy L-BFGS-B']:.0f}× | {qual[k]} |")
    print(f"\ncompilation: batch of {n} {compile_batch:.1f} s, batch of 1 {compile_one:.1f} s "
          f"(not in the rates); SciPy: {t_scipy / sn:.1f} s per problem\n")  # fmt: skip
    print("\n".join(path_gradient_rows(n, cfg.n_points, args.repeats)))
    print()
    print("\n".join(planner_kinematics_rows(goals[:ln], mask[:ln], target[:ln], cfg, args.repeats)))
    print()
    print("\n".join(population_rows(goals[:ln], mask[:ln], target[:ln], cfg, specs)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
