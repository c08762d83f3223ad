"""Populations nobody wrote and the researcher's pick (issue 44): the hyper-distribution's
draws (reproducible, valid, spread over every field), the log-linear pool fitted on held-out
answers against a float64 NumPy re-derivation, and the pick of a simulated study following
the answers while never reading the population."""

from __future__ import annotations

import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slotv_jax import planning
from slotv_jax.answers import (
    PROB_FLOOR,
    load_pool,
    pool_observer,
    pooling,
    save_study,
    simulate_study,
)
from slotv_jax.answers.pick import trusted
from slotv_jax.asking import selection, simulated
from slotv_jax.experiments import people_loop as exp
from slotv_jax.experiments.people_loop import loop
from slotv_jax.experiments.people_loop.__main__ import main
from slotv_jax.observers import labelers
from slotv_jax.observers import population as population_lib
from slotv_jax.observers.common import seen_points
from slotv_jax.planning import evaluation
from slotv_jax.study.cli import main as study_main
from slotv_jax.training.checkpoint import load_observer
from slotv_jax.world.scene import camera as scene_camera

# ------------------------------------------------------------------ the hyper-distribution


def test_random_draws_are_reproducible_valid_and_spread():
    a = [population_lib.random_population(k) for k in range(40)]
    b = [population_lib.get_population(f"random:{k}") for k in range(40)]
    assert a == b  # the K-th draw depends on K alone
    for k, pop in enumerate(a):
        assert pop.name == f"random:{k}"
        d = json.loads(json.dumps(pop.to_dict()))  # the results document's form reads back
        assert population_lib.Population.from_dict(d) == pop
        lo, hi = population_lib.HYPER_BETA["cost_to_go"]
        assert lo <= dict(pop.beta)["cost_to_go"] <= hi
        assert 0 <= pop.lapse <= 0.10 and 0 <= pop.beta_sigma_log <= 1
    views = {v for p in a for v, _ in p.viewpoints}
    assert views == set(population_lib.HYPER_VIEWPOINTS)  # world included
    assert {p.memory for p in a} == {"recency", "dragan"}
    assert len({p.lapse for p in a}) == 40 and len({len(p.viewpoints) for p in a}) >= 3


def test_suite_names_default_homogeneous_and_its_draws():
    specs = population_lib.suite_specs()
    assert specs[:2] == ("default", "homogeneous") and len(specs) >= 10
    assert all(s.startswith("random:") for s in specs[2:])
    for s in specs:
        population_lib.get_population(s)


@pytest.mark.parametrize("spec", ["random:", "random:-1", "random:x", "random:1e3", "random: 1"])
def test_bad_random_specs_are_one_line_errors(tmp_path, capsys, spec):
    with pytest.raises(SystemExit) as e:
        main(["--preset", "tiny", "--out", str(tmp_path / "o"), "--population", spec])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "random:K" in err and repr(spec) in err, err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ the pool


def _pool_nll64(w, logp, counts, mask):
    """The pool's NLL per answer in float64 NumPy (the module doc's formula)."""
    lp = np.where(mask, np.maximum(logp, np.log(1e-12)), 0.0)
    z = np.where(mask, np.tensordot(w, lp, axes=1), -np.inf)
    z = z - z.max(-1, keepdims=True)
    logq = z - np.log(np.exp(z).sum(-1, keepdims=True))
    return -np.sum(counts * np.where(mask, logq, 0.0)) / counts.sum()  # no 0 × (−inf)


def test_pool_weights_are_the_maximum_likelihood_against_numpy():
    rng = np.random.default_rng(0)
    a, g = 300, 4
    mask = np.ones((a, g), bool)
    mask[::3, 3] = False
    truth = np.where(mask, rng.gamma(1.0, size=(a, g)), 0.0)
    truth /= truth.sum(-1, keepdims=True)
    counts = np.stack([rng.multinomial(5, p) for p in truth]).astype(np.float64)
    with np.errstate(divide="ignore"):
        sharp = np.log(truth) * 2.5  # an overconfident fit of the truth
        noise = np.where(mask, np.log(rng.dirichlet(np.ones(g), a)), -np.inf)
    sharp = np.where(mask, sharp - np.log(np.exp(sharp).sum(-1, keepdims=True)), -np.inf)
    logp = np.stack([sharp, noise])
    w = pooling.fit_pool_weights(logp, counts, mask)
    best = _pool_nll64(w, logp, counts, mask)
    # a maximum: no step along either axis, nor the single candidates, does better
    for dw in ([0.02, 0], [-0.02, 0], [0, 0.02], [0, -0.02], [-w[0] + 1, -w[1]]):
        other = np.maximum(w + np.asarray(dw), 0)
        assert best <= _pool_nll64(other, logp, counts, mask) + 1e-6
    assert abs(w[0] - 1 / 2.5) < 0.08  # calibration undoes the sharpening
    assert pooling.heldout_nll(logp, counts, mask, w) == pytest.approx(best, rel=1e-5)
    # keep: the noise alone, its weight the 1-D maximum of a float64 grid; the other stays 0
    w1 = pooling.fit_pool_weights(logp, counts, mask, keep=np.array([False, True]))
    grid = np.linspace(0, 2, 2001)
    nll = [_pool_nll64(np.array([0.0, v]), logp, counts, mask) for v in grid]
    assert w1[0] == 0 and abs(w1[1] - grid[int(np.argmin(nll))]) < 2e-3
    with pytest.raises(ValueError, match="keep"):
        pooling.fit_pool_weights(logp, counts, mask, keep=np.array([False, False]))


def test_folds_keep_each_motion_whole():
    groups = np.random.default_rng(1).integers(0, 30, 500)
    fold = pooling.fold_of(groups, 3, seed=5)
    for gr in np.unique(groups):
        assert np.unique(fold[groups == gr]).size == 1
    assert set(np.unique(fold)) == {0, 1, 2}
    with pytest.raises(ValueError, match="folds"):
        pooling.fold_of(groups[:2], 3, seed=0)


