"""Independent float64 NumPy re-derivation of the four labelers, written from
:ref:`concepts-labelers`.

Plain loops over points and goals, no vectorisation tricks and no code shared with
``slotv_jax.labelers``: each formula is spelled out as the SPEC writes it, so the
tests can compare the JAX implementation against it.

Time stamps: ``t`` (optional, strictly increasing) is normalised to [0, 1]; the
default is ``t_i = i / (T − 1)``.
"""

from __future__ import annotations

import math

import numpy as np

G_MAX = 8


def _norm(v) -> float:
    return math.sqrt(sum(float(x) * float(x) for x in v))


def _times(T: int, t=None) -> np.ndarray:
    if t is None:
        return np.array([i / (T - 1) for i in range(T)])
    t = np.asarray(t, np.float64)
    return (t - t[0]) / (t[-1] - t[0])


def softmax_over_real(s, mask) -> np.ndarray:
    """exp(s_k − max) / Σ exp(s_j − max) over the real goals; 0 on padded slots."""
    real = [k for k in range(G_MAX) if mask[k]]
    top = max(s[k] for k in real)
    e = {k: math.exp(s[k] - top) for k in real}
    z = sum(e.values())
    out = np.zeros(G_MAX)
    for k in real:
        out[k] = e[k] / z
    return out


def dragan(xyz, goals, mask, beta=5.0, t=None) -> np.ndarray:
    """:ref:`concepts-dragan`: y_k = ∫ P_k(t)(1 − t) dt / ∫ (1 − t) dt by the trapezoid rule."""
    xyz, goals = np.asarray(xyz, np.float64), np.asarray(goals, np.float64)
    T = len(xyz)
    tau = _times(T, t)
    start = xyz[0]
    P = np.zeros((T, G_MAX))
    for i in range(T):
        s = np.zeros(G_MAX)
        for k in range(G_MAX):
            s[k] = beta * (_norm(start - goals[k]) - _norm(xyz[i] - goals[k]))
        P[i] = softmax_over_real(s, mask)
    num = np.zeros(G_MAX)
    den = 0.0
    for i in range(T - 1):
        dt = tau[i + 1] - tau[i]
        num += dt * (P[i] * (1 - tau[i]) + P[i + 1] * (1 - tau[i + 1])) / 2
        den += dt * ((1 - tau[i]) + (1 - tau[i + 1])) / 2
    return num / den


def effdist(xyz, goals, mask, beta=5.0, t=None) -> np.ndarray:
    """:ref:`concepts-effdist`: s_k = −β (1/T) Σ_i d_k(i); with time stamps a time-weighted mean.

    With stamps, sample i stands for the interval between the midpoints to its
    neighbours; the ends get a mirrored neighbour (t_{−1} = 2t₀ − t₁,
    t_T = 2t_{T−1} − t_{T−2}).
    """
    xyz, goals = np.asarray(xyz, np.float64), np.asarray(goals, np.float64)
    T = len(xyz)
    if t is None:
        weight = [1.0 / T] * T
    else:
        tau = _times(T, t)
        ext = [2 * tau[0] - tau[1], *tau, 2 * tau[-1] - tau[-2]]
        cells = [(ext[i + 2] - ext[i]) / 2 for i in range(T)]
        weight = [c / sum(cells) for c in cells]
    s = np.zeros(G_MAX)
    for k in range(G_MAX):
        s[k] = -beta * sum(weight[i] * _norm(xyz[i] - goals[k]) for i in range(T))
    return softmax_over_real(s, mask)


def fastapp(xyz, goals, mask, beta=5.0, t=None) -> np.ndarray:
    """:ref:`concepts-fastapp`: s_k = β Σ_i w_i a_k(i) / Σ_i w_i Δt_i, w_i = 1 − t_i, a_k(i) =
    d_k(i−1) − d_k(i).

    T = 2 makes the ratio 0/0; the implementation's documented limit (the single
    approach speed a_k(1)/Δt) is used there.
    """
    xyz, goals = np.asarray(xyz, np.float64), np.asarray(goals, np.float64)
    T = len(xyz)
    tau = _times(T, t)
    s = np.zeros(G_MAX)
    for k in range(G_MAX):
        d = [_norm(xyz[i] - goals[k]) for i in range(T)]
        if T == 2:
            s[k] = beta * (d[0] - d[1]) / (tau[1] - tau[0])
            continue
        num = sum((1 - tau[i]) * (d[i - 1] - d[i]) for i in range(1, T))
        den = sum((1 - tau[i]) * (tau[i] - tau[i - 1]) for i in range(1, T))
        s[k] = beta * num / den
    return softmax_over_real(s, mask)


