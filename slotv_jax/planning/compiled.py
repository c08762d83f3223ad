"""The planner's compiled entry points: many problems, and many observers, in one program.

:func:`make_planner` plans batches of problems with one observer or a set of named ones
(a ``lax.switch`` on an unbatched index, so the forward kinematics and its gradient are
compiled once whatever the observer); :func:`make_family_planner` plans with observers
built from parameters (the dozens of observers a study fits: one compilation for every
parameter set, and for several families side by side). Both validate every input first
(targets, goals, starts within IK's reach: :func:`check_problems`; one beyond the arm's
links laid end to end, :func:`slotv_jax.robot.kinematics.reach`, before anything compiles)
and plan with
:func:`slotv_jax.planning.planner.plan`, the pure function of one problem.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation
from slotv_jax.core.progress import status
from slotv_jax.core.validation import G_MAX
from slotv_jax.observers.observer import ObserverLike
from slotv_jax.planning.planner import (
    MAX_RESIDUAL,
    PlannerConfig,
    PlanResult,
    Problem,
    check_observer,
    plan,
    straight_line,
    switched_observer,
)
from slotv_jax.robot import kinematics

__all__ = [
    "FamilyPlanner",
    "Planner",
    "check_problems",
    "make_family_planner",
    "make_planner",
]


def _check_targets(goals, goal_mask, target) -> np.ndarray:
    t = np.asarray(target)
    if t.dtype.kind not in "iu" and not (t.dtype.kind == "f" and np.all(t == np.round(t))):
        raise ValueError(f"target: expected integer goal slots, got dtype {t.dtype}")
    t = t.astype(np.int64)
    n = np.shape(goals)[0]
    if t.shape != (n,):
        raise ValueError(f"target: expected shape ({n},) (one slot per problem), got {t.shape}")
    mask = np.asarray(goal_mask, bool)
    bad = (t < 0) | (t >= G_MAX)
    bad |= ~mask[np.arange(n), np.clip(t, 0, G_MAX - 1)]
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"target: problem {i} asks for slot {int(t[i])}, which is not a real goal "
            f"(its real slots are {np.flatnonzero(mask[i]).tolist()})"
        )
    return t


def _straight_problems(straight, goals, goal_mask, target, start, note=None) -> Problem:
    """Validated straight-line problems from the compiled ``straight`` (vmapped
    :func:`straight_line`); ``note(n)`` is called once the inputs passed, before ``straight``
    runs on ``n`` problems."""
    validation.check_goals("goals", goals, goal_mask, batch_shape=(None,))
    n = int(np.shape(goals)[0])
    t = jnp.asarray(_check_targets(goals, goal_mask, target), jnp.int32)
    goals32 = jnp.asarray(goals, jnp.float32)
    mask = jnp.asarray(goal_mask).astype(bool)
    _check_reach("target", np.asarray(goals)[np.arange(n), np.asarray(t)])
    if start is None:  # the home TCP, which Q_HOME reaches (its constant compiles once)
        start = np.broadcast_to(kinematics.home_tcp(), (n, 3))
    else:
        validation.check_array("start", start, (n, 3))
        _check_reach("start", np.asarray(start))
    if note is not None:
        note(n)
    problems = straight(goals32, mask, t, jnp.asarray(start, jnp.float32))
    check_problems(problems)
    return problems


@functools.cache
def _straight_program(cfg: PlannerConfig):
    """The compiled, vmapped :func:`straight_line` of ``cfg`` (one per process and config,
    shared by every planner of that config)."""
    return jax.jit(jax.vmap(functools.partial(straight_line, cfg=cfg)))


def straight_lines(
    goals: Float[Array, "B 8 3"],
    goal_mask: Bool[Array, "B 8"],
    target: Int[Array, " B"],
    start: Float[Array, "B 3"] | None = None,
    cfg: PlannerConfig = PlannerConfig(),
) -> Problem:
    """The validated straight-line problems of a batch (:func:`straight_line` of each, in
    one compiled program): the goals and targets are checked first, then every start and
    target must be reached within :data:`MAX_RESIDUAL` (:func:`check_problems`), else
    ValueError. ``start`` defaults to TCP(q_home). What ``planner.straight_line`` of
    :func:`make_planner` and :func:`make_family_planner` gives, without a planner (for a
    caller that must refuse unreachable problems before it builds the observers)."""
    if not isinstance(cfg, PlannerConfig):
        raise ValueError(f"cfg: expected a PlannerConfig, got {type(cfg).__name__}")
    return _straight_problems(_straight_program(cfg), goals, goal_mask, target, start)


def make_planner(
    observer: ObserverLike | Mapping[str, ObserverLike], cfg: PlannerConfig = PlannerConfig()
) -> Planner:
    """A validated, compiled, batched planner for one observer or a set of named observers.

    Returns ``planner(goals (B, 8, 3), goal_mask (B, 8), target (B,), start=None,
    observer=None) -> PlanResult`` with a leading problem axis on every field; ``start``
    is ``(B, 3)`` (default TCP(q_home)). Given a mapping of observers, ``observer=`` names
    the one to plan with (default: the first). All of them share one compiled program:
    the observer is a ``lax.switch`` on an unbatched index, so the forward kinematics and
    its gradient, most of the compilation, are compiled once whatever the observer. Two
    compiled functions in all (the straight lines, the planner) per batch size.

    Raises ValueError naming the argument for: an observer that does not return (8,)
    logits; with ``cfg.taus``, an observer without ``.prefix``; NaN/inf or badly shaped
    goals, masks or starts; a target slot that is not a real goal; a start or target that
    IK cannot reach within 2 mm; an unknown observer name. (The budget and the stop times
    are checked by :class:`PlannerConfig`.)

    ``planner.straight_line(goals, goal_mask, target, start=None)`` gives the straight-line
    problems (batched; one compiled function for every start) and
    ``planner.plan_problems(problems, observer=None)`` plans them. The first call with a
    batch size compiles (10–30 s on a CPU) and says so first, in one line on
    stderr (:func:`slotv_jax.core.progress.status`).
    """
    if not isinstance(cfg, PlannerConfig):
        raise ValueError(f"cfg: expected a PlannerConfig, got {type(cfg).__name__}")
    observers = dict(observer) if isinstance(observer, Mapping) else {"observer": observer}
    if not observers:
        raise ValueError("observer: expected at least one observer")
    for name, obs in observers.items():
        try:
            check_observer(obs, cfg.n_points, prefix=cfg.taus is not None)
        except ValueError as e:
            raise ValueError(f"observer {name!r}: {e}") from None
    names = tuple(observers)
    branches = tuple(observers.values())

    def run(problems: Problem, index) -> PlanResult:
        return jax.vmap(lambda p: plan(switched_observer(index, branches), p, cfg))(problems)

    return Planner(names, cfg, jax.jit(run), _straight_program(cfg))


@dataclasses.dataclass(frozen=True, eq=False)
class Planner:
    """The planner of :func:`make_planner`: ``planner(goals (B, 8, 3), goal_mask (B, 8),
    target (B,), start=None, observer=None) -> PlanResult``, its straight lines and its
    plans of given problems. Compiled once per batch size, for every observer."""

    observers: tuple[str, ...]  # the observers' names, in the order of the switch
    config: PlannerConfig
    _run: Callable[[Problem, jax.Array], PlanResult] = dataclasses.field(repr=False)
    _straight: Callable[..., Problem] = dataclasses.field(repr=False)
    # batch sizes compiled (or being compiled) so far
    _compiled: set[int] = dataclasses.field(default_factory=set, repr=False)

    def _note(self, n: int) -> None:  # a compilation shows no progress: say so before it
        if n not in self._compiled:
            self._compiled.add(n)
            status(f"planning: compiling the straight lines and the planner for {n} problems "
                   f"and {len(self.observers)} observer(s) (10–30 s on a CPU; later calls "
                   f"with {n} problems reuse it)")  # fmt: skip

    def plan_problems(self, problems: Problem, observer: str | None = None) -> PlanResult:
        """Plan ``problems`` (of :meth:`straight_line`) with the observer named ``observer``
        (None: the first)."""
        index = _index_of(self.observers, observer, "observer")
        self._note(int(problems.goals.shape[0]))
        return self._run(problems, index)

    def straight_line(
        self,
        goals: Float[Array, "B 8 3"],
        goal_mask: Bool[Array, "B 8"],
        target: Int[Array, " B"],
        start: Float[Array, "B 3"] | None = None,
    ) -> Problem:
        """The validated straight-line problems of a batch (:func:`straight_lines`)."""
        return _straight_problems(self._straight, goals, goal_mask, target, start, self._note)

    def __call__(
        self,
        goals: Float[Array, "B 8 3"],
        goal_mask: Bool[Array, "B 8"],
        target: Int[Array, " B"],
        start: Float[Array, "B 3"] | None = None,
        observer: str | None = None,
    ) -> PlanResult:
        """Every problem planned with the observer named ``observer`` (None: the first)."""
        index = _index_of(self.observers, observer, "observer")
        return self._run(self.straight_line(goals, goal_mask, target, start), index)


def _index_of(names: Sequence[str], name: str | None, what: str) -> jax.Array:
    """The switch index of ``name`` among ``names`` (None: the first), checked."""
    if name is None:
        return jnp.int32(0)
    if name not in names:
        raise ValueError(f"{what}: expected one of {list(names)}, got {name!r}")
    return jnp.int32(names.index(name))


def make_family_planner(
    build: Callable[[Any], ObserverLike] | Mapping[str, Callable[[Any], ObserverLike]],
    example: Any,
    cfg: PlannerConfig = PlannerConfig(),
) -> FamilyPlanner:
    """A validated planner for many observers of one family in one compiled program.

    ``build(params) -> observer`` makes the observer of one parameter set (any pytree of
    arrays: a labeler's β, a checkpoint's ``params`` with
    :func:`slotv_jax.training.checkpoint.make_observer`); it must accept traced
    parameters. ``example`` is one parameter set, for the checks of :func:`make_planner`.
    Returns ``planner(params, goals (B, 8, 3), goal_mask (B, 8), target (B,), start=None,
    family=None) -> PlanResult`` whose fields have leading axes (F, B): every problem
    planned with every one of the F parameter sets stacked along the leading axis of
    ``params``. It compiles once per (F, B) and parameter structure, whatever the values:
    the planner for the dozens of observers a study fits.
    ``planner.plan_problems(params, problems, family=None)`` plans problems of
    ``planner.straight_line(goals, goal_mask, target, start=None)``.

    Given a mapping ``{name: build}``, several families read one parameter pytree (each
    its own part of it) and ``family=`` names the one to plan with (default: the first);
    they share one compiled program, a ``lax.switch`` on an unbatched index as in
    :func:`make_planner` (``planner.families``: the names): every family fitted in every
    run of a study, planned with one compilation.

    The pattern it packages, which :func:`plan`'s purity allows (the observer is built
    from traced parameters inside the compiled function):

    >>> import jax, jax.numpy as jnp
    >>> from slotv_jax import planning, scene
    >>> cfg = planning.PlannerConfig(iters=5, taus=(0.4, 0.7, 1.0))
    >>> s = scene.sample_scene(jax.random.key(0), 3)
    >>> problems = jax.vmap(lambda t: planning.straight_line(s.goals, s.goal_mask, t, cfg=cfg))(
    ...     jnp.array([0, 1]))                                              # doctest: +SKIP
    >>> def plan_all(beta):  # one β: every problem
    ...     obs = planning.labeler_observer("dragan", beta=beta)
    ...     return jax.vmap(lambda p: planning.plan(obs, p, cfg))(problems)
    >>> res = jax.jit(jax.vmap(plan_all))(jnp.array([5.0, 10.0, 20.0]))   # doctest: +SKIP
    >>> res.xyz.shape                                                       # doctest: +SKIP
    (3, 2, 100, 3)
    """
    if not isinstance(cfg, PlannerConfig):
        raise ValueError(f"cfg: expected a PlannerConfig, got {type(cfg).__name__}")
    builds = dict(build) if isinstance(build, Mapping) else {"family": build}
    if not builds:
        raise ValueError("build: expected at least one family")
    abstract = jax.eval_shape(lambda p: p, example)
    spec = (jax.ShapeDtypeStruct((cfg.n_points, 3), jnp.float32),
            jax.ShapeDtypeStruct((G_MAX, 3), jnp.float32),
            jax.ShapeDtypeStruct((G_MAX,), jnp.bool_))  # fmt: skip
    for name, b in builds.items():
        what = "build" if not isinstance(build, Mapping) else f"build {name!r}"
        if not callable(b):
            raise ValueError(f"{what}: expected a function of parameters, got {type(b).__name__}")
        try:
            check_observer(b(example), cfg.n_points, prefix=cfg.taus is not None)
            jax.eval_shape(lambda p, *a, b=b: b(p)(*a), abstract, *spec)
        except ValueError as e:
            raise ValueError(f"{what}: {e}") from None
        except Exception as e:  # build(traced parameters) failed
            raise ValueError(f"{what}: it does not accept traced parameters ({e})") from e
    names, fns = tuple(builds), tuple(builds.values())

    def observer_of(index, p) -> ObserverLike:  # every family's observer of p, switched
        return switched_observer(index, [b(p) for b in fns])

    def plan_grid(params, problems: Problem, index) -> PlanResult:
        def one_set(p):
            obs = observer_of(index, p)
            return jax.vmap(lambda prob: plan(obs, prob, cfg))(problems)

        # One parameter set (a population's oracle: loop.oracle_plans) is planned without
        # the vmap over sets, its axis put back after. jaxlib 0.10.2's CPU backend
        # segfaults in a YNNPACK reduce fusion (slinky's make_transpose_impl) on a sum over
        # a non-minor axis of a product of two rank-7 arrays with a size-1 axis, e.g.
        # jax.jit(lambda x, y: (x * y).sum(-2)) on two f32[1, 3, 2, 4, 20, 8, 3]; the
        # population's gradient has that sum over the goals when the vmap over one
        # parameter set adds its size-1 axis (sets, problems, stop times, viewpoints,
        # points, goals, xyz). XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=-reduce
        # also avoids it. Test: test_planning's one-parameter-set population test.
        if {jnp.shape(a)[:1] for a in jax.tree.leaves(params)} == {(1,)}:
            one = one_set(jax.tree.map(lambda a: a[0], params))
            return jax.tree.map(lambda a: a[None], one)
        return jax.vmap(one_set)(params)

    return FamilyPlanner(names, cfg, jax.jit(plan_grid), _straight_program(cfg))


@dataclasses.dataclass(frozen=True, eq=False)
class FamilyPlanner:
    """The planner of :func:`make_family_planner`: ``planner(params, goals (B, 8, 3),
    goal_mask (B, 8), target (B,), start=None, family=None) -> PlanResult`` with leading
    axes (F, B), its straight lines and its plans of given problems."""

    families: tuple[str, ...]  # the families' names, in the order of the switch
    config: PlannerConfig
    _run: Callable[[Any, Problem, jax.Array], PlanResult] = dataclasses.field(repr=False)
    _straight: Callable[..., Problem] = dataclasses.field(repr=False)

    def plan_problems(self, params, problems: Problem, family: str | None = None) -> PlanResult:
        """Plan ``problems`` (of :meth:`straight_line`) with every parameter set of
        ``params`` (stacked on the leading axis) of the family named ``family``."""
        return self._run(params, problems, _index_of(self.families, family, "family"))

    def straight_line(
        self,
        goals: Float[Array, "B 8 3"],
        goal_mask: Bool[Array, "B 8"],
        target: Int[Array, " B"],
        start: Float[Array, "B 3"] | None = None,
    ) -> Problem:
        """The validated straight-line problems of a batch (:func:`straight_lines`)."""
        return _straight_problems(self._straight, goals, goal_mask, target, start)

    def __call__(
        self,
        params,
        goals: Float[Array, "B 8 3"],
        goal_mask: Bool[Array, "B 8"],
        target: Int[Array, " B"],
        start: Float[Array, "B 3"] | None = None,
        family: str | None = None,
    ) -> PlanResult:
        """Every problem planned with every parameter set of ``params`` of ``family``."""
        index = _index_of(self.families, family, "family")
        return self._run(params, self.straight_line(goals, goal_mask, target, start), index)


def _out_of_reach(name: str, i: int, pos, why: str) -> ValueError:
    """The planner's one refusal of a start or target it cannot reach."""
    return ValueError(
        f"{name}: problem {i} at {np.round(np.asarray(pos, np.float64), 4).tolist()} m is "
        f"out of reach ({why})"
    )


