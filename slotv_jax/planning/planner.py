"""Legible motion planning for the Panda with any observer model.

The planner maximises the legibility of a target goal, log P(target | ξ), under an
observer: any callable ``observer(xyz (T, 3), goals (8, 3), goal_mask (8,)) -> logits (8,)``.
The four hand-crafted labelers qualify through log y (:func:`labeler_observer`), and
so do the learned observers of :func:`slotv_jax.load_observer` (SLOT-V, T-REX and the
archetypes).

What people read early. An evaluation study stops the motion at times τ and asks for the
goal; legibility is for being read before the end. With ``PlannerConfig.taus`` the
objective is the *prefix legibility*, the mean over the stop times of the log-probability
of the target given the motion seen so far::

    L(ξ) = (1/|taus|) Σ_{τ ∈ taus} log softmax(observer.prefix(ξ, goals, mask, L_τ))[target],
    L_τ = seen_points(τ, T)    (the first L_τ of the T waypoints, t_i = i/(T − 1) ≤ τ),

for any observer with a ``prefix(xyz, goals, goal_mask, seen) -> logits (8,)`` attribute
(:class:`slotv_jax.observers.observer.ObserverLike`: a user's own class or function, and
every :class:`~slotv_jax.observers.observer.Observer` the library hands out: labelers,
networks, archetypes, populations, pools). ``taus=None``
(the default) keeps the whole-motion objective log P(target | ξ).
It bounds the loss of efficiency as Dragan & Srinivasa do ("Generating Legible
Motion", RSS 2013): a trust region on the predictability cost,

    C(ξ) = ½ ∫₀¹ ‖ξ'(t)‖² dt ≈ ½ Σ_i ‖p_{i+1} − p_i‖² / Δt      (m², Δt = 1/(T − 1))
    maximise  L(ξ) = log P(target | ξ)   subject to   C(ξ) ≤ C(ξ_straight) + budget,

where p_i is the TCP position of waypoint i. For a path of length ℓ at constant
speed C = ½ ℓ², so the straight line at constant speed is the minimiser of C and a
budget b lets the path grow to at most √(ℓ² + 2b) (a budget of 0.05 m² takes a 0.5 m
straight line to at most 0.59 m).

Why joint space. The decision variables are the joint configurations of the interior
waypoints, and the path the observer sees is their MJX forward kinematics. So the
path is executable by construction: every waypoint has a configuration, the
gradient flows end to end through FK (no IK inside the loop, no IK failure after
it), and the joint limits hold by a smooth reparameterisation,

    q = q_mid + q_half · tanh(z),    q_mid = (q_max + q_min)/2,  q_half = (q_max − q_min)/2,

which maps every real z inside the limits. The alternative, optimising Cartesian
points and solving IK afterwards, can produce a path the arm cannot follow (or one
whose IK drifts more than the 2 mm tolerance), and the legibility it optimised is
not the legibility of the executed motion.

Endpoints. q_0 is the start configuration (``Q_HOME`` for the start TCP(q_home)),
and q_{T−1} is the project's IK solution for the target goal, within 2 mm; both stay
fixed. The interior waypoints start from the straight line: the Cartesian straight
line from the start to the target, resampled by arc length and solved by the
project's warm-started IK (:func:`slotv_jax.kinematics.solve_path_ik`).

The step (Dragan & Srinivasa's covariant trust-region update). Each iteration takes
g = ∇_z L̃ (L̃ = L minus a table-clearance penalty) and h = ∇_z C and moves

    z ← z + s · A⁻¹ (g − λ h),     s = α_k / √(gᵀ A⁻¹ g),
    λ = max(0, (C(ξ) + s hᵀA⁻¹g − κ) / (s hᵀA⁻¹h)),      κ = C(ξ_straight) + budget,

with A = KᵀK the finite-difference smoothness metric of the interior waypoints (K the
first-difference operator with the endpoints fixed; the same metric as CHOMP, Ratliff
et al. 2009), so that a step is a smooth deformation of the whole path rather than a
kink at one waypoint. λ is the Lagrange multiplier that keeps the linearised
constraint C ≤ κ; s normalises the step to length α_k in the A-norm, with α_k
decaying linearly over a fixed number of iterations (``lax.scan``: one compilation).
The gripper must stay above the goal table, TCP z ≥ ``clearance``, except within
``exempt_radius`` of the target (where it grasps): a smooth quadratic penalty keeps it
there, and the returned plan is the best *feasible* iterate (highest L among the
iterates that satisfy the trust region and the clearance), so both constraints hold
exactly on the result. The straight line is feasible, so there always is one.

Everything is a pure function of arrays; batch it with ``vmap`` over problems and
compile it with ``jit``. :func:`slotv_jax.planning.compiled.make_planner` is the validated,
compiled entry point (:mod:`.compiled`: many problems, observers and fitted families in one
program):

>>> import jax
>>> from slotv_jax import labelers, planning, scene
>>> s = scene.sample_scene(jax.random.key(0), 3)
>>> planner = planning.make_planner(planning.labeler_observer("dragan"))  # doctest: +SKIP
>>> res = planner(s.goals[None], s.goal_mask[None], jax.numpy.array([1]))  # doctest: +SKIP
>>> res.xyz.shape, res.q.shape, bool(res.feasible[0])  # doctest: +SKIP
((1, 100, 3), (1, 100, 7), True)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from numbers import Real
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers import labelers
from slotv_jax.observers.common import mask_logits, masked_log, seen_points
from slotv_jax.observers.observer import (
    Observer,
    ObserverLike,
    check_observer_inputs,
    check_seen,
)
from slotv_jax.observers.prefix import prefix_labels
from slotv_jax.planning import caution
from slotv_jax.robot import kinematics
from slotv_jax.world.scene import camera as scene_camera
from slotv_jax.world.trajectories import resample_polyline

__all__ = [
    "Diagnostics",
    "PlanResult",
    "PlannerConfig",
    "Problem",
    "check_observer",
    "labeler_observer",
    "legibility",
    "metric_inverse",
    "objective",
    "plan",
    "predictability_cost",
    "straight_line",
    "switched_observer",
]


# m: the start and the target must be reached this closely (:ref:`concepts-trajectories`)
MAX_RESIDUAL = 2e-3
_RATIO_CLIP = 1.0 - 1e-5  # |tanh z| of the initial path: joints on a limit start just inside


@dataclasses.dataclass(frozen=True)
class PlannerConfig:
    """Settings of the legible planner (defaults are the experiment's)."""

    n_points: int = 100  # waypoints of the path, endpoints included (the datasets' T)
    iters: int = 50  # covariant steps (fixed: one compilation)
    budget: float = 0.05  # trust region: C(ξ) ≤ C(ξ_straight) + budget (m²)
    step: float = 0.02  # α_0: first step length in the A-norm of z
    step_end: float = 0.1  # α decays linearly to step · step_end at the last iteration
    clearance: float = 0.05  # TCP height above the goal table (m); the cubes' tops
    exempt_radius: float = 0.08  # no clearance needed this close to the target (m)
    clearance_margin: float = 0.005  # the penalty pushes to clearance + this (m)
    table_weight: float = 1e4  # weight of the quadratic clearance penalty (1/m²)
    # the datasets' per-point IK (:ref:`concepts-trajectories`)
    ik: kinematics.IKConfig = dataclasses.field(
        default_factory=lambda: kinematics.IKConfig(iters=2, refine_iters=1)
    )
    # stop times τ ∈ (0, 1] of the prefix objective (module docstring); None: the whole motion
    taus: tuple[float, ...] | None = None

    def __post_init__(self):
        for f in ("n_points", "iters"):
            v = getattr(self, f)
            if not isinstance(v, int | np.integer) or v < (3 if f == "n_points" else 1):
                lo = 3 if f == "n_points" else 1
                raise ValueError(f"PlannerConfig.{f}: expected an integer >= {lo}, got {v!r}")
        if not (np.isfinite(self.budget) and self.budget > 0):
            raise ValueError(
                f"budget: expected a finite trust-region budget > 0 (m²), got {self.budget!r}"
            )
        for f in ("step", "step_end", "exempt_radius", "table_weight"):
            validation.check_positive(f"PlannerConfig.{f}", getattr(self, f))
        for f in ("clearance", "clearance_margin"):
            v = getattr(self, f)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"PlannerConfig.{f}: expected a finite number >= 0, got {v!r}")
        if self.taus is not None:
            bad = isinstance(self.taus, str | bytes) or not isinstance(self.taus, Sequence)
            if bad or any(isinstance(t, bool) or not isinstance(t, Real) for t in self.taus):
                raise ValueError(
                    f"PlannerConfig.taus: expected a tuple of stop times in (0, 1] or None, "
                    f"got {self.taus!r}"
                )
            object.__setattr__(self, "taus", tuple(float(t) for t in self.taus))
            try:
                seen_points(self.taus, int(self.n_points))
            except ValueError as e:
                raise ValueError(f"PlannerConfig.{e}") from None

    def seen(self) -> tuple[int, ...] | None:
        """L_τ = :func:`slotv_jax.observers.common.seen_points` of each stop time (None
        without ``taus``): the waypoints an observer stopped at τ has seen."""
        if self.taus is None:
            return None
        return tuple(int(n) for n in seen_points(self.taus, self.n_points))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class Problem(NamedTuple):
    """One planning problem and its straight-line initialisation (see :func:`straight_line`)."""

    goals: Float[Array, "8 3"]  # goal positions (m); padded slots ignored
    goal_mask: Bool[Array, " 8"]  # real goal slots
    target: Int[Array, ""]  # the goal slot to make legible
    start: Float[Array, " 3"]  # requested start TCP position (m)
    q: Float[Array, "T 7"]  # straight-line joints: q[0] start, q[-1] the target's IK (rad)
    xyz: Float[Array, "T 3"]  # executed straight line FK(q) (m)
    start_residual: Float[Array, ""]  # ‖FK(q[0]) − start‖ (m)
    target_residual: Float[Array, ""]  # ‖FK(q[-1]) − goals[target]‖ (m)


