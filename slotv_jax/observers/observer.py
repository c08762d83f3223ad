"""The observer, everywhere in the public API: one type, and the protocol a planner needs.

An observer maps one motion to logits over the eight goal slots (padded slots −∞), for
the whole motion and for the motion seen up to its first ``seen`` points::

    observer(xyz (T, 3), goals (8, 3), goal_mask (8,)) -> logits (8,)
    observer.prefix(xyz, goals, goal_mask, seen) -> logits (8,)    # seen: int32 scalar, traced

- :class:`ObserverLike` is what a planner requires of one (:mod:`slotv_jax.planning`): any
  callable with a ``prefix`` method or attribute, as a researcher writes for their own model
  of people (a function with a ``prefix`` attribute qualifies, a class of their own too).
- :class:`Observer` is what the library hands out: :func:`slotv_jax.load_observer`, the
  labelers with β bound (:func:`slotv_jax.planning.labeler_observer`), the archetypes
  (:func:`slotv_jax.observers.archetypes.archetype_observer`), a population's
  (:func:`slotv_jax.observers.population.population_observer`) and the pool of observers
  (:func:`slotv_jax.answers.pool_observer`, :func:`slotv_jax.answers.load_pool`). It is a
  pytree whose leaves are its parameters: pass it through ``jit``, ``vmap`` and ``grad``, or
  stack the observers of one family, ``jax.tree.map(lambda *p: jnp.stack(p), *observers)``,
  and ``vmap`` a planner over them.

>>> import jax, jax.numpy as jnp
>>> from slotv_jax import planning
>>> obs = planning.labeler_observer("effdist", beta=jnp.float32(10.0))
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.0]).at[1].set([0.5, -0.2, 0.0])
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.4]), g[0], 20)
>>> m = jnp.arange(8) < 2
>>> grad = jax.grad(lambda o: jax.nn.log_softmax(o(xyz, g, m))[0])(obs)  # d/dβ, an Observer
>>> bool(grad.params > 0)
True
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable
from typing import Any, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import validation
from slotv_jax.core.validation import G_MAX

__all__ = ["Observer", "ObserverLike", "check_observer_inputs", "check_seen"]


@runtime_checkable
class ObserverLike(Protocol):
    """What a planner requires of an observer: a callable ``(xyz (T, 3), goals (8, 3),
    goal_mask (8,)) -> logits (8,)`` with ``prefix(xyz, goals, goal_mask, seen) -> logits
    (8,)`` (``seen`` an int32 scalar, traced). The planner calls ``prefix`` only for the
    prefix objective (``PlannerConfig.taus``). :class:`Observer` is one; so is any object
    or function of the user's with both."""

    def __call__(
        self, xyz: Float[Array, "T 3"], goals: Float[Array, "8 3"], goal_mask: Bool[Array, " 8"]
    ) -> Float[Array, " 8"]: ...

    def prefix(
        self,
        xyz: Float[Array, "T 3"],
        goals: Float[Array, "8 3"],
        goal_mask: Bool[Array, " 8"],
        seen: Int[Array, ""],
    ) -> Float[Array, " 8"]: ...


