"""Benchmark: the people loop's fits of each family on a study's answers.

    python -m slotv_jax.benchmarks.people_fits                   # quick preset (CPU)
    python -m slotv_jax.benchmarks.people_fits --preset paper    # the paper preset (GPU)

Every size of the people loop fits each trained family once on all answers and once per
fold of the pick (:func:`slotv_jax.asking.simulated.fit_runs`, the runs side by side);
those fits are most of a quick population's time. A synthetic pool (T = 100 points to one
of 2-6 goals of the 8 slots, :func:`slotv_jax.benchmarks.selection.synthetic_pool`) and
answers of 5 guesses on each of ``--rows`` stimuli; each family's fit of ``--updates``
(300: the quick loop's at every size), timed after a first call that compiles, the median
of ``--repeats``:

- **padded**: the pool's 8 goal slots, as the loop fitted before 2026-12-07 (the baseline);
- **real slots**: the loop's path, the goal slots that no motion has cut first
  (:func:`slotv_jax.asking.selection.trim_goals`).

The motion reader starts from a random draw here (the loop starts it from its prior: the
same work per update).
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax.asking import selection, simulated
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.benchmarks.selection import _time, synthetic_pool
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.training import config as train_config

#: The people loop's trained families (slotv_jax.experiments.people_loop.config: LEARNED, READER).
FAMILIES = ("mlp", "slotv_plus", "dragan_archetype", "viewpoint_archetype", "mixture_archetype",
            "reader")  # fmt: skip


def padded_fit(tc, pool, cand, counts, rows, keys, blocks, block):
    """The fit of :func:`~slotv_jax.asking.simulated.fit_runs` on the pool's padded goal
    slots (the baseline: fit_runs before it cut them)."""
    sel = selection.make_selector(tc, 1, cand.shape[1])
    ens = jax.jit(jax.vmap(sel.init, in_axes=(0, None)))(keys, None)
    ans = selection.Answers(
        jnp.asarray(cand), jnp.asarray(counts), jnp.full((cand.shape[0],), rows, jnp.int32)
    )
    fit = simulated.fitter(sel, block)
    for j in range(blocks):
        ens, _ = fit(ens, pool, ans, jax.vmap(lambda k, j=j: jax.random.fold_in(k, j))(keys))
    return jax.tree.map(lambda x: x[:, 0], ens.params)


@cli.command
def main(argv=None) -> int:
    ap = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.people_fits")
    ap.add_argument("--preset", default="quick", choices=("quick", "paper"))
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--updates", type=int, default=300, help="updates a fit (the quick loop's)")
    ap.add_argument("--block", type=int, default=100, help="updates a compiled call")
    ap.add_argument("--rows", type=int, default=400, help="answer rows (stimuli) fitted")
    ap.add_argument("--runs", type=int, default=3, help="fits side by side (the pick's folds)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)
    fams = [f for f in args.families.split(",") if f]
    bad = [f for f in fams if f not in FAMILIES]
    if bad or not fams:
        ap.error(f"--families: expected names of {FAMILIES}, got {args.families!r}")
    for name in ("rows", "runs", "repeats", "updates", "block"):
        if getattr(args, name) < 1:
            ap.error(f"--{name}: expected an int >= 1, got {getattr(args, name)}")
    if args.json:  # checked before the benchmark; the file is regenerated
        json_path = pathlib.Path(args.json)
        fileio.check_output_files(json_path.parent, [json_path.name], what="--json")
    env = environment()
    print(f"# people-loop fits benchmark, {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC")
    print(
        f"# {cpu_model()}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}; devices "
        f"{env['devices']}; jax {env['jax']}, flax {env['flax']}"
    )
    print(f"# {slotv_jax.XLA_CONFIG.summary()}")
    pool = synthetic_pool(2000)
    pool = selection.make_pool(
        np.asarray(pool.xyz), np.asarray(pool.goals), np.asarray(pool.goal_mask), (0.4, 0.7, 1.0)
    )
    rng = np.random.default_rng(0)
    mask = np.asarray(pool.goal_mask)[np.asarray(pool.traj)]
    cand = np.stack([rng.choice(pool.traj.shape[0], args.rows, replace=False)] * args.runs)
    counts = np.stack([[rng.multinomial(5, m / m.sum()) for m in mask[c]] for c in cand]).astype(
        np.float32
    )
    keys = jnp.stack([jax.random.key(i) for i in range(args.runs)])
    print(f"# preset {args.preset}: {args.runs} fits side by side, {args.rows} answer rows, pool "
          f"{pool.traj.shape[0]:,} candidates, goals 2-6 of 8 slots")  # fmt: skip
    print("\n| family | updates | padded (s) | real slots (s) | × faster |")
    print("|---|---|---|---|---|")
    rows = {}
    for f in fams:
        tc = train_config.family(args.preset, f)
        block = args.block
        blocks = -(-args.updates // args.block)
        updates = blocks * block

        def padded(tc=tc, b=blocks):
            return padded_fit(tc, pool, cand, counts, args.rows, keys, b, args.block)

        def cut(tc=tc, b=blocks):
            return simulated.fit_runs(tc, pool, cand, counts, args.rows, keys, b, args.block)

        old, new = (_time(fn, repeats=args.repeats) for fn in (padded, cut))
        rows[f] = {"updates": updates, "padded": old, "real_slots": new}
        print(f"| {f} | {updates} | {old[1]:.2f} | {new[1]:.2f} | {old[1] / new[1]:.2f} |",
              flush=True)  # fmt: skip
    total_old = sum(r["padded"][1] for r in rows.values())
    total_new = sum(r["real_slots"][1] for r in rows.values())
    print(f"| **every family** | | {total_old:.2f} | {total_new:.2f} | "
          f"{total_old / total_new:.2f} |")  # fmt: skip
    if args.json:
        doc = {"args": vars(args), "environment": env, "rows": rows}
        fileio.write_text(args.json, json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
