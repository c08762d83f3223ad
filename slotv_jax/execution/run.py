"""A plan, timed and checked: :func:`execute` is the whole of :mod:`slotv_jax.execution` on one
plan, and :func:`summary` is what a report keeps of it.

>>> e = execute(plans["q"][k, p], plans["goals"][p], plans["goal_mask"][p],
...             int(plans["target"][p]))                                   # doctest: +SKIP
>>> e.refusal or f"{e.trajectory.duration:.2f} s"                          # doctest: +SKIP
'2.71 s'
"""

from __future__ import annotations

import dataclasses

import numpy as np
from jaxtyping import Bool, Float

from slotv_jax.execution.checks import Checks, run_checks
from slotv_jax.execution.models import CLEARANCE_HORIZON
from slotv_jax.execution.refusal import Refused
from slotv_jax.execution.timing import TimingConfig, Trajectory, time_plan

__all__ = ["Execution", "execute", "summary"]


@dataclasses.dataclass(frozen=True, eq=False)
class Execution:
    """One plan timed and checked. ``refusal`` is None when the robot may run it."""

    trajectory: Trajectory | None  # None: no timing was found (``refusal`` says why)
    checks: Checks | None  # None: not timed, so not checked
    refusal: str | None  # one line: the first time and the joint and limit, or the pair

    @property
    def ok(self) -> bool:
        return self.refusal is None


def execute(
    q: Float[np.ndarray, "P 7"],
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    target: int | None,
    config: TimingConfig = TimingConfig(),
) -> Execution:
    """Time the plan ``q`` (:func:`slotv_jax.execution.timing.time_plan`) and check it in its
    scene (:func:`slotv_jax.execution.checks.run_checks`; ``target``: the goal slot the hand
    grasps, None if unknown). A plan that is no plan (NaN, outside the joint limits) raises
    ValueError; one the robot would not run comes back with its ``refusal``."""
    try:
        traj = time_plan(q, config)
    except Refused as e:
        return Execution(None, None, str(e))
    checks = run_checks(traj, goals, goal_mask, target)
    return Execution(traj, checks, checks.problem)


def _round(x, digits: int = 4):
    return [round(float(v), digits) for v in np.ravel(x)] if np.ndim(x) else round(float(x), digits)


def summary(e: Execution) -> dict:
    """What a report keeps of one execution (JSON): the duration (s), each peak as a fraction
    of its published limit (the largest over the joints, and per joint), the least clearance
    (m; ``null`` beyond the contact horizon) and its pair, the largest TCP deviation from the
    planned path (m), the tracking errors (rad, m) and the peak torque and torque rate
    (fractions), the timing's rounds and window (samples), and the refusal."""
    out: dict = {"ok": e.ok, "refusal": e.refusal}
    t, c = e.trajectory, e.checks
    if t is None or c is None:
        return out
    lim = t.config.limits
    fr = {
        "dq": c.peak_dq / lim.dq_max,
        "ddq": c.peak_ddq / lim.ddq_max,
        "dddq": c.peak_dddq / lim.dddq_max,
        "tau": c.peak_tau / lim.tau_max,
        "dtau": c.peak_dtau / lim.dtau_max,
    }
    out.update(
        duration=_round(t.duration, 3),
        topp_duration=_round(t.topp_duration, 3),
        window=t.window,
        rounds=t.rounds,
        **{f"peak_{k}": _round(v.max()) for k, v in fr.items()},
        **{f"peak_{k}_joints": _round(v) for k, v in fr.items()},
        peak_tcp_speed=_round(c.peak_translation[0] / lim.translation[0]),
        clearance=None if c.clearance >= CLEARANCE_HORIZON else _round(c.clearance, 5),
        clearance_pair=c.clearance_pair,
        contact_samples=c.contact_samples,
        samples=len(t.t),
        deviation=_round(t.deviation.max(), 6),
        tracking=_round(c.tracking.max(), 6),
        tcp_tracking=_round(c.tcp_tracking, 6),
    )
    return out