class Diagnostics(NamedTuple):
    """How a plan was found and how well it keeps the constraints."""

    objective: Float[
        Array, " K"
    ]  # log P(target | ξ) (taus: its prefix mean) per iterate (K = iters+1)
    cost_history: Float[Array, " K"]  # predictability cost C per iterate (m²)
    objective_straight: Float[Array, ""]  # the objective of the straight line
    cost: Float[Array, ""]  # C of the returned plan (m²)
    cost_straight: Float[Array, ""]  # C of the straight line (m²)
    cost_limit: Float[Array, ""]  # κ = C(ξ_straight) + budget (m²)
    best_iter: Int[Array, ""]  # which iterate was returned (0: the straight line)
    start_residual: Float[Array, ""]  # ‖FK(q_0) − start‖ (m)
    target_residual: Float[Array, ""]  # ‖FK(q_{T−1}) − goal‖ (m)
    joint_margin: Float[Array, ""]  # min over waypoints and joints of the distance to a limit (rad)
    table_clearance: Float[Array, ""]  # min TCP z outside the exempt radius, minus clearance (m)
    feasible: Bool[Array, ""]  # all constraints hold (see :func:`plan`)


class PlanResult(NamedTuple):
    """A planned motion: the executed TCP path, its joints and the diagnostics."""

    xyz: Float[Array, "T 3"]  # executed TCP path FK(q) (m)
    q: Float[Array, "T 7"]  # joint configurations (rad)
    diagnostics: Diagnostics

    @property
    def feasible(self) -> Bool[Array, ""]:
        return self.diagnostics.feasible


