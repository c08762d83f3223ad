"""The observer as a type (slotv_jax.observers.observer): every observer the library hands
out is one ``Observer``, a pytree of its parameters that ``jit``, ``vmap`` and ``grad`` take
whole, and the planner takes any ``ObserverLike`` of the user's.

References: each stacked observer called or planned alone; ``jax.grad`` of the labeler's
own function of β and ``nnx.grad`` of the archetype's module; a user's observer against
the library's labeler observer of the same formula.
"""

from __future__ import annotations

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_log import counting_traces
from flax import nnx

from slotv_jax import planning
from slotv_jax.answers import pool_observer
from slotv_jax.observers import archetypes, labelers
from slotv_jax.observers import population as population_lib
from slotv_jax.observers.common import masked_log
from slotv_jax.observers.observer import Observer, ObserverLike
from slotv_jax.observers.prefix import prefix_labels
from slotv_jax.training import checkpoint
from slotv_jax.training.config import TrainConfig

PACKAGE = Path(__file__).resolve().parent.parent / "slotv_jax"
# Plans of stacked observers against each planned alone: the same float32 program, batched
# (XLA may order a batched reduction differently), a few steps from the same straight line.
PLAN_TOL = 1e-5  # m
LOGIT_TOL = 1e-5
GRAD_RTOL = 1e-5
CFG = planning.PlannerConfig(n_points=20, iters=4, taus=(0.5, 1.0))


def _scene():
    g = jnp.zeros((8, 3)).at[0].set([0.5, 0.2, 0.025]).at[1].set([0.5, -0.2, 0.025])
    g = g.at[2].set([0.45, 0.0, 0.025])
    m = jnp.arange(8) < 3
    xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.45]), g[0], 20)
    return xyz, g, m


def _fitted_dragans() -> list[Observer]:
    """Three observers of one family and config, at other parameters (as three fits of
    the Dragan archetype would be)."""
    cfg = TrainConfig(model="dragan")
    inits = ({"beta": 3.0}, {"beta": 8.0, "alpha": 0.5}, {"beta": 15.0, "start_weight": 0.5})
    params = [nnx.split(archetypes.make_archetype("dragan", **kw))[1] for kw in inits]
    return [checkpoint.make_observer(cfg, p) for p in params]


def test_every_library_observer_is_the_type():
    xyz, g, m = _scene()
    learned = _fitted_dragans()[0]
    label = planning.labeler_observer("nikolaidis", beta=6.0)
    arche = archetypes.archetype_observer("mixture")
    pop = population_lib.population_observer(population_lib.homogeneous())
    pool = pool_observer([learned, label], [0.4, 0.6])
    for obs in (learned, label, arche, pop, pool):
        assert isinstance(obs, Observer) and isinstance(obs, ObserverLike)
        leaves = jax.tree.leaves(obs)
        assert leaves and all(isinstance(x, jax.Array | np.ndarray | float) for x in leaves)
        assert obs(xyz, g, m).shape == (8,)
        assert obs.prefix(xyz, g, m, jnp.int32(7)).shape == (8,)
    assert learned.config == TrainConfig(model="dragan") and label.config == (
        "nikolaidis",
        "observer",
    )
    assert pool.config == ("dragan", "nikolaidis")
    assert pop.config == population_lib.homogeneous()
    # the archetype explains itself through the type
    assert arche.parameters() == archetypes.make_archetype("mixture").parameters()
    with pytest.raises(ValueError, match="no learned model"):
        label.describe()


def test_nothing_is_set_on_a_function_after_the_fact():
    """No attribute is set on an observer or planner function (the type carries them)."""
    hits = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if "type: ignore[attr-defined]" in line or re.search(r"\w\.prefix = ", line):
                hits.append(f"{path.relative_to(PACKAGE)}:{i}: {line.strip()}")
    assert not hits, "\n".join(hits)


