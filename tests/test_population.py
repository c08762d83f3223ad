"""The population of simulated people (slotv_jax.observers.population): P_pop against an
independent float64 NumPy re-derivation, the homogeneous population against the Dragan
labeler, the quadrature against a float64 Monte-Carlo of the model's definition, the
sampler against P_pop (χ² over 2·10⁵ draws), gradients, compilation, population files, and
population participants through the study server."""

from __future__ import annotations

import asyncio
import hashlib
import json
import math
import sqlite3

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compile_log import backend_compiles, counting_traces
from docs_pages import marked_block
from hypothesis import example, given, settings
from hypothesis import strategies as st
from study_fixtures import ServerProcess, write_dot_set

from slotv_jax.core.defaults import DEFAULT_BETAS
from slotv_jax.core.validation import FLOAT32_MAX
from slotv_jax.observers import labelers
from slotv_jax.observers import population as P
from slotv_jax.planning import check_observer
from slotv_jax.study import cli as study_cli
from slotv_jax.webstudy import client, stimuli
from slotv_jax.world import scene

T = 30
F32_ATOL = 2e-5  # float32 against float64: softmax of β e with β e up to ~100
N_DRAWS = 200_000

# a population with every viewpoint (the world too) and rule, wide temperatures
EVERYTHING = P.default().replace(
    name="everything",
    viewpoints=(("observer", 0.2), ("observer_angle", 0.3), ("observer_side", 0.1), ("world", 0.4)),
    rules=(("cost_to_go", 0.4), ("proximity", 0.35), ("direction", 0.25)),
    beta=(("cost_to_go", 25.0), ("proximity", 15.0), ("direction", 4.0)),
    beta_sigma_log=0.6,
    alpha_range=(0.5, 1.5),
    lapse=0.1,
    beta_nodes=5,
    alpha_nodes=3,
)
DRAGAN_MEMORY = EVERYTHING.replace(name="dragan-memory", memory="dragan", alpha_range=None)


def random_problem(seed: int, n_goals: int, *, behind: bool = False, repeat: bool = True):
    """A wiggly path from above the table towards one of ``n_goals`` cubes, with a
    repeated point (the direction rule's zero step) unless not ``repeat``; padded goal
    slots hold junk."""
    rng = np.random.default_rng(seed)
    goals = rng.uniform(-3.0, 3.0, (8, 3))  # padding: anywhere, even behind the cameras
    goals[:n_goals] = rng.uniform([0.3, -0.45, 0.025], [0.7, 0.45, 0.025], (n_goals, 3))
    mask = np.arange(8) < n_goals
    s = np.linspace(0.0, 1.0, T)[:, None]
    start = np.array([0.3, 0.0, 0.49]) + rng.uniform(-0.05, 0.05, 3)
    wiggle = 0.1 * np.sin(np.pi * s * rng.integers(1, 4)) * rng.normal(size=3)
    xyz = start + s * (goals[rng.integers(n_goals)] - start) + wiggle
    if repeat:
        xyz[7] = xyz[6]
    if behind:  # point 20 behind the `observer` camera (at x = 1.6, looking along −x)
        xyz[20] = [1.8, 0.0, 0.9]
    return xyz, goals, mask


# ------------------------------------------------------------------ float64 reference


def ref_view(pts, view):
    """Coordinates (…, 3) seen from ``view`` and the camera depth, NumPy float64."""
    if view == "world":
        return pts, np.full(pts.shape[:-1], np.inf)
    cam = scene.camera(view)
    pc = (pts - np.asarray(cam.pos, np.float64)) @ np.asarray(cam.rot, np.float64)
    depth = -pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([pc[..., 0] / depth, pc[..., 1] / depth, 0 * depth], -1), depth


def ref_evidence(q, h, rule):
    """e (L, G) for seen points q (L, 3) and real goals h (G, 3), written out per point."""
    d = np.linalg.norm(q[:, None] - h[None], axis=-1)
    if rule == "cost_to_go":
        return d[0] - d
    if rule == "proximity":
        return -d
    e = np.zeros_like(d)
    eps2 = P.DIRECTION_EPS**2
    for i in range(1, len(q)):
        a = q[i] - q[i - 1]
        for k in range(len(h)):
            b = h[k] - q[i]
            e[i, k] = a @ b / (np.sqrt(a @ a + eps2) * np.sqrt(b @ b + eps2))
    return e


def ref_weights(L, memory, alpha):
    """(…, L) memory weights; ``alpha`` (…,)."""
    i = np.arange(L, dtype=np.float64)
    if memory == "recency":
        w = ((i + 1) / L) ** np.asarray(alpha, np.float64)[..., None]
    else:
        trap = np.ones(L)
        trap[[0, -1]] = 0.5
        w = trap * (1 - i / (L - 1))
    return w / w.sum(-1, keepdims=True)