# ------------------------------------------------------------------- observers


def _labeler_logits(
    config: tuple[str, str], beta, xyz: Float[Array, "T 3"], goals, goal_mask
) -> Float[Array, " 8"]:
    name, camera = config
    kw = {"beta": beta}
    if name == "nikolaidis":
        kw["camera"] = scene_camera(camera)
    return masked_log(labelers.LABELERS[name](xyz, goals, goal_mask, **kw), goal_mask)


def _labeler_prefix(
    config: tuple[str, str], beta, xyz: Float[Array, "T 3"], goals, goal_mask, seen
) -> Float[Array, " 8"]:
    name, camera = config
    check_observer_inputs(xyz, goals, goal_mask)
    check_seen(seen, jnp.shape(xyz)[0])
    cam = scene_camera(camera) if name == "nikolaidis" else None
    y = prefix_labels(name, xyz, goals, goal_mask, seen, beta=beta, camera=cam)
    return masked_log(y, goal_mask)


def labeler_observer(name: str, *, beta: float | None = None, camera: str = "observer") -> Observer:
    """A hand-crafted labeler as an observer: ``logits = log y`` (−∞ on padded slots).

    softmax(log y) = y over the real goals, so the planner's objective
    log softmax(logits)[target] is log y_target. ``name`` is one of dragan, nikolaidis,
    effdist, fastapp (:ref:`concepts-temperatures`); ``beta`` defaults to the SPEC's (it may be
    traced: build the observer inside a jitted function of β to plan for many β with one
    compilation); ``camera`` is the Nikolaidis viewpoint. An
    :class:`~slotv_jax.observers.observer.Observer` whose ``params`` is β and whose ``config`` is
    ``(name, camera)``: ``grad`` and ``vmap`` take it whole.

    The observer's ``prefix(xyz, goals, goal_mask, seen) -> logits (8,)`` is the labeler
    of the motion seen up to its first ``seen`` points, ``log labeler(xyz[:seen])`` at the
    prefix's own times t_i = i/(seen − 1) (:func:`slotv_jax.observers.prefix.prefix_labels`;
    ``seen`` may be traced).

    >>> obs = labeler_observer("dragan")
    >>> obs.name
    'dragan'
    """
    if name not in labelers.LABELER_NAMES:
        raise ValueError(f"name: expected one of {labelers.LABELER_NAMES}, got {name!r}")
    beta = labelers.DEFAULT_BETAS[name] if beta is None else beta
    validation.check_positive("beta", beta)
    if name == "nikolaidis":
        scene_camera(camera)  # an unknown camera fails here, not at the first call
    return Observer(
        logits_fn=_labeler_logits,
        prefix_fn=_labeler_prefix,
        params=beta,
        config=(name, str(camera)),
        name=name,
    )


