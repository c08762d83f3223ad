"""Benchmark: active selection over a pool of 100,000 candidate stimuli.

    python -m slotv_jax.benchmarks.selection                    # quick network (CPU)
    python -m slotv_jax.benchmarks.selection --preset paper     # the paper's network (GPU)

A synthetic pool (straight-ish motions of T = 100 points to one of 2-6 goals) and an
untrained ensemble of E members of SLOT-V's network (:mod:`slotv_jax.asking.selection`). Timed,
each compiled once and then the median of ``--repeats`` calls (results waited for):

- scoring: every member's log guess probabilities of every candidate
  (:meth:`Selector.log_probs`, ``--chunk`` candidates per step);
- each strategy's pick of k candidates from those scores (:func:`selection.select`),
  beside ``random`` (the baseline: no scores needed);
- one training round of the ensemble (``--updates`` updates of the members side by side).
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax.asking import selection
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.training import config as train_config


def synthetic_pool(n: int, t: int = 100, seed: int = 0) -> selection.Pool:
    """n motions from the home position towards one of 2-6 random goals."""
    rng = np.random.default_rng(seed)
    n_goals = rng.choice([2, 3, 5, 6], n)
    mask = np.arange(8)[None] < n_goals[:, None]
    goals = rng.uniform([0.3, -0.45, 0.0], [0.7, 0.45, 0.05], (n, 8, 3)) * mask[..., None]
    target = goals[np.arange(n), rng.integers(0, n_goals)]
    via = rng.uniform([0.3, -0.45, 0.1], [0.7, 0.45, 0.25], (n, 3))
    s = np.linspace(0, 1, t)[None, :, None]
    start = np.array([0.31, 0.0, 0.49])
    xyz = (1 - s) ** 2 * start + 2 * s * (1 - s) * via[:, None] + s**2 * target[:, None]
    return selection.make_pool(xyz.astype(np.float32), goals.astype(np.float32), mask)


def _time(fn, *args, repeats: int) -> tuple[float, float]:
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    return first, statistics.median(runs)


@cli.command
def main(argv=None) -> int:
    ap = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.selection")
    ap.add_argument("--preset", default="quick", choices=("quick", "paper"))
    ap.add_argument("--pool", type=int, default=100_000)
    ap.add_argument("--members", type=int, default=4)
    ap.add_argument("--k", type=int, default=64, help="candidates picked")
    ap.add_argument("--chunk", type=int, default=None, help="default: 512 CPU, 2048 GPU")
    ap.add_argument("--updates", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)
    if args.json:  # checked before the benchmark; the file is regenerated
        json_path = pathlib.Path(args.json)
        fileio.check_output_files(json_path.parent, [json_path.name], what="--json")
    on_cpu = jax.default_backend() == "cpu"
    chunk = args.chunk or (512 if on_cpu else 2048)
    cfg = train_config.preset(args.preset, "slotv", train_size=None)
    if not on_cpu:
        cfg = train_config.apply_overrides(cfg, ["compute_dtype=bfloat16"])
    env = environment()
    print(f"# selection benchmark, {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC")
    print(
        f"# {cpu_model()}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}; devices "
        f"{env['devices']}; jax {env['jax']}, flax {env['flax']}"
    )
    print(f"# {slotv_jax.XLA_CONFIG.summary()}")
    print(f"# network {cfg.hidden} {cfg.compute_dtype}, E = {args.members}, pool "
          f"{args.pool:,} candidates × T = 100 points, k = {args.k}, chunk {chunk}")  # fmt: skip
    pool = synthetic_pool(args.pool)
    sel = selection.make_selector(cfg, args.members, 1024)
    ens = sel.init(jax.random.key(0))
    cand = jnp.arange(args.pool)
    score = jax.jit(lambda p, c: sel.log_probs(p, pool, c, chunk=chunk))
    rows = {}
    first, med = _time(score, ens.params, cand, repeats=args.repeats)
    rows["scoring (E members × pool)"] = (first, med)
    logp = jax.block_until_ready(score(ens.params, cand))
    avail = jnp.ones(args.pool, bool)
    key = jax.random.key(1)
    for s in selection.STRATEGIES:
        fn = jax.jit(lambda k, lp, av, s=s: selection.select(s, k, lp, av, args.k))
        rows[f"select {s}"] = _time(fn, key, logp, avail, repeats=args.repeats)
    rng = np.random.default_rng(0)
    ans = selection.make_answers(rng.choice(args.pool, 512, replace=False),
                                 rng.dirichlet(np.ones(8), 512), 1024)  # fmt: skip
    fit = jax.jit(lambda e, k: sel.fit(e, pool, ans, k, updates=args.updates))
    rows[f"fit ({args.updates} updates × E members)"] = _time(
        fit, ens, key, repeats=max(1, args.repeats // 2)
    )
    base = rows["select random"][1]
    print("\n| stage | first call (s, compile included) | median (s) | × random |")
    print("|---|---|---|---|")
    for name, (f, m) in rows.items():
        print(f"| {name} | {f:.3f} | {m:.4f} | {m / base:.1f} |")
    full = {s: rows["scoring (E members × pool)"][1] + rows[f"select {s}"][1]
            for s in selection.STRATEGIES}  # fmt: skip
    print("\nscoring + selection of k from the whole pool: "
          + ", ".join(f"{s} {t:.3f} s" for s, t in full.items()))  # fmt: skip
    if args.json:
        doc = {"args": vars(args), "environment": env, "rows": rows}
        fileio.write_text(args.json, json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
