"""A population of simulated people: a documented mixture of observers (issue 37,
:ref:`concepts-populations`).

The four labelers of :ref:`concepts-temperatures` are each one formula at one temperature; people
are not. A *population* is a distribution over participants, each of whom has their own viewpoint,
inference rule, temperature and memory, and sometimes guesses at random. This module states
that model, so that every result obtained from simulated people can say which people
(STYLE principle 20). The model, part by part, with the reason for each:

**Viewpoint** v (``viewpoints``: name → probability). A participant watches the motion on
a screen, filmed by one of the scene's observer cameras (:ref:`concepts-cameras`; the default draws
``observer``, ``observer_angle`` and ``observer_side`` uniformly, the cameras the study's
clips are rendered from), and judges what they see: the points and goals projected into
that camera's normalised image plane, :func:`slotv_jax.world.scene.image_coords`,
``(u, v) = (p_c.x, p_c.y) / (−p_c.z)`` with ``p_c = Rᵀ (p − c)``, written here as
``q = (u, v, 0)``. The viewpoint ``world`` is no projection (``q = p`` in metres): the
labelers' Dragan observer, who sees the motion in 3-D, for the homogeneous population. A
participant who cannot see a seen point or a real goal (camera depth ≤ 1e-6) has no
preference: their guess is uniform over the real goals (as :func:`labelers.nikolaidis`).

**Inference rule** r (``rules``: rule → probability) with its *evidence* ``e_k(i)`` that
point i (of the points seen so far, ``q_0 = S`` the start) gives for goal k (``h_k`` the
goal in the viewpoint's coordinates, ‖·‖ Euclidean)::

    cost_to_go  e_k(i) = ‖S − h_k‖ − ‖q_i − h_k‖                                   (0.5)
    proximity   e_k(i) = −‖q_i − h_k‖                                               (0.3)
    direction   e_k(i) = cos_ε(q_i − q_{i−1}, h_k − q_i),  e_k(0) = 0               (0.2)
                cos_ε(a, b) = a·b / (√(‖a‖² + ε²) √(‖b‖² + ε²)),  ε = 1e-4

``cost_to_go`` is Dragan & Srinivasa's observer (RSS 2013; :ref:`concepts-dragan`), and in the image
Nikolaidis et al.'s (HRI 2016; :ref:`concepts-nikolaidis`): the goal to which the motion so far has
been the most efficient detour. It is the default's most common rule (half of the people; the
proportions are a choice) because it is the model that legibility studies test people
against and found to predict them. ``proximity`` is the goal nearest the gripper (a naive
reading that ignores where the motion began; FastApp-like in spirit, :ref:`concepts-fastapp`: the
motion "is at" a goal when it comes near it): 30 %. ``direction`` is the goal the gripper is
heading for, from its velocity between the last two points: 20 %,
the rarest, because a robot arm's early velocity mostly lifts away from the table rather
than pointing at a cube, so it is the weakest reading. At the start (i = 0) no motion has
been seen: ``e(0) = 0``. ε (in the viewpoint's unit) damps the direction of steps or goal
vectors shorter than about 1e-4 (0.1 mm at 1 m) towards "no evidence", so that a gripper at
rest or on a goal gives finite values and gradients: it scales the cosine by
1/√(1 + (ε/‖step‖)²), by less than 1 % for steps above 7e-4 (1 mm at the cameras' 1.3 m).

Each seen point's evidence gives a per-point belief, a softmax over the real goals::

    P_k(i) = exp(β e_k(i)) / Σ_{l real} exp(β e_l(i))

**Temperature** β (``beta``: a centre β₀ per rule; ``beta_sigma_log`` σ): each participant
draws ``β = β₀ · exp(σ z)``, ``z ~ N(0, 1)`` (log-normal with median β₀: some people read a
motion sharply, some hesitate; σ = 0.5 puts the middle 68 % within a factor 1.65 of β₀;
σ ≤ :data:`SIGMA_LOG_MAX`, and every β a participant can get, at the quadrature's outer node
too, at most :data:`BETA_MAX`, so that P_pop stays finite in float32).
β's unit is the inverse of the evidence's: per unit of image plane for the cameras (≈ per
metre at 1 m depth; the scene's cameras stand 1.3 m from the workspace centre), per metre
for ``world``, none for ``direction`` (a cosine). The default's centres: ``cost_to_go``
30 (the dataset's Nikolaidis temperature, :data:`DEFAULT_BETAS` ``["nikolaidis"]``, the
same rule in the same image units); ``proximity`` 30 (the same unit, and its evidence
differs from cost-to-go's only by the start term ‖S − h_k‖, so the two rules differ in
memory of the start, not in sharpness); ``direction`` 5 (a choice: a goal straight ahead
is e⁵ ≈ 150 times as likely as one at 90°, one at 30° about half as likely as one straight
ahead: a noisy reading of heading). A population that mixes ``world`` and camera viewpoints
uses one β₀ per rule for both units: give such a file its own centres with that in mind.

**Memory** (``memory``): how a participant combines the points they have seen into one
guess. The guess distribution of participant n seen up to point L (points 0..L−1) is the
mixture of the per-point beliefs::

    y_k = Σ_{i<L} w_i P_k(i),   Σ_{i<L} w_i = 1

(as Dragan's legibility integrates P(g | ξ_{S→ξ(t)}) over time): the participant recalls a
moment i with probability w_i and guesses from what it showed. ``recency``: point i of the
L seen (the (i+1)-th, counting from 1) weighs ``w_i ∝ ((i + 1) / L)^α`` with
``α ~ U(alpha_range)``; the default ``[0, 2]`` spans everyone from those who weigh the whole
motion equally (α = 0) to those who mostly judge from its last few points (α = 2: the last
third of the points carries 70 % of the weight at L = 100): people update their guess as a
motion unfolds, recent points weigh more. ``dragan``: :ref:`concepts-dragan`'s fixed weights over
the seen prefix, ``w_i ∝ trap_i (1 − t_i)`` at ``t_i = i / (L − 1)`` (the trapezoid rule times
``1 − t``, :func:`slotv_jax.observers.common.time_weights`; early points weigh more):
the labelers' own observer. Points ≥ L are not seen: they enter neither the value nor the
gradient.

**Lapse** λ (``lapse``): with probability λ a guess is uniform over the real goals (a
participant who was not looking, or clicked by mistake; 5 % in the default, a usual lapse
rate of psychophysics: Wichmann & Hill, Percept. Psychophys. 2001, allow 0–6 %).
Participant n's guess distribution is ``p^(n) = (1 − λ) y^(n) + λ u`` (u uniform over the
real goals).

**The population's guess distribution** is the expectation over its participants,
the probability that a participant drawn from the population guesses g::

    P_pop(g | ξ_{0:L}) = E_{v, r, β, α}[ p^(n)_g ]

an exact sum over the viewpoints and rules, and a Gauss quadrature over log β (Hermite,
``beta_nodes``) and α (Legendre, ``alpha_nodes``): the weighted mean over a fixed set of
representative participants, the quadrature nodes (:func:`quadrature`). It is a pure,
deterministic, differentiable JAX function of the path (:func:`population_probs`; as an
observer for a planner, :func:`population_observer`), within 3e-6 of the expectation with
the default 8 + 8 nodes (measured against 64 + 64), where the mean over a random sample of
N participants has a standard error of up to 0.5 / √N per goal (0.016 at N = 1024). It is
also cheaper: the nodes share one evidence table per viewpoint and rule and one set of
mean memory weights. On the planner's batch (50 paths × 3 stop times, T = 100, 5 goals) on
the 2-core CPU, P_pop takes 8 ms and its gradient 60 ms, for every population alike (the
quadrature is padded to one shape, :func:`quadrature`; experiments/BENCHMARKS.md), against
1.6 s and 1.4 s for the mean over 1024 drawn participants (measured when P_pop was written).
:func:`sample_guesses` draws the guesses of fresh participants, each with their own
parameters (:func:`draw_participants`): their frequencies estimate the same distribution.
The ``homogeneous`` population (everyone the dataset's Dragan labeler: ``world``,
``cost_to_go`` at β = :data:`DEFAULT_BETAS` ``["dragan"]``, σ = 0, ``dragan`` memory, no
lapse) has ``P_pop = labelers.dragan(xyz[:L], goals, goal_mask)``.

A population is a :class:`Population` (frozen; :meth:`Population.from_dict`,
:meth:`Population.to_dict`) and a JSON file with the same fields (:func:`load_population`,
:func:`save_population`; the README documents the format). :func:`get_population` resolves
``default``, ``homogeneous`` or a file name, for commands.

>>> import jax.numpy as jnp
>>> from slotv_jax.observers import labelers
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
>>> mask = jnp.arange(8) < 2
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
>>> p = population_probs(quadrature(homogeneous()), xyz, g, mask, 60)
>>> bool(jnp.allclose(p, labelers.dragan(xyz[:60], g, mask), atol=1e-6))
True
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.core import fileio
from slotv_jax.core.defaults import DEFAULT_BETAS
from slotv_jax.core.validation import FLOAT32_MAX
from slotv_jax.observers.common import masked_log, pairwise_distances, sums, time_weights
from slotv_jax.observers.observer import Observer
from slotv_jax.world import scene

__all__ = [
    "BETA_MAX",
    "DEPTH_EPS",
    "DIRECTION_EPS",
    "MAX_NODES",
    "MEMORIES",
    "NODE_SLOTS",
    "PRESETS",
    "RANDOM_PREFIX",
    "RULES",
    "SIGMA_LOG_MAX",
    "SUITE_DRAWS",
    "VIEW_SLOTS",
    "WORLD",
    "Z_DRAW_MAX",
    "Participants",
    "Population",
    "Quadrature",
    "Viewpoints",
    "default",
    "draw_participants",
    "get_population",
    "guess_goals",
    "homogeneous",
    "load_population",
    "parse_random",
    "participant_drawer",
    "participant_probs",
    "population_observer",
    "population_probs",
    "quadrature",
    "quadrature_observer",
    "random_population",
    "sample_guesses",
    "sample_guesses_batch",
    "save_population",
    "suite_specs",
]

#: The inference rules, in the order of :attr:`Participants.rule`'s indices.
RULES: tuple[str, ...] = ("cost_to_go", "proximity", "direction")
#: The memory kinds: ``recency`` ((i + 1) / L)^α, ``dragan`` :ref:`concepts-dragan`'s time weights.
MEMORIES: tuple[str, ...] = ("recency", "dragan")
#: The viewpoint that sees the motion in world coordinates (no projection).
WORLD = "world"
_ALL_RULES: tuple[int, ...] = tuple(range(len(RULES)))  # every rule's evidence is computed
#: The viewpoints a :class:`Quadrature` or :class:`Participants` holds: every camera of the
#: scene and ``world`` (a population's own first, then ``world`` slots of weight 0).
VIEW_SLOTS = len(scene.CAMERAS) + 1
#: The quadrature nodes of each kind a :class:`Quadrature` holds at least (the default's):
#: populations with fewer are padded, so that they share one compiled program.
NODE_SLOTS = 8
#: ε of the direction rule's cosine (in the viewpoint's unit).
DIRECTION_EPS = 1e-4
#: A point or real goal at camera depth ≤ this is not seen (as :ref:`concepts-cameras`'s labeler).
DEPTH_EPS = 1e-6
#: The most quadrature nodes a population may ask for (per parameter).
MAX_NODES = 64
#: The widest spread of log β a population may have: σ ≤ 5 (the middle two thirds of people
#: within a factor e⁵ ≈ 150 of β₀, already far wider than any group of people reads a motion;
#: beyond it exp(σ z) at the quadrature's outer nodes leaves float32).
SIGMA_LOG_MAX = 5.0
#: ``|z|`` of the sampler's draws is below this: ``jax.random.normal`` in float32 draws
#: ``|z|`` ≤ 5.42 (its uniforms' extreme float32 values through the inverse error function).
Z_DRAW_MAX = 6.0
#: The largest temperature a participant may get (β₀ · exp(σ z) at the quadrature's outer
#: node or a draw's): β · e then stays finite in float32 (:data:`FLOAT32_MAX`) for evidence
#: ``|e|`` up to 1e7 (metres for ``world``; in a camera's image plane, a point 10 m aside at the
#: least depth seen, :data:`DEPTH_EPS`), so that P_pop is finite.
BETA_MAX = FLOAT32_MAX / 1e7
_SUM_TOL = 1e-6  # |Σ probabilities − 1| allowed in a population file

# ------------------------------------------------------------------ the config


@dataclasses.dataclass(frozen=True)
class Population:
    """A population of simulated people (see the module doc for the model and its reasons).

    The mappings are tuples of ``(name, value)`` pairs, so that a population is hashable;
    :meth:`from_dict` / :meth:`to_dict` convert to and from the JSON form (objects).
    Every field is checked on construction (ValueError naming the field).
    """

    name: str
    viewpoints: tuple[tuple[str, float], ...]  # (camera name or "world", probability)
    rules: tuple[tuple[str, float], ...]  # (rule of RULES, probability)
    beta: tuple[tuple[str, float], ...]  # (rule, centre β₀ of its log-normal temperature)
    beta_sigma_log: float  # σ of log β (0: everyone at β₀)
    memory: str  # "recency" or "dragan"
    alpha_range: tuple[float, float] | None  # recency: α ~ U(lo, hi); dragan: None
    lapse: float  # probability of a uniform guess
    beta_nodes: int  # Gauss–Hermite nodes of log β in P_pop (used when σ > 0)
    alpha_nodes: int  # Gauss–Legendre nodes of α in P_pop (recency memory)

    def __post_init__(self):
        _check_fields(self.to_dict(), f"population {self.name!r}")

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: mappings as objects, the range as a list."""
        return {
            "name": self.name,
            "viewpoints": dict(self.viewpoints),
            "rules": dict(self.rules),
            "beta": dict(self.beta),
            "beta_sigma_log": self.beta_sigma_log,
            "memory": self.memory,
            "alpha_range": None if self.alpha_range is None else list(self.alpha_range),
            "lapse": self.lapse,
            "beta_nodes": self.beta_nodes,
            "alpha_nodes": self.alpha_nodes,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "population") -> Population:
        """A population from its JSON form, every field checked first: an unknown or missing
        key, a wrong type, probabilities that do not sum to 1, a negative σ, a lapse outside
        [0, 1], an unknown camera or rule is a ValueError ``"{source}: field 'F': ..."``."""
        d = _check_fields(d, source)
        return cls(
            name=d["name"],
            viewpoints=tuple((k, float(v)) for k, v in d["viewpoints"].items()),
            rules=tuple((k, float(v)) for k, v in d["rules"].items()),
            beta=tuple((k, float(v)) for k, v in d["beta"].items()),
            beta_sigma_log=float(d["beta_sigma_log"]),
            memory=d["memory"],
            alpha_range=None if d["alpha_range"] is None else tuple(map(float, d["alpha_range"])),
            lapse=float(d["lapse"]),
            beta_nodes=int(d["beta_nodes"]),
            alpha_nodes=int(d["alpha_nodes"]),
        )

    def replace(self, **changes) -> Population:
        """A copy with ``changes`` (checked)."""
        return dataclasses.replace(self, **changes)