def _observer_name(observer) -> str:
    name = getattr(observer, "name", None) or getattr(observer, "__name__", None)
    return repr(name) if name else type(observer).__name__


def check_observer(observer: ObserverLike, n_points: int = 100, *, prefix: bool = False) -> None:
    """Raise ValueError unless ``observer(xyz (T, 3), goals (8, 3), goal_mask (8,))``
    returns one float logit per goal slot, shape (8,) (checked abstractly, no compute).
    With ``prefix``, ``observer.prefix(xyz, goals, goal_mask, seen)`` (``seen`` an int32
    scalar) must exist and do the same."""
    if not callable(observer):
        raise ValueError(f"observer: expected a callable, got {type(observer).__name__}")
    args = (
        jax.ShapeDtypeStruct((n_points, 3), jnp.float32),
        jax.ShapeDtypeStruct((G_MAX, 3), jnp.float32),
        jax.ShapeDtypeStruct((G_MAX,), jnp.bool_),
    )
    try:
        out = jax.eval_shape(observer, *args)
    except Exception as e:
        raise ValueError(
            f"observer: calling it on xyz ({n_points}, 3), goals (8, 3), goal_mask (8,) failed: {e}"
        ) from e
    _check_logits(out)
    if not prefix:
        return
    if not callable(getattr(observer, "prefix", None)):
        raise ValueError(
            "observer: PlannerConfig.taus needs an observer that scores a motion seen up to a "
            "stop time (a .prefix(xyz, goals, goal_mask, seen) attribute, as labeler_observer "
            f"and load_observer give); {_observer_name(observer)} has none"
        )
    try:
        out = jax.eval_shape(observer.prefix, *args, jax.ShapeDtypeStruct((), jnp.int32))
    except Exception as e:
        raise ValueError(
            f"observer {_observer_name(observer)}: calling its prefix on xyz ({n_points}, 3), "
            f"goals (8, 3), goal_mask (8,), seen () int32 failed: {e}"
        ) from e
    _check_logits(out)


def _check_logits(out) -> None:
    shape = getattr(out, "shape", None)
    if shape != (G_MAX,) or not jnp.issubdtype(getattr(out, "dtype", np.int32), jnp.floating):
        raise ValueError(
            f"observer: expected float logits of shape ({G_MAX},) for one trajectory, got "
            f"{'a ' + type(out).__name__ if shape is None else f'shape {shape} {out.dtype}'}"
        )


# ----------------------------------------------------------------- the maths


def predictability_cost(xyz: Float[Array, "T 3"]) -> Float[Array, ""]:
    """Dragan & Srinivasa's predictability cost C(ξ) = ½ ∫₀¹ ‖ξ'(t)‖² dt (m²).

    Discretised on t_i = i/(T − 1): ``C = ½ (T − 1) Σ_i ‖p_{i+1} − p_i‖²``. A straight
    line of length ℓ at constant speed has C = ½ ℓ², the least of any path between its ends.

    >>> import jax.numpy as jnp
    >>> line = jnp.linspace(jnp.zeros(3), jnp.array([0.3, 0.4, 0.0]), 11)
    >>> round(float(predictability_cost(line)), 6)
    0.125
    """
    T = xyz.shape[0]
    return 0.5 * (T - 1) * jnp.sum(jnp.diff(xyz, axis=0) ** 2)


