"""Checks that can refuse a timed trajectory, densely along it (every 1 kHz sample).

- :func:`limit_checks`: every joint limit (position, velocity, acceleration, jerk) and the
  Cartesian limits of the TCP (speed, acceleration and jerk of its translation and rotation),
  by backward differences of the 1 kHz samples, as the robot takes them, with the motion
  at rest before and after; against the robot's published limits (unscaled).
- :func:`collision_check`: self-collision and collision with the two tables and the cubes,
  from MuJoCo C's contacts on the Panda's collision shapes
  (:func:`slotv_jax.execution.models.collision_model`).
  The hand may touch the target cube (the cube it grasps, gripper open); everything else
  counts. Contacts are computed at a subset of the samples, and every sample in between is
  certified by a swept-distance bound: between samples k and i no point of the arm moves
  farther than C_i − C_k, with C the running sum of ``Σ_j R_j |Δq_j|`` (R_j: the largest distance
  of a collision shape from joint j's axis, over all configurations, by the triangle
  inequality along the chain), so two shapes at clearance c at sample k stay apart while
  2 (C_i − C_k) < c. The next sample checked is the first one not certified, so a collision
  at any sample is found, and at the first one. The checks fall densely where the arm comes
  near something (a tenth of the samples in all, on the recorded plans), and the least
  clearance among them was within 6 µm of the least over every sample on the 54 recorded
  plans compared. Checking every sample instead costs 4.5× the time
  (``experiments/BENCHMARKS.md``); refining every stretch whose bound falls below the least
  clearance found, for the exact minimum, computed 67 % of the samples instead of 10 %.
- :func:`dynamics_check`: MuJoCo physics of the Panda (its published inertials) tracking the
  trajectory at 1 kHz under a joint impedance controller with inverse-dynamics feedforward
  (:func:`slotv_jax.execution.models.dynamics_model`): the commanded joint torques and their
  rate against the limits, and the tracking error of the joints and the TCP.

Each returns what it measured and the first problem it found (``(t, line)`` or None);
:func:`run_checks` runs all three and names the earliest.
"""

from __future__ import annotations

import dataclasses
import functools

import mujoco
import numpy as np
from jaxtyping import Bool, Float
from mujoco import rollout

from slotv_jax.execution.limits import Limits
from slotv_jax.execution.models import (
    CLEARANCE_HORIZON,
    DAMPING,
    DT,
    STIFFNESS,
    collision_model,
    dynamics_model,
    grasp,
)
from slotv_jax.execution.timing import Trajectory, backward_differences

__all__ = [
    "Checks",
    "collision_check",
    "dynamics_check",
    "goal_label",
    "limit_checks",
    "run_checks",
]

AWAY = np.array([0.0, 0.0, -100.0])  # m: where cubes that hold no goal are put, out of reach
Problem = tuple[float, str] | None  # (time (s), one line) of the first problem, or none


@dataclasses.dataclass(frozen=True)
class Checks:
    """What the checks measured on one trajectory, and the first problem (if any)."""

    peak_dq: np.ndarray  # (7,) rad/s: largest |velocity| per joint (1 kHz differences)
    peak_ddq: np.ndarray  # (7,) rad/s²
    peak_dddq: np.ndarray  # (7,) rad/s³
    peak_translation: tuple[float, float, float]  # TCP: m/s, m/s², m/s³
    peak_rotation: tuple[float, float, float]  # TCP: rad/s, rad/s², rad/s³
    clearance: float  # m: least distance between shapes that may not touch, at the samples checked
    clearance_pair: str  # the two shapes at the least clearance ("" beyond the horizon)
    contact_samples: int  # samples whose contacts were computed
    tracking: np.ndarray  # (7,) rad: largest |q_simulated − q_commanded| per joint
    tcp_tracking: float  # m: largest distance between the simulated and commanded TCP
    peak_tau: np.ndarray  # (7,) N m: largest |commanded torque| per joint
    peak_dtau: np.ndarray  # (7,) N m/s: largest |torque rate| per joint
    problem: str | None  # the earliest problem's line, or None: the robot may run it


# ------------------------------------------------------------------ limits


