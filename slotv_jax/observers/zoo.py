"""The zoo: simulated people outside the population model (``experiments/zoo.md``).

The population model (:mod:`slotv_jax.observers.population`) draws people from one family:
a viewpoint of the scene file, one of three readings of each seen point (cost-to-go,
proximity, direction), a mixture of per-point beliefs weighted by recency or Dragan's
weights, and a lapse. Every candidate observer of the loop was written with that family in
mind. The zoo holds people that it cannot express, each from the literature on how people
infer a goal from a motion, each watching from a camera the scene file does not have. The
list, with the reasons and references, was fixed in ``experiments/zoo.md`` before any
result with them was seen; this module implements it, member by member, in the same
notation.

A member is a :class:`ZooMember`: a reading of the motion (a pure function of one person's
parameters and the motion in the member's coordinates), the distributions of those
parameters over people, and the member's camera. Each person also has a temperature β
(log-normal around the member's centre, σ = 0.5) and a lapse rate λ ~ U[0, 0.06]
(Wichmann & Hill 2001), so that a person's guess distribution is
``p = (1 − λ) y + λ u`` (u uniform over the real goals).

- :func:`zoo_probs` is the member's ``P(goal | motion seen up to point L)``: the mean of
  ``p`` over :data:`N_PEOPLE` representative people, drawn once with a fixed key (a
  pure, deterministic, differentiable JAX function of the path; its standard error
  against the expectation over people is at most ``0.5 / √N_PEOPLE`` = 0.044 per goal,
  far below the differences between members).
- :func:`sample_zoo_guesses` draws fresh people, each with their own parameters, and one
  guess of each.
- A member is itself an observer: ``member(xyz, goals, goal_mask)`` gives log P over the
  whole motion and ``member.prefix(xyz, goals, goal_mask, seen)`` over its first ``seen``
  points, so a planner plans with it as with any observer, and the loop scores plans by it.
- :func:`load_people` resolves ``module:function`` (a researcher's own hypothesis of
  people: a function returning a :class:`ZooMember`) and the members' names.

>>> import jax.numpy as jnp
>>> g = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
>>> mask = jnp.arange(8) < 2
>>> xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), g[0], 100)
>>> p = zoo_probs(MEMBERS["inverse_planning"], xyz, g, mask, 100)
>>> bool(p[0] > p[1]), round(float(p.sum()), 5)
(True, 1.0)
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import math
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers.common import masked_log, masked_softmax
from slotv_jax.world import scene

__all__ = [
    "LAPSE_RANGE",
    "MEMBERS",
    "N_PEOPLE",
    "SIGMA_LOG",
    "ZOO_CAMERAS",
    "ZooMember",
    "draw_people",
    "load_people",
    "look_at_camera",
    "person_probs",
    "sample_zoo_guesses",
    "sample_zoo_guesses_batch",
    "zoo_camera",
    "zoo_names",
    "zoo_probs",
]

N_PEOPLE = 64  # representative people behind zoo_probs (fixed key)
SIGMA_LOG = 0.5  # log-normal spread of β around a member's centre
LAPSE_RANGE = (0.0, 0.06)  # λ ~ U[...]: Wichmann & Hill (2001) allow 0-6 %
DIRECTION_EPS = 1e-4  # cos_ε's damping (as the population's direction rule)
_PEOPLE_KEY = 20261201  # the fixed draw of the representative people

# ---------------------------------------------------------------------- cameras


def look_at_camera(
    position, target, fovy: float, up=(0.0, 0.0, 1.0), resolution=(1280, 720)
) -> scene.Camera:
    """A pinhole camera at ``position (3,)`` looking at ``target (3,)`` (MuJoCo's
    convention: the camera looks along its −z axis, x right, y up; ``up`` fixes the roll).

    ``z = (position − target) / ‖·‖``, ``x = up × z / ‖·‖``, ``y = z × x``; the rotation's
    columns are x, y, z (world from camera, as MuJoCo's ``cam_xmat``).
    """
    pos = np.asarray(position, np.float64)
    z = pos - np.asarray(target, np.float64)
    if not np.all(np.isfinite(z)) or np.linalg.norm(z) < 1e-9:
        raise ValueError("camera: position and target must be finite and distinct")
    z /= np.linalg.norm(z)
    x = np.cross(np.asarray(up, np.float64), z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("camera: up must not be parallel to the viewing direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    if not 0.0 < float(fovy) < 180.0:
        raise ValueError(f"camera: fovy must lie in (0, 180) degrees, got {fovy}")
    return scene.Camera(
        pos=jnp.asarray(pos, jnp.float32),
        rot=jnp.asarray(np.stack([x, y, z], axis=1), jnp.float32),
        fovy=jnp.asarray(float(fovy), jnp.float32),
        resolution=jnp.asarray(resolution, jnp.int32),
    )


#: The zoo's cameras (``experiments/zoo.md``): position, the point looked at, fovy (°).
ZOO_CAMERAS: Mapping[str, tuple[tuple[float, ...], tuple[float, ...], float]] = {
    "zoo_low_left": ((0.95, 1.05, 0.30), (0.45, 0.00, 0.10), 60.0),
    "zoo_overhead": ((0.50, 0.00, 1.90), (0.50, 0.00, 0.00), 45.0),
    "zoo_shoulder": ((-0.45, -0.35, 1.10), (0.50, 0.00, 0.05), 55.0),
}


@functools.cache
def zoo_camera(name: str) -> scene.Camera:
    """The zoo's camera ``name`` (:data:`ZOO_CAMERAS`) as a
    :class:`~slotv_jax.world.scene.Camera`."""
    pos, target, fovy = ZOO_CAMERAS[name]
    # the overhead camera looks straight down: its image's "up" is the world's +x
    up = (1.0, 0.0, 0.0) if name == "zoo_overhead" else (0.0, 0.0, 1.0)
    with jax.ensure_compile_time_eval():
        return look_at_camera(pos, target, fovy, up=up)


def _coords(view: str, xyz: Array, goals: Array) -> tuple[Array, Array]:
    """The motion and the goals in a member's coordinates: the normalised image plane of a
    zoo camera ((u, v); the zoo's cameras see the whole workspace in front of them, and a
    point behind one keeps its finite camera-frame (x, y), as :func:`scene.image_coords`),
    or the table plane (x, y in metres) for ``view == "table"``."""
    if view == "table":
        return xyz[:, :2], goals[:, :2]
    cam = zoo_camera(view)

    def image(p):
        (u, v), _in_front = scene.image_coords(p, cam.pos, cam.rot, 1e-3)
        return jnp.stack([u, v], axis=-1)

    return image(xyz), image(goals)


# ---------------------------------------------------------------------- readings


def _norm(x: Array) -> Array:
    sq = jnp.sum(x * x, axis=-1)
    return jnp.sqrt(jnp.maximum(sq, jnp.finfo(sq.dtype).tiny))


def _cos(a: Array, b: Array) -> Array:
    e2 = DIRECTION_EPS**2
    return jnp.sum(a * b, axis=-1) / (
        jnp.sqrt(jnp.sum(a * a, axis=-1) + e2) * jnp.sqrt(jnp.sum(b * b, axis=-1) + e2)
    )


def _dist(q: Array, h: Array) -> Array:
    """``d[i, k] = ‖q_i − h_k‖``: (T, 2), (8, 2) -> (T, 8)."""
    return _norm(q[:, None, :] - h[None, :, :])


def _c2g(q, h, mask, beta):
    """Dragan's cost-to-go belief at every point: softmax_k β (‖q_0 − h_k‖ − ‖q_i − h_k‖)."""
    d = _dist(q, h)
    return masked_softmax(beta * (d[0] - d), mask)


def _read_inverse_planning(q, h, mask, L, u, person, world):
    beta, gamma = person["beta"], person["gamma"]
    d = _dist(q, h)

    def step(logb, i):
        mix = (1.0 - gamma) * jnp.exp(logb) + gamma * u
        new = jax.nn.log_softmax(
            jnp.where(mask, jnp.log(jnp.where(mask, mix, 1.0)) + beta * (d[i - 1] - d[i]), -1e30)
        )
        return jnp.where(i < L, new, logb), None

    logb0 = jnp.where(mask, jnp.log(jnp.where(mask, u, 1.0)), -1e30)
    logb, _ = jax.lax.scan(step, logb0, jnp.arange(1, q.shape[0]))
    return jnp.where(mask, jnp.exp(logb), 0.0)


def _read_extrapolation(q, h, mask, L, u, person, world):
    beta, kappa, horizon = person["beta"], person["kappa"], person["horizon"]

    def step(v, i):
        new = (1.0 - 1.0 / kappa) * v + (q[i] - q[i - 1]) / kappa
        return jnp.where(i < L, new, v), None

    v, _ = jax.lax.scan(step, jnp.zeros_like(q[0]), jnp.arange(1, q.shape[0]))
    ahead = q[L - 1] + horizon * v
    return masked_softmax(-beta * _norm(ahead[None, :] - h), mask)


def _read_accumulator(q, h, mask, L, u, person, world):
    beta, leak = person["beta"], person["leak"]

    def step(a, i):
        e = _cos((q[i] - q[i - 1])[None, :], h - q[i][None, :])
        return jnp.where(i < L, (1.0 - leak) * a + e, a), None

    a, _ = jax.lax.scan(step, jnp.zeros(h.shape[0], q.dtype), jnp.arange(1, q.shape[0]))
    n = jnp.maximum(L - 1, 1).astype(q.dtype)  # the steps seen
    n_eff = (1.0 - (1.0 - leak) ** n) / leak  # Σ_{j<n} (1 − ℓ)^j
    return masked_softmax(beta * a / n_eff, mask)


DESCENT_SCALE = 0.03  # s (m): how sharply the reading switches on below z_ref
DESCENT_DELTA = 1e-3  # δ: no evidence while the hand is high


def _read_descent(q, h, mask, L, u, person, world):
    beta, z_ref = person["beta"], person["z_ref"]
    z = world[:, 2]  # the hand's height above the goal table (m)
    seen = jnp.arange(q.shape[0]) < L
    w = jnp.where(seen, jax.nn.sigmoid((z_ref - z) / DESCENT_SCALE), 0.0)
    e = -_dist(q, h)
    s = jnp.sum(w[:, None] * e, axis=0) / (jnp.sum(w) + DESCENT_DELTA)
    return masked_softmax(beta * s, mask)


def _read_salience(q, h, mask, L, u, person, world):
    beta, lam = person["beta"], person["centre_bias"]
    d = _dist(q, h)
    return masked_softmax(-lam * _norm(h) + beta * (d[0] - d[L - 1]), mask)


def _read_anchor(q, h, mask, L, u, person, world):
    beta, frac, eta0 = person["beta"], person["anchor"], person["eta0"]
    T = q.shape[0]
    d = _dist(q, h)
    prox = masked_softmax(-beta * d, mask)  # (T, 8)
    c2g = masked_softmax(beta * (d[0] - d), mask)
    t = jnp.arange(T, dtype=q.dtype) / (T - 1)
    i_anchor = jnp.floor(frac * (T - 1))  # the last anchor point

    def step(carry, i):
        y, total, count = carry
        is_anchor = t[i] <= frac
        total_a = total + prox[i]
        y_anchor = total_a / (count + 1.0)
        eta = eta0 / jnp.maximum(1.0 + i - i_anchor, 1.0)  # finite on anchor points too
        y_adjust = y + eta * (c2g[i] - y)
        new = (
            jnp.where(is_anchor, y_anchor, y_adjust),
            jnp.where(is_anchor, total_a, total),
            jnp.where(is_anchor, count + 1.0, count),
        )
        keep = i < L
        return jax.tree.map(lambda a, b: jnp.where(keep, a, b), new, carry), None

    init = (u, jnp.zeros_like(u), jnp.zeros((), q.dtype))
    (y, _, _), _ = jax.lax.scan(step, init, jnp.arange(T))
    return y


HESITANT_SHARPNESS = 0.05  # the confidence gate's width


def _read_hesitant(q, h, mask, L, u, person, world):
    beta, theta = person["beta"], person["threshold"]
    T = q.shape[0]
    b = _c2g(q, h, mask, beta)  # (T, 8)
    conf = jax.nn.sigmoid((jnp.max(b, axis=-1) - theta) / HESITANT_SHARPNESS)
    i = jnp.arange(T, dtype=q.dtype)
    r = jnp.where(i < L, ((i + 1.0) / L) ** 2, 0.0)
    r = r / jnp.sum(r)
    per_point = conf[:, None] * b + (1.0 - conf[:, None]) * u[None, :]
    return jnp.sum(r[:, None] * per_point, axis=0)


# ---------------------------------------------------------------------- members


@dataclasses.dataclass(frozen=True, eq=False)
class ZooMember:
    """One kind of person of the zoo (``experiments/zoo.md``), also an observer.

    - ``name``: the member's name, its ``population`` value in the loop's results;
    - ``view``: a camera of :data:`ZOO_CAMERAS` or ``"table"`` (the table plane, metres);
    - ``beta``: the centre of the per-person temperature (log-normal, σ = :data:`SIGMA_LOG`);
    - ``ranges``: ``((parameter, low, high), ...)``, each person's own parameters, uniform;
    - ``reading``: ``reading(q (T, 2), h (8, 2), mask (8,), L, u (8,), person, world (T, 3))
      -> y (8,)``, the person's guess distribution before lapses (``person`` a dict of
      scalars, ``world`` the motion in the world frame);
    - ``reference``: the literature behind it.
    """

    name: str
    view: str
    beta: float
    ranges: tuple[tuple[str, float, float], ...]
    reading: Callable[..., Array]
    reference: str

    def __post_init__(self):
        if self.view != "table" and self.view not in ZOO_CAMERAS:
            raise ValueError(
                f"{self.name}: view must be 'table' or one of {sorted(ZOO_CAMERAS)}, "
                f"got {self.view!r}"
            )
        if not (math.isfinite(self.beta) and self.beta > 0):
            raise ValueError(f"{self.name}: beta must be a finite number > 0, got {self.beta}")
        for p, lo, hi in self.ranges:
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"{self.name}: range of {p} must be finite, low ≤ high")

    def prefix(
        self,
        xyz: Float[Array, "T 3"],
        goals: Float[Array, "8 3"],
        goal_mask: Bool[Array, " 8"],
        seen: Int[Array, ""],
    ) -> Float[Array, " 8"]:
        """log P(goal | the first ``seen`` points), −∞ on padded slots."""
        return masked_log(zoo_probs(self, xyz, goals, goal_mask, seen), goal_mask)

    def __call__(
        self, xyz: Float[Array, "T 3"], goals: Float[Array, "8 3"], goal_mask: Bool[Array, " 8"]
    ) -> Float[Array, " 8"]:
        """log P(goal | the whole motion), −∞ on padded slots."""
        return self.prefix(xyz, goals, goal_mask, jnp.asarray(xyz).shape[0])