_FIELDS = ("name", "viewpoints", "rules", "beta", "beta_sigma_log", "memory", "alpha_range",
           "lapse", "beta_nodes", "alpha_nodes")  # fmt: skip


def _is_number(x) -> bool:
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


def _is_int(x) -> bool:
    return isinstance(x, int | np.integer) and not isinstance(x, bool)


def _check_camera(name: str, where: str) -> None:
    if name == WORLD:
        return
    try:
        scene.check_camera(name)  # the name alone: nothing posed, nothing compiled
    except ValueError as e:
        raise ValueError(f"{where}: unknown camera {name!r} ({e}; or {WORLD!r})") from None


def _check_distribution(d, field: str, where: str, allowed=None) -> None:
    """A non-empty object name → probability in [0, 1] summing to 1 (names in ``allowed``)."""
    at = f"{where}: field {field!r}"
    if not isinstance(d, Mapping) or not d:
        raise ValueError(f"{at}: expected a non-empty object of name: probability, got {d!r}")
    for k, p in d.items():
        if allowed is not None and k not in allowed:
            raise ValueError(f"{at}: unknown rule {k!r}; expected one of {list(allowed)}")
        if not (_is_number(p) and math.isfinite(p) and 0.0 <= p <= 1.0):
            raise ValueError(f"{at}: {k!r}: expected a probability in [0, 1], got {p!r}")
    total = math.fsum(float(p) for p in d.values())
    if abs(total - 1.0) > _SUM_TOL:
        raise ValueError(f"{at}: the probabilities sum to {total:.9g}, expected 1")