def _first_excess(values: np.ndarray, limit: np.ndarray) -> tuple[int, int] | None:
    """(sample, column) of the first |value| above its limit, or None."""
    over = np.abs(values) > limit
    if not over.any():
        return None
    k = int(np.argmax(over.any(axis=1)))
    return k, int(np.argmax(over[k]))


def _angular_velocity(rot: Float[np.ndarray, "N 3 3"]) -> np.ndarray:
    """World-frame angular velocity (N − 1, 3) (rad/s) between consecutive rotations."""
    rel = np.einsum("nij,nkj->nik", rot[1:], rot[:-1])  # R_{k+1} R_kᵀ
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                     rel[:, 1, 0] - rel[:, 0, 1]], axis=1)  # fmt: skip
    sin = np.sin(angle)
    scale = np.where(sin > 1e-12, angle / (2.0 * np.maximum(sin, 1e-12)), 0.5)
    return axis * scale[:, None] / DT


def limit_checks(traj: Trajectory, limits: Limits) -> tuple[dict, Problem]:
    """Peaks of every limited quantity and the first sample beyond a published limit.

    Positions must lie strictly inside [q_min, q_max] (the robot's condition is strict).
    Times are those of the samples (a difference's time: its later sample).
    """
    q = traj.q
    d1, d2, d3 = backward_differences(q)
    lead = 3  # samples of rest before the motion in the differences (time of d[k]: k − lead)
    peaks = {"peak_dq": np.abs(d1).max(0), "peak_ddq": np.abs(d2).max(0),
             "peak_dddq": np.abs(d3).max(0)}  # fmt: skip
    first: list[tuple[float, str]] = []
    low, high = q <= limits.q_min, q >= limits.q_max
    if (low | high).any():
        k = int(np.argmax((low | high).any(axis=1)))
        j = int(np.argmax((low | high)[k]))
        edge = limits.q_min[j] if low[k, j] else limits.q_max[j]
        first.append((traj.t[k], f"joint {j + 1} position {q[k, j]:.4f} rad reaches its limit "
                      f"{edge:.4f} rad"))  # fmt: skip
    unit = {"velocity": "rad/s", "acceleration": "rad/s²", "jerk": "rad/s³"}
    for name, d, lim, n in (("velocity", d1, limits.dq_max, 1), ("acceleration", d2,
                            limits.ddq_max, 2), ("jerk", d3, limits.dddq_max, 3)):  # fmt: skip
        hit = _first_excess(d, lim)
        if hit:
            k, j = hit
            t = (k + n - lead) * DT
            first.append((t, f"joint {j + 1} {name} {abs(d[k, j]):.4g} {unit[name]} exceeds "
                          f"its limit {lim[j]:.4g} {unit[name]}"))  # fmt: skip
    # the TCP: translation and rotation, each as the norm of its vector
    p1, p2, p3 = backward_differences(traj.tcp)
    w1 = _angular_velocity(np.concatenate([traj.tcp_rot[:1]] * 3 + [traj.tcp_rot]
                                          + [traj.tcp_rot[-1:]] * 3))  # fmt: skip
    w2 = np.diff(w1, axis=0) / DT
    w3 = np.diff(w2, axis=0) / DT
    cart = {"translation": [np.linalg.norm(x, axis=1) for x in (p1, p2, p3)],
            "rotation": [np.linalg.norm(x, axis=1) for x in (w1, w2, w3)]}  # fmt: skip
    units = {"translation": ("m/s", "m/s²", "m/s³"), "rotation": ("rad/s", "rad/s²", "rad/s³")}
    for kind, series in cart.items():
        peaks[f"peak_{kind}"] = tuple(float(x.max()) for x in series)
        named = zip(series, getattr(limits, kind), ("speed", "acceleration", "jerk"), strict=True)
        for n, (x, lim, what) in enumerate(named):
            over = np.flatnonzero(x > lim)
            if len(over):
                k, unit = int(over[0]), units[kind][n]
                line = f"TCP {kind} {what} {x[k]:.4g} {unit} exceeds its limit {lim:.4g} {unit}"
                first.append(((k + n + 1 - lead) * DT, line))
    return peaks, min(first, default=None)


