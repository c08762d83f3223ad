"""Every observer family scores a motion seen up to a stop time (slotv_jax.observers.prefix,
common.seen_points, the ``prefix`` of labelers, archetypes, networks and load_observer).

References: the study format's own count of seen points (Study.seen); the labelers applied to
the sliced motion ``xyz[:L]`` (answers.crossval.labeler_probs, and the independent float64
NumPy labelers of tests/ref_labelers.py); the archetypes called on ``xyz[:L]``; for the
networks, answers.fitting.prefix_scores (what training on answers optimises).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import ref_labelers
from flax import nnx

import slotv_jax  # applies the XLA CPU setting before JAX starts
from slotv_jax import planning
from slotv_jax.answers import crossval, fitting
from slotv_jax.answers.format import make_study
from slotv_jax.asking import selection
from slotv_jax.observers import archetypes, common, labelers
from slotv_jax.planning import labeler_observer
from slotv_jax.training import checkpoint
from slotv_jax.training import config as train_config
from slotv_jax.training import trainer as train
from slotv_jax.world import scene

PROB_TOL = 2e-6  # float32 probabilities of one formula computed two ways (absolute)
LOGIT_TOL = 2e-5  # float32 log-probabilities / logits of one formula computed two ways
GRAD_TOL = 1e-4  # float32 gradients of one formula computed two ways (relative to max |g|)
T = 40
HOME = np.array([0.3069, 0.0, 0.4869])
SEENS = (2, 3, 4, 11, 27, T)
BETAS = {"dragan": 20.0, "nikolaidis": 30.0, "effdist": 10.0, "fastapp": 2.0}


def random_set(seed: int, n: int, t: int = T):
    """Cubes on the table, a via-point path from the home TCP to a random real goal
    (piecewise linear, resampled to t points by arc length), with a little noise."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((n, 8, 3))
    mask = np.zeros((n, 8), bool)
    xyz = np.zeros((n, t, 3))
    for i in range(n):
        c = int(rng.choice((2, 3, 5)))
        pts: list[np.ndarray] = []
        while len(pts) < c:
            p = np.array([rng.uniform(0.3, 0.7), rng.uniform(-0.45, 0.45), 0.025])
            if all(np.linalg.norm(p - q) >= 0.1 for q in pts):
                pts.append(p)
        goals[i, :c], mask[i, :c] = pts, True
        via = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4], 3)
        path = np.vstack([HOME, via, goals[i, rng.integers(0, c)]])
        arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        u = np.linspace(0, arc[-1], t)
        xyz[i] = np.stack([np.interp(u, arc, path[:, j]) for j in range(3)], 1)
    xyz += 0.003 * rng.standard_normal(xyz.shape)
    return xyz.astype(np.float32), goals.astype(np.float32), mask


@pytest.fixture(scope="module")
def paths():
    return random_set(0, 6)


# ------------------------------------------------------------------- seen points


def test_seen_points_agree_with_the_study_format():
    rng = np.random.default_rng(1)
    for t in (2, 3, 11, 40, 100):
        grid = np.arange(1, t) / (t - 1)  # every t_i itself (rounding at the boundary)
        taus = np.concatenate([grid, rng.uniform(1 / (t - 1), 1.0, 50), [1.0, 0.3, 0.7, 0.4]])
        taus = taus[taus >= 1 / (t - 1)]
        xyz = np.linspace(HOME, [0.5, 0.2, 0.025], t)[None]
        goals = np.zeros((8, 3))
        goals[:2] = [[0.5, 0.2, 0.025], [0.5, -0.2, 0.025]]
        counts = np.zeros((taus.size, 8))
        counts[:, 0] = 1
        study = make_study(xyz, goals, np.arange(8) < 2, np.zeros(taus.size, int), counts,
                           answer_tau=taus)  # fmt: skip
        np.testing.assert_array_equal(common.seen_points(taus, t), study.seen())
    # by hand: 11 points at t_i = i/10; 3/10 rounds above 0.3 in float64 and still counts
    assert common.seen_points([0.05, 0.1, 0.3, 0.35, 1.0], 11).tolist() == [2, 2, 4, 4, 11]
    for bad in ([0.0], [1.2], [], [np.nan]):
        with pytest.raises(ValueError, match="taus"):
            common.seen_points(bad, 11)
    with pytest.raises(ValueError, match="n_points"):
        common.seen_points([0.5], 1)