def _member(name, view, beta, ranges, reading, reference) -> ZooMember:
    return ZooMember(name, view, float(beta), tuple(ranges), reading, reference)


#: The zoo, in the order of ``experiments/zoo.md``.
MEMBERS: Mapping[str, ZooMember] = {
    m.name: m
    for m in (
        _member(
            "inverse_planning",
            "zoo_low_left",
            40.0,
            [("gamma", 0.005, 0.05)],
            _read_inverse_planning,
            "Baker, Saxe & Tenenbaum 2009, Cognition 113(3)",
        ),
        _member(
            "extrapolation",
            "zoo_shoulder",
            25.0,
            [("kappa", 3.0, 15.0), ("horizon", 10.0, 40.0)],
            _read_extrapolation,
            "Freyd & Finke 1984, J. Exp. Psychol. LMC 10(1)",
        ),
        _member(
            "accumulator",
            "zoo_overhead",
            4.0,
            [("leak", 0.01, 0.2)],
            _read_accumulator,
            "Usher & McClelland 2001, Psychol. Rev. 108(3)",
        ),
        _member(
            "descent",
            "table",
            20.0,
            [("z_ref", 0.10, 0.25)],
            _read_descent,
            "Ansuini et al. 2015, Front. Psychol.; Becchio et al. 2012, Front. Hum. Neurosci.",
        ),
        _member(
            "salience",
            "zoo_low_left",
            30.0,
            [("centre_bias", 0.0, 6.0)],
            _read_salience,
            "Tatler 2007, J. Vision 7(14)",
        ),
        _member(
            "anchor",
            "zoo_shoulder",
            30.0,
            [("anchor", 0.1, 0.3), ("eta0", 0.05, 0.5)],
            _read_anchor,
            "Hogarth & Einhorn 1992, Cogn. Psychol. 24(1); Tversky & Kahneman 1974",
        ),
        _member(
            "hesitant",
            "zoo_overhead",
            30.0,
            [("threshold", 0.5, 0.9)],
            _read_hesitant,
            "Dragan, Lee & Srinivasa 2013, HRI",
        ),
    )
}