# ------------------------------------------------------------------ the pick


@pytest.fixture(scope="module")
def label_pool():
    """A pool of 120 straight-ish motions to 3 goals, stop times 0.5 and 1."""
    rng = np.random.default_rng(3)
    goals = np.zeros((8, 3), np.float32)
    goals[:3] = [[0.5, 0.3, 0.025], [0.5, -0.3, 0.025], [0.65, 0.0, 0.025]]
    mask = np.arange(8) < 3
    start = np.array([0.307, 0.0, 0.487])
    xyz = []
    for i in range(120):
        via = start + rng.uniform([-0.05, -0.35, -0.3], [0.35, 0.35, -0.1])
        end = goals[i % 3]
        t = np.linspace(0, 1, 40)[:, None]
        xyz.append(
            np.where(t < 0.5, start + (via - start) * 2 * t, via + (end - via) * (2 * t - 1))
        )
    xyz = np.asarray(xyz, np.float32)
    taus = (0.5, 1.0)
    pool = selection.make_pool(
        xyz, np.broadcast_to(goals, (120, 8, 3)), np.broadcast_to(mask, (120, 8)), taus
    )
    return pool, taus


def _answers(pool, taus, name, beta, n_rows=160, per=6, seed=0):
    """Counts of ``per`` guesses per candidate drawn from the labeler ``name`` at ``beta``."""
    cand = np.random.default_rng(seed).choice(pool.traj.shape[0], n_rows, replace=False)
    logp = simulated.labeler_log_probs(pool, taus, cand, name, beta, exp.CAMERA)
    rng = np.random.default_rng(seed + 1)
    probs = np.exp(logp.astype(np.float64))
    probs /= probs.sum(-1, keepdims=True)  # float32 rounding
    counts = np.stack([rng.multinomial(per, p) for p in probs])
    return cand.astype(np.int32), counts.astype(np.float32)


@pytest.mark.parametrize("truth", ["dragan", "nikolaidis"])
def test_the_pick_follows_the_answers_and_never_reads_the_population(
    label_pool, monkeypatch, truth
):
    """Two studies of the same motions whose answers differ only in which family explains
    them (Dragan's or Nikolaidis' observer): the pick puts its largest weight on that family.
    Every function of the population module raises while the pick runs."""
    pool, taus = label_pool
    beta = {"dragan": 8.0, "nikolaidis": 12.0}[truth]
    cand, counts = _answers(pool, taus, truth, beta)
    cfg = dataclasses.replace(
        exp.tiny(),
        families=("dragan_fitted", "nikolaidis_fitted", "pick"),
        taus=taus,
        planner=planning.PlannerConfig(n_points=20, iters=3, taus=taus),
    )

    def forbidden(*a, **k):
        raise AssertionError("the pick read the population")

    for name in population_lib.__all__:
        if callable(getattr(population_lib, name)) and name[0].islower():
            monkeypatch.setattr(population_lib, name, forbidden)
    heldout = loop.pick_heldout(cfg, pool, cand[None], counts[None], cand.size,
                                [("random", 0)])  # fmt: skip
    w, reports = loop.pick_runs(cfg, heldout, counts[None], cand.size)
    rep = reports[0]
    assert rep["pick"] == f"{truth}_fitted", rep
    assert w.shape == (1, 2) and w[0, rep["candidates"].index(f"{truth}_fitted")] > 0.5
    assert rep["pool_nll"] <= min(rep["heldout_nll"]) + 1e-6
    # Left out (its plans judged least legible), the family the answers favour weighs 0 and
    # the other takes the pool: the held-out likelihood decides among the rest only.
    keep = np.array([[n != f"{truth}_fitted" for n in rep["candidates"]]])
    w2, reports2 = loop.pick_runs(cfg, heldout, counts[None], cand.size, keep)
    assert w2[0, ~keep[0]] == 0 and w2[0, keep[0]] > 0
    assert reports2[0]["pool_nll"] > rep["pool_nll"]


def test_the_pools_observer_is_the_weighted_log_pool():
    """The planner's pick observer (the loop's and `study pick --by pool`'s): softmax of
    Σ w_f log p_f, against NumPy."""
    goals = jnp.zeros((8, 3)).at[0].set([0.5, 0.3, 0.025]).at[1].set([0.5, -0.3, 0.025])
    mask = jnp.arange(8) < 2
    xyz = jnp.linspace(jnp.array([0.3, 0.0, 0.49]), goals[0], 30)
    obs = [planning.labeler_observer("dragan"), planning.labeler_observer("effdist")]
    w = jnp.array([0.7, 0.4])
    pooled = pool_observer(obs, w)
    got = np.asarray(jax.nn.softmax(pooled.prefix(xyz, goals, mask, 20)))
    p = [np.asarray(labelers.dragan(xyz[:20], goals, mask), np.float64)[:2],
         np.asarray(labelers.effdist(xyz[:20], goals, mask), np.float64)[:2]]  # fmt: skip
    z = 0.7 * np.log(p[0]) + 0.4 * np.log(p[1])
    want = np.exp(z - z.max()) / np.exp(z - z.max()).sum()
    np.testing.assert_allclose(got[:2], want, atol=1e-5)
    assert np.all(got[2:] == 0)


# ------------------------------------------------------------------ python -m slotv_jax.study pick


def _dragan_study(label_pool, seed: int, path):
    """A study of the pool's first 60 motions answered by Dragan's observer at β = 8 (6
    guesses each, the pool's stop times), saved to ``path``: (study, its arrays, taus)."""
    pool, taus = label_pool
    arrays = tuple(np.asarray(a)[:60] for a in (pool.xyz, pool.goals, pool.goal_mask))
    study = simulate_study(jax.random.key(seed), *arrays, 6, labeler="dragan", beta=8.0,
                           taus=taus)  # fmt: skip
    save_study(path, study)
    return study, arrays, taus