def metric_inverse(n: int) -> np.ndarray:
    """A⁻¹ for the finite-difference metric A = KᵀK of ``n`` interior waypoints (float64).

    With both endpoints fixed, A = tridiag(−1, 2, −1) (n × n), and its inverse is the
    discrete Green's function (A⁻¹)_ij = min(i, j) (n + 1 − max(i, j)) / (n + 1), i, j = 1..n.

    >>> metric_inverse(2) * 3
    array([[2., 1.],
           [1., 2.]])
    """
    i = np.arange(1, n + 1, dtype=np.float64)
    return np.minimum.outer(i, i) * (n + 1 - np.maximum.outer(i, i)) / (n + 1)


def _limits(dtype):
    lo = jnp.asarray(kinematics.Q_MIN, dtype)
    hi = jnp.asarray(kinematics.Q_MAX, dtype)
    return (hi + lo) / 2, (hi - lo) / 2


def _joints(z: Float[Array, "n 7"], q_start, q_end) -> Float[Array, "T 7"]:
    mid, half = _limits(z.dtype)
    return jnp.concatenate([q_start[None], mid + half * jnp.tanh(z), q_end[None]])


def _fk(q: Float[Array, "T 7"]) -> Float[Array, "T 3"]:
    return jax.vmap(kinematics.fk_position)(q)


def _initial_z(q: Float[Array, "T 7"]) -> Float[Array, "n 7"]:
    mid, half = _limits(q.dtype)
    return jnp.arctanh(jnp.clip((q[1:-1] - mid) / half, -_RATIO_CLIP, _RATIO_CLIP))


def legibility(
    observer: ObserverLike,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    target: Int[Array, ""],
    cfg: PlannerConfig = PlannerConfig(),
) -> Float[Array, ""]:
    """The legibility the planner maximises, for one path (pure; no checks):
    log P(target | ξ) = log softmax(observer(xyz, goals, goal_mask))[target] over the real
    goals; with ``cfg.taus`` the prefix legibility (module docstring)::

        (1/|taus|) Σ_τ log softmax(observer.prefix(xyz, goals, goal_mask, L_τ))[target],

    L_τ = ``seen_points(taus, T)`` for the path's T points (static). For a
    :func:`slotv_jax.planning.caution.lower_bound_observer` each log-probability is the
    ensemble's lower confidence bound, mean_m ℓ_m − κ sd_m ℓ_m (:mod:`.caution`).

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.0]).at[1].set([0.5, -0.2, 0.0])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.4]), g[0], 11)
    >>> obs, m = labeler_observer("dragan"), jnp.arange(8) < 2
    >>> cfg = PlannerConfig(n_points=11, taus=(0.3, 1.0))
    >>> early = obs.prefix(xyz, g, m, jnp.int32(4))  # t_0..t_3 (≤ 0.3)
    >>> ref = (jax.nn.log_softmax(early)[0] + jax.nn.log_softmax(obs(xyz, g, m))[0]) / 2
    >>> bool(jnp.isclose(legibility(obs, xyz, g, m, 0, cfg), ref))
    True
    """
    branches = _switch_branches(observer)
    if branches is not None:  # each branch's own objective (a bound stays a bound)
        return jax.lax.switch(
            observer.params,
            [lambda x, o=o: legibility(o, x, goals, goal_mask, target, cfg) for o in branches],
            xyz,
        )
    mask = jnp.asarray(goal_mask).astype(bool)
    if caution.is_lower_bound(observer):  # the bound over an ensemble (:mod:`.caution`)
        kappa, _ = caution.members_of(observer)
        terms = jax.vmap(lambda o: _log_probs(o, xyz, goals, mask, target, cfg))(observer.params)
        return jnp.mean(caution.lower_bound(terms, kappa))
    return jnp.mean(_log_probs(observer, xyz, goals, mask, target, cfg))


def _switch_logits(observers, index, xyz, g, m):
    return jax.lax.switch(index, observers, xyz, g, m)