@dataclasses.dataclass(frozen=True, eq=False)
class Observer:
    """An observer of the library: its parameters (the pytree's leaves) and its static
    config, with the two functions that compute its logits from them.

    ``observer(xyz, goals, goal_mask)`` is ``logits_fn(config, params, xyz, goals,
    goal_mask)``, ``observer.prefix(xyz, goals, goal_mask, seen)`` is ``prefix_fn(config,
    params, xyz, goals, goal_mask, seen)``. Only ``params`` is a pytree child; ``config``,
    ``name`` and the functions are static metadata (hashable, compared by value or, for
    the functions, identity), so two observers of one family and config have one tree
    structure: stack their parameters and ``vmap`` over them, or take ``jax.grad`` with
    respect to the observer (the gradient is an :class:`Observer` whose ``params`` are the
    gradients). ``dataclasses.replace(observer, params=p)`` (:meth:`replace`) is the
    observer at other parameters, traced ones included.

    A frozen dataclass registered with ``jax.tree_util.register_dataclass`` [choice]: core
    JAX, the same mechanism as ``flax.struct.dataclass`` without a Flax object in the type
    a user composes with; the functions are static fields as in ``jax.tree_util.Partial``.
    Equality is identity (``eq=False``): the parameters are arrays.
    """

    # logits_fn(config, params, xyz, goals, goal_mask) -> (8,)
    logits_fn: Callable[..., Array] = dataclasses.field(repr=False)
    # prefix_fn(config, params, xyz, goals, goal_mask, seen) -> (8,)
    prefix_fn: Callable[..., Array] = dataclasses.field(repr=False)
    params: Any = dataclasses.field(default=(), repr=False)  # pytree of arrays: weights, β, ...
    config: Hashable = None  # static: what, with the functions, defines the family
    name: str = ""  # static: how messages name it ("dragan", "pool", ...)
    # model_fn(config, params) -> the model behind it (a learned observer's network or archetype)
    model_fn: Callable[[Any, Any], Any] | None = dataclasses.field(default=None, repr=False)

    def __call__(
        self, xyz: Float[Array, "T 3"], goals: Float[Array, "8 3"], goal_mask: Bool[Array, " 8"]
    ) -> Float[Array, " 8"]:
        """The logits (8,) of the whole motion ``xyz`` (T, 3), padded slots −∞."""
        return self.logits_fn(self.config, self.params, xyz, goals, goal_mask)

    def prefix(
        self,
        xyz: Float[Array, "T 3"],
        goals: Float[Array, "8 3"],
        goal_mask: Bool[Array, " 8"],
        seen: Int[Array, ""],
    ) -> Float[Array, " 8"]:
        """The logits (8,) of the motion seen up to its first ``seen`` points (2 ≤ seen ≤ T,
        an int32 scalar, may be traced)."""
        return self.prefix_fn(self.config, self.params, xyz, goals, goal_mask, seen)

    def replace(self, **changes) -> Observer:
        """This observer with fields replaced: ``observer.replace(params=p)``."""
        return dataclasses.replace(self, **changes)

    def model(self) -> Any:
        """The model behind a learned observer (its network or archetype, an ``nnx``
        module at these parameters); ValueError for an observer without one."""
        if self.model_fn is None:
            raise ValueError(f"observer {self.name!r}: it has no learned model behind it")
        return self.model_fn(self.config, self.params)

    def describe(self) -> str:
        """An archetype's fitted parameters with their units, in words (:meth:`model`'s)."""
        return self.model().describe()

    def parameters(self) -> dict[str, float]:
        """An archetype's fitted parameters by name (:meth:`model`'s)."""
        return self.model().parameters()


jax.tree_util.register_dataclass(
    Observer,
    data_fields=["params"],
    meta_fields=["logits_fn", "prefix_fn", "config", "name", "model_fn"],
)


def check_observer_inputs(xyz, goals, goal_mask, *, batch_shape: tuple[int, ...] = ()) -> None:
    """Boundary checks for one trajectory (or a batch): shapes, finiteness, a real goal.

    ``xyz`` is (..., T, 3) with T ≥ 2, ``goals`` (..., 8, 3), ``goal_mask`` (..., 8) with
    at least one real goal. Value checks run only on concrete arrays.
    """
    validation.check_array("xyz", xyz, (*batch_shape, None, 3))
    if jnp.shape(xyz)[-2] < 2:
        raise ValueError(f"xyz: expected at least 2 trajectory points, got shape {jnp.shape(xyz)}")
    validation.check_array("goals", goals, (*batch_shape, G_MAX, 3))
    validation.check_goal_mask("goal_mask", goal_mask, batch_shape=batch_shape)


def check_seen(seen, n_points: int, *, batch_shape: tuple[int, ...] = ()) -> None:
    """Boundary check of a prefix length: ``seen`` is an integer of shape ``batch_shape``
    with 2 ≤ seen ≤ ``n_points`` (values checked only when concrete)."""
    if jnp.shape(seen) != tuple(batch_shape):
        raise ValueError(f"seen: expected shape {tuple(batch_shape)}, got {jnp.shape(seen)}")
    if not jnp.issubdtype(jnp.result_type(seen), jnp.integer) or isinstance(seen, bool):
        raise ValueError(f"seen: expected an integer count of points, got {seen!r}")
    if validation.is_concrete(seen):  # NumPy: jnp would trace a Python int inside jit
        v = np.asarray(seen)
        if not bool(np.all((v >= 2) & (v <= n_points))):
            raise ValueError(
                f"seen: expected 2 <= seen <= {n_points} (the trajectory's points), got "
                f"{v.tolist()}"
            )