# ------------------------------------------------------------------ collisions


@functools.cache
def _sweep_radii() -> np.ndarray:
    """R_j (7,): a bound on the distance of any collision shape moved by joint j from its
    axis, over all configurations (the chain's offsets, the shape's offset and its bounding
    radius, added up by the triangle inequality)."""
    m = collision_model()
    robot = m.geom_contype > 0
    radii = np.zeros(m.njnt)
    for j in range(m.njnt):
        root = m.jnt_bodyid[j]
        for g in np.flatnonzero(robot):
            b, chain = m.geom_bodyid[g], 0.0
            while b not in (root, 0):
                chain += np.linalg.norm(m.body_pos[b])
                b = m.body_parentid[b]
            if b == root:
                reach = chain + np.linalg.norm(m.jnt_pos[j]) + np.linalg.norm(m.geom_pos[g])
                radii[j] = max(radii[j], reach + m.geom_rbound[g])
    return radii


def goal_label(slot: int) -> str:
    """The label a study shows for goal slot ``slot``: A, B, C, ..."""
    return chr(ord("A") + int(slot))


def _names(m: mujoco.MjModel) -> list[str]:
    """Readable names of the collision model's geoms: ``link3``, ``hand``, ``finger_left``,
    ``goal_table``, ``cube 2 (goal C)``."""
    out = []
    for g in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g])
        if name and name.startswith("c_"):
            out.append(name[2:])
        elif body and body.startswith("cube"):
            out.append(f"cube {body[4:]} (goal {goal_label(int(body[4:]))})")
        else:
            out.append(name or body)
    return out


class _Contacts:
    """The collision model set up for one scene: the clearance of one configuration."""

    def __init__(self, goals, goal_mask, target: int | None):
        m = grasp(collision_model(), target)
        self.m, self.d = m, mujoco.MjData(m)
        pos = np.tile(AWAY, (m.nmocap, 1))
        mask = np.asarray(goal_mask, bool)
        pos[: len(mask)][mask] = np.asarray(goals, np.float64)[mask]
        self.d.mocap_pos[:] = pos
        self.names = _names(m)

    def clearance(self, q: np.ndarray) -> tuple[float, int, int]:
        """(least distance, geom1, geom2) at configuration ``q``; (horizon, −1, −1) if no
        two shapes are nearer than :data:`CLEARANCE_HORIZON`."""
        m, d = self.m, self.d
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if d.ncon:
            c = d.contact
            dist = c.dist
            i = int(dist.argmin())
            if dist[i] < CLEARANCE_HORIZON:
                return float(dist[i]), int(c.geom1[i]), int(c.geom2[i])
        return CLEARANCE_HORIZON, -1, -1

    def pair(self, g1: int, g2: int) -> str:
        """``hand with cube 2 (goal C)``: the robot's part first ("" for no pair)."""
        if g1 < 0:
            return ""
        if self.m.geom_contype[g1] == 0:  # the world's
            g1, g2 = g2, g1
        return f"{self.names[g1]} with {self.names[g2]}"


def collision_check(
    traj: Trajectory,
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    target: int | None,
) -> tuple[dict, Problem]:
    """Least clearance (at the samples checked), its pair, the samples checked, and the
    first collision (see the module docstring)."""
    con = _Contacts(goals, goal_mask, target)
    q = traj.q
    step = np.abs(np.diff(q, axis=0)) @ _sweep_radii()
    C = np.concatenate([[0.0], np.cumsum(step)])  # bound on any point's travel since the start
    n = len(q)
    seen: dict[int, tuple[float, int, int]] = {}

    def at(k):
        if k not in seen:
            seen[k] = con.clearance(q[k])
        return seen[k]

    k, checks = 0, []
    while True:
        c, g1, g2 = at(k)
        if c < 0.0:  # every earlier sample is certified clear: the first collision
            line = f"collision: {con.pair(g1, g2)}"
            return _clearance(seen, con), (traj.t[k], line)
        checks.append(k)
        if k == n - 1:
            break
        nxt = int(np.searchsorted(C, C[k] + c / 2.0, side="left"))  # first uncertified sample
        k = min(max(nxt, k + 1), n - 1)  # ... and the last sample, always
    return _clearance(seen, con), None