def zoo_names() -> tuple[str, ...]:
    """The members' names, in the order of ``experiments/zoo.md``."""
    return tuple(MEMBERS)


def draw_people(member: ZooMember, key: jax.Array, n: int) -> dict[str, Float[Array, " n"]]:
    """``n`` people of ``member``, each a dict entry ``(n,)``: ``beta`` (log-normal around
    the member's centre, σ = :data:`SIGMA_LOG`), ``lapse`` (U :data:`LAPSE_RANGE`) and each
    of the member's own parameters (uniform over its range)."""
    keys = jax.random.split(key, 2 + len(member.ranges))
    people = {
        "beta": member.beta * jnp.exp(SIGMA_LOG * jax.random.normal(keys[0], (n,))),
        "lapse": jax.random.uniform(keys[1], (n,), minval=LAPSE_RANGE[0], maxval=LAPSE_RANGE[1]),
    }
    for k, (p, lo, hi) in zip(keys[2:], member.ranges, strict=True):
        people[p] = jax.random.uniform(k, (n,), minval=lo, maxval=hi)
    return people


def person_probs(
    member: ZooMember,
    person: Mapping[str, Array],
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""],
) -> Float[Array, " 8"]:
    """One person's guess distribution after the first ``seen`` points (at least 2):
    ``p = (1 − λ) y + λ u``, ``y`` the member's reading; exact zeros on padded slots."""
    xyz = jnp.asarray(xyz)
    dtype = jnp.result_type(xyz.dtype, jnp.float32)
    xyz = xyz.astype(dtype)
    goals = jnp.asarray(goals, dtype)
    mask = jnp.asarray(goal_mask).astype(bool)
    T = xyz.shape[0]
    L = jnp.clip(jnp.asarray(seen, jnp.int32), 2, T)
    u = (mask / jnp.sum(mask)).astype(dtype)
    q, h = _coords(member.view, xyz, goals)
    y = member.reading(q, h, mask, L, u, person, xyz)
    lapse = person["lapse"]
    return jnp.where(mask, (1.0 - lapse) * y + lapse * u, 0.0)