@pytest.mark.slow
def test_stacked_observers_score_and_plan_in_one_vmap():
    """The parameters of three fitted observers of one family, stacked through the public
    type (``jax.tree.map(jnp.stack, ...)`` over the observers themselves), vmapped through
    one planner: each slice equals that observer scored and planned alone."""
    observers = _fitted_dragans()
    stacked = jax.tree.map(lambda *p: jnp.stack(p), *observers)
    assert isinstance(stacked, Observer) and stacked.config == observers[0].config
    xyz, g, m = _scene()
    logits = jax.jit(jax.vmap(lambda o: o.prefix(xyz, g, m, jnp.int32(12))))(stacked)
    for i, obs in enumerate(observers):
        np.testing.assert_allclose(logits[i], obs.prefix(xyz, g, m, 12), atol=LOGIT_TOL)
    assert np.abs(np.diff(np.asarray(logits[:, :3]), axis=0)).max() > 1e-2  # three observers

    problems = planning.straight_lines(
        np.stack([g, g]), np.stack([m, m]), np.array([0, 1]), cfg=CFG
    )

    def plan_all(obs):  # one observer: every problem
        return jax.vmap(lambda p: planning.plan(obs, p, CFG))(problems)

    res = jax.jit(jax.vmap(plan_all))(stacked)
    assert res.xyz.shape == (3, 2, CFG.n_points, 3)
    counted, traces = counting_traces(plan_all)
    one = jax.jit(counted)  # an Observer is a jit argument: one program for all three
    for i, obs in enumerate(observers):
        alone = one(obs)
        np.testing.assert_allclose(res.xyz[i], alone.xyz, atol=PLAN_TOL)
        np.testing.assert_array_equal(res.feasible[i], alone.feasible)
    assert np.abs(res.xyz[0] - res.xyz[2]).max() > 1e-4  # other observers, other plans
    assert len(traces) == 1


def test_grad_with_respect_to_the_observer_parameters():
    """``jax.grad`` of a score with respect to an observer gives an Observer of gradients:
    for a labeler, d/dβ of the labeler's own function; for a fitted archetype, ``nnx.grad``
    of its module."""
    xyz, g, m = _scene()
    beta = jnp.float32(7.0)
    obs = planning.labeler_observer("dragan", beta=beta)
    got = jax.grad(lambda o: jax.nn.log_softmax(o(xyz, g, m))[0])(obs)
    assert isinstance(got, Observer) and got.name == "dragan"
    want = jax.grad(lambda b: jnp.log(labelers.dragan(xyz, g, m, beta=b)[0]))(beta)
    np.testing.assert_allclose(got.params, want, rtol=GRAD_RTOL)
    seen = jnp.int32(9)
    got = jax.grad(lambda o: jax.nn.log_softmax(o.prefix(xyz, g, m, seen))[1])(obs)
    want = jax.grad(lambda b: jnp.log(prefix_labels("dragan", xyz, g, m, seen, beta=b)[1]))(beta)
    np.testing.assert_allclose(got.params, want, rtol=GRAD_RTOL)

    fitted = _fitted_dragans()[1]
    got = jax.jit(jax.grad(lambda o: jax.nn.log_softmax(o(xyz, g, m))[0]))(fitted)
    module = archetypes.make_archetype("dragan", beta=8.0, alpha=0.5)
    want = nnx.grad(lambda mod: jax.nn.log_softmax(mod(xyz, g, m))[0])(module)
    for a, b in zip(jax.tree.leaves(got.params), jax.tree.leaves(want), strict=True):
        np.testing.assert_allclose(a, b, rtol=GRAD_RTOL, atol=1e-7)
    assert any(float(jnp.abs(a).max()) > 0 for a in jax.tree.leaves(got.params))


class MyDragan:
    """A researcher's own observer: a plain class, not the library's type."""

    def __init__(self, beta: float):
        self.beta = beta

    def __call__(self, xyz, goals, goal_mask):
        return masked_log(labelers.dragan(xyz, goals, goal_mask, beta=self.beta), goal_mask)

    def prefix(self, xyz, goals, goal_mask, seen):
        y = prefix_labels("dragan", xyz, goals, goal_mask, seen, beta=self.beta)
        return masked_log(y, goal_mask)


@pytest.mark.slow
def test_the_planner_takes_a_users_own_observer():
    """A plain class and a plain function with a ``prefix`` attribute are observers to the
    planner (``ObserverLike``) and plan what the library's labeler observer of the same
    formula plans."""
    mine = MyDragan(10.0)

    def fn(xyz, goals, goal_mask):
        return mine(xyz, goals, goal_mask)

    fn.prefix = mine.prefix
    for obs in (mine, fn):
        assert isinstance(obs, ObserverLike) and not isinstance(obs, Observer)
    _, g, m = _scene()
    planner = planning.make_planner(
        {"class": mine, "function": fn, "library": planning.labeler_observer("dragan", beta=10.0)},
        CFG,
    )
    assert planner.observers == ("class", "function", "library")
    problems = planner.straight_line(np.stack([g, g]), np.stack([m, m]), np.array([0, 2]))
    want = planner.plan_problems(problems, observer="library")
    assert bool(np.all(want.feasible))
    for name in ("class", "function"):
        got = planner.plan_problems(problems, observer=name)
        np.testing.assert_allclose(got.xyz, want.xyz, atol=PLAN_TOL)