def _switch_prefix(observers, index, xyz, g, m, n):
    return jax.lax.switch(index, tuple(o.prefix for o in observers), xyz, g, m, n)


def switched_observer(index: Int[Array, ""], observers: Sequence[ObserverLike]) -> ObserverLike:
    """The observer ``observers[index]`` (and its ``prefix``): a ``lax.switch`` on an
    unbatched index, so one program holds them all. :func:`legibility` switches between the
    branches' own objectives, so a branch that is a
    :func:`slotv_jax.planning.caution.lower_bound_observer` is planned for its bound."""
    if len(observers) == 1:
        return observers[0]
    return Observer(_switch_logits, _switch_prefix, params=index, config=tuple(observers))


def _switch_branches(observer) -> tuple[ObserverLike, ...] | None:
    """The branches of a :func:`switched_observer` (None for any other observer)."""
    if isinstance(observer, Observer) and observer.logits_fn is _switch_logits:
        return observer.config
    return None


def _log_probs(observer, xyz, goals, mask, target, cfg: PlannerConfig) -> Float[Array, " K"]:
    """log P(target | ξ) (K = 1), or at each stop time of ``cfg.taus``."""
    if cfg.taus is None:
        logits = mask_logits(observer(xyz, goals, mask), mask)
        return jax.nn.log_softmax(logits)[target][None]
    if not callable(getattr(observer, "prefix", None)):
        raise ValueError(
            "observer: PlannerConfig.taus needs an observer with a .prefix(xyz, goals, "
            f"goal_mask, seen) attribute; {_observer_name(observer)} has none"
        )
    return stop_log_probs(observer, xyz, goals, mask, target, cfg.taus)


def stop_log_probs(
    observer: ObserverLike,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    target: Int[Array, ""],
    taus: Sequence[float],
) -> Float[Array, " K"]:
    """log P(target | ξ_{0:τ}) = log softmax(observer.prefix(xyz, goals, goal_mask, L_τ))[target]
    over the real goals, at each stop time τ of ``taus`` (L_τ = ``seen_points(taus, T)``):
    the terms of the prefix legibility (:func:`legibility`, their mean). Pure; the observer
    needs ``.prefix``."""
    mask = jnp.asarray(goal_mask).astype(bool)
    seen = jnp.asarray(seen_points(taus, xyz.shape[0]), jnp.int32)

    def one(n):  # one prefix, traced over the stop times: the observer is compiled once
        return jax.nn.log_softmax(mask_logits(observer.prefix(xyz, goals, mask, n), mask))[target]

    return jax.vmap(one)(seen)


def _legibility(observer: ObserverLike, xyz, problem: Problem, cfg: PlannerConfig) -> Array:
    return legibility(observer, xyz, problem.goals, problem.goal_mask, problem.target, cfg)


def _exempt(xyz, problem: Problem, cfg: PlannerConfig) -> Bool[Array, " T"]:
    goal = problem.goals[problem.target]
    return jnp.linalg.norm(xyz - goal, axis=-1) < cfg.exempt_radius


def _table_penalty(xyz, problem: Problem, cfg: PlannerConfig) -> Float[Array, ""]:
    short = jax.nn.relu(cfg.clearance + cfg.clearance_margin - xyz[:, 2])
    return cfg.table_weight * jnp.sum(jnp.where(_exempt(xyz, problem, cfg), 0.0, short**2))


def _clearance(xyz, problem: Problem, cfg: PlannerConfig) -> Float[Array, ""]:
    """min TCP z outside the exempt radius, minus the clearance (≥ 0: the table is kept)."""
    z = jnp.where(_exempt(xyz, problem, cfg), jnp.inf, xyz[:, 2])
    return jnp.min(z) - cfg.clearance


def objective(
    observer: ObserverLike, problem: Problem, z: Float[Array, "n 7"], cfg: PlannerConfig
) -> Float[Array, ""]:
    """The function the planner ascends: log P(target | ξ(z)) (with ``cfg.taus``: its mean
    over the prefixes) minus the clearance penalty.

    ``ξ(z) = FK(q(z))`` with ``q(z) = [q_start, q_mid + q_half tanh(z), q_end]`` (the
    endpoints from ``problem.q``). Exposed for checking its gradient.
    """
    xyz = _fk(_joints(z, problem.q[0], problem.q[-1]))
    return _legibility(observer, xyz, problem, cfg) - _table_penalty(xyz, problem, cfg)


