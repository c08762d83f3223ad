"""Caution where answers are thin (slotv_jax.planning.caution) and the people loop's cautious
pick: the lower confidence bound against a float64 NumPy re-derivation from the reference
labelers (tests/ref_labelers.py), its limits, the planner's use of it, bad input, and the
loop's ensemble of fold fits."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import ref_labelers

from slotv_jax import planning
from slotv_jax.experiments import people_loop as exp
from slotv_jax.experiments.people_loop import loop
from slotv_jax.observers.common import seen_points
from slotv_jax.planning import caution

BETAS = (3.0, 6.0, 12.0)


def scene():
    g = np.zeros((8, 3), np.float32)
    g[:3] = [[0.5, 0.25, 0.0], [0.55, -0.2, 0.0], [0.35, 0.05, 0.0]]
    mask = np.arange(8) < 3
    t = np.linspace(0, 1, 30)[:, None]
    start = np.array([0.3, 0.0, 0.45], np.float32)
    bend = np.array([0.0, 0.12, 0.0], np.float32)
    xyz = (start + (g[0] - start) * t + bend * np.sin(np.pi * t)).astype(np.float32)
    return xyz, g, mask


def stacked(betas, name="effdist"):
    return jax.vmap(lambda b: planning.labeler_observer(name, beta=b))(jnp.asarray(betas))


@pytest.mark.parametrize("kappa", [0.0, 1.0, 2.5])
@pytest.mark.parametrize("target", [0, 2])
def test_the_bound_is_the_members_mean_less_kappa_sample_deviations(kappa, target):
    """B_τ = mean_m ℓ_m − κ sd_m ℓ_m (ddof 1), ℓ_m = log y_m(target) of the reference EffDist
    labeler (float64, NumPy) on the first L_τ points, averaged over τ: the planner's
    legibility of the lower bound."""
    xyz, g, mask = scene()
    taus = (0.3, 0.6, 1.0)
    cfg = planning.PlannerConfig(n_points=xyz.shape[0], taus=taus)
    obs = caution.lower_bound_observer(stacked(BETAS), kappa)
    got = float(planning.legibility(obs, xyz, g, mask, target, cfg))
    ell = np.array(
        [
            [
                np.log(ref_labelers.effdist(xyz[:n].astype(np.float64), g, mask, beta=b)[target])
                for n in seen_points(taus, xyz.shape[0])
            ]
            for b in BETAS
        ]
    )
    want = np.mean(ell.mean(0) - kappa * ell.std(0, ddof=1))
    assert got == pytest.approx(want, abs=2e-5)
    if kappa:  # the bound lies below the members' mean by κ deviations, no less
        mean = caution.lower_bound_observer(stacked(BETAS), 0.0)
        assert got < float(planning.legibility(mean, xyz, g, mask, target, cfg)) - 1e-3


def test_the_whole_motion_bound_and_the_observer_it_is_when_called():
    """Without stop times the bound is over the whole motion; called as an observer the
    ensemble is the members' log-linear pool with equal weights (−∞ on padding)."""
    xyz, g, mask = scene()
    obs = caution.lower_bound_observer(stacked(BETAS), 1.0)
    ys = np.array([ref_labelers.effdist(xyz.astype(np.float64), g, mask, beta=b) for b in BETAS])
    ell = np.log(ys[:, 1])
    cfg = planning.PlannerConfig(n_points=xyz.shape[0])
    got = float(planning.legibility(obs, xyz, g, mask, 1, cfg))
    assert got == pytest.approx(ell.mean() - ell.std(ddof=1), abs=2e-5)
    logits = np.asarray(obs(xyz, g, mask))
    assert np.all(np.isneginf(logits[3:]))
    pooled = np.log(ys[:, :3]).mean(0)
    np.testing.assert_allclose(logits[:3], pooled, atol=2e-5)
    np.testing.assert_allclose(
        np.asarray(obs.prefix(xyz, g, mask, jnp.int32(xyz.shape[0]))), logits, atol=1e-6
    )