def _check_fields(d: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Every check of a population's JSON form; returns it as a dict."""
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: expected a JSON object of the population's fields")
    unknown = [k for k in d if k not in _FIELDS]
    if unknown:
        raise ValueError(f"{where}: field {unknown[0]!r}: unknown; expected {list(_FIELDS)}")
    missing = [k for k in _FIELDS if k not in d]
    if missing:
        raise ValueError(f"{where}: field {missing[0]!r}: missing")

    def at(field):
        return f"{where}: field {field!r}"

    if not isinstance(d["name"], str) or not d["name"]:
        raise ValueError(f"{at('name')}: expected a non-empty string, got {d['name']!r}")
    _check_distribution(d["viewpoints"], "viewpoints", where)
    for k in d["viewpoints"]:
        _check_camera(k, at("viewpoints"))
    _check_distribution(d["rules"], "rules", where, RULES)
    beta = d["beta"]
    if not isinstance(beta, Mapping) or set(beta) != set(d["rules"]):
        raise ValueError(
            f"{at('beta')}: expected one temperature centre per rule of 'rules' "
            f"({list(d['rules'])}), got {beta!r}"
        )
    for k, b in beta.items():
        if not (_is_number(b) and 0 < b <= BETA_MAX):
            raise ValueError(
                f"{at('beta')}: {k!r}: expected a number in (0, {BETA_MAX:.3g}] (β · evidence "
                f"finite in float32), got {b!r}"
            )
    s = d["beta_sigma_log"]
    if not (_is_number(s) and 0 <= s <= SIGMA_LOG_MAX):
        raise ValueError(
            f"{at('beta_sigma_log')}: expected a number in [0, {SIGMA_LOG_MAX:g}], got {s!r}"
        )
    if d["memory"] not in MEMORIES:
        raise ValueError(f"{at('memory')}: expected one of {list(MEMORIES)}, got {d['memory']!r}")
    a = d["alpha_range"]
    if d["memory"] == "dragan":
        if a is not None:
            raise ValueError(f"{at('alpha_range')}: expected null with memory 'dragan', got {a!r}")
    elif not (
        isinstance(a, list | tuple)
        and len(a) == 2
        and all(_is_number(x) and math.isfinite(x) for x in a)
        and 0 <= a[0] <= a[1] <= FLOAT32_MAX
    ):
        raise ValueError(
            f"{at('alpha_range')}: expected [lo, hi] with 0 <= lo <= hi <= {FLOAT32_MAX:.4g} "
            f"(float32; memory 'recency'), got {a!r}"
        )
    lapse = d["lapse"]
    if not (_is_number(lapse) and 0.0 <= lapse <= 1.0):
        raise ValueError(f"{at('lapse')}: expected a probability in [0, 1], got {lapse!r}")
    for field in ("beta_nodes", "alpha_nodes"):
        n = d[field]
        if not (_is_int(n) and 1 <= n <= MAX_NODES):
            raise ValueError(f"{at(field)}: expected an integer in 1..{MAX_NODES}, got {n!r}")
    z = _z_reach(s, d["beta_nodes"])
    for k, b in beta.items():
        if b * math.exp(s * z) > BETA_MAX:
            raise ValueError(
                f"{at('beta')}: {k!r}: {b!r} gives participants temperatures up to "
                f"{b * math.exp(s * z):.3g} (β₀ · exp(σ z) at σ = {s!r}, |z| = {z:.3g}: the "
                f"quadrature's outer node or a draw), expected at most {BETA_MAX:.3g} (β · "
                "evidence finite in float32); lower it, 'beta_sigma_log' or 'beta_nodes'"
            )
    return dict(d)


def _z_reach(sigma: float, nodes: int) -> float:
    """The largest ``|z|`` at which a participant's β = β₀ · exp(σ z) is taken: the outer
    Gauss–Hermite node of :func:`quadrature` (σ > 0) or a draw's (:data:`Z_DRAW_MAX`)."""
    if sigma == 0:
        return 0.0
    return max(Z_DRAW_MAX, float(np.polynomial.hermite_e.hermegauss(nodes)[0].max()))


# ------------------------------------------------------------------ presets and files


def default() -> Population:
    """The default population (the module doc gives the reason for each value): the three
    observer cameras uniformly; cost-to-go 0.5, proximity 0.3, direction 0.2; β₀ 30, 30, 5
    (per unit of image plane; direction: none), σ_log 0.5; recency memory α ~ U(0, 2);
    5 % lapses; 8 quadrature nodes of log β and of α."""
    third = 1.0 / 3.0
    beta = DEFAULT_BETAS["nikolaidis"]
    return Population(
        name="default",
        viewpoints=(("observer", third), ("observer_angle", third), ("observer_side", third)),
        rules=(("cost_to_go", 0.5), ("proximity", 0.3), ("direction", 0.2)),
        beta=(("cost_to_go", beta), ("proximity", beta), ("direction", 5.0)),
        beta_sigma_log=0.5,
        memory="recency",
        alpha_range=(0.0, 2.0),
        lapse=0.05,
        beta_nodes=8,
        alpha_nodes=8,
    )


def homogeneous() -> Population:
    """Everyone the dataset's Dragan labeler (:ref:`concepts-dragan`): world coordinates, cost-to-go
    at β = :data:`DEFAULT_BETAS` ``["dragan"]``, σ 0, Dragan's time weights, no lapse."""
    return Population(
        name="homogeneous",
        viewpoints=((WORLD, 1.0),),
        rules=(("cost_to_go", 1.0),),
        beta=(("cost_to_go", DEFAULT_BETAS["dragan"]),),
        beta_sigma_log=0.0,
        memory="dragan",
        alpha_range=None,
        lapse=0.0,
        beta_nodes=8,
        alpha_nodes=8,
    )


#: The shipped populations, by name.
PRESETS: dict[str, Callable[[], Population]] = {"default": default, "homogeneous": homogeneous}


def load_population(path: str | os.PathLike) -> Population:
    """A population from a JSON file (every field checked; errors name the file and field).

    A duplicated key is an error too (JSON would keep the last silently)."""

    def pairs(kv):
        seen = set()
        for k, _ in kv:
            if k in seen:
                raise ValueError(f"{path}: field {k!r}: given twice")
            seen.add(k)
        return dict(kv)

    return Population.from_dict(fileio.read_json(path, object_pairs_hook=pairs), str(path))


def save_population(pop: Population, path: str | os.PathLike) -> None:
    """Write ``pop`` as JSON (atomically: a temporary file renamed)."""
    fileio.write_text(path, json.dumps(pop.to_dict(), indent=2) + "\n")


def get_population(spec: str | os.PathLike) -> Population:
    """``default``, ``homogeneous`` (:data:`PRESETS`), ``random:K`` (the K-th draw of the
    hyper-distribution, :func:`random_population`) or the path of a population JSON file.

    >>> get_population("homogeneous").memory
    'dragan'
    """
    if str(spec) in PRESETS:
        return PRESETS[str(spec)]()
    if str(spec).startswith(RANDOM_PREFIX):
        return random_population(parse_random(str(spec)))
    if Path(spec).is_dir():
        raise ValueError(
            f"population {spec}: is a directory; expected a population JSON file (or "
            f"{', '.join(PRESETS)} or {RANDOM_PREFIX}K)"
        )
    if not Path(spec).is_file():
        raise ValueError(
            f"population: expected {', '.join(PRESETS)}, {RANDOM_PREFIX}K (the K-th draw) or a "
            f"population JSON file, got {str(spec)!r} (no such file)"
        )
    return load_population(spec)


# ------------------------------------------------------------------ populations nobody wrote

#: ``random:K`` names the K-th draw of the hyper-distribution (:func:`random_population`).
RANDOM_PREFIX = "random:"
#: The candidate viewpoints of a drawn population: the scene's three observer cameras and
#: the motion seen in 3-D.
HYPER_VIEWPOINTS: tuple[str, ...] = ("observer", "observer_angle", "observer_side", WORLD)
#: Log-uniform ranges of the temperature centres β₀ per rule (the unit of each rule's
#: evidence: per metre or per unit of image plane; none for ``direction``).
HYPER_BETA: dict[str, tuple[float, float]] = {
    "cost_to_go": (10.0, 60.0),
    "proximity": (10.0, 60.0),
    "direction": (2.0, 10.0),
}
HYPER_SIGMA = (0.0, 1.0)  # σ of log β ~ U(lo, hi)
HYPER_RECENCY = 0.75  # P(memory = recency); else Dragan's time weights
HYPER_ALPHA = (0.0, 2.0)  # recency: lo ~ U(0, 2), hi = lo + U(0, 2)
HYPER_LAPSE = (0.0, 0.10)  # λ ~ U(lo, hi)
_HYPER_SEED = 44  # the hyper-distribution's own stream: draw K uses SeedSequence((44, K))
#: The drawn populations of ``--population suite`` (after ``default`` and ``homogeneous``):
#: the first draws K = 0, 1, 2, … whose oracle gain over the straight line is large enough to
#: measure (``python -m slotv_jax.experiments.people_loop.suite`` screens them and records
#: the rule and every screened draw in ``experiments/population_suite.md``).
SUITE_DRAWS: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 7)