def ref_tables(pop, xyz, goals, mask, L):
    """Per (viewpoint, rule): the evidence on the real goals (L, G_real), and whether the
    viewpoint sees every seen point and real goal."""
    out = {}
    for view, _ in pop.viewpoints:
        q, dq = ref_view(xyz[:L], view)
        h, dh = ref_view(goals[mask], view)
        sees = bool(np.all(dq > 1e-6) and np.all(dh > 1e-6))
        for rule, _ in pop.rules:
            out[view, rule] = (ref_evidence(q, h, rule) if sees else None), sees
    return out


def ref_people(tables, mask, L, memory, lapse, view, rule, beta, alpha):
    """p^(n) (M, 8) of M participants of one viewpoint and rule, float64."""
    e, sees = tables[view, rule]
    beta = np.asarray(beta, np.float64)
    u = mask / mask.sum()
    if not sees:
        return np.broadcast_to((1 - lapse) * u + lapse * u, (beta.size, 8))
    z = beta[:, None, None] * e[None]
    p = np.exp(z - z.max(-1, keepdims=True))
    p /= p.sum(-1, keepdims=True)  # (M, L, G_real)
    y = np.zeros((beta.size, 8))
    y[:, mask] = np.einsum("ml,mlg->mg", np.broadcast_to(ref_weights(L, memory, alpha),
                                                         (beta.size, L)), p)  # fmt: skip
    return (1 - lapse) * y + lapse * u


def ref_population(pop, xyz, goals, mask, L):
    """P_pop by its definition: exact sums over viewpoints and rules, Gauss–Hermite nodes of
    log β, Gauss–Legendre nodes of α, float64."""
    tables = ref_tables(pop, xyz, goals, mask, L)
    J = pop.beta_nodes if pop.beta_sigma_log > 0 else 1
    z, wz = np.polynomial.hermite_e.hermegauss(J)
    wz = wz / wz.sum()
    if pop.memory == "recency":
        x, wa = np.polynomial.legendre.leggauss(pop.alpha_nodes)
        lo, hi = pop.alpha_range
        alphas, wa = lo + (hi - lo) * (x + 1) / 2, wa / wa.sum()
    else:
        alphas, wa = np.zeros(1), np.ones(1)
    out = np.zeros(8)
    for view, pv in pop.viewpoints:
        for rule, pr in pop.rules:
            beta = dict(pop.beta)[rule] * np.exp(pop.beta_sigma_log * z)
            b, a = np.repeat(beta, alphas.size), np.tile(alphas, J)
            p = ref_people(tables, mask, L, pop.memory, pop.lapse, view, rule, b, a)
            out += pv * pr * np.einsum("j,k,jkg->g", wz, wa, p.reshape(J, alphas.size, 8))
    return out


# ------------------------------------------------------------------ P_pop


@pytest.mark.parametrize("pop", [EVERYTHING, DRAGAN_MEMORY, P.default()], ids=lambda p: p.name)
def test_population_probs_match_float64_reference(pop):
    f = jax.jit(P.population_probs)
    quad = P.quadrature(pop)
    for seed, n_goals, behind in [(0, 2, False), (1, 5, True), (2, 8, False), (3, 3, True)]:
        xyz, goals, mask = random_problem(seed, n_goals, behind=behind)
        for L in (2, 3, 11, 20, 21, T):
            got = np.asarray(f(quad, xyz.astype(np.float32), goals.astype(np.float32), mask, L))
            want = ref_population(pop, xyz, goals, mask, L)
            np.testing.assert_allclose(got, want, atol=F32_ATOL, err_msg=f"{seed=} {L=}")
            assert np.all(got[~mask] == 0.0)


def test_every_population_shares_one_program():
    """P_pop and the guesses take the population as arrays of one shape: one compilation
    for every population (and seen count), whatever its viewpoints, rules, nodes, memory."""
    pops = [EVERYTHING, DRAGAN_MEMORY, P.default(), P.homogeneous(),
            *(P.random_population(k) for k in range(4))]  # fmt: skip
    assert len({(len(p.viewpoints), len(p.rules), p.memory) for p in pops}) >= 4
    counted, traces = counting_traces(P.population_probs)
    probs = jax.jit(counted)
    xyz, goals, mask = random_problem(1, 5, behind=True)
    keys = jax.random.split(jax.random.key(0), 2)
    x2, g2, m2 = (np.stack([a, a]) for a in (xyz.astype(np.float32), goals, mask))
    with backend_compiles() as compiled:
        for i, pop in enumerate(pops):
            probs(P.quadrature(pop), xyz.astype(np.float32), goals, mask, 5 + i)
            P.sample_guesses_batch(pop, keys, x2, g2, m2, np.asarray([5 + i, 9]), 13)  # new
    assert len(traces) == 1
    assert compiled.count("jit(guess_goals)") == 1  # the guesses: one program too