def test_members_that_agree_give_their_own_objective_and_finite_gradients():
    """Identical members: the bound is the member's log P less κ·10⁻⁶ (the variance's
    epsilon), and its gradient through the path is the member's, finite."""
    xyz, g, mask = scene()
    cfg = planning.PlannerConfig(n_points=xyz.shape[0], taus=(0.5, 1.0))
    one = planning.labeler_observer("dragan", beta=jnp.float32(5.0))
    same = caution.lower_bound_observer(stacked([5.0, 5.0, 5.0], "dragan"), 2.0)
    a = planning.legibility(one, xyz, g, mask, 0, cfg)
    b = planning.legibility(same, xyz, g, mask, 0, cfg)
    assert float(b) == pytest.approx(float(a) - 2.0 * np.sqrt(caution.VAR_EPS), abs=1e-6)
    ga = jax.grad(lambda x: planning.legibility(one, x, g, mask, 0, cfg))(jnp.asarray(xyz))
    gb = jax.grad(lambda x: planning.legibility(same, x, g, mask, 0, cfg))(jnp.asarray(xyz))
    assert np.all(np.isfinite(np.asarray(gb)))
    np.testing.assert_allclose(np.asarray(gb), np.asarray(ga), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize(
    ("members", "kappa", "words"),
    [
        (lambda: stacked(BETAS), -1.0, "caution: expected a finite number >= 0"),
        (lambda: stacked(BETAS), float("nan"), "caution: expected a finite number >= 0"),
        (lambda: stacked(BETAS), True, "caution: expected a number"),
        (lambda: stacked(BETAS), "1", "caution: expected a number"),
        (lambda: planning.labeler_observer("effdist"), 1.0, "members: expected every parameter"),
        (lambda: stacked([4.0]), 1.0, "members: expected at least 2 stacked members"),
        (lambda: lambda x, g, m: x, 1.0, "members: expected stacked observers with a .prefix"),
    ],
)
def test_bad_input_is_refused_naming_the_argument(members, kappa, words):
    with pytest.raises(ValueError, match=words):
        caution.lower_bound_observer(members(), kappa)


def test_the_planner_climbs_the_bound():
    """A planner of the lower bound returns a feasible plan whose bound is at least the
    straight line's, and the objective it reports is the bound of that plan."""
    _, g, mask = scene()
    cfg = planning.PlannerConfig(n_points=20, iters=8, taus=(0.5, 1.0))
    obs = caution.lower_bound_observer(stacked(BETAS), 1.0)
    planner = planning.make_planner(obs, cfg)
    res = planner(g[None], mask[None], np.array([0]))
    d = res.diagnostics
    assert bool(res.feasible[0])
    best = float(jnp.take_along_axis(d.objective, d.best_iter[:, None], 1)[0, 0])
    assert best >= float(d.objective_straight[0])
    again = float(planning.legibility(obs, res.xyz[0], g, mask, 0, cfg))
    assert again == pytest.approx(best, abs=1e-4)


def test_the_loops_ensemble_is_each_folds_fit_then_the_full_fit():
    """``loop.ensemble``: run r's member k < K is the fit without fold k (row r·K + k of the
    folds' fits), member K the fit on every answer."""
    cfg = exp.tiny()
    k, r = cfg.pick_folds, 3
    rng = np.random.default_rng(0)
    draw = lambda *shape: rng.normal(size=shape).astype(np.float32)  # noqa: E731 (fits' dtype)
    full = {"mlp": {"w": draw(r, 4, 2)}, "beta": draw(r, 2)}
    fits = {"mlp": {"w": draw(r * k, 4, 2)}, "beta": draw(r * k, 2)}
    ens = loop.ensemble(cfg, full, fits)
    assert ens["mlp"]["w"].shape == (r, k + 1, 4, 2) and ens["beta"].shape == (r, k + 1, 2)
    for i in range(r):
        for f in range(k):
            np.testing.assert_array_equal(ens["mlp"]["w"][i, f], fits["mlp"]["w"][i * k + f])
            np.testing.assert_array_equal(ens["beta"][i, f], fits["beta"][i * k + f])
        np.testing.assert_array_equal(ens["mlp"]["w"][i, k], full["mlp"]["w"][i])
        np.testing.assert_array_equal(ens["beta"][i, k], full["beta"][i])


def test_the_loop_config_refuses_a_cautious_pick_without_the_pick_or_a_bad_kappa():
    import dataclasses

    cfg = exp.tiny()
    with pytest.raises(ValueError, match=r"pick_cautious.*needs 'pick'"):
        dataclasses.replace(cfg, families=("mlp", "dragan_fitted", "pick_cautious"))
    for bad in (-0.5, float("inf"), True):
        with pytest.raises(ValueError, match=r"caution: expected a (finite )?number"):
            dataclasses.replace(cfg, caution=bad)
    assert "caution" not in dataclasses.replace(cfg, families=("mlp", "dragan_fitted")).to_json()


@pytest.mark.parametrize("kappa", [0.0, 2.0])
def test_a_family_planner_of_several_families_plans_the_bound(kappa):
    """Beside other families in one program (the people loop's planner: a ``lax.switch`` over
    the families' observers), the cautious family still plans its bound: its plan and
    objective are those of :func:`make_planner` on the bound alone, and κ changes them."""
    _, g, mask = scene()
    cfg = planning.PlannerConfig(n_points=20, iters=8, taus=(0.5, 1.0))
    builds = {
        "effdist": lambda p: planning.labeler_observer("effdist", beta=p["beta"][0]),
        "cautious": lambda p: caution.lower_bound_observer(stacked(p["beta"]), kappa),
    }
    params = {"beta": jnp.asarray(BETAS)}
    family = planning.make_family_planner(builds, params, cfg)
    got = family(jax.tree.map(lambda a: a[None], params), g[None], mask[None], np.array([0]),
                 family="cautious")  # fmt: skip
    alone = planning.make_planner(caution.lower_bound_observer(stacked(BETAS), kappa), cfg)
    want = alone(g[None], mask[None], np.array([0]))
    np.testing.assert_allclose(got.xyz[0, 0], want.xyz[0], atol=1e-5)
    d, w = got.diagnostics, want.diagnostics
    np.testing.assert_allclose(d.objective[0, 0], w.objective[0], rtol=1e-5, atol=1e-6)
    other = planning.make_planner(caution.lower_bound_observer(stacked(BETAS), kappa + 1.0), cfg)
    assert not np.allclose(other(g[None], mask[None], np.array([0])).xyz[0], got.xyz[0, 0])
