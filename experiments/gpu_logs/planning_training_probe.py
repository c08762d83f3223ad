"""Probe, not part of the package: train SLOT-V+ observers under several training configs
and seeds, plan the planning experiment's paper problems with each and score the plans
with the true labeler, as the experiment does. Recorded in experiments/planning_paper.md
("SLOT-V+: training length"). Run on one H100 (2026-11-24, the code of commit cebca53,
jax 0.11.2), several calls, each as

    python experiments/gpu_logs/planning_training_probe.py paper nikolaidis \
        "ep5|3,4,5,6,7|compute_dtype=bfloat16;start_term=true;time_weight=true;epochs=5"

Args: preset, family, then specs "LABEL|SEEDS|OVERRIDES" (TrainConfig overrides of the
preset's SLOT-V, separated by ";"). A label starting with "cos" trains with a cosine
decay of the learning rate to 0; "ema" also scores the exponential moving averages of
the parameters (decays 0.9998 and 0.99995, kept in the optimiser state); a label with
two or more seeds also scores the ensemble (mean log-probability) of its trainings.
Each line: accuracy on trajectory_test / position_test / goal_count_test, α, the cosine
of the planning gradient with the oracle's at the straight lines, the gain kept and the
rate at which the true legibility was lowered (observer evaluated in float32).

Nikolaidis, gain kept (all paper data, paper widths 1536/768, bfloat16 matmuls):

    15 epochs (the paper's):  89.3 81.6 79.3 | 83.2 77.6 75.7 75.4   (two calls)
    5 epochs:                 90.0 | 83.4 85.2 | 81.1 83.1 79.3 81.1 81.4   (three calls)
    cosine decay, 15 epochs:  89.4 75.9 89.7
    EMA 0.99995, 15 epochs:   81.8 81.5 81.0 80.2   (same trainings as 83.2 77.6 75.7 75.4)
    EMA 0.9998:               83.6 78.2 77.8 76.8
    ensembles: 15 epochs, 4 trainings 79.2; EMA 0.99995, 4: 82.7; 5 epochs, 5: 81.8
    256/128 widths: 75.3; 64/32 widths, 3 epochs, 8,000 trajectories: 91.9
    15 epochs, float32 matmuls: 82.4; bfloat16 trainings planned in float32 instead of
    bfloat16: within 0.3 points of each other in every case
    goal input (first layer sees r − g and g, a trial option, not kept): 76.7 78.8 76.3,
    with higher accuracy (up to 0.943/0.931/0.907); Dragan 91.2 83.1 (worse)

Dragan, 5 epochs: 96.8 96.4 96.3 (accuracy 0.935–0.951 / 0.913–0.932 / 0.913–0.918).
"""

import dataclasses
import sys
import time

import jax
import optax
from flax import nnx
from planning_probe_setup import EVAL_SPLITS, Problems

from slotv_jax.observers import models
from slotv_jax.training import checkpoint, evaluate, losses, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

preset, family, specs = sys.argv[1], sys.argv[2], sys.argv[3:]
P = Problems(preset, family)

ORIG_MK = losses.make_optimizer
EMA_DECAYS = (0.9998, 0.99995)
ALL = {}  # (label, variant) -> parameters of every seed


def cosine(total):
    """RMSprop with the learning rate decayed to 0 over ``total`` updates."""

    def mk(c):
        sched = optax.cosine_decay_schedule(c.learning_rate, total)
        return optax.rmsprop(sched, decay=c.rho, eps=c.eps, eps_in_sqrt=False)

    return mk


def with_ema(c):
    """The config's optimiser, its state also holding EMAs of the parameters."""
    base = ORIG_MK(c)

    def init(params):
        return base.init(params), tuple(params for _ in EMA_DECAYS)

    def update(grads, state, params):
        u, inner = base.update(grads, state[0], params)
        new = optax.apply_updates(params, u)
        emas = tuple(
            jax.tree.map(lambda e, n, d=d: d * e + (1 - d) * n, e, new)
            for d, e in zip(EMA_DECAYS, state[1], strict=True)
        )
        return u, (inner, emas)

    return optax.GradientTransformation(init, update)


def score(obs):
    kept, low = P.score(obs)
    return f"align {P.alignment(obs):.3f} kept {kept:.1%} low {low:.3f}"


for spec in specs:
    label, _, rest = spec.partition("|")
    seeds, _, overrides = rest.partition("|")
    tc = train_config.apply_overrides(P.cfg.train["slotv"], [o for o in overrides.split(";") if o])
    data = types.prepare(P.ds["train"], family, size=tc.train_size)
    tc = dataclasses.replace(tc, train_size=None)
    train._make_train.cache_clear()
    losses.make_optimizer = ORIG_MK
    if label.startswith("cos"):
        losses.make_optimizer = cosine(tc.epochs * tc.steps_per_epoch(data.xyz.shape[0]))
    elif label.startswith("ema"):
        losses.make_optimizer = with_ema
    f32 = dataclasses.replace(tc, compute_dtype="float32")
    for seed in [int(x) for x in seeds.split(",")]:
        t0 = time.time()
        state, _ = train.train_trials(tc, data, [seed], progress=False)
        state = train.select_trial(state, 0)
        variants = [("raw", state.params)]
        if label.startswith("ema"):
            variants += [
                (f"ema{d}", e) for d, e in zip(EMA_DECAYS, state.opt_state[1], strict=True)
            ]
        for name, params in variants:
            ALL.setdefault((label, name), []).append(params)
            acc = "/".join(
                f"{float(evaluate.accuracy(tc, params, P.ds[x], family)):.3f}" for x in EVAL_SPLITS
            )
            model = nnx.merge(models.graphdef(tc), params)
            alpha = "" if model.alpha is None else f" alpha {float(model.alpha):.3f}"
            res = score(checkpoint.make_observer(f32, params))
            print(f"{family} {label} {name} seed {seed}: acc {acc}{alpha} [float32] {res} "
                  f"({time.time() - t0:.0f}s)", flush=True)  # fmt: skip
    for (lab, name), plist in ALL.items():
        if lab == label and len(plist) > 1:
            members = [checkpoint.make_observer(f32, p) for p in plist]

            def ensemble(x, gg, mm, members=members):
                return sum(jax.nn.log_softmax(o(x, gg, mm)) for o in members) / len(members)

            print(f"{family} {label} {name} ENSEMBLE of {len(plist)}: {score(ensemble)}",
                  flush=True)  # fmt: skip