def _clearance(seen: dict, con: _Contacts) -> dict:
    c, g1, g2 = min(seen.values())
    return {"clearance": c, "clearance_pair": con.pair(g1, g2), "contact_samples": len(seen)}


# ------------------------------------------------------------------ dynamics


def _feedforward(q, dq, ddq) -> np.ndarray:
    """Inverse dynamics τ = M(q) q̈ + c(q, q̇) + g(q) (N, 7) by MuJoCo C's ``mj_inverse``
    (the controller's damping taken out: it is the controller's, not the arm's)."""
    m = dynamics_model()
    d = mujoco.MjData(m)
    out = np.empty_like(q)
    qpos, qvel, qacc, res, inv = d.qpos, d.qvel, d.qacc, d.qfrc_inverse, mujoco.mj_inverse
    for k in range(len(q)):
        qpos[:], qvel[:], qacc[:] = q[k], dq[k], ddq[k]
        inv(m, d)
        out[k] = res
    return out - DAMPING * dq  # mj_inverse counted the controller's damping as the arm's


def dynamics_check(traj: Trajectory, limits: Limits) -> tuple[dict, Problem]:
    """Simulate the arm tracking ``traj`` (see the module docstring): tracking errors, peak
    commanded torque and torque rate, and the first torque or torque-rate excess."""
    m = dynamics_model()
    d = mujoco.MjData(m)
    qd, dqd = traj.q, traj.dq
    ff = _feedforward(qd, dqd, traj.ddq)
    ctrl = qd + (DAMPING * dqd + ff) / STIFFNESS
    d.qpos[:] = qd[0]
    d.qvel[:] = 0.0
    state0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states, sensors = rollout.rollout(m, d, state0[None], ctrl[None, :-1])
    nq = m.nq
    q = np.concatenate([qd[:1], states[0, :, 1 : 1 + nq]])  # state k + 1: after step k
    dq = np.concatenate([np.zeros((1, nq)), states[0, :, 1 + nq : 1 + 2 * nq]])
    tcp = sensors[0]  # sensors of step k: the state before it
    tau = STIFFNESS * (qd - q) + DAMPING * (dqd - dq) + ff
    dtau = np.diff(tau, axis=0) / DT
    out = {
        "tracking": np.abs(q - qd).max(0),
        "tcp_tracking": float(np.linalg.norm(tcp - traj.tcp[:-1], axis=1).max()),
        "peak_tau": np.abs(tau).max(0),
        "peak_dtau": np.abs(dtau).max(0) if len(dtau) else np.zeros(nq),
    }
    first = []
    hit = _first_excess(tau, limits.tau_max)
    if hit:
        k, j = hit
        first.append((traj.t[k], f"joint {j + 1} torque {abs(tau[k, j]):.4g} N m exceeds its "
                      f"limit {limits.tau_max[j]:.4g} N m (simulated)"))  # fmt: skip
    hit = _first_excess(dtau, limits.dtau_max)
    if hit:
        k, j = hit
        first.append((traj.t[k + 1], f"joint {j + 1} torque rate {abs(dtau[k, j]):.4g} N m/s "
                      f"exceeds its limit {limits.dtau_max[j]:.4g} N m/s (simulated)"))  # fmt: skip
    return out, min(first, default=None)


# ------------------------------------------------------------------ all


def run_checks(
    traj: Trajectory,
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    target: int | None,
) -> Checks:
    """All three checks on ``traj`` against its robot's published limits; ``problem`` is
    the earliest problem as one line, ``t = 1.234 s: ...``."""
    limits = traj.config.limits
    peaks, p1 = limit_checks(traj, limits)
    clear, p2 = collision_check(traj, goals, goal_mask, target)
    dyn, p3 = dynamics_check(traj, limits)
    found = [p for p in (p1, p2, p3) if p is not None]
    problem = None
    if found:
        t, line = min(found, key=lambda p: p[0])
        problem = f"t = {t:.3f} s: {line}"
    return Checks(**peaks, **clear, **dyn, problem=problem)
