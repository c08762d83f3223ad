"""Probe, not part of the package: train one learned observer with several seeds, plan the
planning experiment's problems with each and score them as the experiment does.

Recorded in experiments/planning_paper.md (SLOT-V+ over seeds). Run on one H100
(2026-11-24, the code of commit add0b95, jax 0.11.2) as

    python experiments/gpu_logs/planning_seed_sweep.py paper nikolaidis 3 \
        compute_dtype=bfloat16 start_term=true time_weight=true

(args: preset, family, seeds, then TrainConfig overrides of the preset's SLOT-V). Output
(accuracy on trajectory_test / position_test / goal_count_test; the cosine of the
planning gradient with the oracle's at the straight lines, as in
planning_gradient_alignment.py; the learned α; the gain kept and the lowered rate):

    nikolaidis seed 0: acc 0.914/0.904/0.860 align 0.804 alpha 1.022 kept 75.8% lowered 0.003
    nikolaidis seed 1: acc 0.911/0.888/0.861 align 0.794 alpha 0.996 kept 76.3% lowered 0.002
    nikolaidis seed 2: acc 0.913/0.899/0.862 align 0.822 alpha 1.033 kept 76.1% lowered 0.000
    dragan seed 0: acc 0.925/0.897/0.887 align 0.962 alpha 1.052 kept 96.8% lowered 0.000
    dragan seed 1: acc 0.936/0.909/0.914 align 0.954 alpha 1.040 kept 96.2% lowered 0.000
    dragan seed 2: acc 0.943/0.923/0.906 align 0.954 alpha 1.060 kept 96.3% lowered 0.000

Re-run after the oracle and the scoring took the datasets' temperatures (β 30 for
Nikolaidis; before, β 7.5 scored observers trained at 30), with the preset's 5 epochs
(``... paper nikolaidis 5 compute_dtype=bfloat16 start_term=true time_weight=true
epochs=5``; H100, code of commit b1efd59, 2026-11-24)::

    nikolaidis seed 0: acc 0.891/0.877/0.788 align 0.906 alpha 1.043 kept 86.0% lowered 0.000
    nikolaidis seed 1: acc 0.914/0.908/0.871 align 0.896 alpha 1.090 kept 83.9% lowered 0.000
    nikolaidis seed 2: acc 0.895/0.876/0.827 align 0.867 alpha 1.059 kept 81.3% lowered 0.000
    nikolaidis seed 3: acc 0.907/0.896/0.854 align 0.859 alpha 1.073 kept 79.7% lowered 0.000
    nikolaidis seed 4: acc 0.883/0.846/0.822 align 0.846 alpha 1.050 kept 80.8% lowered 0.000

The first block of outputs was scored at β 7.5 (Nikolaidis) and 5 (Dragan). An earlier
version of this probe (the code of commit 9b728f6, same configuration, before a
refactor that changes float rounding only) gave, for seeds 0–2: Nikolaidis 81.8, 82.9,
75.6 %; Dragan 96.7, 96.2, 89.1 %.
"""

import dataclasses
import sys

from flax import nnx
from planning_probe_setup import EVAL_SPLITS, Problems

from slotv_jax.observers import models
from slotv_jax.training import checkpoint, evaluate, types
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train

preset, family, n_seeds = sys.argv[1], sys.argv[2], int(sys.argv[3])
P = Problems(preset, family)
tc = train_config.apply_overrides(P.cfg.train["slotv"], sys.argv[4:])
data = types.prepare(P.ds["train"], family, size=tc.train_size)
tc = dataclasses.replace(tc, train_size=None)
for seed in range(n_seeds):
    state, _ = train.train_trials(tc, data, [seed], progress=False)
    params = train.select_trial(state, 0).params
    obs = checkpoint.make_observer(tc, params)
    acc = "/".join(
        f"{float(evaluate.accuracy(tc, params, P.ds[s], family)):.3f}" for s in EVAL_SPLITS
    )
    kept, low = P.score(obs)
    model = nnx.merge(models.graphdef(tc), params)
    alpha = "" if model.alpha is None else f" alpha {float(model.alpha):.3f}"
    print(f"{family} seed {seed}: acc {acc} align {P.alignment(obs):.3f}{alpha} "
          f"kept {kept:.1%} lowered {low:.3f}", flush=True)  # fmt: skip