def parse_random(spec: str) -> int:
    """K of ``random:K`` (a ValueError naming the population for anything else)."""
    k = spec[len(RANDOM_PREFIX) :] if spec.startswith(RANDOM_PREFIX) else ""
    if not (k.isascii() and k.isdigit()) or len(k) > 9:
        raise ValueError(
            f"population: expected random:K with K an integer in 0..999999999, got {spec!r}"
        )
    return int(k)


def random_population(k: int) -> Population:
    """The K-th draw of the hyper-distribution over every population field (issue 44: a suite
    of populations nobody tuned to). Reproducible: draw K comes from NumPy's PCG64 seeded by
    ``SeedSequence((44, K))`` alone, whatever else runs. Named ``random:K``.

    ============== =========================================== ===============================
    field          distribution                                why
    ============== =========================================== ===============================
    viewpoints     each of ``observer``, ``observer_angle``,   a study films its clips from
                   ``observer_side`` and ``world`` kept with   one camera or several, or shows
                   probability 1/2 (drawn again if none is     the robot live (3-D, ``world``);
                   kept); weights Dirichlet(1, …, 1) over      any subset and weighting is
                   those kept                                  possible, none is favoured
    rules          weights Dirichlet(1, 1, 1) over             the literature finds people's
                   ``cost_to_go``, ``proximity``,              goal inference explained by
                   ``direction``                               efficiency (Dragan & Srinivasa
                                                               2013; Baker et al. 2009), by
                                                               proximity and by heading
                                                               (Gielniak & Thomaz 2011 on
                                                               anticipation); no mix is known,
                                                               so uniform on the simplex
    beta           per rule, log-uniform: cost-to-go and       the dataset's temperatures (20
                   proximity on [10, 60], direction on         m⁻¹, 30 per image unit; the
                   [2, 10]                                     default's direction 5) sit near
                                                               each range's geometric centre;
                                                               at β = 10 five centimetres of
                                                               progress give odds 1.6 (a
                                                               hesitant reader), at 60 they
                                                               give 20 (a sharp one)
    beta_sigma_log U(0, 1)                                     from everyone alike to the
                                                               middle 68 % within a factor 2.7:
                                                               fitted rationality differs
                                                               widely between people (Baker
                                                               et al. 2009)
    memory         recency with probability 3/4, else          people update their guess as a
                   Dragan's time weights                       motion unfolds, recent points
                                                               weigh more (Hogarth & Einhorn
                                                               1992); the labelers' own
                                                               weighting stays possible
    alpha_range    lo ~ U(0, 2), hi = lo + U(0, 2)             from equal weights (α = 0) to
                                                               judging from the last points
                                                               (α = 4: the last fifth carries
                                                               ~60 % of the weight)
    lapse          U(0, 0.10)                                  0–6 % in the laboratory
                                                               (Wichmann & Hill 2001), more in
                                                               online studies of inattentive
                                                               participants
    ============== =========================================== ===============================

    The quadrature keeps 8 + 8 nodes (within 3e-4 of 64 + 64 at σ = 1, :func:`quadrature`).
    These ranges were chosen from the literature above before any result with them was seen.

    >>> random_population(3) == random_population(3), random_population(3).name
    (True, 'random:3')
    """
    if not (_is_int(k) and 0 <= k <= 999_999_999):
        raise ValueError(f"k: expected an integer in 0..999999999, got {k!r}")
    rng = np.random.default_rng(np.random.SeedSequence((_HYPER_SEED, int(k))))
    keep = np.zeros(len(HYPER_VIEWPOINTS), bool)
    while not keep.any():
        keep = rng.random(len(HYPER_VIEWPOINTS)) < 0.5
    views = [v for v, kept in zip(HYPER_VIEWPOINTS, keep, strict=True) if kept]
    w_view = _simplex(rng.dirichlet(np.ones(len(views))))
    w_rule = _simplex(rng.dirichlet(np.ones(len(RULES))))
    beta = {r: float(np.exp(rng.uniform(*np.log(HYPER_BETA[r])))) for r in RULES}
    sigma = float(rng.uniform(*HYPER_SIGMA))
    recency = bool(rng.random() < HYPER_RECENCY)
    lo = float(rng.uniform(*HYPER_ALPHA))
    hi = lo + float(rng.uniform(*HYPER_ALPHA))
    lapse = float(rng.uniform(*HYPER_LAPSE))
    return Population(
        name=f"{RANDOM_PREFIX}{k}",
        viewpoints=tuple(zip(views, w_view, strict=True)),
        rules=tuple(zip(RULES, w_rule, strict=True)),
        beta=tuple((r, round(beta[r], 6)) for r in RULES),
        beta_sigma_log=round(sigma, 6),
        memory="recency" if recency else "dragan",
        alpha_range=(round(lo, 6), round(hi, 6)) if recency else None,
        lapse=round(lapse, 6),
        beta_nodes=8,
        alpha_nodes=8,
    )