@pytest.mark.parametrize("pop", [EVERYTHING, DRAGAN_MEMORY], ids=lambda p: p.name)
def test_batched_guesses_are_sample_guesses_path_by_path(pop):
    """The shared program draws exactly what sample_guesses draws with each path's key (the
    simulated answers and the evaluation rely on it: the same answers as before)."""
    xyz, goals, mask = random_problem(2, 5, behind=True)
    keys = jax.random.split(jax.random.key(4), 3)
    seen = np.asarray([3, 20, T])
    x3, g3, m3 = (np.stack([a] * 3) for a in (xyz.astype(np.float32), goals, mask))
    got = np.asarray(P.sample_guesses_batch(pop, keys, x3, g3, m3, seen, 64))
    want = [P.sample_guesses(pop, k, x3[0], goals, mask, int(s), 64)
            for k, s in zip(keys, seen, strict=True)]  # fmt: skip
    np.testing.assert_array_equal(got, np.stack(want))


def test_unseen_viewpoint_guesses_uniformly():
    """A point behind the `observer` camera: before it is seen the camera's people judge the
    motion, after it they guess uniformly (the reference agrees above; here by hand)."""
    pop = EVERYTHING.replace(viewpoints=(("observer", 1.0),), lapse=0.0)
    xyz, goals, mask = random_problem(1, 4, behind=True)
    quad = P.quadrature(pop)
    before = P.population_probs(quad, xyz, goals, mask, 20)
    after = P.population_probs(quad, xyz, goals, mask, 21)
    assert np.abs(np.asarray(before[:4]) - 0.25).max() > 0.01
    np.testing.assert_array_equal(np.asarray(after), mask / 4.0)


def test_participant_probs_match_float64_reference():
    pop = EVERYTHING
    parts = P.draw_participants(pop, jax.random.key(3), 64)
    xyz, goals, mask = random_problem(5, 6, behind=True)
    views = [v for v, _ in pop.viewpoints]
    for L in (2, 17, 25):
        got = np.asarray(P.participant_probs(parts, xyz, goals, mask, L))
        tables = ref_tables(pop, xyz, goals, mask, L)
        for n in range(parts.size):
            view, rule = views[int(parts.viewpoint[n])], P.RULES[int(parts.rule[n])]
            want = ref_people(tables, mask, L, pop.memory, pop.lapse, view, rule,
                              [float(parts.beta[n])], [float(parts.alpha[n])])[0]  # fmt: skip
            np.testing.assert_allclose(got[n], want, atol=F32_ATOL, err_msg=f"{n=} {L=}")


def test_homogeneous_population_is_the_dragan_labeler():
    quad = P.quadrature(P.homogeneous())
    assert P.homogeneous().beta == (("cost_to_go", DEFAULT_BETAS["dragan"]),)
    for seed, n_goals in [(0, 2), (1, 5), (2, 8)]:
        xyz, goals, mask = random_problem(seed, n_goals)
        xyz, goals = xyz.astype(np.float32), goals.astype(np.float32)
        for L in (2, 3, 12, T):
            want = labelers.dragan(xyz[:L], goals, mask)
            np.testing.assert_allclose(P.population_probs(quad, xyz, goals, mask, L), want,
                                       rtol=1e-5, atol=1e-6)  # fmt: skip


def test_one_camera_population_is_the_nikolaidis_labeler():
    """The image cost-to-go of one camera with Dragan's memory is :ref:`concepts-cameras`'s
    labeler."""
    pop = P.homogeneous().replace(viewpoints=(("observer_angle", 1.0),),
                                  beta=(("cost_to_go", DEFAULT_BETAS["nikolaidis"]),))  # fmt: skip
    quad = P.quadrature(pop)
    xyz, goals, mask = random_problem(4, 4)
    xyz, goals = xyz.astype(np.float32), goals.astype(np.float32)
    for L in (2, 9, T):
        want = labelers.nikolaidis(xyz[:L], goals, mask, "observer_angle")
        np.testing.assert_allclose(P.population_probs(quad, xyz, goals, mask, L), want,
                                   rtol=1e-5, atol=1e-6)  # fmt: skip


