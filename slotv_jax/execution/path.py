"""The plan's path as a smooth joint path, and how far its tool strays from the planned one.

A plan is P joint configurations ``q_0 .. q_{P-1}`` (:ref:`concepts-trajectories`: 100, equally
spaced by the TCP's arc length). People judged the TCP path through them, so the path must stay as
planned; only its timing is new. The joint path is a C² cubic spline (SciPy's
``CubicSpline``, not-a-knot ends, through toppra's ``SplineInterpolator``) through the
configurations, parametrised by the cumulative joint-space chord length

    s_0 = 0,   s_{i+1} = s_i + ‖q_{i+1} − q_i‖   (rad),

which keeps the spline from overshooting where the steps between configurations change
length. Repeated configurations (a step under :data:`SAME_CONFIGURATION`) are dropped.

**Planned path and deviation.** Between two configurations the study's clips move the robot
along the straight joint-space line (:func:`slotv_jax.rendering.frames.resample`), so the
planned motion is the piecewise-straight joint path through the plan's configurations, and
the planned TCP path its image. It is taken as the polyline through the TCP points of the
spline's knots, all of which lie on that joint path: at first the plan's own configurations
(for the SPEC's plans, TCP points about 1 cm apart, where polyline and image differ by
micrometres), then points between them where the path is refined. A point of the spline at
parameter s deviates by its TCP's distance to the polyline's segment that holds s
(:func:`deviation`). Where that exceeds a tolerance (a sharp corner of the plan, or long
steps whose TCP arcs away from the chord), :func:`refine` splits that plan segment: knots are
added along the straight joint-space line, the spline hugs it closer, and the polyline follows
the planned image closer. A plan's own configurations keep their parameters s_i through every
refinement.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from jaxtyping import Float

from slotv_jax.execution.models import tcp_poses

if TYPE_CHECKING:
    from toppra import SplineInterpolator

__all__ = ["SAME_CONFIGURATION", "JointPath", "deviation", "make_path", "refine"]

SAME_CONFIGURATION = 1e-9  # rad: a step this short repeats the configuration (dropped)


@dataclasses.dataclass(frozen=True, eq=False)
class JointPath:
    """A cubic-spline joint path through a plan's configurations (see the module docstring)."""

    plan_q: np.ndarray  # (P, 7) the plan's distinct configurations (rad)
    plan_s: np.ndarray  # (P,) their path parameters (rad of joint-space chord)
    plan_xyz: np.ndarray  # (P, 3) their TCP positions (m)
    levels: np.ndarray  # (P − 1,) each plan segment is split into 2**level spline intervals
    knots_s: np.ndarray  # (K,) the spline's knots
    knots_q: np.ndarray  # (K, 7)
    knots_xyz: np.ndarray  # (K, 3) their TCP positions: the planned path's polyline (m)
    spline: SplineInterpolator  # q(s), with derivatives path(s, 1), path(s, 2)

    @property
    def length(self) -> float:
        """The last parameter s_{P−1} (rad)."""
        return float(self.plan_s[-1])

    def __call__(self, s, order: int = 0) -> np.ndarray:
        """q(s) (order 0), q'(s) or q''(s) at parameters ``s`` (N,) -> (N, 7)."""
        return self.spline(s, order)


def make_path(q: Float[np.ndarray, "P 7"], levels: np.ndarray | None = None) -> JointPath:
    """The joint path through the configurations ``q`` (rad), each plan segment split into
    ``2**levels[i]`` spline intervals (default: none split). Needs two distinct configurations."""
    q = np.asarray(q, np.float64)
    step = np.linalg.norm(np.diff(q, axis=0), axis=1)
    keep = np.concatenate([[True], step > SAME_CONFIGURATION])
    q = q[keep]
    if len(q) < 2:
        raise ValueError("q: the plan does not move (all its configurations are the same)")
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
    xyz, _ = tcp_poses(q)
    return _build(q, s, xyz, np.zeros(len(q) - 1, int) if levels is None else levels)


def _build(q, s, xyz, levels) -> JointPath:
    parts_s, parts_q = [s[:1]], [q[:1]]
    for i, lv in enumerate(levels):
        f = np.arange(1, 2**lv + 1) / 2**lv
        parts_s.append(s[i] + f * (s[i + 1] - s[i]))
        parts_q.append(q[i] + f[:, None] * (q[i + 1] - q[i]))
    ks, kq = np.concatenate(parts_s), np.concatenate(parts_q)
    levels = np.asarray(levels, int)
    kxyz = xyz if len(kq) == len(q) else tcp_poses(kq)[0]
    from toppra import SplineInterpolator  # SciPy's interpolation: loaded on first use

    return JointPath(q, s, xyz, levels, ks, kq, kxyz, SplineInterpolator(ks, kq))


def refine(path: JointPath, segments: np.ndarray, times: np.ndarray | None = None) -> JointPath:
    """``path`` with the plan segments ``segments`` (indices) and their neighbours split
    ``2**times`` times more finely (``times`` per segment, default 1; the deviation halves
    with each)."""
    times = np.ones(len(segments), int) if times is None else np.asarray(times, int)
    add = np.zeros(len(path.levels), int)
    for i, n in zip(segments, times, strict=True):
        lo, hi = max(i - 1, 0), i + 2
        add[lo:hi] = np.maximum(add[lo:hi], n)
    return _build(path.plan_q, path.plan_s, path.plan_xyz, path.levels + add)


def deviation(
    path: JointPath, s: Float[np.ndarray, " N"], tcp: Float[np.ndarray, "N 3"]
) -> tuple[np.ndarray, np.ndarray]:
    """The distance (N,) (m) from each TCP position ``tcp`` of the path at parameter ``s`` to
    its segment of the planned path's polyline, and the plan segment (N,) that holds s."""
    k = np.clip(np.searchsorted(path.knots_s, s, side="right") - 1, 0, len(path.knots_s) - 2)
    a, b = path.knots_xyz[k], path.knots_xyz[k + 1]
    seg = np.clip(np.searchsorted(path.plan_s, s, side="right") - 1, 0, len(path.plan_s) - 2)
    ab = b - a
    u = np.einsum("ij,ij->i", tcp - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30)
    closest = a + np.clip(u, 0.0, 1.0)[:, None] * ab
    return np.linalg.norm(tcp - closest, axis=1), seg