def _simplex(w: np.ndarray) -> list[float]:
    """Weights rounded to 6 digits that still sum to 1 (the last takes the remainder), so a
    drawn population reads back from its JSON form unchanged."""
    r = [round(float(x), 6) for x in w[:-1]]
    return [*r, round(1.0 - math.fsum(r), 6)]


def suite_specs() -> tuple[str, ...]:
    """``--population suite``: ``default``, ``homogeneous`` and the draws of
    :data:`SUITE_DRAWS`."""
    return ("default", "homogeneous", *(f"{RANDOM_PREFIX}{k}" for k in SUITE_DRAWS))


# ------------------------------------------------------------------ viewpoints and evidence


@struct.dataclass
class Viewpoints:
    """The V viewpoints of a population, in its order, then ``world`` slots of weight 0 up
    to :data:`VIEW_SLOTS` (:func:`quadrature`)."""

    pos: Float[Array, "V 3"]  # camera centres, world frame (m) (world viewpoints: unused)
    rot: Float[Array, "V 3 3"]  # world-from-camera rotations (world viewpoints: unused)
    world: Bool[Array, " V"]  # True: no projection


def _viewpoints(pop: Population) -> Viewpoints:
    """The population's viewpoints, padded with ``world`` to :data:`VIEW_SLOTS`."""
    names = [name for name, _ in pop.viewpoints]
    names += [WORLD] * (VIEW_SLOTS - len(names))
    pos, rot, world = [], [], []
    for name in names:
        cam = None if name == WORLD else scene.camera(name)
        pos.append(np.zeros(3) if cam is None else np.asarray(cam.pos))
        rot.append(np.eye(3) if cam is None else np.asarray(cam.rot))
        world.append(cam is None)
    return Viewpoints(
        pos=jnp.asarray(np.asarray(pos), jnp.float32),
        rot=jnp.asarray(np.asarray(rot), jnp.float32),
        world=jnp.asarray(world),
    )


def _evidence(
    views: Viewpoints, xyz: Array, goals: Array, mask: Array, L: Array, rules: tuple[int, ...]
) -> tuple[Float[Array, "V R T G"], Bool[Array, " V"]]:
    """The evidence e_k(i) of the ``rules`` (indices into :data:`RULES`) in every viewpoint,
    and whether each viewpoint sees every seen point and real goal. Points ≥ L are replaced
    by the start first: they reach neither the values nor the gradients."""
    T = xyz.shape[0]
    vis = jnp.arange(T) < L
    xyz = jnp.where(vis[:, None], xyz, xyz[0])

    def one(pos, rot, world):
        (u, v), ok = scene.image_coords(xyz, pos, rot, DEPTH_EPS)
        (gu, gv), ok_g = scene.image_coords(goals, pos, rot, DEPTH_EPS)
        q = jnp.where(world, xyz, jnp.stack([u, v, jnp.zeros_like(u)], -1))  # (T, 3)
        h = jnp.where(world, goals, jnp.stack([gu, gv, jnp.zeros_like(gu)], -1))  # (G, 3)
        sees = world | (jnp.all(ok | ~vis) & jnp.all(ok_g | ~mask))
        d = pairwise_distances(q, h)  # (T, G): ‖q_i − h_k‖
        out = []
        for r in rules:
            if RULES[r] == "cost_to_go":
                out.append(d[:1] - d)
            elif RULES[r] == "proximity":
                out.append(-d)
            else:  # direction: cos_ε(q_i − q_{i−1}, h_k − q_i), 0 at i = 0 (no step)
                step = q - jnp.concatenate([q[:1], q[:-1]])  # (T, 3)
                to_goal = h[None, :, :] - q[:, None, :]  # (T, G, 3)
                eps2 = DIRECTION_EPS**2
                n_step = jnp.sqrt(jnp.sum(step * step, -1) + eps2)[:, None]
                n_goal = jnp.sqrt(jnp.sum(to_goal * to_goal, -1) + eps2)
                out.append(jnp.sum(step[:, None, :] * to_goal, -1) / (n_step * n_goal))
        return jnp.stack(out), sees

    return jax.vmap(one)(views.pos, views.rot, views.world)