def _each_person(member, people, xyz, goals, goal_mask, seen) -> Float[Array, "n 8"]:
    """:func:`person_probs` of every person of ``people`` (dict entries ``(n,)``)."""
    return jax.vmap(lambda p: person_probs(member, p, xyz, goals, goal_mask, seen))(people)


@functools.cache
def _representatives(member: ZooMember) -> dict[str, Array]:
    with jax.ensure_compile_time_eval():
        return draw_people(member, jax.random.key(_PEOPLE_KEY), N_PEOPLE)


def zoo_probs(
    member: ZooMember,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""],
) -> Float[Array, " 8"]:
    """The member's ``P(goal | motion seen up to point L = seen)``: the mean guess
    distribution of :data:`N_PEOPLE` representative people (a fixed draw), a pure,
    differentiable function of ``xyz``; exact zeros on padded slots."""
    return jnp.mean(_each_person(member, _representatives(member), xyz, goals, goal_mask, seen), 0)


def sample_zoo_guesses(
    member: ZooMember,
    key: jax.Array,
    xyz: Float[Array, "T 3"],
    goals: Float[Array, "8 3"],
    goal_mask: Bool[Array, " 8"],
    seen: Int[Array, ""],
    n: int,
) -> Int[Array, " n"]:
    """The guesses (goal slots) of ``n`` fresh people of ``member``, each with their own
    parameters, after the first ``seen`` points."""
    k_people, k_guess = jax.random.split(key)
    p = _each_person(member, draw_people(member, k_people, n), xyz, goals, goal_mask, seen)
    logits = masked_log(p, jnp.asarray(goal_mask).astype(bool)[None, :])
    return jax.random.categorical(k_guess, logits, axis=-1).astype(jnp.int32)