def test_study_pick_scores_every_candidate_and_writes_the_pick(label_pool, tmp_path, capsys):
    """A study answered by Dragan's observer: the command prints each candidate's held-out
    NLL and weight, picks Dragan's labeler and writes its β; a bad flag is one line."""
    path = tmp_path / "s.npz"
    _dragan_study(label_pool, 0, path)
    out = tmp_path / "pick"
    argv = ["pick", str(path), "--out", str(out), "--candidates", "dragan,nikolaidis,effdist"]
    with pytest.raises(SystemExit) as e:
        study_main(argv)
    assert e.value.code == 2 and "--candidates" in capsys.readouterr().err
    assert not out.exists()
    argv[-1] = "dragan,nikolaidis"
    assert study_main([*argv, "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "| dragan **(pick)** |" in text and "| nikolaidis |" in text, text
    rec = json.loads((out / "pick.json").read_text())
    assert rec["labeler"] == "dragan" and 4.0 < rec["beta"] < 16.0
    assert rec["pick"]["heldout_nll"][0] < rec["pick"]["heldout_nll"][1]
    # a learned candidate on a study of 3 goals (its logits have fewer slots than G_MAX)
    out2 = tmp_path / "pick2"
    argv2 = ["pick", str(path), "--out", str(out2), "--candidates", "dragan_archetype,dragan"]
    assert study_main([*argv2, "--folds", "2", "--no-progress"]) == 0
    assert "| dragan_archetype" in capsys.readouterr().out


def test_study_pick_by_plans_judges_every_plan_and_writes_them(
    label_pool, tmp_path, capsys, monkeypatch
):
    """``study pick --by plans``: every candidate (fitted on every answer) plans the study's
    own scenes; the printed and recorded judgments are each fit's mean P(target | ξ up to
    τ) of the written plans, re-derived here with the labelers themselves (float64 NumPy
    mean, the study's τ); the pick is the best mean judgment of the other fits; a rerun by
    likelihood with --overwrite leaves none of the earlier output behind."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.answers.crossval import fit_beta
    from slotv_jax.planning.plans import load_plans

    monkeypatch.setitem(pick_lib.PLANNERS, "quick", {"n_points": 20, "iters": 3})
    path = tmp_path / "s.npz"
    study, (xyz, goals, mask), taus = _dragan_study(label_pool, 1, path)
    out = tmp_path / "pick"
    argv = ["pick", str(path), "--out", str(out), "--candidates", "dragan,nikolaidis",
            "--by", "plans", "--no-progress"]  # fmt: skip
    with pytest.raises(SystemExit) as e:
        study_main([*argv, "--problems", "0"])
    assert e.value.code == 2 and "--problems" in capsys.readouterr().err
    by_plans = pick_lib.pick_by_plans
    made: list = []  # this run's fits and plans, reused by --by pool below (deterministic)
    monkeypatch.setattr(pick_lib, "pick_by_plans", lambda *a, **k: made.append(by_plans(*a, **k))
                        or made[-1])  # fmt: skip
    assert study_main(argv) == 0
    text = capsys.readouterr().out
    rec = json.loads((out / "pick.json").read_text())
    rep = rec["pick"]
    assert rep["rule"] == "plans" and rep["taus"] == list(taus) and rep["problems"] == 3
    plans = load_plans(out / "plans.npz")
    assert plans["names"].tolist() == ["straight", "dragan", "nikolaidis"]
    betas = {n: fit_beta(study, n)[0] for n in ("dragan", "nikolaidis")}
    seen = seen_points(taus, 20)
    want = np.zeros((2, 2))
    cam = {"camera": scene_camera("observer")}
    for i in range(2):
        for j, g in enumerate(("dragan", "nikolaidis")):
            fn = functools.partial(getattr(labelers, g), **(cam if g == "nikolaidis" else {}))
            ys = [float(fn(plans["xyz"][1 + i, p, :s], plans["goals"][p], plans["goal_mask"][p],
                           beta=betas[g])[plans["target"][p]])
                  for p in range(3) for s in seen]  # fmt: skip
            want[i, j] = np.mean(np.asarray(ys, np.float64))
    np.testing.assert_allclose(rep["judged"], want, atol=2e-5)
    assert rep["scores"] == pytest.approx([want[0, 1], want[1, 0]], abs=2e-5)
    assert rep["pick"] == ("dragan", "nikolaidis")[int(want[1, 0] > want[0, 1])]
    assert rec["labeler"] == rep["pick"] and rec["beta"] == pytest.approx(betas[rep["pick"]])
    assert f"| {rep['pick']} **(pick)** |" in text, text
    # the plans reach each target from the home TCP
    ends = plans["xyz"][:, np.arange(3), -1]
    tgt = plans["goals"][np.arange(3), plans["target"]]
    assert np.all(np.linalg.norm(ends - tgt, axis=-1) < 2e-3)
    # --by pool: the loop's pick, the candidate of the least-judged plans left out of the
    # pool (weight 0), the pool of the rest; its largest weight is written, with the plans
    argv[-3:-1] = ["--by", "pool"]
    monkeypatch.setattr(pick_lib, "pick_by_plans", lambda *a, **k: made[0])
    assert study_main([*argv, "--folds", "2", "--overwrite"]) == 0
    monkeypatch.setattr(pick_lib, "pick_by_plans", by_plans)
    text = capsys.readouterr().out
    doc = json.loads((out / "pool.json").read_text())
    pool = doc["meta"]["pick"]
    worse = ("dragan", "nikolaidis")[int(np.argmin(rep["scores"]))]
    # the rule re-derived: the least-judged left out, and any no better than guessing, but
    # never the best held-out fit
    cands = pool["candidates"]
    h = dict(zip(cands, pool["heldout_nll"], strict=True))
    best = min(h, key=h.get)
    expect = [c for c in cands if c != best and (c == worse or h[c] >= pool["uniform_nll"])]
    assert pool["rule"] == "pool" and pool["left_out"] == expect
    n = study.goal_mask[study.answer_trajectory].sum(-1)
    c = np.asarray(study.counts, np.float64).sum(-1)
    assert pool["uniform_nll"] == pytest.approx(np.sum(c * np.log(n)) / c.sum(), abs=1e-6)
    assert all(pool["weights"][cands.index(c)] == 0 for c in expect)
    assert ("(left out:" in text) == bool(expect) and "uniform guessing" in text
    assert sorted(p.name for p in out.iterdir()) == ["plans.npz", "pool.json"]
    # the pool itself is written: the members of weight > 0, each labeler with its β fitted
    # on every answer; loaded, its P is Π_f P_f^{w_f} renormalised (float64, by hand)
    w = dict(zip(cands, pool["weights"], strict=True))
    members = [c for c in cands if w[c] > 0]
    assert pool["pick"] == max(w, key=w.get) and pool["pick"] not in expect
    assert doc["members"] == [{"name": c, "weight": w[c], "labeler": c,
                               "beta": pytest.approx(betas[c])} for c in members]  # fmt: skip
    obs = load_pool(out)
    for p in range(3):
        x, g, m = plans["xyz"][0, p], plans["goals"][p], plans["goal_mask"][p]
        logit = np.zeros(8)
        for c in members:
            fn = functools.partial(getattr(labelers, c), **(cam if c == "nikolaidis" else {}))
            y = np.asarray(fn(x, g, m, beta=betas[c]), np.float64)
            logit += w[c] * np.log(np.maximum(y, PROB_FLOOR))
        want_p = np.where(m, np.exp(logit - logit[m].max()), 0.0)
        got = np.asarray(jax.nn.softmax(obs(jnp.asarray(x), jnp.asarray(g), jnp.asarray(m))))
        np.testing.assert_allclose(got, want_p / want_p.sum(), atol=2e-5)
    # the plans file holds the pool's own plans too: those the loaded pool plans (its
    # planner at the study's τ), next to the candidates' plans of the run above
    pooled = load_plans(out / "plans.npz")
    assert pooled["names"].tolist() == ["straight", "dragan", "nikolaidis", "pool"]
    np.testing.assert_array_equal(pooled["q"][:3], plans["q"])
    cfg = planning.PlannerConfig(n_points=20, iters=3, taus=taus)
    again = planning.make_planner(obs, cfg)(plans["goals"], plans["goal_mask"], plans["target"])
    np.testing.assert_allclose(pooled["q"][3], np.asarray(again.q), rtol=0, atol=1e-5)
    assert "and the pool's: " in text
    with pytest.raises(ValueError, match=r"a pool of observers.*load_pool"):
        load_observer(out)
    argv[-3:-1] = ["--by", "likelihood"]
    assert study_main([*argv, "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["pick.json"]
    assert json.loads((out / "pick.json").read_text())["pick"].get("rule") is None
    # a study whose scenes the Panda cannot reach: refused before any fit, nothing written
    shift = np.array([2.0, 0.0, 0.0], np.float32)
    far_goals = np.where(mask[..., None], np.add(goals, shift), 0.0).astype(np.float32)
    far = simulate_study(jax.random.key(1), np.add(xyz, shift), far_goals, mask, 6,
                         labeler="dragan", beta=8.0, taus=taus)  # fmt: skip
    save_study(tmp_path / "far.npz", far)
    monkeypatch.setattr(pick_lib, "fit_candidates", lambda *a, **k: pytest.fail("fitted"))
    with pytest.raises(SystemExit) as e:
        study_main(["pick", str(tmp_path / "far.npz"), "--out", str(tmp_path / "far"),
                    "--candidates", "dragan,slotv_plus", "--by", "plans",
                    "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--by plans: the study's scenes" in err and "out of reach" in err
    assert not (tmp_path / "far").exists()
    with pytest.raises(SystemExit) as e:  # --by pool names itself
        study_main(["pick", str(tmp_path / "far.npz"), "--out", str(tmp_path / "far"),
                    "--candidates", "dragan,slotv_plus", "--by", "pool", "--folds", "2",
                    "--no-progress"])  # fmt: skip
    assert e.value.code == 2 and "--by pool: the study's scenes" in capsys.readouterr().err
    assert not (tmp_path / "far").exists()


# ------------------------------------------------------------------ the pick by plans


def _paths(runs: int, problems: int, n: int, seed: int = 0):
    """Bent paths from the home TCP to one of 3 goals: (R, P, n, 3), goals, mask, target."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((runs, problems, 8, 3), np.float32)
    goals[..., :3, :] = [[0.5, 0.3, 0.025], [0.5, -0.3, 0.025], [0.65, 0.0, 0.025]]
    mask = np.broadcast_to(np.arange(8) < 3, (runs, problems, 8))
    target = rng.integers(0, 3, (runs, problems)).astype(np.int32)
    t = np.linspace(0, 1, n)[:, None]
    start = np.array([0.307, 0.0, 0.487])
    xyz = np.empty((runs, problems, n, 3), np.float32)
    for r in range(runs):
        for p in range(problems):
            bend = rng.uniform([-0.1, -0.25, -0.1], [0.1, 0.25, 0.1])
            end = goals[r, p, target[r, p]]
            xyz[r, p] = start + (end - start) * t + bend * np.sin(np.pi * t)
    return xyz, goals, mask, target


def test_a_judge_gives_its_observers_p_target_at_each_stop_time(monkeypatch):
    """loop.judge: the population's observer judges paths as the evaluation's quadrature
    scores them (planning.evaluation.population_scorer, another code path); the loop's
    judge of the fitted Dragan baseline is Dragan's labeler at each run's own fitted β,
    applied to each prefix (labelers.dragan of the sliced path) and built without reading
    the population."""
    taus, n = (0.4, 0.7, 1.0), 20
    xyz, goals, mask, target = _paths(2, 3, n)
    pop = population_lib.get_population("default")
    got = loop.judge(lambda p: population_lib.population_observer(pop), taus)(
        jnp.zeros(2), xyz, goals, mask, target
    )
    assert got.shape == (2, 3, len(taus))
    flat = lambda a: a.reshape((-1, *a.shape[2:]))  # noqa: E731
    scorer = evaluation.population_scorer(pop, taus, n, 2)
    want, _ = scorer(jax.random.split(jax.random.key(0), 6), *map(flat, (xyz, goals, mask, target)))
    np.testing.assert_allclose(np.asarray(got).reshape(6, -1), want, atol=2e-6)

    def forbidden(*a, **k):
        raise AssertionError("the judge read the population")

    for name in population_lib.__all__:
        if callable(getattr(population_lib, name)) and name[0].islower():
            monkeypatch.setattr(population_lib, name, forbidden)
    cfg = dataclasses.replace(
        exp.tiny(),
        families=("dragan_fitted", "nikolaidis_fitted", "pick_cross"),
        taus=taus,
        planner=planning.PlannerConfig(n_points=n, iters=3, taus=taus),
    )
    betas = np.array([[4.0, 1.0], [9.0, 1.0]], np.float32)  # (runs, [dragan, nikolaidis])
    got = np.asarray(loop.judge_for(cfg, "dragan_fitted")({"beta": betas}, xyz, goals, mask,
                                                          target))  # fmt: skip
    seen = seen_points(taus, n)
    for r in range(2):
        for p in range(3):
            for k, s in enumerate(seen):
                y = labelers.dragan(xyz[r, p, :s], goals[r, p], mask[r, p], beta=betas[r, 0])
                assert got[r, p, k] == pytest.approx(float(y[target[r, p]]), abs=2e-6)


def test_the_pick_by_plans_leaves_each_family_out_of_its_own_judgment():
    """cross_judged by hand: family a's fit finds its own plans very legible, the other fits
    do not; each family is scored by the mean of the others' judgments, per run."""
    judged = {
        "a": {"a": np.array([0.95, 0.2]), "b": np.array([0.3, 0.2]), "c": np.array([0.35, 0.2])},
        "b": {"a": np.array([0.6, 0.2]), "b": np.array([0.5, 0.9]), "c": np.array([0.7, 0.2])},
        "c": {"a": np.array([0.5, 0.3]), "b": np.array([0.5, 0.8]), "c": np.array([0.99, 0.1])},
    }
    idx, s = loop.cross_judged(judged, ["a", "b", "c"])
    np.testing.assert_allclose(s, [[0.325, 0.65, 0.5], [0.2, 0.2, 0.55]])
    assert idx.tolist() == [1, 2]
    with pytest.raises(ValueError, match="candidates"):
        loop.cross_judged(judged, ["a"])
    # the pool's candidates: all but the least-judged one (the first of a tie)
    assert trusted(s).tolist() == [[False, True, True], [False, True, True]]
    with pytest.raises(ValueError, match="scores"):
        trusted(s[:, :1])


# ------------------------------------------------------------------ pre-trained families


@dataclasses.dataclass
class _Split:
    """The fields of a dataset split that pre-training reads."""

    xyz: np.ndarray
    goals: np.ndarray
    goal_mask: np.ndarray
    labels: dict

    def __len__(self):
        return self.xyz.shape[0]


def test_a_pretrained_family_starts_from_the_labelers_mixture_and_fine_tunes(
    label_pool, monkeypatch
):
    """loop.pretrained_params trains on the mean of the labelers' label distributions (a
    float64 NumPy mean), never reads the population, and fits the mixture better than the
    random draw it replaces; the answers' fit then starts from it (no update: θ₀ itself)
    with the minibatch keys of the family it starts, and moves away from it."""
    pool, _ = label_pool
    n = 60
    xyz, goals, mask = (np.asarray(a)[:n] for a in (pool.xyz, pool.goals, pool.goal_mask))
    rng = np.random.default_rng(4)
    labels = {}
    for name in ("dragan", "nikolaidis", "effdist", "fastapp"):  # each near the motion's goal
        y = np.where(mask, rng.gamma(1.0, size=mask.shape), 0.0)
        y[np.arange(n), np.arange(n) % 3] += 4.0
        labels[name] = (y / y.sum(-1, keepdims=True)).astype(np.float32)
    split = _Split(xyz, goals, mask, labels)
    cfg = dataclasses.replace(
        exp.tiny(),
        families=("mlp", "mlp_pre", "dragan_fitted", "pick"),
        overrides=("hidden=16,8", "epochs=40"),  # 40 updates on the 60 motions
    )

    def forbidden(*a, **k):
        raise AssertionError("pre-training read the population")

    for name in population_lib.__all__:
        if callable(getattr(population_lib, name)) and name[0].islower():
            monkeypatch.setattr(population_lib, name, forbidden)
    seen = []
    real = loop.train_lib.train_trials

    def spy(tc, data, seeds, **kw):
        seen.append(np.asarray(data.labels, np.float64))
        return real(tc, data, seeds, **kw)

    monkeypatch.setattr(loop.train_lib, "train_trials", spy)
    loop._PRETRAINED.clear()
    theta0 = loop.pretrained_params(cfg, "mlp_pre", split)
    want = np.mean([labels[k].astype(np.float64) for k in sorted(labels)], axis=0)
    np.testing.assert_allclose(seen[0], want, atol=1e-7)

    tc = cfg.train_config("mlp_pre")
    assert tc == cfg.train_config("mlp")
    sel = selection.make_selector(tc, 1, 1)

    def mixture_nll(params):
        lp = np.asarray(
            sel.log_probs(jax.tree.map(lambda x: x[None], params), _full_pool(split), jnp.arange(n))
        )[0]
        return -np.sum(np.where(mask, want * np.maximum(lp, -1e9), 0.0)) / n

    fresh = jax.tree.map(lambda x: x[0], sel.init(jax.random.key(1_000)).params)
    assert mixture_nll(theta0) < mixture_nll(fresh) - 0.05  # 40 updates: 1.09 -> 1.00

    cand = np.arange(20, dtype=np.int32)[None]
    counts = np.zeros((1, 20, 8), np.float32)
    counts[0, :, 0] = 5.0
    inits = {"mlp_pre": theta0}
    same = simulated.fit_runs(tc, pool, cand, counts, 20, loop._init_keys("mlp_pre", [0]), 0, 5,
                              theta0)  # fmt: skip
    for a, b in zip(jax.tree.leaves(same), jax.tree.leaves(theta0), strict=True):
        np.testing.assert_array_equal(np.asarray(a)[0], np.asarray(b))
    assert np.array_equal(
        jax.random.key_data(loop._init_keys("mlp_pre", [0, (1, 2)])),
        jax.random.key_data(loop._init_keys("mlp", [0, (1, 2)])),
    )
    moved = loop.fit_family(cfg, "mlp_pre", pool, cand, counts, 20, [0], inits)
    d = [np.abs(np.asarray(a)[0] - np.asarray(b)).max() for a, b in
         zip(jax.tree.leaves(moved), jax.tree.leaves(theta0), strict=True)]  # fmt: skip
    assert max(d) > 1e-4
    with pytest.raises(ValueError, match="inits"):
        loop.fit_family(cfg, "mlp_pre", pool, cand, counts, 20, [0])


def _full_pool(split):
    """Every motion of ``split`` seen whole (stop time 1)."""
    return selection.make_pool(split.xyz, split.goals, split.goal_mask, (1.0,))


def test_the_mixture_archetype_is_a_family_of_the_presets():
    """mixture_archetype: the distance/approach archetype's config (SLOT-V loss), a family of
    the loop's presets and of study pick's default candidates; the loop's observer of a fit
    is the archetype's own masked logits of the motion seen up to each stop."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.experiments.people_loop import config as loop_config
    from slotv_jax.observers import archetypes
    from slotv_jax.training import config as train_config

    tc = train_config.family("quick", "mixture_archetype")
    assert (tc.model, tc.method, tc.train_size) == ("mixture", "slotv", None)
    assert "mixture_archetype" in loop_config.FAMILIES
    assert "mixture_archetype" in loop_config.DEFAULT_FAMILIES
    assert exp.quick().families == exp.paper().families == loop_config.DEFAULT_FAMILIES
    assert pick_lib.check_candidates(["mixture_archetype", "dragan"])
    assert "mixture_archetype" in pick_lib.DEFAULT_CANDIDATES
    # the loop's pick and study pick choose among the same observers by default
    labelers = {f: loop_config.FITTED[f] for f in loop_config.FITTED}
    loop_cands = [labelers.get(f, f) for f in exp.paper().candidates]
    assert loop_cands == list(pick_lib.DEFAULT_CANDIDATES)
    cfg = dataclasses.replace(exp.tiny(), families=("mixture_archetype", "dragan_fitted"))
    sel = selection.make_selector(cfg.train_config("mixture_archetype"), 1, 1)
    params = jax.tree.map(lambda x: x[0], sel.init(jax.random.key(0)).params)
    obs = loop._family_build(cfg, "mixture_archetype")({"mixture_archetype": params})
    xyz, goals, mask, _ = _paths(1, 1, 20)
    model = archetypes.DistanceApproachMixture()  # the archetype at its defaults (θ of init)
    for seen in (8, 20):
        got = np.asarray(obs.prefix(xyz[0, 0], goals[0, 0], mask[0, 0], seen))
        want = np.asarray(model.prefix(xyz[0, 0], goals[0, 0], mask[0, 0], seen))
        np.testing.assert_allclose(got[:3] - got[0], want[:3] - want[0], atol=1e-5)
        assert np.all(np.isneginf(got[3:]))


# The README's CSV example of a study with time stamps (seconds): τ 0.5, 0.8, 1.0 and the
# whole motions' 1.5, 1.2 and 2.0.
README_TRAJECTORIES = """trajectory,t,x,y,z
a,0.0,0.31,0.00,0.49
a,0.5,0.40,0.12,0.30
a,1.0,0.50,0.20,0.03
a,1.5,0.50,0.25,0.03
b,0.0,0.31,0.00,0.49
b,0.4,0.45,-0.05,0.35
b,0.8,0.55,-0.15,0.10
b,1.2,0.55,-0.20,0.03
c,0.0,0.31,0.00,0.49
c,1.0,0.42,0.00,0.20
c,2.0,0.45,0.00,0.03
"""
README_GOALS = """goal,x,y,z
left,0.50,0.25,0.025
right,0.55,-0.20,0.025
middle,0.45,0.00,0.025
"""
README_ANSWERS = """trajectory,tau,guess,participant,condition
a,0.5,left,p1,front
a,0.5,middle,p2,front
a,,left,p3,front
b,0.8,right,p1,front
b,,right,p2,front
b,,right,p3,front
c,1.0,middle,p1,front
c,1.0,left,p2,front
c,,middle,p3,front
"""


def test_pick_refusals_say_what_is_wrong_and_what_to_do(tmp_path, capsys, monkeypatch):
    """On the README's study with time stamps, --by plans and --by pool name the stop times
    outside (0, 1] (1.2, 1.5, 2 s), not the count (6, within the limit) and valid ones; more
    than 8 stop times is said as such; an earlier pick as --out offers --overwrite or
    another --out (pick has no --resume). All before any fit, nothing written."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.answers.tables import read_tables

    files = []
    for name, text in [("trajectories", README_TRAJECTORIES), ("goals", README_GOALS),
                       ("answers", README_ANSWERS)]:  # fmt: skip
        files.append(tmp_path / f"{name}.csv")
        files[-1].write_text(text)
    timed, _ = read_tables(*files)
    assert sorted(set(timed.answer_tau)) == [0.5, 0.8, 1.0, 1.2, 1.5, 2.0]
    save_study(tmp_path / "timed.npz", timed)
    monkeypatch.setattr(pick_lib, "fit_candidates", lambda *a, **k: pytest.fail("fitted"))
    out = tmp_path / "pick"
    for by in ("plans", "pool"):
        with pytest.raises(SystemExit) as e:
            study_main(["pick", str(tmp_path / "timed.npz"), "--out", str(out), "--by", by,
                        "--candidates", "dragan,nikolaidis", "--no-progress"])  # fmt: skip
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.count("\n") == 1, err
        assert err.startswith(
            f"error: --by {by}: expected the stop times τ of the study's answers in (0, 1], the "
            "fraction of the motion seen, got 3 of its 6 outside: 1.2, 1.5, 2 (the study has "
            "time stamps t: its τ are in their unit, not fractions of the motion)"
        ), err
        assert not out.exists()
    xyz, goals, mask = _paths(1, 1, 20)[:3]
    nine = simulate_study(jax.random.key(0), xyz[0], goals[0], mask[0], 90, labeler="dragan",
                          beta=8.0, taus=tuple(np.arange(1, 10) / 10))  # fmt: skip
    with pytest.raises(ValueError) as e:
        pick_lib.study_taus(nine, "plans")
    assert str(e.value) == (
        "--by plans: expected at most 8 distinct stop times in the study's answers (the "
        "planner's objective takes that many), got 9: 0.1, 0.2, 0.3, 0.4, 0.5, ... (4 more)"
    )
    out.mkdir()
    (out / "pick.json").write_text("{}")  # an earlier pick
    with pytest.raises(SystemExit) as e:
        study_main(["pick", str(tmp_path / "timed.npz"), "--out", str(out)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "--resume" not in err, err
    assert err == (
        f"error: --out {out}: holds an earlier output; pass --overwrite to replace it, or "
        "choose another --out to keep it\n"
    )
    assert (out / "pick.json").read_text() == "{}"


def test_study_pick_says_which_planner_its_preset_plans_with(tmp_path, capsys, monkeypatch):
    """``study pick --by plans|pool`` starts with one line naming the preset's planner
    (points and iterations, those of PlannerConfig under PLANNERS[preset]) and the other
    preset's, before any work; ``--help`` names them; the pick by likelihood plans nothing."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.study import cli as study_cli

    class Started(Exception):
        pass

    def started(*a, **k):
        raise Started

    monkeypatch.setattr(study_cli, "load_study", lambda path: None)
    for fn in ("pick_by_plans", "pick_pool", "pick_study"):
        monkeypatch.setattr(pick_lib, fn, started)
    quick = planning.PlannerConfig(**pick_lib.PLANNERS["quick"])
    paper = planning.PlannerConfig()
    assert (quick.n_points, quick.iters) == (50, 30) and (paper.n_points, paper.iters) == (100, 50)
    for by in ("plans", "pool", "likelihood"):
        with pytest.raises(Started):
            study_main(["pick", "s.npz", "--out", str(tmp_path / by), "--by", by])
        lines = capsys.readouterr().out.splitlines()
        if by == "likelihood":
            assert not any("iterations" in ln for ln in lines)
            continue
        assert lines == [
            "planner: 50 points, 30 iterations per plan (the quick preset's; "
            "--preset paper: 100 points, 50 iterations)"
        ]
    with pytest.raises(SystemExit):
        study_main(["pick", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "quick 50 points, 30 iterations per plan; paper 100 points, 50 iterations" in text


def test_the_pick_keeps_the_best_fit_and_says_when_none_explains_the_answers():
    """Near-uniform fits judge the one sharp fit's plans least legible: the sharp fit is
    still kept (the best held-out fit always is), a candidate no better than guessing gets
    no weight, and the table says when even the best fit closes under 5 % of uniform
    guessing's NLL (counts and predictions made up; the NLLs re-derived by hand)."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.answers import pooling

    mask = np.ones((40, 3), bool)
    counts = np.zeros((40, 3))
    counts[:] = [7.0, 2.0, 1.0]  # the sharp fit's own probabilities: it is the best fit
    sharp, flat, worse = [0.7, 0.2, 0.1], [0.36, 0.33, 0.31], [0.30, 0.35, 0.35]
    logp = np.log(np.array([[p] * 40 for p in (sharp, flat, worse)], np.float32))
    rep = pooling.pick_report(["sharp", "flat", "worse"], logp, counts, mask)
    want = [-np.dot([7, 2, 1], np.log(p)) / 10 for p in (sharp, flat, worse)]
    assert rep["heldout_nll"] == pytest.approx(want, abs=1e-5)
    assert rep["uniform_nll"] == pytest.approx(np.log(3), abs=1e-6)
    keep = pick_lib.trusted(np.array([[0.30, 0.40, 0.38]]), np.array([rep["heldout_nll"]]),
                            np.array([rep["uniform_nll"]]))  # fmt: skip
    assert keep.tolist() == [[True, True, False]]  # sharp least judged, kept; worse > uniform
    assert pick_lib.trusted(np.array([[0.30, 0.40, 0.38]])).tolist() == [[False, True, True]]
    good = {**pooling.pick_report(["sharp", "flat", "worse"], logp, counts, mask, keep[0]),
            "folds": 3, "left_out": ["worse"]}  # fmt: skip
    text = pick_lib.pick_table(good)
    assert "(left out: no better than guessing)" in text and "no candidate explains" not in text
    assert not good["poor_fit"] and good["weights"][0] > 0 and good["weights"][2] == 0
    poor = pooling.pick_report(["flat", "worse"], logp[1:], counts, mask)
    assert poor["poor_fit"] and poor["quality"][0] == pytest.approx(
        (np.log(3) - want[1]) / np.log(3), abs=1e-5
    )
    assert "no candidate explains these answers well" in pick_lib.pick_table({**poor, "folds": 3})


def test_study_pick_by_pool_with_caution_plans_the_pools_lower_bound(
    label_pool, tmp_path, monkeypatch, capsys
):
    """``study pick --by pool --caution K``: the plans file gets ``pool_cautious`` after
    ``pool``, the plans of the lower bound over the pool of each fold's fits and of the fits
    on every answer: re-planned here from members rebuilt by hand (each fold's β fitted again
    on its own rows, the pool's weights, κ), to the same joints. Bad values are one line
    before any fit."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.answers.crossval import fit_beta
    from slotv_jax.planning import caution
    from slotv_jax.planning.plans import load_plans

    monkeypatch.setitem(pick_lib.PLANNERS, "quick", {"n_points": 20, "iters": 3})
    path = tmp_path / "s.npz"
    study, _, taus = _dragan_study(label_pool, 1, path)
    out = tmp_path / "pick"
    argv = ["pick", str(path), "--out", str(out), "--candidates", "dragan,nikolaidis",
            "--folds", "2", "--no-progress"]  # fmt: skip
    monkeypatch.setattr(pick_lib, "fit_candidates", lambda *a, **k: pytest.fail("fitted"))
    for extra, words in (
        (["--by", "plans", "--caution", "1"], "--caution: plans the pool's bound"),
        (["--by", "pool", "--caution", "-1"], "--caution: expected a finite number >= 0"),
        (["--by", "pool", "--caution", "nan"], "--caution: expected a finite number >= 0"),
    ):
        with pytest.raises(SystemExit) as e:
            study_main([*argv, *extra])
        assert e.value.code == 2 and words in capsys.readouterr().err, extra
        assert not out.exists()
    monkeypatch.undo()
    monkeypatch.setitem(pick_lib.PLANNERS, "quick", {"n_points": 20, "iters": 3})
    assert study_main([*argv, "--by", "pool", "--caution", "1.5"]) == 0
    text = capsys.readouterr().out
    assert "pool_cautious: the pool's lower bound, κ = 1.5" in text
    plans = load_plans(out / "plans.npz")
    names = plans["names"].tolist()
    assert names == ["straight", "dragan", "nikolaidis", "pool", "pool_cautious"]
    rep = json.loads((out / "pool.json").read_text())["meta"]["pick"]
    assert rep["caution"] == 1.5
    w = dict(zip(rep["candidates"], rep["weights"], strict=True))
    members = [c for c in rep["candidates"] if w[c] > 0]
    fold = pooling.fold_of(study.answer_trajectory, 2, 0)
    fits = [study.select_rows(fold != f) for f in range(2)] + [study]
    cam = {"camera": "observer"}
    pools = [
        pooling.pool_observer(
            [planning.labeler_observer(c, beta=fit_beta(s, c)[0], **cam) for c in members],
            [w[c] for c in members],
        )
        for s in fits
    ]
    stacked = jax.tree.map(lambda *p: jnp.stack([jnp.asarray(x) for x in p]), *pools)
    bound = caution.lower_bound_observer(stacked, 1.5)
    cfg = planning.PlannerConfig(n_points=20, iters=3, taus=taus)
    again = planning.make_planner(bound, cfg)(plans["goals"], plans["goal_mask"], plans["target"])
    k = names.index("pool_cautious")
    np.testing.assert_allclose(plans["q"][k], np.asarray(again.q), rtol=0, atol=1e-5)
    assert np.all(np.asarray(again.feasible))


def test_a_cautious_pool_of_learned_fits_stacks_folds_trained_with_other_batches(
    label_pool, tmp_path
):
    """:func:`slotv_jax.answers.pick.cautious_pool` with a learned family: a fold's fit on
    fewer rows had another batch (another TrainConfig), and is rebuilt with the full fit's
    config; called as an observer, the bound is the equal-weight pool of its members."""
    from slotv_jax.answers import pick as pick_lib
    from slotv_jax.planning import caution
    from slotv_jax.training import checkpoint

    study, (xs, gs, ms), _ = _dragan_study(label_pool, 2, tmp_path / "s.npz")
    cfg = pick_lib.fit_config("quick", "dragan_archetype", study.n_rows)
    small = pick_lib.fit_config("quick", "dragan_archetype", 8)
    assert small != cfg  # a fold of few rows trains with another batch
    state = pick_lib.fit(cfg, study, jax.random.key(0))
    archetype = checkpoint.make_observer(cfg, state.params)
    dragan = planning.labeler_observer("dragan", beta=6.0)
    fits = {
        "dragan_archetype": {"cfg": cfg, "observer": archetype},
        "dragan": {"observer": dragan, "beta": 6.0},
    }
    folds = [
        {"dragan_archetype": {"params": jax.tree.map(lambda a, s=s: a * s, state.params)},
         "dragan": {"beta": b}}
        for s, b in ((0.9, 4.0), (1.1, 9.0))
    ]  # fmt: skip
    members, weights = ["dragan_archetype", "dragan"], [0.7, 0.4]
    full = pooling.pool_observer([archetype, dragan], weights)
    obs = pick_lib.cautious_pool(full, fits, folds, members, weights, 1.0)
    assert caution.members_of(obs) == (1.0, 3)
    xyz, g, m = xs[0], gs[0], ms[0]
    got = np.asarray(obs(xyz, g, m))
    want = []
    for ff in [*folds, None]:
        parts = [
            checkpoint.make_observer(cfg, ff["dragan_archetype"]["params"]) if ff else
            fits["dragan_archetype"]["observer"],
            planning.labeler_observer("dragan", beta=ff["dragan"]["beta"] if ff else 6.0),
        ]  # fmt: skip
        z = np.asarray(pooling.pool_observer(parts, weights)(xyz, g, m), np.float64)
        want.append(z[m] - np.log(np.sum(np.exp(z[m] - z[m].max()))) - z[m].max())
    np.testing.assert_allclose(got[m], np.mean(want, axis=0), atol=2e-5)