def test_quadrature_is_the_population_expectation():
    """P_pop (the quadrature) against a float64 Monte-Carlo of the model's definition:
    40,000 participants drawn with NumPy (viewpoint, rule, β = β₀ e^{σz}, α uniform), each
    one's p^(n) from the reference; |P_pop − mean| ≤ 5 standard errors + the quadrature's
    own error (8 nodes against 32, bounded here too)."""
    pop = EVERYTHING.replace(beta_nodes=8, alpha_nodes=8)
    fine = pop.replace(beta_nodes=32, alpha_nodes=32)
    rng = np.random.default_rng(7)
    M = 40_000
    views = np.array([v for v, _ in pop.viewpoints])
    rules = np.array([r for r, _ in pop.rules])
    for seed, L in [(11, 14), (12, T)]:
        xyz, goals, mask = random_problem(seed, 4, behind=seed == 11)
        tables = ref_tables(pop, xyz, goals, mask, L)
        v = rng.choice(len(views), M, p=[p for _, p in pop.viewpoints])
        r = rng.choice(len(rules), M, p=[p for _, p in pop.rules])
        beta = np.array([dict(pop.beta)[x] for x in rules[r]]) * np.exp(
            pop.beta_sigma_log * rng.normal(size=M)
        )
        alpha = rng.uniform(*pop.alpha_range, M)
        p = np.zeros((M, 8))
        for i, view in enumerate(views):
            for j, rule in enumerate(rules):
                at = (v == i) & (r == j)
                p[at] = ref_people(tables, mask, L, pop.memory, pop.lapse, view, rule,
                                   beta[at], alpha[at])  # fmt: skip
        mc, se = p.mean(0), p.std(0) / np.sqrt(M)
        got = np.asarray(P.population_probs(P.quadrature(pop), xyz, goals, mask, L), np.float64)
        ref = np.asarray(P.population_probs(P.quadrature(fine), xyz, goals, mask, L), np.float64)
        quad_err = np.abs(got - ref).max()
        assert quad_err < 1e-4
        assert np.all(np.abs(got - mc) <= 5 * se + quad_err + F32_ATOL), (got, mc, se)
        assert se.max() < 3e-3  # the check has teeth: a 1.5 % error fails it


def chi2_stat(counts, p):
    m = p > 0
    expected = counts.sum() * p[m]
    return float(np.sum((counts[m] - expected) ** 2 / expected)), int(m.sum() - 1)


def test_sampler_matches_population_probs():
    """2·10⁵ guesses of fresh participants against P_pop: Pearson's χ² (the multinomial
    error; P_pop's quadrature error, < 1e-5, adds < 0.01 to χ² at this size) below its
    1 − 1e-4 quantile. The same counts against a population with another lapse fail."""
    from scipy.stats import chi2

    pop = EVERYTHING.replace(lapse=0.05)
    other = pop.replace(lapse=0.2)
    f = jax.jit(P.sample_guesses, static_argnums=(0, 6))
    for seed, n_goals, L in [(21, 3, 9), (22, 6, T), (23, 8, 2)]:
        xyz, goals, mask = random_problem(seed, n_goals, behind=seed == 22)
        xyz, goals = xyz.astype(np.float32), goals.astype(np.float32)
        g = np.asarray(f(pop, jax.random.key(seed), xyz, goals, mask, L, N_DRAWS))
        assert set(np.unique(g)) <= set(np.flatnonzero(mask))
        counts = np.bincount(g, minlength=8).astype(np.float64)
        p = np.asarray(P.population_probs(P.quadrature(pop), xyz, goals, mask, L), np.float64)
        stat, df = chi2_stat(counts, p / p.sum())
        assert stat < chi2.ppf(1 - 1e-4, df), (stat, df, counts / N_DRAWS, p)
        if L > 2:  # at L = 2 cost-to-go and direction are uniform: lapses change little
            q = np.asarray(P.population_probs(P.quadrature(other), xyz, goals, mask, L))
            assert chi2_stat(counts, q / q.sum())[0] > chi2.ppf(1 - 1e-4, df)


def test_drawn_participants_follow_the_population():
    pop = EVERYTHING
    parts = P.draw_participants(pop, jax.random.key(0), N_DRAWS)
    v = np.bincount(np.asarray(parts.viewpoint), minlength=4) / N_DRAWS
    np.testing.assert_allclose(v, [p for _, p in pop.viewpoints], atol=0.005)
    r = np.asarray(parts.rule)
    np.testing.assert_allclose(np.bincount(r, minlength=3) / N_DRAWS,
                               [p for _, p in pop.rules], atol=0.005)  # fmt: skip
    for k, rule in enumerate(P.RULES):
        log_b = np.log(np.asarray(parts.beta)[r == k] / dict(pop.beta)[rule])
        assert abs(log_b.mean()) < 0.01 and abs(log_b.std() - pop.beta_sigma_log) < 0.01
    a = np.asarray(parts.alpha)
    assert a.min() >= 0.5 and a.max() <= 1.5 and abs(a.mean() - 1.0) < 0.005


