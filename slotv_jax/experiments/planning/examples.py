"""The example plans the planning experiment keeps: ``OUT/plans.npz``
(:mod:`slotv_jax.planning.plans`, with the planning experiment's extras per row)."""

from __future__ import annotations

import numpy as np

from slotv_jax.experiments.planning.config import (
    FAMILIES,
    N_SAVED,
    SPLITS,
    PlanningConfig,
    observer_key,
)


def example_indices(problems: dict, n: int) -> list[int]:
    """The first problem of ``n`` evenly spaced scenes with at least three goals
    (deterministic; all scenes if none has three)."""
    split, scene_ = problems["split"], problems["scene"]
    many = np.flatnonzero(problems["goal_mask"].sum(-1) >= 3)
    first = [i for i in many if i == 0 or scene_[i] != scene_[i - 1] or split[i] != split[i - 1]]
    first = first or list(range(len(problems["target"])))
    pick = np.linspace(0, len(first) - 1, min(n, len(first))).round().astype(int)
    return [int(first[i]) for i in pick]


def saved_plans(cfg: PlanningConfig, problems: dict, straight, plans: dict, labels: dict) -> dict:
    """The arrays of ``plans.npz`` (:mod:`slotv_jax.planning.plans`, with the module
    docstring's extras) for the :func:`example_indices`."""
    idx = example_indices(problems, N_SAVED)
    names = ("straight", "oracle", *dict.fromkeys(m for f in FAMILIES for m in cfg.methods(f)))
    fams = [f for f in FAMILIES for _ in idx]
    probs = np.asarray(idx * len(FAMILIES), np.int32)
    T = np.shape(straight.xyz)[1]
    q = np.full((len(names), len(probs), T, 7), np.nan, np.float32)
    xyz = np.full((len(names), len(probs), T, 3), np.nan, np.float32)
    y = np.full((len(names), len(probs), problems["goals"].shape[1]), np.nan, np.float32)
    for k, name in enumerate(names):
        for p, (family, i) in enumerate(zip(fams, probs, strict=True)):
            key = {"straight": "straight", "oracle": family}.get(name, name)
            res = straight if key == "straight" else plans.get(observer_key(key, family))
            if res is not None:
                q[k, p], xyz[k, p], y[k, p] = res.q[i], res.xyz[i], labels[family, key][i]
    betas = cfg.scoring_betas()
    return {
        **{k: problems[k][probs] for k in ("goals", "goal_mask", "target", "scene")},
        "family": np.asarray(fams, str),
        "beta": np.asarray([betas[f] for f in fams], np.float32),
        "problem": probs,
        "split": np.asarray([SPLITS[s] for s in problems["split"][probs]], str),
        "names": np.asarray(names, str),
        "q": q,
        "xyz": xyz,
        "y": y,
    }