# ------------------------------------------------------------------ problems


def straight_line(
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    target: Int[Array, ""],
    start: Float[Array, " 3"] | None = None,
    cfg: PlannerConfig = PlannerConfig(),
) -> Problem:
    """The planning problem with its straight-line initialisation (pure; vmap to batch).

    The Cartesian line from ``start`` (default TCP(q_home), reached by ``Q_HOME``) to
    ``goals[target]``, ``cfg.n_points`` points equally spaced by arc length, solved by the
    warm-started path IK from the start configuration (``cfg.ik``'s iterations per point);
    the last configuration is then refined onto the goal with
    :func:`slotv_jax.kinematics.solve_ik`'s default iterations (6 + 4). Another start than
    the home TCP is first solved from ``Q_HOME`` the same way. The three solves are one chain
    (:func:`slotv_jax.kinematics.solve_ik_chain`, ``cfg.ik``'s gains): the forward
    kinematics compiles once (the straight line's program compiles in about half the time
    of three separate solves). No value checks here: :func:`make_planner` rejects
    unreachable starts and targets.
    """
    goals = jnp.asarray(goals)
    dtype = goals.dtype
    goal = goals[target]
    q_home = jnp.asarray(kinematics.Q_HOME, dtype)
    home = jnp.asarray(kinematics.home_tcp(), dtype)
    start = home if start is None else jnp.asarray(start, dtype)
    path = resample_polyline(jnp.stack([start, goal]), cfg.n_points)
    # Targets: the start (from Q_HOME; no step at the home TCP, which Q_HOME reaches), the
    # path's points (cfg.ik's counts), the goal again (solve_ik's default counts).
    end = kinematics.IKConfig()
    at_home = jnp.all(start == home)

    def counts(start_n, path_n, goal_n):
        c = jnp.full(cfg.n_points + 2, path_n, jnp.int32).at[-1].set(goal_n)
        return c.at[0].set(jnp.where(at_home, 0, start_n))

    every = end.iters + end.refine_iters
    soft = counts(end.iters, cfg.ik.iters, end.iters)
    total = counts(every, cfg.ik.iters + cfg.ik.refine_iters, every)
    targets = jnp.concatenate([start[None], path, goal[None]])
    qs = kinematics.solve_ik_chain(targets, q_home, soft, total, cfg.ik)
    q = qs[1:-1].at[0].set(qs[0]).at[-1].set(qs[-1])
    xyz = _fk(q)
    return Problem(
        goals=goals,
        goal_mask=jnp.asarray(goal_mask).astype(bool),
        target=jnp.asarray(target, jnp.int32),
        start=start,
        q=q,
        xyz=xyz,
        start_residual=jnp.linalg.norm(xyz[0] - start),
        target_residual=jnp.linalg.norm(xyz[-1] - goal),
    )


# ------------------------------------------------------------------- planner