def _recency_weights(alpha: Array, T: int, L: Array, dtype) -> Float[Array, "... T"]:
    """``w_i ∝ ((i + 1) / L)^α`` on the seen points i < L, 0 beyond; ``alpha (...)``."""
    i = jnp.arange(T, dtype=dtype)
    vis = i < L
    log_r = jnp.where(vis, jnp.log((i + 1) / L.astype(dtype)), 0.0)  # ≤ 0 where seen
    w = jnp.where(vis, jnp.exp(alpha[..., None].astype(dtype) * log_r), 0.0)
    return w / jnp.sum(w, -1, keepdims=True)


def _dragan_weights(T: int, L: Array, dtype) -> Float[Array, " T"]:
    """:ref:`concepts-dragan`'s weights over the first L points, ``trap_i (1 − t_i)`` at t_i = i/(L
    − 1) (:func:`~slotv_jax.observers.common.time_weights`), 0 beyond."""
    tau = jnp.minimum(jnp.arange(T, dtype=dtype) / (L - 1).astype(dtype), 1.0)
    return time_weights(tau, 1.0, trapezoid_rule=True)


def _beliefs(E: Array, beta: Array, mask: Array) -> tuple[list[Array], Array]:
    """``exp(β E_k − max)`` per goal and their sum over goals, each ``(..., J, T)``."""
    logits = [jnp.where(mask[k], beta[..., :, None] * E[..., None, :, k], -jnp.inf)
              for k in range(E.shape[-1])]  # fmt: skip
    top = functools.reduce(jnp.maximum, logits)
    e = [jnp.exp(logit - top) for logit in logits]
    return e, functools.reduce(jnp.add, e)


def _unbroadcast(x: Array, shape: tuple[int, ...]) -> Array:
    """Sum ``x`` down to ``shape`` (the transpose of broadcasting)."""
    x = jnp.sum(x, axis=tuple(range(x.ndim - len(shape))))
    return jnp.sum(x, axis=tuple(i for i, n in enumerate(shape) if n == 1), keepdims=True)


@jax.custom_vjp
def _mixture(E: Array, beta: Array, W: Array, mask: Array) -> Float[Array, "... J G"]:
    """``y_jk = Σ_i W_i softmax_k(β_j E_ik)`` over the real goals, for evidence
    ``E (..., T, G)``, temperatures ``beta (..., J)`` and weights ``W (..., T)`` (leading
    axes broadcast).

    The goals are a Python loop (as in :func:`~slotv_jax.observers.common.dragan_kernel`):
    the softmax over goals is elementwise across G arrays of shape (..., J, T) and the sums
    over points one variadic reduction, so XLA computes each exponential once, in one loop.
    The gradient is written out (:func:`_mixture_bwd`): it recomputes the beliefs in one
    fused pass instead of storing them (3× faster than autodiff, measured on the planner's
    batch)."""
    e, norm = _beliefs(E, beta, mask)
    w = W[..., None, :] / norm
    return jnp.stack(sums([ek * w for ek in e]), axis=-1)


def _mixture_fwd(E, beta, W, mask):
    return _mixture(E, beta, W, mask), (E, beta, W, mask)


def _mixture_bwd(res, y_bar):
    """With ``P_jik`` the beliefs and ``a = ȳ``: ``∂logit_jik = W_i P_jik (a_jk − Σ_l P_jil
    a_jl)``, ``Ē_ik = Σ_j β_j ∂logit_jik``, ``β̄_j = Σ_ik E_ik ∂logit_jik``,
    ``W̄_i = Σ_jk a_jk P_jik``."""
    E, beta, W, mask = res
    e, norm = _beliefs(E, beta, mask)
    p = [ek / norm for ek in e]  # (..., J, T)
    a = [y_bar[..., k, None] for k in range(E.shape[-1])]  # (..., J, 1)
    pa = functools.reduce(jnp.add, [pk * ak for pk, ak in zip(p, a, strict=True)])
    dlogit = [W[..., None, :] * pk * (ak - pa) for pk, ak in zip(p, a, strict=True)]
    E_bar = jnp.stack([jnp.sum(beta[..., :, None] * d, axis=-2) for d in dlogit], axis=-1)
    beta_bar = sum(jnp.sum(d * E[..., None, :, k], -1) for k, d in enumerate(dlogit))
    W_bar = jnp.sum(pa, axis=-2)
    return (_unbroadcast(E_bar, E.shape), _unbroadcast(beta_bar, beta.shape),
            _unbroadcast(W_bar, W.shape), None)  # fmt: skip


_mixture.defvjp(_mixture_fwd, _mixture_bwd)


def _inputs(xyz, goals, goal_mask, seen):
    xyz = jnp.asarray(xyz)
    dtype = jnp.result_type(xyz.dtype, jnp.float32)
    T = xyz.shape[0]
    L = jnp.clip(jnp.asarray(seen, jnp.int32), 2, T)
    mask = jnp.asarray(goal_mask).astype(bool)
    uniform = (mask / jnp.sum(mask)).astype(dtype)
    return xyz.astype(dtype), jnp.asarray(goals, dtype), mask, L, uniform


# ------------------------------------------------------------------ P_pop


@struct.dataclass
class Quadrature:
    """The population as weighted representative participants: one per viewpoint v, rule r
    (every rule of :data:`RULES`, in its order) and temperature node j (weight
    π_v π_r ω_j), each remembering with the mean of the memory weights over the α nodes
    (weights ω_k). See :func:`quadrature`. Every field is an array, and every population
    has the same shapes (the viewpoints, rules and nodes it lacks padded with weight 0), so
    that one compiled program takes any population's quadrature as an argument."""

    views: Viewpoints
    beta: Float[Array, "R J"]  # β₀_r · exp(σ z_j)
    weight: Float[Array, "V R J"]  # π_v π_r ω_j, summing to 1
    alpha: Float[Array, " K"]  # α nodes (recency memory)
    alpha_weight: Float[Array, " K"]  # ω_k, summing to 1
    lapse: Float[Array, ""]
    dragan: Bool[Array, ""]  # memory: True Dragan's time weights, False recency


