"""TOPP-RA's part of the time law (:mod:`slotv_jax.execution.timing`): its joint velocity and
acceleration constraints with a bound scaled along the path, and one solve.

Pham and Pham, "A New Approach to Time-Optimal Path Parameterization Based on Reachability
Analysis", IEEE T-RO 34(3), 2018; the ``toppra`` package. Its own module so that ``toppra``
(which imports SciPy's interpolation and matplotlib, about 1.6 s) loads when a plan is first
timed, not whenever a command that can time one starts.
"""

from __future__ import annotations

import numpy as np
import toppra.algorithm
import toppra.constraint
from jaxtyping import Float

from slotv_jax.execution.path import JointPath
from slotv_jax.execution.refusal import Refused


class ScaledVelocity(toppra.constraint.JointVelocityConstraint):
    """``|q'_j(s) ṡ| ≤ σ(s) v_j``: toppra's joint velocity constraint, its bound scaled by
    ``self.scale`` (σ at each grid point, set before each solve), and ṡ² ≤ ``self.cap``
    (the path's own jerk bound, ``timing._jerk_cap``)."""

    scale: np.ndarray
    cap: np.ndarray

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        out = list(super().compute_constraint_params(path, gridpoints, *args, **kwargs))
        xbound = np.array(out[6])
        xbound[:, 1] = np.minimum(xbound[:, 1] * self.scale**2, self.cap)
        out[6] = xbound
        return tuple(out)


class ScaledAcceleration(toppra.constraint.JointAccelerationConstraint):
    """``|q'_j(s) s̈ + q''_j(s) ṡ²| ≤ σ(s)² a_j``: toppra's joint acceleration constraint
    (interpolation discretisation), the path's coefficients divided by σ² at each grid point."""

    scale: np.ndarray

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        k = self.scale[:, None] ** 2
        dof = path.dof
        f = np.concatenate([np.eye(dof), -np.eye(dof)])
        g = np.concatenate([self.alim[:, 1], -self.alim[:, 0]])
        a, b = path(gridpoints, 1) / k, path(gridpoints, 2) / k
        return toppra.constraint.canlinear_colloc_to_interpolate(
            a, b, np.zeros_like(a), f, g, None, None, gridpoints, identical=True
        )


def topp(path: JointPath, grid: Float[np.ndarray, " N"], constraints) -> Float[np.ndarray, " N"]:
    """TOPP-RA's path velocities ṡ ≥ 0 on ``grid`` (the fastest ṡ(s) that every constraint
    admits, found by reachability analysis; Pham and Pham 2018), at rest at both ends;
    :class:`~slotv_jax.execution.refusal.Refused` when no timing exists."""
    algo = toppra.algorithm.TOPPRA(
        constraints, path.spline, gridpoints=grid, solver_wrapper="seidel",
        parametrizer="ParametrizeConstAccel",
    )  # fmt: skip
    algo.compute_parameterization(0.0, 0.0)
    data = algo.problem_data
    sd = data.sd_vec
    if data.return_code != toppra.algorithm.ParameterizationReturnCode.Ok or sd is None:
        raise Refused(
            f"t = 0.000 s: TOPP-RA found no timing of the path ({data.return_code})",
            t=0.0, check="timing",
        )  # fmt: skip
    return np.maximum(np.asarray(sd, np.float64), 0.0)