def test_prefix_times_and_weights_by_hand():
    np.testing.assert_allclose(common.prefix_times(5, 3), [0, 0.5, 1, 1, 1])
    # trapezoid × (1 − t) at t = 0, 1/2, 1: (1/4)(1), (1/2)(1/2), (1/4)(0) -> 1/2, 1/2, 0
    w = common.prefix_time_weights(6, 3, 1.0, trapezoid_rule=True)
    np.testing.assert_allclose(w, [0.5, 0.5, 0, 0, 0, 0], atol=1e-7)
    # a traced exponent gives the same weights, in log form −∞ after the prefix
    lw = common.prefix_time_weights(6, 3, jnp.float32(1.0), trapezoid_rule=True, log=True)
    np.testing.assert_allclose(np.exp(lw), w, atol=1e-7)
    assert np.all(np.isneginf(np.asarray(lw)[3:]))
    assert float(lw[2]) < -80  # the last seen point: log ε, as at the whole motion's end
    # batched seen
    b = common.prefix_time_weights(4, jnp.array([2, 4]), 0.0)
    np.testing.assert_allclose(b, [[0.5, 0.5, 0, 0], [0.25] * 4], atol=1e-7)


# ------------------------------------------------------------------- the labelers


def _study(xyz, goals, mask, seens):
    """Every trajectory at every seen count, as a study with uniform times (τ = t_{L−1})."""
    n, t = xyz.shape[:2]
    rows = [(i, s) for i in range(n) for s in seens]
    counts = np.zeros((len(rows), 8))
    counts[:, 0] = 1
    return make_study(xyz, goals, mask, [r[0] for r in rows], counts,
                      answer_tau=[(s - 1) / (t - 1) for _, s in rows])  # fmt: skip


@pytest.mark.parametrize("name", labelers.LABELER_NAMES)
def test_labeler_prefix_is_the_sliced_labeler(paths, name):
    xyz, goals, mask = paths
    study = _study(xyz, goals, mask, SEENS)
    seen = study.seen()
    assert sorted(set(seen.tolist())) == sorted(SEENS)
    obs = labeler_observer(name, beta=BETAS[name])
    tr = study.answer_trajectory
    got = jax.jit(jax.vmap(obs.prefix))(xyz[tr], goals[tr], mask[tr], jnp.asarray(seen))
    want = crossval.labeler_probs(study, name, beta=BETAS[name])  # the sliced computation
    np.testing.assert_allclose(jax.nn.softmax(got), want, atol=PROB_TOL)
    assert np.all(np.isneginf(np.asarray(got)[~mask[tr]]))
    # and the independent float64 NumPy labelers on xyz[:L]
    cam = scene.camera("observer")
    for a in range(0, len(seen), 5):
        x, g = np.asarray(xyz[tr[a]], np.float64), np.asarray(goals[tr[a]], np.float64)
        m, L = mask[tr[a]], int(seen[a])
        kw = {"beta": BETAS[name]}
        if name == "nikolaidis":
            ref = ref_labelers.nikolaidis(x[:L], g, m, np.asarray(cam.pos), np.asarray(cam.rot),
                                          **kw)  # fmt: skip
        else:
            ref = getattr(ref_labelers, name)(x[:L], g, m, **kw)
        np.testing.assert_allclose(jax.nn.softmax(got[a]), ref, atol=PROB_TOL)