@functools.cache
def quadrature(pop: Population) -> Quadrature:
    """The nodes and weights of P_pop's expectation over the participants (cached):

    - viewpoints and rules: exact sums over the population's categories;
    - ``log β = log β₀ + σ z``, ``z ~ N(0, 1)``: Gauss–Hermite, ``beta_nodes`` nodes z_j
      with weights ω_j (``numpy.polynomial.hermite_e.hermegauss``, normalised); one node
      when σ = 0;
    - ``α ~ U(lo, hi)``: Gauss–Legendre, ``alpha_nodes`` nodes on [lo, hi]; one node when
      lo = hi (recency memory only).

    Every node set is exact for polynomials of degree < 2 × nodes; P_pop is a smooth
    function of log β and α (a softmax, a power), and 8 nodes of each put it within
    3e-6 of 64 nodes on the default population (σ = 0.5; 3e-4 at σ = 1: give a wider
    population more nodes).

    The arrays are padded to one shape for every population: :data:`VIEW_SLOTS`
    viewpoints (``world``), every rule of :data:`RULES`, at least :data:`NODE_SLOTS`
    nodes of each kind (copies of the first), all of weight 0. A term of weight 0 adds an
    exact 0 (its evidence is finite), so P_pop is the population's; a program that takes
    the quadrature as an argument (:func:`quadrature_observer`) compiles once for every
    population with at most :data:`NODE_SLOTS` nodes.
    """
    with jax.ensure_compile_time_eval():
        J = pop.beta_nodes if pop.beta_sigma_log > 0 else 1
        z, wz = np.polynomial.hermite_e.hermegauss(J)
        wz = wz / wz.sum()
        p_view = np.zeros(VIEW_SLOTS)
        p_view[: len(pop.viewpoints)] = [p for _, p in pop.viewpoints]
        p_rule = np.asarray([dict(pop.rules).get(r, 0.0) for r in RULES])
        centre = np.asarray([dict(pop.beta).get(r, 1.0) for r in RULES])
        if pop.memory == "recency" and pop.alpha_range[1] > pop.alpha_range[0]:
            x, wa = np.polynomial.legendre.leggauss(pop.alpha_nodes)
            lo, hi = pop.alpha_range
            alpha, wa = lo + (hi - lo) * (x + 1) / 2, wa / wa.sum()
        else:
            alpha, wa = np.asarray([pop.alpha_range[0] if pop.alpha_range else 0.0]), np.ones(1)
        z, wz = _pad(z, z[0]), _pad(wz, 0.0)
        alpha, wa = _pad(alpha, alpha[0]), _pad(wa, 0.0)
        return Quadrature(
            views=_viewpoints(pop),
            beta=jnp.asarray(centre[:, None] * np.exp(pop.beta_sigma_log * z)[None], jnp.float32),
            weight=jnp.asarray(p_view[:, None, None] * p_rule[None, :, None] * wz, jnp.float32),
            alpha=jnp.asarray(alpha, jnp.float32),
            alpha_weight=jnp.asarray(wa, jnp.float32),
            lapse=jnp.float32(pop.lapse),
            dragan=jnp.asarray(pop.memory == "dragan"),
        )


def _pad(x: np.ndarray, fill: float) -> np.ndarray:
    """Quadrature nodes or weights ``x`` padded with ``fill`` to :data:`NODE_SLOTS`."""
    return np.concatenate([x, np.full(max(NODE_SLOTS - len(x), 0), fill)])


def population_probs(
    quad: Quadrature,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""] | int,
) -> Float[Array, " 8"]:
    """``P_pop(g | ξ_{0:L})``, the population's guess distribution for the path seen up to
    point ``L = seen`` (points ≥ L ignored; L clipped to 2..T), from :func:`quadrature`::

        W_i      = Σ_k ω_k w_i(α_k)                       (the mean memory weights)
        y_k(vrj) = Σ_{i<L} W_i softmax_k(β_rj e^{(v, r)}_k(i))   (uniform if v cannot see)
        P_pop    = (1 − λ) Σ_{v,r,j} π_v π_r ω_j y(vrj) + λ u

    (y is linear in the memory weights, and α is independent of the other parameters,
    so the α-mean moves onto the weights). Sums to 1 over the real goals, exactly 0 on
    padded slots. Pure and differentiable in ``xyz`` and ``goals``; ``seen`` may be traced
    (one compilation for every ``seen``).

    >>> import jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
    >>> p = population_probs(quadrature(default()), xyz, g, jnp.arange(8) < 2, 70)
    >>> bool(p[0] > p[1]), float(p[2:].sum())
    (True, 0.0)
    """
    xyz, goals, mask, L, uniform = _inputs(xyz, goals, goal_mask, seen)
    T, dtype = xyz.shape[0], xyz.dtype
    E, sees = _evidence(quad.views, xyz, goals, mask, L, _ALL_RULES)  # (V, R, T, G), (V,)
    W = jnp.where(
        quad.dragan,
        _dragan_weights(T, L, dtype),
        quad.alpha_weight.astype(dtype) @ _recency_weights(quad.alpha, T, L, dtype),
    )
    y = _mixture(E, quad.beta.astype(dtype), W, mask)  # (V, R, J, G)
    y = jnp.where(sees[:, None, None, None], y, uniform)
    y = jnp.einsum("vrj,vrjg->g", quad.weight.astype(dtype), y)
    lapse = quad.lapse.astype(dtype)
    return (1 - lapse) * y + lapse * uniform


def _population_prefix(
    config, quad: Quadrature, xyz: Float[Array, "T 3"], goals, goal_mask, seen
) -> Float[Array, " 8"]:
    return masked_log(population_probs(quad, xyz, goals, goal_mask, seen), goal_mask)


def _population_logits(
    config, quad: Quadrature, xyz: Float[Array, "T 3"], goals, goal_mask
) -> Float[Array, " 8"]:
    return _population_prefix(config, quad, xyz, goals, goal_mask, jnp.shape(xyz)[0])


def quadrature_observer(quad: Quadrature) -> Observer:
    """The population of the quadrature ``quad`` as an observer (the planner's contract,
    :mod:`slotv_jax.planning`): ``observer(xyz (T, 3), goals (8, 3), goal_mask (8,)) ->
    logits (8,)``, the logits ``log P_pop`` of the whole motion (−∞ on padded slots), and
    ``observer.prefix(xyz, goals, goal_mask, seen) -> logits``, ``log P_pop`` of the motion
    seen up to point ``seen`` (traced). An :class:`~slotv_jax.observers.observer.Observer`
    whose ``params`` are ``quad``: ``quad`` may be traced, so a planner whose parameters
    are quadratures (:func:`slotv_jax.planning.make_family_planner`) plans every population
    with one compiled program."""
    return Observer(
        logits_fn=_population_logits, prefix_fn=_population_prefix, params=quad, name="population"
    )


def population_observer(pop: Population) -> Observer:
    """:func:`quadrature_observer` of ``pop``'s :func:`quadrature`, named, with ``pop`` its
    ``config``.

    >>> obs = population_observer(homogeneous())
    >>> obs.name
    'population:homogeneous'
    """
    observer = quadrature_observer(quadrature(pop))
    return observer.replace(config=pop, name=f"population:{pop.name}")


# ------------------------------------------------------------------ participants


@struct.dataclass
class Participants:
    """N participants, each with their own parameters (drawn by :func:`draw_participants`).
    Every field is an array, with one shape for every population (``views`` padded to
    :data:`VIEW_SLOTS`): one compiled program guesses for any population's participants
    (:func:`guess_goals`)."""

    viewpoint: Int[Array, " N"]  # index into the population's viewpoints
    rule: Int[Array, " N"]  # index into RULES
    beta: Float[Array, " N"]  # temperature (per unit of the viewpoint's coordinates)
    alpha: Float[Array, " N"]  # recency exponent (0 under dragan memory)
    views: Viewpoints
    lapse: Float[Array, ""]  # probability of a uniform guess
    dragan: Bool[Array, ""]  # memory: True Dragan's time weights, False recency

    @property
    def size(self) -> int:
        return int(self.viewpoint.shape[0])