# ------------------------------------------------------------------ gradients, observer


def test_gradients_are_finite_and_ignore_unseen_points():
    quad = P.quadrature(P.default())
    xyz, goals, mask = random_problem(31, 4)
    xyz[-1] = goals[0]  # the motion ends exactly on a goal
    xyz, goals = xyz.astype(np.float32), goals.astype(np.float32)

    def loss(x, L):
        return jnp.log(P.population_probs(quad, x, goals, mask, L)[0])

    counted, traces = counting_traces(loss)
    grad = jax.jit(jax.grad(counted))
    for L in (2, 8, T):
        g = np.asarray(grad(xyz, L))
        assert np.all(np.isfinite(g)) and np.abs(g[:L]).max() > 0
        assert np.all(g[L:] == 0.0)
    assert len(traces) == 1
    # NaN beyond the seen points reaches neither the value nor the gradient
    bad = xyz.copy()
    bad[15:] = np.nan
    assert np.all(np.isfinite(grad(bad, 15))) and np.isfinite(loss(bad, 15))


@pytest.mark.slow
def test_gradient_matches_finite_differences():
    """The hand-written gradient of the softmax mixture against central differences
    (float64), on a path without a repeated point: there the direction's ε-floor bends
    the function on a 1e-4 scale, too sharp for differences of 1e-6."""
    from jax.test_util import check_grads

    with jax.enable_x64(True):
        pop = EVERYTHING
        quad = P.quadrature(pop)
        xyz, goals, mask = random_problem(41, 3, repeat=False)
        parts = P.draw_participants(pop, jax.random.key(1), 6)

        def f(x, g):
            return jnp.log(P.population_probs(quad, x, g, mask, 17)[:3])

        def h(x):
            return P.participant_probs(parts, x, goals, mask, 17)[:, :3]

        check_grads(f, (jnp.asarray(xyz), jnp.asarray(goals)), order=1, modes=["rev"],
                    atol=1e-5, rtol=1e-5, eps=1e-6)  # fmt: skip
        check_grads(h, (jnp.asarray(xyz),), order=1, modes=["rev"], atol=1e-5, rtol=1e-5,
                    eps=1e-6)  # fmt: skip


def test_population_observer_contract():
    pop = P.default()
    obs = P.population_observer(pop)
    check_observer(obs, prefix=True)
    xyz, goals, mask = random_problem(51, 5)
    xyz, goals = xyz.astype(np.float32), goals.astype(np.float32)
    quad = P.quadrature(pop)
    logits = obs(xyz, goals, mask)
    np.testing.assert_allclose(jnp.exp(logits), P.population_probs(quad, xyz, goals, mask, T),
                               rtol=1e-6)  # fmt: skip
    assert np.all(np.isneginf(np.asarray(logits)[~mask]))
    counted, traces = counting_traces(obs.prefix)
    prefix = jax.jit(counted)
    for L in (4, 19):
        np.testing.assert_allclose(
            jnp.exp(prefix(xyz, goals, mask, L)),
            P.population_probs(quad, xyz, goals, mask, L),
            rtol=1e-6,
        )
    assert len(traces) == 1


# ------------------------------------------------------------------ population files


def test_files_round_trip_and_names(tmp_path):
    for pop in (P.default(), P.homogeneous(), EVERYTHING):
        path = tmp_path / f"{pop.name}.json"
        P.save_population(pop, path)
        assert P.load_population(path) == pop == P.get_population(path)
        assert json.loads(path.read_text()) == pop.to_dict()
    assert P.get_population("default") == P.default()
    assert P.get_population("homogeneous") == P.homogeneous()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    with pytest.raises(ValueError, match="population: expected default, homogeneous, random:K "):
        P.get_population("nobody")


def test_a_population_is_made_and_loaded_without_posing_a_camera(tmp_path):
    """Its camera names are checked against the scene model by name: nothing is compiled
    (posing each camera for the check was 25 s of the README's population snippet on a
    loaded 2-core CPU)."""
    scene._camera_cached.cache_clear()
    with backend_compiles() as compiled:
        P.save_population(P.default().replace(name="mine"), tmp_path / "p.json")
        assert P.load_population(tmp_path / "p.json").name == "mine"
    assert compiled == []  # (an unknown camera: test_bad_population_files_are_one_named_error)