@pytest.mark.slow
@pytest.mark.parametrize("name", labelers.LABELER_NAMES)
def test_labeler_prefix_gradient_is_the_sliced_gradient(paths, name):
    xyz, goals, mask = paths
    obs = labeler_observer(name, beta=BETAS[name])
    fn = labelers.LABELERS[name]
    kw = {"camera": scene.camera("observer")} if name == "nikolaidis" else {}
    got, want = {}, {}

    # one program for every L: the seen count is traced, as in the planner's objective
    @jax.jit
    @jax.grad
    def prefix_lp(x, L):
        return jax.nn.log_softmax(obs.prefix(x, goals[0], mask[0], L))[1]

    def sliced_lp(x):
        return jnp.log(fn(x, goals[0], mask[0], beta=BETAS[name], **kw)[1])

    for L in (2, 3, 17, T):
        got[L] = np.asarray(prefix_lp(xyz[0], jnp.int32(L)))
        want[L] = np.asarray(jax.grad(sliced_lp)(xyz[0, :L]))
    # rounding relative to the gradients' size on this path (at L = 2 Dragan's is exactly 0
    # in exact arithmetic, two equal terms cancelling: float32 leaves ~1e-7 of them)
    scale = max(np.abs(r).max() for r in want.values())
    for L, g in got.items():
        assert np.all(np.isfinite(g))
        assert np.all(g[L:] == 0.0)  # the unseen points get no gradient
        np.testing.assert_allclose(g[:L], want[L], atol=GRAD_TOL * scale)


def test_labeler_prefix_with_traced_beta_and_a_bad_seen(paths):
    xyz, goals, mask = paths
    f = jax.jit(lambda b, L: labeler_observer("dragan", beta=b).prefix(xyz[0], goals[0],
                                                                       mask[0], L))  # fmt: skip
    want = labelers.dragan(xyz[0, :9], goals[0], mask[0], beta=7.0)
    np.testing.assert_allclose(jax.nn.softmax(f(jnp.float32(7.0), jnp.int32(9))), want,
                               atol=PROB_TOL)  # fmt: skip
    obs = labeler_observer("dragan")
    for bad in (1, T + 1):
        with pytest.raises(ValueError, match="seen: expected 2 <= seen"):
            obs.prefix(xyz[0], goals[0], mask[0], bad)
    with pytest.raises(ValueError, match="seen"):
        obs.prefix(xyz[0], goals[0], mask[0], 3.5)


# ------------------------------------------------------------------- the archetypes

ARCHETYPE_INIT = {
    "dragan": {"beta": 15.0, "alpha": 0.6, "start_weight": 0.7, "metric": (1.0, 2.0, 0.5)},
    "viewpoint": {"yaw": 0.3, "pitch": 0.5, "distance": 1.4, "beta": 9.0},
    "mixture": {"beta_effdist": 4.0, "beta_fastapp": 7.0, "alpha_effdist": 0.5,
                "alpha_fastapp": 1.7},
}  # fmt: skip


@pytest.mark.parametrize("name", archetypes.ARCHETYPES)
def test_archetype_prefix_is_the_sliced_archetype(paths, name):
    xyz, goals, mask = paths
    m = archetypes.make_archetype(name, **ARCHETYPE_INIT[name])
    f = jax.jit(jax.vmap(m.prefix, in_axes=(None, None, None, 0)))
    for i in range(len(xyz)):
        got = np.asarray(f(xyz[i], goals[i], mask[i], jnp.asarray(SEENS)))
        for j, L in enumerate(SEENS):
            want = np.asarray(m(xyz[i, :L], goals[i], mask[i]))
            np.testing.assert_allclose(got[j][mask[i]], want[mask[i]], atol=LOGIT_TOL)
            assert np.all(np.isneginf(got[j][~mask[i]]))
    # the batched form (seen per trajectory) and the whole motion
    seen = jnp.asarray([SEENS[i % len(SEENS)] for i in range(len(xyz))])
    batched = np.asarray(m.prefix(xyz, goals, mask, seen))
    for i in range(len(xyz)):
        want = np.asarray(m(xyz[i, : int(seen[i])], goals[i], mask[i]))
        np.testing.assert_allclose(batched[i][mask[i]], want[mask[i]], atol=LOGIT_TOL)
    whole = np.asarray(m.prefix(xyz, goals, mask, jnp.full(len(xyz), T)))
    np.testing.assert_allclose(whole[mask], np.asarray(m(xyz, goals, mask))[mask], atol=LOGIT_TOL)