@functools.partial(jax.jit, static_argnums=(0, 6))
def _guesses_batch(member, keys, xyz, goals, goal_mask, seen, n):
    return jax.vmap(lambda k, x, g, m, s: sample_zoo_guesses(member, k, x, g, m, s, n))(
        keys, xyz, goals, goal_mask, seen
    )


def sample_zoo_guesses_batch(
    member: ZooMember,
    keys: jax.Array,
    xyz: Float[Array, "B T 3"],
    goals: Float[Array, "B 8 3"],
    goal_mask: Bool[Array, "B 8"],
    seen: Int[Array, " B"],
    n: int,
) -> Int[Array, "B n"]:
    """:func:`sample_zoo_guesses` for B stimuli at once (stimulus b's people drawn from
    ``keys[b]``), compiled once per member, batch size and ``n``."""
    return _guesses_batch(member, keys, xyz, goals, goal_mask, jnp.asarray(seen), int(n))


def _check_member(obj, spec: str) -> ZooMember:
    if not isinstance(obj, ZooMember):
        raise ValueError(
            f"population: {spec} must give a ZooMember (slotv_jax.observers.zoo), "
            f"got {type(obj).__name__}"
        )
    xyz = jnp.linspace(jnp.array([0.31, 0.0, 0.49]), jnp.array([0.5, 0.3, 0.025]), 20)
    goals = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    mask = jnp.arange(8) < 2
    try:
        p = np.asarray(_each_person(obj, _representatives(obj), xyz, goals, mask, 20))
    except Exception as e:  # a user's reading: any failure is theirs to see, in one line
        raise ValueError(f"population: {spec}: its reading fails on a test motion: {e}") from e
    if p.shape != (N_PEOPLE, 8) or not np.all(np.isfinite(p)):
        raise ValueError(
            f"population: {spec}: its reading must give a finite (8,) distribution per person, "
            f"got shape {p.shape[1:]}"
        )
    if not np.allclose(p.sum(-1), 1.0, atol=1e-4) or np.any(p[:, 2:] != 0):
        raise ValueError(
            f"population: {spec}: its reading must sum to 1 over the real goals and be 0 on "
            "padded slots"
        )
    return obj


@functools.cache  # a user's module is imported and checked once (failures are not kept)
def load_people(spec: str) -> ZooMember:
    """A zoo member by name (:func:`zoo_names`) or ``module:function``, a researcher's own
    people: ``function()`` returns a :class:`ZooMember`, checked on a test motion (shape,
    finiteness, a distribution over the real goals) before any work."""
    if spec in MEMBERS:
        return MEMBERS[spec]
    if ":" not in spec:
        raise ValueError(
            f"population: expected a zoo member ({', '.join(MEMBERS)}) or module:function, "
            f"got {spec!r}"
        )
    mod_name, _, fn_name = spec.partition(":")
    try:
        mod = importlib.import_module(mod_name)
    except Exception as e:
        raise ValueError(f"population: cannot import module {mod_name!r}: {e}") from e
    fn = getattr(mod, fn_name, None)
    if not callable(fn):
        raise ValueError(f"population: module {mod_name!r} has no function {fn_name!r}")
    try:
        member = fn()
    except Exception as e:
        raise ValueError(f"population: {spec}() failed: {e}") from e
    return _check_member(member, spec)
