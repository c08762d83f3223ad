"""An independent time-optimal path parameterisation: float64 NumPy forward/backward passes.

For a joint path q(s) (any callable ``path(s, order)`` returning q′ or q″ at parameters s)
and limits |q̇_j| ≤ v_j, |q̈_j| ≤ a_j, at rest at both ends, the fastest time law is found on
a fine uniform grid in x = ṡ² (the numerical integration of Bobrow et al. and Shin & McKay).
With q̇ = q′ ṡ, q̈ = q′ s̈ + q″ x and s̈ = dx / (2 ds), joint j (q′_j ≠ 0) allows

    α_j x − β_j ≤ s̈ ≤ α_j x + β_j,   α_j = −q″_j / q′_j,   β_j = a_j / |q′_j|,

and a joint with q′_j = 0 allows x ≤ a_j / |q″_j|. So:

- the velocity limits cap x ≤ min_j (v_j / |q′_j|)²; the acceleration limits cap it where
  the intervals stop meeting: x ≤ (β_j + β_k) / (α_j − α_k) for every pair with α_j > α_k;
- forward: x_{i+1} = min(cap_{i+1}, x_i + 2 Δs min_j(α_j x_i + β_j)); backward:
  x_i = min(x_i, x_{i+1} − 2 Δs max_j(α_j x_{i+1} − β_j)), from x = 0 at both ends.

The duration is Σ 2 Δs / (ṡ_i + ṡ_{i+1}). Written for the tests, sharing nothing with
``slotv_jax.execution`` (no toppra). Without ``jerk`` it is the time-optimal duration under
velocity and acceleration alone, a lower bound on any timing of the path within those limits.

With ``jerk`` (j, (7,)) the path's own jerk term caps the speed too: q⃛ = q‴ ṡ³ + 3 q″ ṡ s̈
+ q′ s⃛, and x ≤ min_j (j_j / |q‴_j|)^⅔ keeps |q‴ ṡ³| ≤ j (q‴ from the differences of q″ over
the fine grid, the larger of the two cells at each point). That is an estimate of what a
jerk bound costs, not a bound: the other two terms can add to q‴ ṡ³ or cancel some of it.
"""

from __future__ import annotations

import numpy as np

STILL = 1e-12  # |q′_j| below this: joint j does not move along the path there


def optimal_duration(path, length: float, v, a, n: int = 20001, jerk=None) -> float:
    """The time-optimal duration (s) of ``path`` over s in [0, ``length``] under joint velocity
    limits ``v`` (7,) and acceleration limits ``a`` (7,), at rest at both ends; ``n`` grid points;
    ``jerk`` (7,): the speed capped by the path's jerk term too (see the module docstring)."""
    v, a = np.asarray(v, np.float64), np.asarray(a, np.float64)
    s = np.linspace(0.0, length, n)
    ds = s[1] - s[0]
    d1, d2 = np.asarray(path(s, 1), np.float64), np.asarray(path(s, 2), np.float64)
    moving = np.abs(d1) > STILL
    safe = np.where(moving, d1, 1.0)
    alpha = np.where(moving, -d2 / safe, 0.0)
    beta = np.where(moving, a / np.abs(safe), np.inf)
    with np.errstate(divide="ignore"):
        cap = np.min(np.where(moving, (v / np.abs(safe)) ** 2, np.inf), axis=1)
        still = np.where(moving, np.inf, a / np.abs(d2))  # q′_j = 0: |q″_j| x ≤ a_j
        cap = np.minimum(cap, still.min(axis=1))
        da = alpha[:, :, None] - alpha[:, None, :]  # α_j − α_k
        pair = np.where(
            da > 0, (beta[:, :, None] + beta[:, None, :]) / np.where(da > 0, da, 1), np.inf
        )
    cap = np.minimum(cap, pair.reshape(n, -1).min(axis=1))
    if jerk is not None:
        d3 = np.abs(np.diff(d2, axis=0)) / ds  # q‴ on each cell of the grid
        d3 = np.maximum(np.concatenate([d3[:1], d3]), np.concatenate([d3, d3[-1:]]))
        with np.errstate(divide="ignore"):
            cap = np.minimum(cap, np.min((np.asarray(jerk) / d3) ** (2.0 / 3.0), axis=1))
    x = np.zeros(n)
    for i in range(n - 1):  # forward: accelerate as hard as allowed
        x[i + 1] = min(cap[i + 1], max(0.0, x[i] + 2.0 * ds * np.min(alpha[i] * x[i] + beta[i])))
    x[-1] = 0.0
    for i in range(n - 1, 0, -1):  # backward: decelerate as hard as allowed
        x[i - 1] = min(x[i - 1], max(0.0, x[i] - 2.0 * ds * np.max(alpha[i] * x[i] - beta[i])))
    sd = np.sqrt(x)
    return float(np.sum(2.0 * ds / np.maximum(sd[:-1] + sd[1:], 1e-300)))