def _bad(**changes):
    d = P.default().to_dict()
    for k, v in changes.items():
        if v is _DROP:
            del d[k]
        else:
            d[k] = v
    return d


_DROP = object()
BAD = {
    "unknown key": (_bad(colour="red"), "'colour': unknown"),
    "missing key": (_bad(lapse=_DROP), "'lapse': missing"),
    "probability as text": (_bad(rules={"cost_to_go": "0.5", "proximity": 0.5}), "'rules'"),
    "boolean probability": (_bad(viewpoints={"observer": True}), "'viewpoints'"),
    "rules do not sum to 1": (
        _bad(rules={"cost_to_go": 0.5, "proximity": 0.3, "direction": 0.3}),
        "sum to 1.1",
    ),
    "viewpoints do not sum to 1": (_bad(viewpoints={"observer": 0.5}), "sum to 0.5"),
    "negative sigma": (_bad(beta_sigma_log=-0.1), "'beta_sigma_log'"),
    "lapse above 1": (_bad(lapse=1.5), "'lapse'"),
    "negative lapse": (_bad(lapse=-0.01), "'lapse'"),
    "unknown camera": (_bad(viewpoints={"observer": 0.5, "ceiling": 0.5}), "camera 'ceiling'"),
    "unknown rule": (_bad(rules={"cost_to_go": 0.5, "telepathy": 0.5}), "rule 'telepathy'"),
    "beta for another rule": (_bad(beta={"cost_to_go": 30.0, "proximity": 30.0}), "'beta'"),
    "beta zero": (
        _bad(beta={"cost_to_go": 0.0, "proximity": 30.0, "direction": 5.0}),
        "'beta'",
    ),
    "unknown memory": (_bad(memory="goldfish"), "'memory'"),
    "alpha range reversed": (_bad(alpha_range=[2.0, 0.0]), "'alpha_range'"),
    "alpha range with dragan": (_bad(memory="dragan"), "'alpha_range'"),
    "nodes zero": (_bad(beta_nodes=0), "'beta_nodes'"),
    "nodes as float": (_bad(alpha_nodes=8.0), "'alpha_nodes'"),
    "name empty": (_bad(name=""), "'name'"),
    "not an object": ([1, 2], "expected a JSON object"),
    # values whose use overflows float32 (P_pop was NaN)
    "beta beyond float32": (
        _bad(beta={"cost_to_go": 1e300, "proximity": 30.0, "direction": 5.0}),
        "'beta': 'cost_to_go': expected a number in (0, ",
    ),
    "sigma too wide": (_bad(beta_sigma_log=1000), "'beta_sigma_log': expected a number in [0, 5]"),
    "temperatures overflow at the outer node": (
        _bad(beta_sigma_log=5.0, beta_nodes=64),
        "'beta': 'cost_to_go': 30.0 gives participants temperatures up to",
    ),
    "alpha beyond float32": (_bad(alpha_range=[0.0, 1e300]), "'alpha_range'"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_population_files_are_one_named_error(case, tmp_path):
    doc, field = BAD[case]
    path = tmp_path / "people.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError) as e:
        P.load_population(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and field in msg and "\n" not in msg, msg


def test_bad_json_and_duplicate_keys(tmp_path):
    path = tmp_path / "people.json"
    path.write_text(json.dumps(P.default().to_dict())[:-20])
    with pytest.raises(ValueError, match=r"people\.json, line 1, .*truncated"):
        P.load_population(path)
    path.write_text('{"lapse": 0.1, "lapse": 0.2}')
    with pytest.raises(ValueError, match=r"people\.json: field 'lapse': given twice"):
        P.load_population(path)


def test_deep_json_and_a_directory_are_named(tmp_path):
    """A file nested 100,000 deep (Python's json raises RecursionError) and a directory:
    one line naming the file, through get_population as the commands call it."""
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=rf"^{deep}: not a JSON document .* nested too deeply"):
        P.get_population(deep)
    with pytest.raises(ValueError, match=rf"^population {tmp_path}: is a directory; expected a "):
        P.get_population(tmp_path)


_log_uniform = st.floats(-3.0, 40.0).map(lambda e: 10.0**e)
# the largest centre at σ = 5: the outer node of 64 at exactly BETA_MAX
_AT_THE_BOUND = P.BETA_MAX / math.exp(P.SIGMA_LOG_MAX * P._z_reach(5.0, P.MAX_NODES)) * 0.999


@settings(max_examples=20)
@given(
    beta=st.tuples(_log_uniform, _log_uniform, _log_uniform),
    sigma=st.one_of(st.just(0.0), st.floats(0.0, 8.0)),
    alpha_hi=st.one_of(st.just(2.0), _log_uniform),
    lapse=st.sampled_from([0.0, 0.05]),
)
@example(beta=(P.BETA_MAX,) * 3, sigma=0.0, alpha_hi=FLOAT32_MAX, lapse=0.0)  # the bounds
@example(beta=(_AT_THE_BOUND,) * 3, sigma=P.SIGMA_LOG_MAX, alpha_hi=2.0, lapse=0.0)
def test_an_accepted_population_gives_finite_probabilities(beta, sigma, alpha_hi, lapse):
    """Any population the checks accept gives a finite P_pop and finite drawn participants'
    probabilities, on a path seen from a camera and in the world; any other is refused in
    one line naming a field (temperatures up to 1e40, σ up to 8, α up to 1e40; 64 nodes of
    log β, the quadrature's outermost)."""
    d = _bad(
        viewpoints={"observer_side": 0.5, "world": 0.5},
        beta=dict(zip(P.RULES, beta, strict=True)),
        beta_sigma_log=sigma,
        beta_nodes=P.MAX_NODES,
        alpha_range=[0.0, alpha_hi],
        alpha_nodes=2,
        lapse=lapse,
    )
    try:
        pop = P.Population.from_dict(d, "pop.json")
    except ValueError as e:
        assert str(e).startswith("pop.json: field '") and "\n" not in str(e), e
        return
    xyz, goals, mask = random_problem(0, 3)
    p = _jit_population_probs(P.quadrature(pop), xyz, goals, mask, 20)
    assert np.isfinite(np.asarray(p)).all() and float(p.sum()) == pytest.approx(1.0, abs=1e-5)
    people = P.draw_participants(pop, jax.random.key(1), 16)
    assert np.isfinite(np.asarray(_jit_participant_probs(people, xyz, goals, mask, 20))).all()


_jit_population_probs = jax.jit(P.population_probs)  # one compilation per node count
_jit_participant_probs = jax.jit(P.participant_probs)


def test_population_constructed_in_python_is_checked():
    with pytest.raises(ValueError, match=r"population 'default': field 'lapse'"):
        P.default().replace(lapse=2.0)


# ------------------------------------------------------------------ through the server


@pytest.fixture(scope="module")
def dot_study(tmp_path_factory):
    out = tmp_path_factory.mktemp("pop") / "stim"
    write_dot_set(out, n=4, taus=(0.5, 1.0))
    return out


def test_population_guesser_answers_from_its_own_draw(dot_study):
    crowd = client.PopulationGuesser(dot_study, EVERYTHING, seed=3)
    people = [crowd.participant(i) for i in range(4)]
    draws = [p.parameters() for p in people]
    assert len({d["beta"] for d in draws}) == 4  # each their own temperature
    assert crowd.participant(2).parameters() == draws[2]  # reproducible from (seed, i)
    st = stimuli.load_stimulus_set(dot_study, verify=False)
    still = (dot_study / st.manifest["stimuli"][1]["still"]).read_bytes()
    # the dot renderer draws every motion alike at one τ: the still names the last of them
    s, st = crowd.stimuli.by_still[hashlib.sha256(still).hexdigest()]
    pts = np.asarray(st.trajectories[s["trajectory"]], np.float64)
    L = max(2, int(np.sum(pts[:, 0] <= s["tau"] + 1e-9)))
    g = st.goals[s["trajectory"]]
    goals = np.zeros((8, 3))
    goals[: len(g)] = [row[1:] for row in g]
    mask = np.arange(8) < len(g)
    for person in people:
        labels, p = person.probs(still)
        assert labels == [row[0] for row in g]
        want = P.participant_probs(person.people, pts[:, 1:], goals, mask, L)[0, : len(g)]
        np.testing.assert_allclose(p, want, rtol=1e-5)


def test_simulate_population_through_the_server(dot_study, tmp_path, capsys):
    db = tmp_path / "study.db"
    server = ServerProcess(dot_study, db)
    try:
        code = study_cli.main(["simulate", "--url", server.url, "--stimuli", str(dot_study),
                               "--participants", "3", "--population", "default", "--seed",
                               "5"])  # fmt: skip
    finally:
        server.stop()
    assert code == 0
    assert "3 of 3 simulated participants finished, 18 answers" in capsys.readouterr().out
    con = sqlite3.connect(db)
    guesses = [g for (g,) in con.execute("SELECT guess FROM answers")]
    con.close()
    assert len(guesses) == 18 and set(guesses) <= {"A", "B", "C"}


def test_simulate_against_another_study_names_the_stimuli_folder(dot_study, tmp_path, capsys):
    """A server that serves another study folder than --stimuli: one line naming the
    folder, not a KeyError traceback (the stills of a set at another τ are not this one's)."""
    other = tmp_path / "other"
    write_dot_set(other, n=4, taus=(0.3,))
    server = ServerProcess(other, tmp_path / "study.db")
    try:
        with pytest.raises(SystemExit) as e:
            study_cli.main(["simulate", "--url", server.url, "--stimuli", str(dot_study),
                            "--participants", "2", "--population", "default"])  # fmt: skip
    finally:
        server.stop()
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: --stimuli {dot_study}: the server showed a still") and (
        err.count("\n") == 1
    ), err


def test_a_later_crowd_under_answered_ids_is_refused_in_one_line(dot_study, tmp_path, capsys):
    """``simulate --first`` under ids an earlier crowd answered with: the server refuses the
    start (409) and the command says so in one line naming the flag and the participant,
    not an ``HTTPStatusError`` traceback; the earlier crowd's answers stay as they were."""
    db = tmp_path / "study.db"
    server = ServerProcess(dot_study, db)
    sim = ["simulate", "--url", server.url, "--stimuli", str(dot_study)]
    try:
        assert study_cli.main([*sim, "--participants", "2"]) == 0  # sim-0, sim-1
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:
            study_cli.main([*sim, "--participants", "3", "--first", "1"])  # sim-1 answered
    finally:
        server.stop()
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: --first 1: participant sim-1 already exists on the server "
                          "(409 Conflict"), err  # fmt: skip
    assert "sim-1 ... sim-3: choose another --first" in err
    con = sqlite3.connect(db)
    rows = con.execute("SELECT p.external_id, COUNT(*) FROM answers a JOIN trials t ON "
                       "t.trial = a.trial JOIN participants p ON p.participant = t.participant "
                       "GROUP BY p.external_id").fetchall()  # fmt: skip
    con.close()
    assert dict(rows)["sim-0"] == dict(rows)["sim-1"] == 6  # their whole study, once


