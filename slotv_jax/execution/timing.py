"""Time a plan's path: time-optimal under the scaled limits, jerk bounded, at rest at both ends.

The path is fixed (:mod:`slotv_jax.execution.path`); only the time law s(t) is chosen.

1. **TOPP-RA** (Pham & Pham, "A New Approach to Time-Optimal Path Parameterization Based on
   Reachability Analysis", IEEE T-RO 34(3), 2018; the ``toppra`` package) gives the fastest
   path velocity ṡ(s) on a grid (the spline's knots and the midpoints between them) under::

       |q′_j(s) ṡ| ≤ σ(s) v_j,   |q′_j(s) s̈ + q″_j(s) ṡ²| ≤ σ(s)² a_j,   ṡ(0) = ṡ(end) = 0,

   with v, a the joint velocity and acceleration limits times the speed scale, and σ ≤ 1 a
   factor per grid point that starts at 0.99 (step 3); and ṡ is capped where the path's own
   jerk term would exceed 0.9 of the jerk bound j (step 2): ``|q‴_j(s)| ṡ³ ≤ 0.9 j_j`` (the
   spline's q‴ is constant on each interval). Between grid points s̈ is constant
   (toppra's ``ParametrizeConstAccel``); this module samples that law at 1 kHz.
2. **Jerk.** TOPP-RA's s̈ jumps (bang-bang), so the joint jerk is unbounded. The sampled
   s(t) is averaged over a sliding window of w samples (at rest before the start and after
   the end). The average of a piecewise-constant s̈ is continuous and piecewise linear, so
   the jerk of s is at most 2 max|s̈| / (w Δt), and the path stays the same (only s(t)
   changes). The jerk bound j_i of joint i is the scaled jerk limit, or less where the arm's
   torque rate binds: following the motion takes τ = M(q) q̈ + …, so τ̇_i ≈ Σ_j M_ij q⃛_j,
   and j_i = 0.9 τ̇_max,i / max_q ``Σ_j |M_ij|`` (M at the plan's configurations; 180–320 rad/s³
   on joints 1–4 of the Panda) keeps Franka's torque-rate limit (1000 N m/s) with 10 % for
   gravity, Coriolis and feedback. The window is at least ``⌈2 max_{i,t} |q′_i s̈| / j_i / Δt⌉``
   samples for the s̈ TOPP-RA takes: the least that keeps a full swing of those
   accelerations within j_i.
3. **Verify, and adjust.** The backward differences of the 1 kHz samples (as the robot takes
   them) must stay within the scaled velocity and acceleration limits and the jerk bound.
   Averaging near a sharp bend and TOPP-RA's discretisation can overshoot; then σ is lowered
   where it did, over the stretch the window mixes, once per round by 0.98/r with r the
   largest of the velocity's ratio to its limit, the acceleration's square root and the
   cube root of a jerk of the path's own terms (q‴ ṡ³ + 3 q″ ṡ s̈): slowing the motion by σ
   scales them by σ, σ² and σ³, so the least of the three factors corrects all three (their
   product, lowering σ for each limit in turn, made full-speed timings up to 2.4 times the
   time-optimal duration). A jerk mostly of the smoothing's term (q′ s⃛) widens the window
   instead (w ← ⌈1.05 r w⌉). The timing is computed again, at most ``rounds`` times, then the
   plan is refused.
4. **The path as planned.** The TCP at every 1 kHz sample must lie within ``deviation``
   (1 mm) of the planned path; where it does not, the path is refined there
   (:func:`slotv_jax.execution.path.refine`; the deviation about halves with each split, so
   a stretch d away is split ⌈log₂(d / 1 mm)⌉ times, at most 4 at once) and timed again,
   at most ``refinements`` times.

The result, :class:`Trajectory`, holds the 1 kHz samples with one sample at rest before the
motion and one after (so that the central differences at both ends are 0), the time at which
the robot passes each of the plan's configurations (``knot_times``, for clips at the robot's
speed) and the 1 kHz TCP poses.

>>> traj = time_plan(plan_q)                                   # doctest: +SKIP
>>> traj.duration, traj.at_rate(100)[0][:3]                    # doctest: +SKIP
(2.716, array([0.  , 0.01, 0.02]))
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Float

from slotv_jax.execution.limits import DEFAULT_SPEED, ROBOTS, Limits, check_speed
from slotv_jax.execution.models import DT, RATE, mass_matrices, tcp_poses
from slotv_jax.execution.path import JointPath, deviation, make_path, refine
from slotv_jax.execution.refusal import Refused
from slotv_jax.robot import kinematics

__all__ = [
    "LIMIT_TOL",
    "TimingConfig",
    "Trajectory",
    "backward_differences",
    "check_plan",
    "time_path",
    "time_plan",
]

LIMIT_TOL = 1e-6  # rad: a plan may touch a position limit by float32 rounding


@dataclasses.dataclass(frozen=True)
class TimingConfig:
    """How a plan is timed (see the module docstring)."""

    speed: float = DEFAULT_SPEED  # scale of the velocity, acceleration and jerk limits
    robot: str = "fer"  # "fer" (Panda) or "fr3": whose limits (limits.ROBOTS)
    deviation: float = 1e-3  # m: the TCP's largest distance from the planned path
    refinements: int = 4  # times the path may be refined where it strays
    rounds: int = 12  # timings tried per path before the plan is refused
    grid: int = 2  # TOPP-RA grid points per spline interval

    def __post_init__(self):
        check_speed(self.speed)
        if self.robot not in ROBOTS:
            raise ValueError(f"robot: expected one of {sorted(ROBOTS)}, got {self.robot!r}")
        if not self.deviation > 0:
            raise ValueError(f"deviation: expected metres > 0, got {self.deviation!r}")
        for f in ("refinements", "rounds", "grid"):
            least = int(f != "refinements")
            if not (isinstance(getattr(self, f), int) and getattr(self, f) >= least):
                raise ValueError(f"{f}: expected an integer >= {least}, got {getattr(self, f)!r}")

    @property
    def limits(self) -> Limits:
        """The robot's published limits (unscaled)."""
        return ROBOTS[self.robot]