@pytest.mark.parametrize("name", archetypes.ARCHETYPES)
def test_archetype_prefix_gradients(paths, name):
    xyz, goals, mask = paths
    m = archetypes.make_archetype(name, **ARCHETYPE_INIT[name])
    for L in (2, 5, T):
        g = np.asarray(jax.grad(lambda x, L=L: jax.nn.log_softmax(
            m.prefix(x, goals[1], mask[1], jnp.int32(L)))[0])(xyz[1]))  # fmt: skip
        ref = np.asarray(jax.grad(lambda x: jax.nn.log_softmax(m(x, goals[1], mask[1]))[0])(
            xyz[1, :L]))  # fmt: skip
        assert np.all(np.isfinite(g)) and np.all(g[L:] == 0.0)
        np.testing.assert_allclose(g[:L], ref, atol=GRAD_TOL * np.abs(ref).max())
    # the parameters' gradient is finite at a prefix (the −∞ weights of unseen points)
    gd, st = nnx.split(m)
    gp = jax.grad(lambda s: jax.nn.log_softmax(nnx.merge(gd, s).prefix(
        xyz[1], goals[1], mask[1], jnp.int32(3)))[0])(st)  # fmt: skip
    assert all(np.all(np.isfinite(np.asarray(v))) for v in jax.tree.leaves(gp))
    assert any(np.any(np.asarray(v) != 0) for v in jax.tree.leaves(gp))


# ------------------------------------------------------------------- load_observer

MODEL_CONFIGS = {
    "mlp_slotv": train_config.quick("slotv", hidden=(8, 4)),
    "mlp_trex": train_config.quick("trex", hidden=(8, 4)),
    "slotv_plus": train_config.quick("slotv", hidden=(8, 4), start_term=True, time_weight=True),
    "dragan": train_config.archetype("quick", "dragan"),
    "viewpoint": train_config.archetype("quick", "viewpoint"),
    "mixture": train_config.archetype("quick", "mixture"),
}


@pytest.mark.parametrize("which", MODEL_CONFIGS)
def test_loaded_observer_prefix(tmp_path, paths, which):
    xyz, goals, mask = paths
    cfg = MODEL_CONFIGS[which]
    trainer = train.make_train(cfg, progress=False)
    state = trainer.init(jax.random.key(3))
    checkpoint.save(tmp_path / which, cfg, state)
    obs = slotv_jax.load_observer(tmp_path / which)
    model = trainer.model(state.params)
    seen = jnp.asarray([SEENS[i % len(SEENS)] for i in range(len(xyz))])
    got = np.asarray(jax.jit(jax.vmap(obs.prefix))(xyz, goals, mask, seen))
    # what training on answers optimises, masked
    want = np.asarray(fitting.prefix_logits(model, xyz, goals, mask, seen))
    np.testing.assert_allclose(got[mask], want[mask], atol=LOGIT_TOL)
    assert np.all(np.isneginf(got[~mask]))
    if cfg.model != "mlp":  # an archetype: its formula on the sliced motion
        for i in range(len(xyz)):
            ref = np.asarray(obs(xyz[i, : int(seen[i])], goals[i], mask[i]))
            np.testing.assert_allclose(got[i][mask[i]], ref[mask[i]], atol=LOGIT_TOL)
    # the whole motion is the observer itself; the unseen points get no gradient
    whole = np.asarray(obs.prefix(xyz[0], goals[0], mask[0], T))
    np.testing.assert_allclose(whole[mask[0]], np.asarray(obs(xyz[0], goals[0], mask[0]))[mask[0]],
                               rtol=1e-5, atol=LOGIT_TOL)  # fmt: skip
    g = jax.grad(lambda x: jax.nn.log_softmax(obs.prefix(x, goals[0], mask[0], 5))[0])(xyz[0])
    assert np.all(np.isfinite(np.asarray(g))) and np.all(np.asarray(g)[5:] == 0.0)
    with pytest.raises(ValueError, match="seen"):
        obs.prefix(xyz[0], goals[0], mask[0], 1)