def project(p, cam_pos, cam_xmat) -> tuple[np.ndarray, float]:
    """Pinhole projection, MuJoCo convention: the camera looks along its −z axis.

    ``cam_xmat`` is world-from-camera (columns = camera axes in world coordinates),
    as MuJoCo's ``data.cam_xmat``. Returns (u, v) and the depth −p_c.z.
    """
    R = np.asarray(cam_xmat, np.float64).reshape(3, 3)
    rel = np.asarray(p, np.float64) - np.asarray(cam_pos, np.float64)
    pc = [sum(R[r, c] * rel[r] for r in range(3)) for c in range(3)]  # Rᵀ (p − c)
    depth = -pc[2]
    return np.array([pc[0] / depth, pc[1] / depth]), depth


def nikolaidis(xyz, goals, mask, cam_pos, cam_xmat, beta=7.5, t=None) -> np.ndarray:
    """:ref:`concepts-cameras`: Dragan legibility of the projected points and goals."""
    pts, gs = [], []
    for p in np.asarray(xyz, np.float64):
        uv, depth = project(p, cam_pos, cam_xmat)
        assert depth > 1e-6, "point behind the camera"
        pts.append(uv)
    for k, g in enumerate(np.asarray(goals, np.float64)):
        uv, depth = project(g, cam_pos, cam_xmat)
        assert depth > 1e-6 or not mask[k], "goal behind the camera"
        gs.append(uv if depth > 1e-6 else np.zeros(2))
    return dragan(np.array(pts), np.array(gs), mask, beta=beta, t=t)


def dragan_author_form(xyz, goals, mask, velocity) -> np.ndarray:
    """Dragan legibility the way the first author's public numpy code frames it.

    V(x → g) is the cost ∫‖v‖² dt of the straight constant-speed path at speed
    ``velocity``, integrated with the trapezoid rule from the finite-difference
    velocity at its two ends (v at the start, 0 at the end): V = v² · (L/v) / 2.
    P(g | S → p_i) ∝ exp(V(S → g) − V(p_i → g) − C(S → p_i)) with the cost so far
    C; the label is the (1 − t)-weighted trapezoid average of P over the path.
    :ref:`concepts-dragan` says this equals :func:`dragan` with β = velocity / 2.
    """
    xyz, goals = np.asarray(xyz, np.float64), np.asarray(goals, np.float64)
    T = len(xyz)
    t = np.linspace(0.0, 1.0, T)

    def straight_cost(a, b):
        duration = _norm(b - a) / velocity
        return duration * (velocity**2 + 0.0**2) / 2  # trapezoid of speed²: v at start, 0 at end

    # Cost so far: finite-difference speed² of the path itself, cumulative trapezoid.
    speed2 = [
        float(np.sum(((xyz[i + 1] - xyz[i]) / (t[i + 1] - t[i])) ** 2)) for i in range(T - 1)
    ] + [0.0]
    cost_so_far = [0.0]
    for i in range(T - 1):
        cost_so_far.append(cost_so_far[-1] + (t[i + 1] - t[i]) * (speed2[i] + speed2[i + 1]) / 2)

    P = np.zeros((T, G_MAX))
    for i in range(T):
        logit = np.full(G_MAX, -np.inf)
        for k in range(G_MAX):
            if mask[k]:
                logit[k] = (
                    straight_cost(xyz[0], goals[k])
                    - straight_cost(xyz[i], goals[k])
                    - cost_so_far[i]
                )
        e = np.where(mask, np.exp(logit - np.max(logit)), 0.0)
        P[i] = e / e.sum()
    scale = 1.0 - t
    num = sum(
        (t[i + 1] - t[i]) * (P[i] * scale[i] + P[i + 1] * scale[i + 1]) / 2 for i in range(T - 1)
    )
    den = sum((t[i + 1] - t[i]) * (scale[i] + scale[i + 1]) / 2 for i in range(T - 1))
    return num / den