def _check_reach(name: str, pos: np.ndarray) -> None:
    """Before anything compiles: no start or target ``pos`` (B, 3) that no configuration
    reaches within MAX_RESIDUAL, farther than the arm's links laid end to end
    (:func:`slotv_jax.robot.kinematics.reach`) plus MAX_RESIDUAL from its shoulder: the
    IK residual of :func:`check_problems` would be larger than MAX_RESIDUAL for it."""
    centre, radius = kinematics.reach()
    dist = np.linalg.norm(np.asarray(pos, np.float64) - centre, axis=-1)
    bad = np.flatnonzero(dist > radius + MAX_RESIDUAL)
    if bad.size:
        i = int(bad[0])
        raise _out_of_reach(name, i, pos[i], f"{dist[i]:.3f} m from the Panda's shoulder, "
                            f"which its links reach {radius:.3f} m from")  # fmt: skip


def check_problems(problems: Problem) -> None:
    """Raise ValueError if a (batched, concrete) problem's start or target is out of reach."""
    for name, res in (("start", problems.start_residual), ("target", problems.target_residual)):
        r = np.asarray(res, np.float64).reshape(-1)
        bad = ~(r <= MAX_RESIDUAL)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            where = np.asarray(problems.start if name == "start" else problems.goals)
            pos = where.reshape(r.size, -1, 3)[i, 0] if name == "start" else None
            if name == "target":
                pos = where.reshape(r.size, G_MAX, 3)[
                    i, int(np.asarray(problems.target).reshape(-1)[i])
                ]
            why = f"IK residual {r[i] * 1e3:.1f} mm > {MAX_RESIDUAL * 1e3:.0f} mm"
            raise _out_of_reach(name, i, pos, why)