def _log_probs(pairs) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.log(np.asarray([p for _, p in pairs], np.float64)).astype(np.float32)


def draw_participants(pop: Population, key: jax.Array, n: int) -> Participants:
    """``n`` participants drawn independently from ``pop``: viewpoint and rule from their
    categorical distributions, ``β = β₀[rule] · exp(σ z)`` with ``z ~ N(0, 1)``, and
    (recency memory) ``α ~ U(alpha_range)``. Pure in ``key``; ``n`` static."""
    rule_ids = np.asarray([RULES.index(r) for r, _ in pop.rules], np.int32)
    centres = np.asarray([dict(pop.beta)[r] for r, _ in pop.rules], np.float32)
    kv, kr, kb, ka = jax.random.split(key, 4)
    viewpoint = jax.random.categorical(kv, _log_probs(pop.viewpoints), shape=(n,))
    slot = jax.random.categorical(kr, _log_probs(pop.rules), shape=(n,))
    z = jax.random.normal(kb, (n,), jnp.float32)
    if pop.memory == "recency":
        lo, hi = pop.alpha_range
        alpha = jax.random.uniform(ka, (n,), jnp.float32, lo, hi)
    else:
        alpha = jnp.zeros((n,), jnp.float32)
    return Participants(
        viewpoint=viewpoint.astype(jnp.int32),
        rule=jnp.asarray(rule_ids)[slot],
        beta=jnp.asarray(centres)[slot] * jnp.exp(jnp.float32(pop.beta_sigma_log) * z),
        alpha=alpha,
        views=_viewpoints(pop),
        lapse=jnp.float32(pop.lapse),
        dragan=jnp.asarray(pop.memory == "dragan"),
    )


def participant_probs(
    parts: Participants,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""] | int,
) -> Float[Array, "N 8"]:
    """Each participant's guess distribution ``p^(n) = (1 − λ) y^(n) + λ u`` for the path
    seen up to point ``seen`` (as :func:`population_probs`), exact zeros on padded goals::

        y_k = Σ_{i<L} w_i(α_n) softmax_k(β_n e^{(v_n, r_n)}_k(i))   (uniform if v_n cannot see)
    """
    xyz, goals, mask, L, uniform = _inputs(xyz, goals, goal_mask, seen)
    T, dtype = xyz.shape[0], xyz.dtype
    E, sees = _evidence(parts.views, xyz, goals, mask, L, _ALL_RULES)
    W = jnp.where(
        parts.dragan, _dragan_weights(T, L, dtype), _recency_weights(parts.alpha, T, L, dtype)
    )
    beta = parts.beta.astype(dtype)[:, None]
    y = _mixture(E[parts.viewpoint, parts.rule], beta, W, mask)[:, 0]  # (N, G)
    y = jnp.where(sees[parts.viewpoint][:, None], y, uniform)
    lapse = parts.lapse.astype(dtype)
    return (1 - lapse) * y + lapse * uniform


# ------------------------------------------------------------------ the sampler


def guess_goals(
    parts: Participants,
    key: jax.Array,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""] | int,
    *,
    batch_size: int = 4096,
) -> Int[Array, " N"]:
    """One guess (a goal slot) by each participant of ``parts``: with probability λ a real
    goal uniformly (a lapse), else a goal drawn from the participant's ``y^(n)``. Computed
    ``batch_size`` participants at a time, so that memory stays bounded."""
    n = parts.size
    k_lapse, k_uniform, k_guess = jax.random.split(key, 3)
    size = min(batch_size, n)
    chunks = -(-n // size)

    def chunked(x):  # (N,) -> (chunks, size), padded with the first participant
        return jnp.concatenate([x, jnp.broadcast_to(x[:1], (chunks * size - n,))]).reshape(
            chunks, size
        )

    def one(p):
        v, r, b, a = p
        chunk = parts.replace(
            viewpoint=v, rule=r, beta=b, alpha=a, lapse=jnp.zeros_like(parts.lapse)
        )
        return participant_probs(chunk, xyz, goals, goal_mask, seen)

    per = tuple(map(chunked, (parts.viewpoint, parts.rule, parts.beta, parts.alpha)))
    y = jax.lax.map(one, per).reshape(chunks * size, -1)[:n]  # (N, 8)
    mask = jnp.asarray(goal_mask).astype(bool)
    drawn = jax.random.categorical(k_guess, masked_log(y, jnp.broadcast_to(mask, y.shape)))
    uniform = jax.random.categorical(k_uniform, jnp.where(mask, 0.0, -jnp.inf), shape=(n,))
    lapsed = jax.random.uniform(k_lapse, (n,)) < parts.lapse
    return jnp.where(lapsed, uniform, drawn).astype(jnp.int32)


def sample_guesses(
    pop: Population,
    key: jax.Array,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""] | int,
    n: int,
) -> Int[Array, " n"]:
    """``n`` guesses (goal slots), each by a fresh participant of ``pop`` with their own
    parameters (:func:`draw_participants`, then :func:`guess_goals`). Their distribution is
    the population's, which :func:`population_probs` computes.

    >>> import jax, jax.numpy as jnp
    >>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    >>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
    >>> k = jax.random.key(0)
    >>> sample_guesses(default(), k, xyz, g, jnp.arange(8) < 2, 100, 5).shape
    (5,)
    """
    k_people, k_guess = jax.random.split(key)
    return guess_goals(draw_participants(pop, k_people, n), k_guess, xyz, goals, goal_mask, seen)


@functools.cache
def participant_drawer(pop: Population, n: int) -> Callable[[jax.Array], Participants]:
    """``draw(keys (B,)) -> Participants`` with a leading axis B: :func:`draw_participants`
    of ``pop``, ``n`` participants for each key, compiled (once per population and ``n``:
    a small program of random draws)."""
    return jax.jit(jax.vmap(lambda k: draw_participants(pop, k, n)))


_guesses = jax.jit(jax.vmap(guess_goals))


def sample_guesses_batch(
    pop: Population,
    keys: jax.Array,
    xyz: Float[Array, "B T 3"],
    goals: Float[Array, "B 8 3"],
    goal_mask: Bool[Array, "B 8"],
    seen: Int[Array, " B"],
    n: int,
) -> Int[Array, "B n"]:
    """:func:`sample_guesses` for each of B paths, path b's with ``keys[b]``: the same
    draws, with the guessing compiled once for every population. Each key is split into
    (participants, guesses) as :func:`sample_guesses` does; the participants come from
    :func:`participant_drawer` (a small program of ``pop``'s own) and the guesses from one
    program shared by every population (:class:`Participants` has one shape for all)."""
    pairs = jax.vmap(jax.random.split)(keys)  # (B, 2): k_people, k_guess of each path
    parts = participant_drawer(pop, int(n))(pairs[:, 0])
    return _guesses(parts, pairs[:, 1], xyz, goals, goal_mask, seen)