def plan(
    observer: ObserverLike, problem: Problem, cfg: PlannerConfig = PlannerConfig()
) -> PlanResult:
    """Plan the most legible motion to ``problem.target`` within the trust region (pure).

    Ascends :func:`objective` from the straight line with ``cfg.iters`` covariant
    trust-region steps (module docstring) and returns the best feasible iterate:
    highest log P(target | ξ) (or its prefix mean, ``cfg.taus``) among iterates with
    C(ξ) ≤ C(ξ_straight) + budget and TCP z ≥ clearance outside the exempt radius.
    ``feasible`` also requires the start and the target within 2 mm, the joints within
    their limits and finite values. Batch it with ``jax.vmap(plan, in_axes=(None, 0,
    None))`` over problems; the observer may be built from traced parameters inside the
    compiled function (one compilation for many fitted observers of one family:
    :func:`make_family_planner`).
    """
    q_start, q_end = problem.q[0], problem.q[-1]
    z0 = _initial_z(problem.q)
    dtype = z0.dtype
    m_inv = jnp.asarray(metric_inverse(z0.shape[0]), dtype)
    tiny = jnp.finfo(dtype).tiny

    def path(z):
        return _fk(_joints(z, q_start, q_end))

    def penalised(xyz):
        val = _legibility(observer, xyz, problem, cfg)
        return val - _table_penalty(xyz, problem, cfg), val

    # C of the straight line, from the problem's FK: the only FK outside the loop below.
    cost0 = predictability_cost(problem.xyz)
    kappa = cost0 + cfg.budget
    # Aim the linearised constraint a little inside κ: C is convex in the positions, so a
    # step onto the linearised boundary lands slightly outside it.
    kappa_aim = kappa - 0.02 * cfg.budget

    def ok(xyz, cost):
        return (cost <= kappa) & (_clearance(xyz, problem, cfg) >= 0) & jnp.all(jnp.isfinite(xyz))

    def step(carry, k):
        z, best, c_lin, alpha_prev, curv = carry
        xyz, pull = jax.vjp(path, z)
        # One trace of the observer gives log P and its gradient.
        g_xyz, val = jax.grad(penalised, has_aux=True)(xyz)
        cost, h_xyz = jax.value_and_grad(predictability_cost)(xyz)
        # Keep the best feasible iterate (z, its path, log P, iteration).
        better = ok(xyz, cost) & (val > best[2])
        best = jax.tree.map(lambda new, old: jnp.where(better, new, old), (z, xyz, val, k), best)
        # C is not linear in z: the last step raised it by its linear prediction plus a
        # second-order part; per unit α², that part predicts the next step's.
        curv = jnp.where(k > 0, jnp.maximum(cost - c_lin, 0.0) / alpha_prev**2, curv)
        # Covariant step in the metric A, with Dragan's multiplier for the trust region.
        g, h = jax.vmap(lambda c: pull(c)[0])(jnp.stack([g_xyz, h_xyz]))
        mg, mh = m_inv @ g, m_inv @ h
        gmg, hmh, hmg = jnp.sum(g * mg), jnp.sum(h * mh), jnp.sum(h * mg)
        frac = jnp.minimum(k / max(cfg.iters - 1, 1), 1.0)
        alpha = cfg.step * (1.0 - (1.0 - cfg.step_end) * frac)
        s = alpha / jnp.sqrt(gmg + tiny)
        lam = jnp.maximum(0.0, (cost + curv * alpha**2 - kappa_aim + s * hmg) / (s * hmh + tiny))
        dz = s * (mg - lam * mh)
        c_lin = cost + jnp.sum(h * dz)
        padded = jnp.pad(dz, ((1, 1), (0, 0)))  # ‖dz‖_A² = ‖K dz‖², endpoints fixed
        alpha_eff = jnp.sqrt(jnp.sum(jnp.diff(padded, axis=0) ** 2) + tiny)
        z_new = z + dz
        z_new = jnp.where(jnp.all(jnp.isfinite(z_new)), z_new, z)
        return (z_new, best, c_lin, alpha_eff, curv), (val, cost)

    best0 = (z0, problem.xyz, jnp.asarray(-jnp.inf, dtype), jnp.asarray(0, jnp.int32))
    zero = jnp.zeros((), dtype)
    # iters steps, plus one more evaluation of the last iterate (its step is discarded).
    ks = jnp.arange(cfg.iters + 1, dtype=jnp.int32)
    init = (z0, best0, cost0, jnp.ones((), dtype), zero)
    (_, (best_z, xyz, _, best_k), *_), (vals, costs) = jax.lax.scan(step, init, ks)

    q = _joints(best_z, q_start, q_end)
    cost = predictability_cost(xyz)
    lo = jnp.asarray(kinematics.Q_MIN, dtype)
    hi = jnp.asarray(kinematics.Q_MAX, dtype)
    margin = jnp.min(jnp.minimum(q - lo, hi - q))
    clear = _clearance(xyz, problem, cfg)
    start_res = jnp.linalg.norm(xyz[0] - problem.start)
    target_res = jnp.linalg.norm(xyz[-1] - problem.goals[problem.target])
    feasible = (
        ok(xyz, cost)
        & (margin >= 0)
        & (start_res <= MAX_RESIDUAL)
        & (target_res <= MAX_RESIDUAL)
        & jnp.all(jnp.isfinite(q))
    )
    diag = Diagnostics(
        objective=vals,
        cost_history=costs,
        objective_straight=vals[0],
        cost=cost,
        cost_straight=cost0,
        cost_limit=kappa,
        best_iter=best_k,
        start_residual=start_res,
        target_residual=target_res,
        joint_margin=margin,
        table_clearance=clear,
        feasible=feasible,
    )
    return PlanResult(xyz=xyz, q=q, diagnostics=diag)