# ------------------------------------------------------------------- active selection


def test_selection_scores_archetype_prefixes(paths):
    xyz, goals, mask = paths
    pool = selection.make_pool(xyz, goals, mask, taus=(0.1, 0.5, 1.0))
    sel = selection.make_selector(train_config.archetype("quick", "dragan"), 2, 8)
    sel.check_pool(pool)
    ens = sel.init(jax.random.key(0))
    cand = jnp.arange(pool.traj.shape[0])
    logp = np.asarray(jax.jit(sel.log_probs)(ens.params, pool, cand))
    for e in range(2):
        model = sel.base.model(jax.tree.map(lambda a, e=e: a[e], ens.params))
        for c in range(pool.traj.shape[0]):
            n, L = int(pool.traj[c]), int(pool.seen[c])
            ref = np.asarray(jax.nn.log_softmax(model(xyz[n, :L], goals[n], mask[n])))
            np.testing.assert_allclose(logp[e, c][mask[n]], ref[mask[n]], atol=LOGIT_TOL)


# ------------------------------------------------------------------- traced parameters


def test_observers_built_from_traced_parameters(paths):
    """One compiled function scores (and so plans with) many fitted observers of one family:
    checkpoint.make_observer and labeler_observer accept traced parameters, and give what
    each concrete observer gives."""
    xyz, goals, mask = paths
    cfg = train_config.archetype("quick", "dragan")
    gd = nnx.split(archetypes.make_archetype("dragan"))[0]
    fits = [nnx.split(archetypes.make_archetype("dragan", beta=b, alpha=a))[1]
            for b, a in ((5.0, 1.0), (20.0, 0.4), (12.0, 2.0))]  # fmt: skip
    stacked = jax.tree.map(lambda *v: jnp.stack(v), *fits)
    pcfg = planning.PlannerConfig(n_points=T, taus=(0.3, 0.6, 1.0))

    def score(params):
        obs = checkpoint.make_observer(cfg, params)
        return planning.legibility(obs, xyz[0], goals[0], mask[0], 1, pcfg)

    traces = []
    f = jax.jit(jax.vmap(lambda p: (traces.append(1), score(p))[1]))
    got = np.asarray(f(stacked))
    f(jax.tree.map(lambda v: v * 1.01, stacked))
    assert len(traces) == 1  # new values, no new compilation
    for i, p in enumerate(fits):
        m = nnx.merge(gd, p)
        want = np.mean([jax.nn.log_softmax(m(xyz[0, :L], goals[0], mask[0]))[1]
                        for L in common.seen_points(pcfg.taus, T)])  # fmt: skip
        assert got[i] == pytest.approx(want, abs=LOGIT_TOL)
    betas = jnp.array([5.0, 20.0])
    lab = jax.jit(
        jax.vmap(
            lambda b: planning.legibility(
                labeler_observer("dragan", beta=b), xyz[0], goals[0], mask[0], 1, pcfg
            )
        )
    )(betas)
    for b, v in zip((5.0, 20.0), np.asarray(lab), strict=True):
        want = np.mean([np.log(labelers.dragan(xyz[0, :L], goals[0], mask[0], beta=b)[1])
                        for L in common.seen_points(pcfg.taus, T)])  # fmt: skip
        assert v == pytest.approx(want, abs=LOGIT_TOL)