def test_simulate_population_errors_before_any_work(tmp_path, capsys, dot_study):
    bad, deep, big = (tmp_path / f"{n}.json" for n in ("bad", "deep", "big"))
    bad.write_text(json.dumps(_bad(lapse=3)))
    deep.write_text("[" * 100_000 + "]" * 100_000)
    big.write_text(json.dumps(_bad(beta_sigma_log=1000)))
    url = "http://127.0.0.1:9"  # nothing listens: the error must come before contacting it
    for extra, msg in [(["--population", str(bad)], f"{bad}: field 'lapse'"),
                       (["--population", str(deep)], f"{deep}: not a JSON document"),
                       (["--population", str(big)], f"{big}: field 'beta_sigma_log'"),
                       (["--population", str(tmp_path)], "is a directory"),
                       (["--population", "nobody"], "population: expected default"),
                       (["--population", "default", "--labeler", "dragan"],
                        "--labeler, --population")]:  # fmt: skip
        with pytest.raises(SystemExit) as e:
            study_cli.main(["simulate", "--url", url, "--stimuli", str(dot_study), *extra])
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and msg in err and err.count("\n") == 1, err


def test_run_crowd_gives_each_participant_their_own_guesser():
    made = []

    class Crowd:
        def participant(self, i):
            made.append(i)
            return lambda state, still: state["goals"][0]

    async def run():
        try:
            await client.run_crowd("http://127.0.0.1:9", 3, Crowd(), timeout=0.01, media=False)
        except TimeoutError:
            pass

    asyncio.run(run())
    assert made == [0, 1, 2]


# ------------------------------------------------------------------ the README


def test_readme_population_file_is_the_default():
    """The population guide's file of the default population is the default."""
    block = marked_block("docs/guides/population.md", "population-file", "json")
    assert P.Population.from_dict(json.loads(block), "population.md") == P.default()


def test_readme_python_example_runs(tmp_path, monkeypatch):
    """The population guide's Python block: a saved population, P_pop and its sampler agree."""
    block = marked_block("docs/guides/population.md", "population-python", "python")
    monkeypatch.chdir(tmp_path)
    env: dict = {}
    exec(compile(block, "docs/guides/population.md", "exec"), env)
    assert P.load_population(tmp_path / "my_people.json").lapse == 0.1
    freq = np.bincount(np.asarray(env["guesses"]), minlength=8) / 100_000
    np.testing.assert_allclose(freq, env["p"], atol=0.006)  # 4.6 standard errors