@dataclasses.dataclass(frozen=True, eq=False)
class Trajectory:
    """A timed joint trajectory, sampled at 1 kHz (``DT``), at rest at both ends."""

    t: np.ndarray  # (N,) s: k / 1000
    q: np.ndarray  # (N, 7) rad
    dq: np.ndarray  # (N, 7) rad/s: central differences (0 at both ends)
    ddq: np.ndarray  # (N, 7) rad/s²: central differences (0 at both ends)
    s: np.ndarray  # (N,) the path parameter of each sample
    tcp: np.ndarray  # (N, 3) m: TCP positions
    tcp_rot: np.ndarray  # (N, 3, 3): world-from-tool rotations
    deviation: np.ndarray  # (N,) m: each TCP's distance from the planned path
    knot_times: np.ndarray  # (P,) s: when the robot passes the plan's configurations
    path: JointPath
    config: TimingConfig
    topp_duration: float  # s: TOPP-RA's time-optimal duration (last round), before smoothing
    window: int  # samples of the smoothing window
    margin: float  # the least σ of the limits TOPP-RA was given (last round)
    rounds: int  # timings computed (all refinements together)

    @property
    def duration(self) -> float:
        """Seconds from the first sample to the last."""
        return float(self.t[-1])

    def at_rate(self, rate: int) -> tuple[np.ndarray, ...]:
        """``(t, q, dq, ddq)`` at ``rate`` Hz, a divisor of 1000: every (1000 / rate)-th
        sample, the motion padded at rest to a whole number of periods."""
        step = rate_step(rate)
        n = len(self.t)
        m = -(-(n - 1) // step) * step + 1  # samples to the first period end at or after the end
        idx = np.arange(0, m, step)
        pick = np.minimum(idx, n - 1)
        q, dq, ddq = self.q[pick], self.dq[pick], self.ddq[pick]
        beyond = idx > n - 1  # at rest after the end
        dq[beyond], ddq[beyond] = 0.0, 0.0
        return idx / RATE, q, dq, ddq


def rate_step(rate) -> int:
    """Samples of 1 kHz per sample at ``rate`` Hz; ValueError unless ``rate`` divides 1000."""
    if isinstance(rate, bool) or not isinstance(rate, int | np.integer) or not 1 <= rate <= 1000:
        raise ValueError(f"rate: expected a whole number of Hz dividing 1000, got {rate!r}")
    if 1000 % rate:
        raise ValueError(f"rate: expected a divisor of 1000 Hz (the robot's 1 kHz), got {rate}")
    return 1000 // int(rate)


def check_plan(q, limits: Limits, what: str = "q") -> np.ndarray:
    """A plan's configurations as float64 (P, 7): ValueError naming ``what`` unless finite,
    at least two, and within ``limits``' positions (to :data:`LIMIT_TOL`)."""
    q = np.asarray(q)
    if q.ndim != 2 or q.shape[1] != kinematics.NQ or q.shape[0] < 2:
        raise ValueError(f"{what}: expected (P >= 2, 7) joint configurations, got {q.shape}")
    if q.dtype.kind not in "iuf":
        raise ValueError(f"{what}: expected real numbers, got dtype {q.dtype}")
    q = q.astype(np.float64)
    bad = ~np.isfinite(q)
    if bad.any():
        i = int(np.argwhere(bad)[0, 0])
        raise ValueError(f"{what}: configuration {i} is not finite (NaN or inf): no plan")
    below, above = q < limits.q_min - LIMIT_TOL, q > limits.q_max + LIMIT_TOL
    if (below | above).any():
        i, j = (int(v) for v in np.argwhere(below | above)[0])
        lim = limits.q_min[j] if below[i, j] else limits.q_max[j]
        raise ValueError(
            f"{what}: configuration {i}, joint {j + 1} at {q[i, j]:.4f} rad is outside the "
            f"{limits.name.upper()}'s limits [{limits.q_min[j]:.4f}, {limits.q_max[j]:.4f}] "
            f"(beyond {lim:.4f})"
        )
    return q


def backward_differences(x: Float[np.ndarray, "N D"], dt: float = DT, order: int = 3):
    """The first ``order`` backward differences of samples ``x`` (N, D), as the robot takes
    them at 1 kHz, with ``x`` at rest before its first and after its last sample: a list of
    (N + order, D) arrays, velocity first."""
    ext = np.concatenate([np.repeat(x[:1], order, 0), x, np.repeat(x[-1:], order, 0)])
    out, d = [], ext
    for _ in range(order):
        d = np.diff(d, axis=0) / dt
        out.append(d)
    return out


def _grid(path: JointPath, per: int) -> np.ndarray:
    """TOPP-RA's grid: ``per`` points per spline interval (the knots and between them)."""
    ks = path.knots_s
    f = np.arange(per) / per
    return np.concatenate([(ks[:-1, None] + f * np.diff(ks)[:, None]).ravel(), ks[-1:]])


def _sample(grid: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """s(t) at 1 kHz of the piecewise-constant-s̈ law through (grid, ṡ), ending at the end."""
    ds = np.diff(grid)
    vsum = sd[:-1] + sd[1:]
    if np.any(vsum <= 0):
        raise Refused("t = 0.000 s: TOPP-RA stops the path midway (ṡ = 0)", t=0.0,
                      check="timing")  # fmt: skip
    seg_t = 2.0 * ds / vsum
    u = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
    t_grid = np.concatenate([[0.0], np.cumsum(seg_t)])
    n = int(np.ceil(t_grid[-1] / DT - 1e-9))
    t = np.arange(n + 1) * DT
    k = np.clip(np.searchsorted(t_grid, t, side="right") - 1, 0, len(ds) - 1)
    tau = np.minimum(t - t_grid[k], seg_t[k])
    s = grid[k] + sd[k] * tau + 0.5 * u[k] * tau**2
    s = np.minimum(np.maximum.accumulate(s), grid[-1])
    s[-1] = grid[-1]
    return s


def _smooth(s: np.ndarray, w: int) -> np.ndarray:
    """The moving average of ``s`` over ``w`` samples, at rest before and after: a sequence
    from 0 to s_end, with one more sample at rest at each end."""
    end = s[-1]
    pad = np.concatenate([np.zeros(w), s, np.full(w, end)])
    c = np.concatenate([[0.0], np.cumsum(pad)])
    y = (c[w:] - c[:-w]) / w  # y[k] = mean(pad[k : k + w])
    first = np.argmax(y > 0.0)  # the window's first nonzero sample
    last = len(y) - np.argmax(y[::-1] < end)  # one past the window's last sample below the end
    y = np.maximum.accumulate(np.clip(y[first - 1 : last + 1], 0.0, end))
    y[:1], y[-1:] = 0.0, end
    return np.concatenate([[0.0], y, [end]])


def _per_sample(r: np.ndarray, shift: int, n: int) -> np.ndarray:
    """Ratios of differences (``backward_differences`` order 3 - ``shift``) per sample they
    end at (n,); those ending before the first or after the last sample go to that one."""
    out = np.zeros(n)
    np.maximum.at(out, np.clip(np.arange(len(r)) - shift, 0, n - 1), r)
    return out


def _excess(path: JointPath, s: np.ndarray, lim: Limits):
    """Per sample of ``s`` (1 kHz, N): how far the velocity, acceleration and jerk ending
    there (backward differences of q(s)) go beyond ``lim`` (the largest ratio over the
    joints), and the part of the jerk ratio that the smoothing window controls: the q′ s⃛
    term of q⃛ = q‴ ṡ³ + 3 q″ ṡ s̈ + q′ s⃛."""
    n = len(s)
    d1, d2, d3 = backward_differences(path(s))
    pairs = ((d1, lim.dq_max, 2), (d2, lim.ddq_max, 1), (d3, lim.dddq_max, 0))
    r = [_per_sample(np.max(np.abs(d) / m, axis=1), shift, n) for d, m, shift in pairs]
    s3 = backward_differences(s[:, None])[2][:n, 0]  # s⃛ ending at each sample
    window = np.max(np.abs(path(s, 1) * s3[:, None]) / lim.dddq_max, axis=1)
    return r, window


def _lower(scale, grid, s, ratio, w) -> None:
    """Lower σ in place where samples overshoot (``ratio`` > 1, in σ's own terms): by
    0.98 / ratio at both grid points around every sample the smoothing window mixes with
    them (± w)."""
    f = np.where(ratio > 1.0, 0.98 / np.maximum(ratio, 1.0), 1.0)
    if f.min() >= 1.0:
        return
    f = np.lib.stride_tricks.sliding_window_view(np.pad(f, w, constant_values=1.0),
                                                 2 * w + 1).min(axis=1)  # fmt: skip
    i = np.clip(np.searchsorted(grid, s, side="right") - 1, 0, len(grid) - 2)
    g = np.ones(len(grid))
    np.minimum.at(g, i, f)
    np.minimum.at(g, i + 1, f)
    scale *= g


TORQUE_RATE_SHARE = 0.9  # of Franka's torque-rate limit the jerk may use (step 2)
# σ's start (step 3): the moving average overshoots the velocity limit by 0.1-1.2 % on the
# recorded plans; starting 1 % under it spares a second round on 41 % of them and, the local
# lowering then being milder, ends 0.6 % faster on average (2.705 s against 2.722 s)
SIGMA_START = 0.99
# of the jerk bound the path's own term q‴ ṡ³ may take in TOPP-RA's speed cap (step 1); the
# rest is for 3 q″ ṡ s̈ and the smoothing's q′ s⃛. 0.9 measured best of 0.8, 0.9 and 1 at
# speed 1 on the recorded plans (experiments/execution.md, "Full speed")
PATH_JERK_SHARE = 0.9


def _jerk_cap(path: JointPath, grid: np.ndarray, jerk: np.ndarray) -> np.ndarray:
    """ṡ² on ``grid`` at which the path's own jerk term, q‴ ṡ³, is :data:`PATH_JERK_SHARE` of
    ``jerk`` (7,) (step 1). The spline's q‴ is constant on each interval; a grid point takes
    the larger of the intervals on its sides, so ṡ, which lies between its values at the
    grid points (ṡ² is linear in s between them), keeps the cap on every interval."""
    ks = path.knots_s
    per = np.abs(path.spline.cspl(0.5 * (ks[:-1] + ks[1:]), 3))  # (K − 1, 7) q‴ per interval
    right = np.clip(np.searchsorted(ks, grid, side="right") - 1, 0, len(ks) - 2)
    left = np.clip(np.searchsorted(ks, grid, side="left") - 1, 0, len(ks) - 2)
    d3 = np.maximum(per[right], per[left])
    with np.errstate(divide="ignore"):
        return np.min((PATH_JERK_SHARE * jerk / d3) ** (2.0 / 3.0), axis=1)


def _window(path: JointPath, raw: np.ndarray, jerk: np.ndarray) -> int:
    """The least smoothing window (samples) that keeps a full swing of the joint accelerations
    q′ s̈ that the TOPP-RA law ``raw`` (1 kHz s) takes, −a to +a, within ``jerk`` (7,)."""
    sdd = backward_differences(raw[:, None])[1][1 : len(raw) + 1, 0]  # s̈ ending at each sample
    need = np.max(np.abs(path(raw, 1) * sdd[:, None]) / jerk)
    return max(1, int(np.ceil(2.0 * need / DT - 1e-9)))


def _torque_rate_jerk(path: JointPath, limits: Limits) -> np.ndarray:
    """The jerk bound (7,) (rad/s³) of step 2: joint j's q⃛ within 0.9 τ̇_max,j /
    max_q Σ_i |M_ji|, with the Panda's inertials (``franka_assets/panda.xml``; the FR3 is
    taken to be alike)."""
    rows = np.abs(mass_matrices(path.plan_q)).sum(axis=2).max(axis=0)  # max_q Σ_i |M_ji|
    return TORQUE_RATE_SHARE * limits.dtau_max / rows


def time_path(path: JointPath, config: TimingConfig = TimingConfig()) -> Trajectory:
    """Steps 1-3 of the module docstring on ``path``; the TCP deviation is measured, not
    bounded (:func:`time_plan` bounds it). Raises :class:`Refused` when no timing within the
    scaled limits is found in ``config.rounds`` rounds."""
    lim = config.limits.scaled(config.speed)
    lim = dataclasses.replace(lim, dddq_max=np.minimum(lim.dddq_max, _torque_rate_jerk(path, lim)))
    w = 1  # the smoothing window: at least what each round's s̈ needs (_window), or widened
    grid = _grid(path, config.grid)
    from slotv_jax.execution import topp  # toppra (and SciPy, matplotlib) on first use

    vel, acc = topp.ScaledVelocity(lim.dq_max), topp.ScaledAcceleration(lim.ddq_max)
    scale = np.full(len(grid), SIGMA_START)
    vel.scale = acc.scale = scale  # σ: lowered in place where a round overshoots
    vel.cap = _jerk_cap(path, grid, lim.dddq_max)
    for r in range(1, config.rounds + 1):
        raw = _sample(grid, topp.topp(path, grid, [vel, acc]))
        w = max(w, _window(path, raw, lim.dddq_max))
        s = _smooth(raw, w)
        (rv, ra, rj), window = _excess(path, s, lim)
        worst = {"velocity": rv.max(), "acceleration": ra.max(), "jerk": rj.max()}
        if max(worst.values()) <= 1.0:
            return _trajectory(path, config, s, path(s), (len(raw) - 1) * DT, w,
                               float(scale.min()), r)  # fmt: skip
        smoothing = (rj > 1.0) & (window >= 0.5 * rj)  # jerk of the smoothing: widen it
        path_jerk = np.where(smoothing, 1.0, rj)  # the path's terms: ∝ σ³
        # velocity ∝ σ, acceleration ∝ σ², jerk ∝ σ³: one σ for all three, the least they need
        _lower(scale, grid, s, np.maximum.reduce([rv, np.sqrt(ra), np.cbrt(path_jerk)]), w)
        if smoothing.any():
            w = int(np.ceil(1.05 * w * rj[smoothing].max()))
    name = max(worst, key=worst.get)
    raise Refused(
        f"t = 0.000 s: no timing within the {config.speed:g}-scaled limits after "
        f"{config.rounds} rounds ({name} at {worst[name]:.3f} of its limit)",
        t=0.0, check="timing", limit=name, value=float(worst[name]),
    )  # fmt: skip


def _trajectory(path, config, s, q, topp_duration, w, margin, rounds) -> Trajectory:
    n = len(s)
    t = np.arange(n) / RATE  # the double nearest k / 1000: written back as such
    ext = np.concatenate([q[:1], q, q[-1:]])
    dq = (ext[2:] - ext[:-2]) / (2 * DT)
    ddq = (ext[2:] - 2 * ext[1:-1] + ext[:-2]) / DT**2
    tcp, rot = tcp_poses(q)
    dev, _ = deviation(path, s, tcp)
    moving = np.flatnonzero(np.diff(s) > 0)  # s[k] < s[k + 1]: s is strictly rising there
    rise_s = np.concatenate([s[moving], s[-1:]])
    rise_t = np.concatenate([t[moving], t[-1:]])
    knots = np.interp(path.plan_s, rise_s, rise_t)
    knots[0], knots[-1] = 0.0, t[-1]
    return Trajectory(t, q, dq, ddq, s, tcp, rot, dev, knots, path, config, topp_duration, w,
                      margin, rounds)  # fmt: skip


def time_plan(q: Float[np.ndarray, "P 7"], config: TimingConfig = TimingConfig()) -> Trajectory:
    """Time a plan's configurations ``q`` (rad): the whole module docstring.

    Raises ValueError for a plan that is not one (:func:`check_plan`: NaN, outside the
    robot's joint limits, fewer than two configurations, none moving) and :class:`Refused`
    when no timing keeps the limits or the TCP within ``config.deviation`` of the planned path.
    """
    q = check_plan(q, config.limits)
    path = make_path(q)
    rounds = 0
    for refinement in range(config.refinements + 1):
        traj = time_path(path, config)
        rounds += traj.rounds
        far = traj.deviation > config.deviation
        if not far.any():
            return dataclasses.replace(traj, rounds=rounds)
        if refinement < config.refinements:  # halving it as often as it is too far, there
            dev, seg = deviation(path, traj.s[far], traj.tcp[far])
            worst = np.zeros(len(path.levels))
            np.maximum.at(worst, seg, dev)
            hit = np.flatnonzero(worst)
            times = np.clip(np.ceil(np.log2(worst[hit] / config.deviation)), 1, 4).astype(int)
            path = refine(path, hit, times)
    k = int(np.argmax(far))
    worst = float(traj.deviation.max())
    raise Refused(
        f"t = {traj.t[k]:.3f} s: the tool leaves the planned path by {worst * 1e3:.2f} mm "
        f"(more than {config.deviation * 1e3:g} mm) after {config.refinements} refinements",
        t=float(traj.t[k]), check="path", value=worst, limit=config.deviation,
    )  # fmt: skip
