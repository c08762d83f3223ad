"""Probe, not part of the package: how well a learned observer's planning gradient points
where the oracle's does, at the straight lines of a planning run.

For each problem, the cosine in the planner's metric between an observer's planning
gradient and the oracle's at the straight line (planning_probe_setup.py); its mean and
median over the problems.
Recorded in experiments/planning_paper.md. Run on one H100 (2026-11-24, commit 9b728f6)
after the paper-preset planning run, as

    python experiments/gpu_logs/planning_gradient_alignment.py runs/pl \
        slotv_plus_dragan trex_plus_dragan

Output:

    dragan     cosine(A^-1) to oracle at straight: mean 1.000 median 1.000 frac<0 0.000
    slotv      cosine(A^-1) to oracle at straight: mean 0.521 median 0.523 frac<0 0.000
    trex       cosine(A^-1) to oracle at straight: mean 0.488 median 0.490 frac<0 0.000
    arch       cosine(A^-1) to oracle at straight: mean 0.936 median 0.957 frac<0 0.000
    effdist    cosine(A^-1) to oracle at straight: mean 0.948 median 0.954 frac<0 0.000
    fastapp    cosine(A^-1) to oracle at straight: mean 0.927 median 0.941 frac<0 0.000
    slotv_plus_dragan cosine(A^-1) to oracle at straight: mean 0.959 median 0.975 frac<0 0.000
    trex_plus_dragan cosine(A^-1) to oracle at straight: mean 0.680 median 0.684 frac<0 0.000
"""

import sys

import numpy as np
from planning_probe_setup import metric_cosines, planning_gradients

import slotv_jax
from slotv_jax import planning

run = sys.argv[1] if len(sys.argv) > 1 else "runs/planning_quick"
f = np.load(f"{run}/plans.npz")
s = f["xyz/straight"]
obs = {
    "dragan": planning.labeler_observer("dragan"),
    "slotv": slotv_jax.load_observer(f"{run}/observers/slotv_dragan"),
    "trex": slotv_jax.load_observer(f"{run}/observers/trex_dragan"),
    "arch": slotv_jax.load_observer(f"{run}/observers/archetype_dragan", model="dragan"),
    "effdist": planning.labeler_observer("effdist"),
    "fastapp": planning.labeler_observer("fastapp"),
}
for extra in sys.argv[2:]:
    obs[extra] = slotv_jax.load_observer(f"{run}/observers/{extra}")
problems = (s, f["goals"], f["goal_mask"], f["target"])
a_inv = planning.metric_inverse(s.shape[1] - 2)
ref = planning_gradients(obs["dragan"], *problems)
for name, o in obs.items():
    cos = metric_cosines(planning_gradients(o, *problems), ref, a_inv)
    print(
        f"{name:10s} cosine(A^-1) to oracle at straight: mean {np.mean(cos):.3f} "
        f"median {np.median(cos):.3f} frac<0 {np.mean(cos < 0):.3f}"
    )
