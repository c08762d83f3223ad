"""Random pick-and-place trajectories (:ref:`concepts-trajectories`).

For a scene and a key:

1. the target is uniform among the scene's real goals;
2. the number of via points is uniform in ``via_counts`` (default ``{1}``; see below);
3. via points are uniform in a box: by default :data:`TABLE_VIA_BOX`, over the goal
   table's cube region (x ∈ [0.30, 0.70], y ∈ [−0.45, 0.45], z ∈ [0.10, 0.25]);
   the first version drew them in the SPEC's larger box :data:`SPEC_VIA_BOX`
   (x ∈ [0.25, 0.70], y ∈ [−0.50, 0.50], z ∈ [0.10, 0.40]);
4. the Cartesian path is TCP(q_home) → via_1 → … → via_N → target, piecewise linear;
5. it is resampled to 100 points (t_i = i / 99), equally spaced by arc length
   (``timing="arc_length"``) or with equal time on every segment
   (``timing="segment"``: each of the N + 1 segments gets 99 / (N + 1) of the steps);
6. joint configurations come from warm-started, position-only IK (MJX FK and
   Jacobian; soft terms in the null space), starting from ``Q_HOME``;
7. the stored path is the executed one, FK(q_i). A draw whose worst position
   residual exceeds 2 mm is rejected by the caller (see :mod:`slotv_jax.data`).

Shapes are fixed: unused via-point slots are collapsed onto the goal, adding
zero-length segments that the resampling skips.

The distribution of the paper is not fully stated: its text reads "Sample
N_control ∈ [3, 5] control points … adding the starting position and the position
of the chosen goal to the list of control points", which counts 3–5 via points if
the start and goal come on top, or 1–3 if they are among the 3–5; the first
author's public generator used one via point and equal time per segment. The
ablation ``python -m slotv_jax.experiments.fidelity`` (``experiments/fidelity.md``)
measures what each reading does to Table 1. :data:`DISTRIBUTIONS` names the
choices: ``"default"`` (the evidence-based default: one via point in the table box,
arc length) and ``"spec_v1"`` (the first version: 3–5 via points in the SPEC's box,
arc length).

>>> import jax
>>> from slotv_jax.scene import sample_scene
>>> tr = sample_trajectory(jax.random.key(0), sample_scene(jax.random.key(1), 3))
>>> tr.xyz.shape, tr.q.shape
((100, 3), (100, 7))
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxtyping import Array, Float, Int

from slotv_jax.core import validation
from slotv_jax.robot import kinematics
from slotv_jax.world.scene import Scene

TIMINGS = ("arc_length", "segment")
# Via-point boxes (m), (lower corner, upper corner). :ref:`concepts-trajectories`'s [choice] spans
# the reachable
# workspace in front of the robot; the table box lies over the goal table's cube region
# (:ref:`concepts-scenes`), lower down. The fidelity ablation chose the table box
# (experiments/fidelity.md).
SPEC_VIA_BOX = ((0.25, -0.50, 0.10), (0.70, 0.50, 0.40))
TABLE_VIA_BOX = ((0.30, -0.45, 0.10), (0.70, 0.45, 0.25))


@dataclasses.dataclass(frozen=True)
class TrajectoryConfig:
    """How random trajectories are drawn."""

    n_points: int = 100  # samples along the path (t_i = i / (n_points - 1))
    via_counts: tuple[int, ...] = (1,)  # allowed numbers of via points, drawn uniformly
    timing: str = "arc_length"  # "arc_length": equal spacing; "segment": equal time per segment
    via_low: tuple[float, float, float] = TABLE_VIA_BOX[0]  # via-point box, lower corner (m)
    via_high: tuple[float, float, float] = TABLE_VIA_BOX[1]  # via-point box, upper corner (m)
    max_residual: float = 2e-3  # reject draws whose IK misses any point by more (m)
    ik: kinematics.IKConfig = dataclasses.field(  # iterations per path point
        default_factory=lambda: kinematics.IKConfig(iters=2, refine_iters=1)
    )

    def __post_init__(self):
        if int(self.n_points) < 2:
            raise ValueError(f"TrajectoryConfig.n_points: expected >= 2, got {self.n_points}")
        counts = tuple(self.via_counts)
        if not counts or any(not isinstance(c, int | np.integer) or c < 0 for c in counts):
            raise ValueError(
                f"TrajectoryConfig.via_counts: expected non-negative int counts, got {counts}"
            )
        object.__setattr__(self, "via_counts", tuple(int(c) for c in counts))
        if self.timing not in TIMINGS:
            raise ValueError(
                f"TrajectoryConfig.timing: expected one of {TIMINGS}, got {self.timing!r}"
            )
        lo, hi = np.asarray(self.via_low), np.asarray(self.via_high)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
            raise ValueError(
                "TrajectoryConfig.via_low/via_high: expected 3-vectors with low < high"
            )
        validation.check_positive("TrajectoryConfig.max_residual", self.max_residual)

    @property
    def max_via(self) -> int:
        return max(self.via_counts)


@struct.dataclass
class Trajectory:
    """One trajectory, as stored in the datasets."""

    target: Int[Array, ""]  # goal slot the robot moves to
    xyz: Float[Array, "T 3"]  # executed TCP path FK(q_i) (m)
    q: Float[Array, "T 7"]  # joint configurations (rad)
    n_via: Int[Array, ""]  # number of via points used
    residual: Float[Array, ""]  # worst ‖FK(q_i) − planned_i‖ over the path (m)


def resample_polyline(waypoints: Float[Array, "W 3"], n: int) -> Float[Array, "n 3"]:
    """``n`` points equally spaced by arc length along a polyline, ends included.

    Zero-length segments are allowed and skipped.
    """
    seg = jnp.linalg.norm(jnp.diff(waypoints, axis=0), axis=-1)  # (W-1,)
    cum = jnp.concatenate([jnp.zeros(1, seg.dtype), jnp.cumsum(seg)])  # (W,)
    s = jnp.linspace(0.0, 1.0, n, dtype=seg.dtype) * cum[-1]
    # Segment index of each sample: the last segment whose start is <= s (clamped), skipping
    # zero-length segments because their start equals the next one's.
    idx = jnp.clip(jnp.searchsorted(cum, s, side="right") - 1, 0, seg.shape[0] - 1)
    frac = jnp.where(seg[idx] > 0, (s - cum[idx]) / jnp.where(seg[idx] > 0, seg[idx], 1.0), 0.0)
    frac = jnp.clip(frac, 0.0, 1.0)
    return waypoints[idx] + frac[:, None] * (waypoints[idx + 1] - waypoints[idx])


def resample_segments(
    waypoints: Float[Array, "W 3"], n_segments: Int[Array, ""], n: int
) -> Float[Array, "n 3"]:
    """``n`` points with equal time on each of the first ``n_segments`` segments, ends included.

    Point i sits at segment time u_i = (i / (n − 1)) · n_segments: on segment ⌊u_i⌋, a
    fraction u_i − ⌊u_i⌋ of the way along it. Segments after the first ``n_segments`` are
    never visited (they are the collapsed via slots).

    >>> w = jnp.array([[0.0, 0, 0], [1, 0, 0], [1, 3, 0]])
    >>> resample_segments(w, jnp.int32(2), 5)[:, :2].tolist()
    [[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.0, 1.5], [1.0, 3.0]]
    """
    u = jnp.linspace(0.0, 1.0, n, dtype=waypoints.dtype) * n_segments
    idx = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, jnp.maximum(n_segments - 1, 0))
    frac = jnp.clip(u - idx, 0.0, 1.0)
    return waypoints[idx] + frac[:, None] * (waypoints[idx + 1] - waypoints[idx])


class Plan(NamedTuple):
    """A planned Cartesian path (steps 1–5 of :ref:`concepts-trajectories`)."""

    target: Int[Array, ""]  # goal slot
    n_via: Int[Array, ""]  # via points used
    waypoints: Float[Array, "W 3"]  # start, via points (unused ones collapsed onto the goal), goal
    path: Float[Array, "n 3"]  # resampled path (m), spaced as ``cfg.timing`` says


def plan_path(key: jax.Array, scene: Scene, cfg: TrajectoryConfig = TrajectoryConfig()) -> Plan:
    """Draw target, via points and the resampled Cartesian path (steps 1–5)."""
    k_target, k_count, k_via = jax.random.split(key, 3)
    target = jax.random.randint(k_target, (), 0, scene.n_goals)
    n_via = jnp.asarray(cfg.via_counts, jnp.int32)[
        jax.random.randint(k_count, (), 0, len(cfg.via_counts))
    ]
    via = jax.random.uniform(
        k_via, (cfg.max_via, 3), minval=jnp.asarray(cfg.via_low), maxval=jnp.asarray(cfg.via_high)
    )
    goal = scene.goals[target]
    via = jnp.where((jnp.arange(cfg.max_via) < n_via)[:, None], via, goal)
    start = jnp.asarray(kinematics.home_tcp(), via.dtype)
    waypoints = jnp.concatenate([start[None], via, goal[None]], axis=0)
    if cfg.timing == "segment":
        path = resample_segments(waypoints, n_via + 1, cfg.n_points)
    else:
        path = resample_polyline(waypoints, cfg.n_points)
    return Plan(target, n_via, waypoints, path)


#: Named trajectory distributions (:ref:`concepts-trajectories`). ``default`` is the distribution
# chosen on the
#: evidence of the fidelity ablation (experiments/fidelity.md); ``spec_v1`` is the first
#: version's (3–5 via points in the SPEC's box, equal arc-length spacing).
DISTRIBUTIONS: dict[str, TrajectoryConfig] = {
    "default": TrajectoryConfig(),
    "spec_v1": TrajectoryConfig(
        via_counts=(3, 4, 5), timing="arc_length", via_low=SPEC_VIA_BOX[0], via_high=SPEC_VIA_BOX[1]
    ),
}


def distribution(name: str, **overrides) -> TrajectoryConfig:
    """The named trajectory distribution of :data:`DISTRIBUTIONS`, with field overrides."""
    if name not in DISTRIBUTIONS:
        raise ValueError(f"distribution: expected one of {tuple(DISTRIBUTIONS)}, got {name!r}")
    return dataclasses.replace(DISTRIBUTIONS[name], **overrides)


def straight_path(goal: Float[Array, "3"], n: int = 100) -> Float[Array, "n 3"]:
    """``n`` points from TCP(q_home) straight to ``goal`` (the reachability check of a goal)."""
    start = jnp.asarray(kinematics.home_tcp(), goal.dtype)
    return resample_polyline(jnp.stack([start, goal]), n)


def sample_trajectory(
    key: jax.Array, scene: Scene, cfg: TrajectoryConfig = TrajectoryConfig()
) -> Trajectory:
    """One random trajectory in ``scene`` (pure; deterministic in ``key``; vmap to batch)."""
    target, n_via, _, path = plan_path(key, scene, cfg)
    ik = kinematics.solve_path_ik(path, jnp.asarray(kinematics.Q_HOME, path.dtype), cfg.ik)
    return Trajectory(target=target, xyz=ik.xyz, q=ik.q, n_via=n_via, residual=jnp.max(ik.residual))
