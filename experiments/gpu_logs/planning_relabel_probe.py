"""Probe, not part of the package: relabel the planner's own motions and retrain.

Recorded in experiments/planning_paper.md ("What did not close the gap"). Run on one H100
(2026-11-23, the code of commit 1a4c65d, jax 0.11.2) as

    python experiments/gpu_logs/planning_relabel_probe.py \
        paper dragan 2 3 0.0125,0.025,0.05 slotv,trex arch

(args: preset, family, rounds, copies of the relabelled plans, budgets, methods, "arch" for
the archetype reference). Output:

    [  37.0s] data
    [ 116.0s] 597 test problems, 1041 train problems; straight 0.2640 oracle 0.3256
    [ 158.7s] slotv round 0 (n=100000): mean y 0.2859 kept 35.6% lowered 0.174
    [ 231.8s] slotv round 1 (n=109369): mean y 0.2890 kept 40.7% lowered 0.017
    [ 260.4s] slotv round 2 (n=118738): mean y 0.2789 kept 24.2% lowered 0.092
    [ 294.6s] trex round 0 (n=100000): mean y 0.2825 kept 30.1% lowered 0.116
    [ 356.9s] trex round 1 (n=109369): mean y 0.2861 kept 36.0% lowered 0.010
    [ 378.7s] trex round 2 (n=118738): mean y 0.2897 kept 41.8% lowered 0.134
    [ 401.6s] dragan archetype (SLOT-V loss): mean y 0.3194 kept 90.0% lowered 0.000
"""

import dataclasses
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.experiments import planning as PE
from slotv_jax.training import checkpoint, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train
from slotv_jax.training import types as training_types

T0 = time.perf_counter()
preset, family, rounds, rep = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
budgets = [float(b) for b in sys.argv[5].split(",")]
methods = sys.argv[6].split(",")
cfg = PE.PRESETS[preset]()
if preset == "paper":
    cfg = dataclasses.replace(
        cfg,
        train={m: dataclasses.replace(c, compute_dtype="bfloat16") for m, c in cfg.train.items()},
    )


def log(*a):
    print(f"[{time.perf_counter() - T0:6.1f}s]", *a, flush=True)


ds = data_lib.generate_dataset(
    cfg.data,
    data_lib.dataset_dir(Path("data"), cfg.data),
    splits=("train", *PE.SPLITS),
    progress=False,
)
log("data")
problems = PE.make_problems(PE.held_out_scenes(cfg, ds))
tr = ds["train"]
tg, tm = tr.scene_goals, tr.scene_mask
rows = [(e, k) for e in range(tg.shape[0]) for k in np.flatnonzero(tm[e])]
P = {
    "goals": np.stack([tg[e] for e, k in rows]),
    "goal_mask": np.stack([tm[e] for e, k in rows]),
    "target": np.array([k for e, k in rows], np.int32),
}
oracle = planning.labeler_observer(family)
pl0 = planning.make_planner({"oracle": oracle}, cfg.planner)
S_test = pl0.straight_line(problems["goals"], problems["goal_mask"], problems["target"])
S_train = pl0.straight_line(P["goals"], P["goal_mask"], P["target"])
ri = np.arange(len(problems["target"]))


def ytrue(xyz, pr):
    return PE.true_labels(family, np.asarray(xyz), pr["goals"], pr["goal_mask"])


ys = ytrue(S_test.xyz, problems)[ri, problems["target"]]
yo = ytrue(pl0.plan_problems(S_test).xyz, problems)[ri, problems["target"]]
log(
    f"{len(ri)} test problems, {len(rows)} train problems; "
    f"straight {ys.mean():.4f} oracle {yo.mean():.4f}"
)


def planner_for(tc, budget):
    pc = dataclasses.replace(cfg.planner, budget=budget)
    return jax.jit(
        lambda params, prob: jax.vmap(
            lambda p: planning.plan(checkpoint.make_observer(tc, params), p, pc)
        )(prob)
    )


def report(tag, tc, params, planners):
    res = planners[cfg.planner.budget](params, S_test)
    y = ytrue(res.xyz, problems)[ri, problems["target"]]
    log(
        f"{tag}: mean y {y.mean():.4f} "
        f"kept {(y.mean() - ys.mean()) / (yo.mean() - ys.mean()):.1%} "
        f"lowered {(y < ys).mean():.3f}"
    )


def fit(tc, data, seed=0):
    st, _ = train.train_trials(tc, data, [seed], progress=False)
    return train.select_trial(st, 0).params


for method in methods:
    tc = cfg.train[method]
    base = training_types.prepare(tr, family, size=tc.train_size)
    tc = dataclasses.replace(tc, train_size=None)
    planners = {b: planner_for(tc, b) for b in set(budgets) | {cfg.planner.budget}}
    data, extra = base, []
    for r in range(rounds + 1):
        params = fit(tc, data)
        report(f"{method} round {r} (n={data.xyz.shape[0]})", tc, params, planners)
        if r == rounds:
            break
        for b in budgets:
            xyz = np.asarray(planners[b](params, S_train).xyz)
            extra.append(types.make_data(xyz, P["goals"], P["goal_mask"], ytrue(xyz, P)))
        parts = [base] + [e for e in extra for _ in range(rep)]
        data = types.TrainData(
            *[jnp.concatenate([getattr(p, f) for p in parts]) for f in types.TrainData._fields]
        )
        perm = np.random.default_rng(r + 1).permutation(data.xyz.shape[0])
        data = types.TrainData(*[x[perm] for x in data])
# reference: the dragan archetype fitted with SLOT-V's loss
if family == "dragan" and "arch" in sys.argv[7:]:
    ta = train_config.archetype("paper" if preset == "paper" else "quick", "dragan")
    params = fit(ta, training_types.prepare(tr, family))
    planners = {cfg.planner.budget: planner_for(ta, cfg.planner.budget)}
    report("dragan archetype (SLOT-V loss)", ta, params, planners)
log("done")
