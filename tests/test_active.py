"""Active selection (slotv_jax.asking.selection, slotv_jax.experiments.active): the criteria
against hand-computed two-goal pools, determinism, the vmapped ensemble against a loop
over members, and the experiment's bookkeeping."""

import json
import math
import shutil
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx

from slotv_jax.asking import replay, selection, simulated
from slotv_jax.experiments import active, active_report, active_stream
from slotv_jax.runs import summary
from slotv_jax.training import config as train_config

EPS = 1e-6  # "certain" members give the other goal this probability
H = lambda p: -sum(q * math.log(q) for q in p if q > 0)  # noqa: E731  float64 entropy
# vmapped and single-member float32 reductions round differently (~1e-7); five RMSprop
# steps (each divides by the root of the squared-gradient average) grow that to ~1e-5. A
# wrong member, key or bootstrap weight gives differences of order 1.
FLOAT32_STEPS = 1e-4
SELECT = jax.jit(selection.select, static_argnums=(0, 4), static_argnames=("shortlist",))


def _two_goal_logp():
    """E = 4 members, 5 candidates, 2 goals (hand-made predictions):

    0 A  every member says 50/50 (a noisy motion: high entropy, nothing to learn)
    1 B  members {0,1} are sure of goal 0, {2,3} of goal 1 (the informative motion)
    2 B' a copy of B
    3 D  members {0,2} lean 0.9 to goal 0, {1,3} 0.9 to goal 1 (informative, less so)
    4 C  every member is sure of goal 0
    """
    sure0, sure1 = [1 - EPS, EPS], [EPS, 1 - EPS]
    lean0, lean1, half = [0.9, 0.1], [0.1, 0.9], [0.5, 0.5]
    p = np.array(
        [
            [half, sure0, sure0, lean0, sure0],
            [half, sure0, sure0, lean1, sure0],
            [half, sure1, sure1, lean0, sure0],
            [half, sure1, sure1, lean1, sure0],
        ]
    )  # (E, C, G)
    return jnp.asarray(np.log(p), jnp.float32), p


def test_criteria_match_hand_computed_values():
    logp, _ = _two_goal_logp()
    u = np.asarray(selection.uncertainty(logp), np.float64)
    b = np.asarray(selection.bald(logp), np.float64)
    # by hand: p̄ and the mean member entropy of each candidate
    expect_u = [math.log(2), math.log(2), math.log(2), math.log(2), H([1 - EPS, EPS])]
    expect_b = [
        0.0,
        math.log(2) - H([1 - EPS, EPS]),
        math.log(2) - H([1 - EPS, EPS]),
        math.log(2) - H([0.9, 0.1]),
        0.0,
    ]
    np.testing.assert_allclose(u, expect_u, atol=2e-6)
    np.testing.assert_allclose(b, expect_b, atol=2e-6)
    # weighted: members {0, 1} only -> they agree on B, disagree on D
    w = jnp.array([0.5, 0.5, 0.0, 0.0])
    bw = np.asarray(selection.bald(logp, w), np.float64)
    np.testing.assert_allclose(bw[[1, 3]], [0.0, math.log(2) - H([0.9, 0.1])], atol=2e-6)


def test_margin_prefers_a_tie_of_two_goals_to_a_flat_spread():
    p = np.array([[[0.5, 0.5, 0.0], [0.4, 0.3, 0.3], [0.9, 0.05, 0.05]]])  # (E=1, C=3, G=3)
    with np.errstate(divide="ignore"):
        logp = jnp.asarray(np.log(p), jnp.float32)
    np.testing.assert_allclose(np.asarray(selection.margin(logp)), [1.0, 0.9, 0.15], atol=1e-6)
    np.testing.assert_allclose(
        np.asarray(selection.uncertainty(logp)),
        [H([0.5, 0.5]), H([0.4, 0.3, 0.3]), H([0.9, 0.05, 0.05])],
        atol=1e-6,
    )
    avail = jnp.ones(3, bool)
    assert int(SELECT("margin", jax.random.key(0), logp, avail, 1)[0]) == 0
    assert int(SELECT("uncertainty", jax.random.key(0), logp, avail, 1)[0]) == 1


def test_error_asks_where_the_observer_stands_alone():
    """``error`` = 1 − p̄(ŷ₀): a motion where member 0 holds to a goal the others reject
    comes before a tie that everyone shares, which ``margin`` asks first."""
    p = np.array(
        [
            [[0.5, 0.5], [0.9, 0.1], [0.8, 0.2], [0.6, 0.4]],  # member 0: tie, A, A, A
            [[0.5, 0.5], [0.1, 0.9], [0.8, 0.2], [0.6, 0.4]],
            [[0.5, 0.5], [0.1, 0.9], [0.8, 0.2], [0.2, 0.8]],
        ]
    )  # (E=3, C=4, G=2): a shared tie; member 0 alone; all agree; one member doubts
    logp = jnp.asarray(np.log(p), jnp.float32)
    pbar = p.mean(0)  # float64 by hand; member 0's guesses: A (the tie to the first goal)
    expect = 1.0 - pbar[:, 0]  # [0.5, 1 − 1.1/3, 0.2, 1 − 1.4/3]
    np.testing.assert_allclose(np.asarray(selection.error(logp)), expect, atol=1e-6)
    w = jnp.array([1.0, 0.0, 0.0])  # member 0 alone: its own least confidence
    np.testing.assert_allclose(np.asarray(selection.error(logp, w)), 1 - p[0].max(-1), atol=1e-6)
    avail = jnp.ones(4, bool)
    first = lambda s: int(SELECT(s, jax.random.key(0), logp, avail, 1)[0])  # noqa: E731
    assert (first("error"), first("margin")) == (1, 0)
    assert selection.ranking_score("error", jax.random.key(0), logp)[0] == "error"


def test_strategies_pick_the_informative_motions():
    logp, _ = _two_goal_logp()
    avail = jnp.ones(5, bool)
    key = jax.random.key(0)
    pick = lambda s, k=2: sorted(np.asarray(SELECT(s, key, logp, avail, k)).tolist())  # noqa: E731
    assert pick("bald", 1) == [1]  # B (its copy B' ties: the first index)
    assert pick("bald") == [1, 2]  # top-2 BALD: B and its copy
    assert pick("bald_cluster") == [1, 3]  # B' is at distance 0, C and A have BALD 0
    # margin ties A, B, B', D (p̄ = 50/50 each): A first (the lowest index), then B (√2
    # from A in the members' predictions, D only √1.28), then D (B' is at distance 0 from B)
    assert pick("margin_cluster", 3) == [0, 1, 3]
    assert int(SELECT("uncertainty", key, logp, avail, 1)[0]) in (0, 1, 2, 3)
    # unavailable candidates are never picked; random picks distinct available ones
    avail = jnp.array([True, False, False, True, True])
    assert sorted(np.asarray(SELECT("bald", key, logp, avail, 2)).tolist()) == [0, 3]
    r = np.asarray(SELECT("random", key, logp, avail, 3)).tolist()
    assert sorted(r) == [0, 3, 4]
    for gone in ("entropy", "bald_fantasy"):  # not a strategy; removed (bald_cluster won)
        with pytest.raises(ValueError, match="strategy"):
            selection.select(gone, key, logp, avail, 1)
    assert selection.STRATEGIES == ("random", "uncertainty", "margin", "margin_cluster",
                                    "error", "bald", "bald_cluster", "epig")  # fmt: skip


def _epig_reference(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """float64 EPIG from its definition: the mean over targets of
    Σ_{y,y*} p(y, y*) log(p(y, y*) / (p(y) p(y*))), p(y, y*) = Σ_e w_e p_e(y) q_e(y*)."""
    out = np.zeros(p.shape[1])
    for c in range(p.shape[1]):
        for s in range(q.shape[1]):
            joint = np.einsum("e,eg,eh->gh", w, p[:, c], q[:, s])
            indep = np.outer(joint.sum(1), joint.sum(0))
            nz = joint > 0
            out[c] += np.sum(joint[nz] * np.log(joint[nz] / indep[nz])) / q.shape[1]
    return out


def test_epig_matches_a_float64_reference():
    rng = np.random.default_rng(0)
    e, c, s, g = 3, 21, 7, 4
    logits = rng.normal(0, 2, (e, c + s, g))
    logits[:, ::3, 3] = -np.inf  # padded goal slots (three goals) on every third motion
    logp = logits - np.logaddexp.reduce(logits, -1, keepdims=True)
    p = np.exp(logp)
    for w in (np.full(e, 1 / e), np.array([0.6, 0.3, 0.1])):
        got = selection.epig(
            jnp.asarray(logp[:, :c], jnp.float32),
            jnp.asarray(logp[:, c:], jnp.float32),
            jnp.asarray(w, jnp.float32),
            chunk=8,  # 21 candidates: a padded last chunk
        )
        np.testing.assert_allclose(
            np.asarray(got), _epig_reference(p[:, :c], p[:, c:], w), atol=2e-6
        )
        assert np.isfinite(np.asarray(got)).all()


def test_epig_asks_what_changes_the_predictions():
    logp, _ = _two_goal_logp()
    # targets = the five motions: y at B tells which pair of members is right, and so y*
    # at B and B'; D's answer splits the members the other way, which B and B' ignore
    # (their members agree within each pair of D's split): EPIG(B) = 2/5 I(y_B; y*_B)
    got = np.asarray(selection.epig(logp, logp), np.float64)
    i_b = 2 * math.log(2) - H([0.5 - EPS + EPS**2, EPS - EPS**2, EPS - EPS**2, 0.5 - EPS + EPS**2])
    i_d = 2 * math.log(2) - H([0.41, 0.09, 0.09, 0.41])
    np.testing.assert_allclose(got, [0.0, 0.4 * i_b, 0.4 * i_b, 0.2 * i_d, 0.0], atol=2e-6)
    # BALD rewards B's disagreement wherever it goes; EPIG only where it changes what the
    # observer will predict: with A and C as the targets (all members agree) B teaches nothing
    np.testing.assert_allclose(np.asarray(selection.epig(logp, logp[:, [0, 4]])), 0.0, atol=2e-6)
    assert float(selection.bald(logp)[1]) > 0.69
    avail = jnp.ones(5, bool)
    assert sorted(np.asarray(SELECT("epig", jax.random.key(0), logp, avail, 2)).tolist()) == [1, 2]


def test_oracles_read_the_labels():
    labels = jnp.array([[0.6, 0.4, 0.0], [0.1, 0.1, 0.8]])  # the second motion: 3 goals
    with np.errstate(divide="ignore"):
        logp0 = jnp.asarray(np.log([[0.5, 0.5, 0.0], [0.2, 0.2, 0.6]]), jnp.float32)
    loss = np.asarray(replay.oracle_score("oracle_loss", logp0, labels))
    np.testing.assert_allclose(loss, [math.log(2), -(0.2 * math.log(0.2) + 0.8 * math.log(0.6))],
                               rtol=1e-6)  # fmt: skip
    gap = np.asarray(replay.oracle_score("oracle_margin", logp0, labels))
    np.testing.assert_allclose(gap, [1 - 0.2, 1 - 0.7], atol=1e-6)
    with pytest.raises(ValueError, match="strategy"):
        replay.oracle_score("oracle_entropy", logp0, labels)


def test_selection_is_deterministic_and_prefix_consistent():
    key = jax.random.key(3)
    logp = jax.nn.log_softmax(jax.random.normal(key, (3, 200, 5)), -1)
    avail = jax.random.bernoulli(jax.random.key(4), 0.8, (200,))
    for s in selection.STRATEGIES:
        a = np.asarray(SELECT(s, key, logp, avail, 16, shortlist=64))
        b = np.asarray(SELECT(s, key, logp, avail, 16, shortlist=64))
        np.testing.assert_array_equal(a, b)
        if s in ("random", "bald_cluster"):  # sequential picks (margin_cluster: the same
            # k-centre loop as bald_cluster)
            c = np.asarray(SELECT(s, key, logp, avail, 8, shortlist=64))
            np.testing.assert_array_equal(a[:8], c)  # the experiment takes a prefix of k_max
        assert np.unique(a).size == 16 and np.asarray(avail)[a].all(), s


def _tiny_pool(n=40, t=10, g=3, seed=0):
    rng = np.random.default_rng(seed)
    goals = np.zeros((n, 8, 3), np.float32)
    goals[:, :g] = rng.uniform([0.3, -0.4, 0.0], [0.7, 0.4, 0.05], (n, g, 3))
    mask = np.arange(8)[None] < g
    mask = np.repeat(mask, n, 0)
    start = np.array([0.31, 0.0, 0.49], np.float32)
    target = goals[np.arange(n), rng.integers(0, g, n)]
    s = np.linspace(0, 1, t)[None, :, None]
    xyz = (1 - s) * start + s * target[:, None, :] + 0.02 * rng.standard_normal((n, t, 3))
    return xyz.astype(np.float32), goals, mask, rng


def test_pool_and_answers_validate():
    xyz, goals, mask, _ = _tiny_pool()
    pool = selection.make_pool(xyz, goals, mask, taus=(0.5, 1.0))
    assert pool.traj.shape == (80,) and pool.seen[:2].tolist() == [5, 10]
    with pytest.raises(ValueError, match="taus"):
        selection.make_pool(xyz, goals, mask, taus=(0.0,))
    with pytest.raises(ValueError, match="goal_mask"):
        selection.make_pool(xyz, goals, mask[:, :4])
    with pytest.raises(ValueError, match="capacity"):
        selection.make_answers([0, 1, 2], np.ones((3, 8)), 2)
    sel = selection.make_selector(train_config.archetype("quick", "dragan"), 2, 8)
    sel.check_pool(pool)  # archetypes score prefixes too (tests/test_prefix.py)


def test_a_fit_cuts_the_goal_slots_no_motion_has_and_learns_the_same(monkeypatch):
    """Fitting on the pool's real goal slots only (``selection.trim_goals``) gives the fit
    of the 8 padded slots: a padded slot adds nothing to the likelihood or its gradient."""
    xyz, goals, mask, rng = _tiny_pool(g=3)
    mask[::2, 2] = False  # scenes of 2 and 3 goals: slots 3-7 are padding everywhere
    pool = selection.make_pool(xyz, goals, mask, taus=(0.6, 1.0))
    cand = rng.choice(pool.traj.shape[0], (2, 16), replace=False)
    counts = np.zeros((2, 16, 8), np.float32)
    for r in range(2):
        real = mask[np.asarray(pool.traj)[cand[r]]]
        counts[r, :, :3] = rng.multinomial(5, [0.5, 0.3, 0.2], 16) * real[:, :3]
    trimmed, c = selection.trim_goals(pool, counts)
    assert trimmed.goals.shape[1:] == (3, 3) and c.shape == (2, 16, 3)
    tc = train_config.archetype("quick", "dragan")
    keys = jnp.stack([jax.random.key(1), jax.random.key(2)])
    cut = simulated.fit_runs(tc, pool, cand, counts, 16, keys, 2, 10)
    monkeypatch.setattr(selection, "trim_goals", lambda p, c: (p, np.asarray(c)))
    padded = simulated.fit_runs(tc, pool, cand, counts, 16, keys, 2, 10)
    for a, b in zip(jax.tree.leaves(cut), jax.tree.leaves(padded), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=FLOAT32_STEPS, atol=1e-6)
    monkeypatch.undo()
    counts[0, 0, 5] = 1.0  # a guess of a goal that no motion of the pool has
    with pytest.raises(ValueError, match="counts: guesses of a goal slot past"):
        selection.trim_goals(pool, counts)


@pytest.fixture(scope="module")
def trained():
    xyz, goals, mask, rng = _tiny_pool()
    pool = selection.make_pool(xyz, goals, mask, taus=(0.6, 1.0))
    cfg = train_config.quick("slotv", hidden=(8, 4), batch_size=4)
    sel = selection.make_selector(cfg, 3, 16)
    cand = rng.choice(pool.traj.shape[0], 12, replace=False)
    counts = rng.multinomial(5, [0.6, 0.3, 0.1], 12).astype(np.float32)
    counts = np.concatenate([counts, np.zeros((12, 5), np.float32)], 1)
    ans = selection.make_answers(cand, counts, 16)
    ens0 = sel.init(jax.random.key(7))
    fit = jax.jit(lambda e, k: sel.fit(e, pool, ans, k, updates=5))
    ens, losses = fit(ens0, jax.random.key(8))
    return sel, pool, ans, ens0, ens, losses, fit


def test_ensemble_vmap_equals_a_loop_over_members(trained):
    sel, pool, ans, ens0, ens, losses, _ = trained
    tx = sel.base.tx
    e_count, bs = sel.members, sel.cfg.batch_size
    k_members, _ = jax.random.split(jax.random.key(7))
    step_keys = jax.random.split(jax.random.key(8), 5)
    assert float(jnp.min(ens0.boot[1:])) >= 0 and bool(jnp.all(ens0.boot[0] == 1))

    @jax.jit
    def one_step(params, opt, k, boot):  # one member, one update, no vmap
        rows = jax.random.randint(k, (bs,), 0, ans.n)
        loss, grads = jax.value_and_grad(sel.loss)(params, pool, ans, rows, boot)
        upd, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, upd), opt, loss

    whole = jnp.flatnonzero(pool.seen == pool.xyz.shape[1])[:7]
    lp_all = sel.log_probs(ens.params, pool, whole, chunk=4)  # every member at once
    for e in range(e_count):
        # member e alone: its own init and key stream, one Python step per update
        state = sel.base.init(jax.random.fold_in(k_members, e))
        params, opt = state.params, state.opt_state
        for u in range(5):
            k = jax.random.split(step_keys[u], e_count)[e]
            params, opt, loss = one_step(params, opt, k, ens0.boot[e])
            np.testing.assert_allclose(float(losses[u, e]), float(loss), rtol=FLOAT32_STEPS)
        got = jax.tree.map(lambda x, e=e: x[e], ens.params)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(params), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=FLOAT32_STEPS, atol=1e-6)
        # log_probs of member e against the model's own masked call on the whole motions
        lp = lp_all[e]
        model = nnx.merge(sel.base.graphdef, params)
        t = pool.traj[whole]
        ref = jax.nn.log_softmax(model(pool.xyz[t], pool.goals[t], pool.goal_mask[t]), -1)
        np.testing.assert_allclose(np.asarray(lp), np.asarray(ref), rtol=1e-4, atol=1e-5)


def test_fit_is_deterministic(trained):
    *_, ens0, ens, losses, fit = trained
    again, losses2 = fit(ens0, jax.random.key(8))
    for a, b in zip(jax.tree.leaves(ens.params), jax.tree.leaves(again.params), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(losses), np.asarray(losses2))
    assert np.isfinite(np.asarray(losses)).all()


def test_answers_to_target_and_comparisons():
    assert summary.crossing([10, 100], [0.6, 0.9], 0.75) == pytest.approx(math.sqrt(1000))
    assert summary.crossing([10, 100], [0.85, 0.9], 0.8) == 10.0
    assert summary.crossing([10, 100], [0.5, 0.7], 0.8) is None
    cfg = {"labels_target": 0.8, "study_targets": [["mlp", 0.8]], "strategies": ["random", "bald"]}
    runs = [
        {"strategy": "random", "seed": 0, "accuracy": [0.5, 0.7, 0.8]},
        {"strategy": "random", "seed": 1, "accuracy": [0.5, 0.8, 0.9]},
        {"strategy": "bald", "seed": 0, "accuracy": [0.5, 0.8, 0.9]},
        {"strategy": "bald", "seed": 1, "accuracy": [0.5, 0.6, 0.7]},
    ]
    grp = {"setting": "labels", "labeler": "dragan", "model": "mlp", "answers": [10, 20, 40],
           "runs": runs}  # fmt: skip
    out = active_report.comparisons({"config": cfg, "groups": [grp]})
    by = {c["strategy"]: c for c in out}
    assert by["random"]["answers_to_target"] == pytest.approx(30.0)  # mean of 40 and 20
    assert by["bald"]["answers_to_target"] is None and by["bald"]["seeds_reached"] == 1
    for c in out:
        assert {"setting", "model", "labeler", "strategy", "answers_to_target", "seeds"} <= set(c)
        assert c["seeds"] == 2
    # an oracle reads the labels: it is kept out of the strategies' comparisons
    cfg["strategies"].append("oracle_loss")
    grp["runs"] += [
        {"strategy": "oracle_loss", "seed": s, "accuracy": [0.8, 0.9, 0.9]} for s in (0, 1)
    ]
    doc = active_report.summarise({"config": cfg, "groups": [grp]})
    assert [c["strategy"] for c in doc["comparisons"]] == ["random", "bald"]
    assert [c["strategy"] for c in doc["oracles"]] == ["oracle_loss"]
    assert doc["oracles"][0]["ratio_random_over_this"] == pytest.approx(30.0 / 10.0)


def test_config_rejects_bad_settings():
    with pytest.raises(ValueError, match="subset"):
        active.quick(subset=10)
    with pytest.raises(ValueError, match="strategies"):
        active.quick(strategies=("bald",))
    with pytest.raises(ValueError, match="study_targets"):
        active.quick(study_targets=(("mlp", 0.8),))
    assert active.geometric(16, 512, 2.0) == (16, 32, 64, 128, 256, 512)
    assert active.up_to((16, 32, 64), 256) == (16, 32, 64, 128, 256)  # --study-max
    assert active.up_to((16, 32, 64), 40) == (16, 32)
    assert active.quick().groups()[0] == ("labels", "dragan", "mlp")


def test_a_finished_document_is_summarised_again_without_work(tmp_path):
    """Re-running a finished experiment (e.g. to re-render its report on another machine)
    generates no dataset and keeps where and when it ran."""
    cfg = active.quick(
        strategies=("random", "oracle_loss"), seeds=1, labels_labelers=("dragan",),
        study_models=("dragan",),
    )  # fmt: skip
    groups = [
        {"setting": s, "labeler": lab, "model": m, "answers": [16, 32], "motions": [16, 32],
         "runs": [{"strategy": st, "seed": 0, "accuracy": [0.5, 0.95]} for st in cfg.strategies],
         "timing": {"fit_s": 1.0, "score_s": 1.0, "select_s": 1.0, "eval_s": 1.0}}
        for s, lab, m in cfg.groups()
    ]  # fmt: skip
    doc = {"preset": "quick", "config": cfg.to_json(), "groups": groups,
           "timing": {"total_s": 5.0}, "environment": {"devices": ["cuda:0"]},
           "machine": "x86_64, gpu: H100", "date": "then"}  # fmt: skip
    (tmp_path / "active_results.json").write_text(json.dumps(doc))
    got = active.run(cfg, tmp_path, cache=tmp_path / "cache", progress=False)
    assert not (tmp_path / "cache").exists()  # no dataset made
    assert (got["machine"], got["date"], got["timing"]) == (
        doc["machine"],
        "then",
        {"total_s": 5.0},
    )
    assert [c["strategy"] for c in got["comparisons"]] == ["random", "random"]
    assert [c["strategy"] for c in got["oracles"]] == ["oracle_loss", "oracle_loss"]
    assert json.loads((tmp_path / "active_results.json").read_text()) == got


@pytest.mark.parametrize(
    "module, stem",
    [(active, "active"), (active, "active_paper"), (active_stream, "active_stream"),
     (active_stream, "active_stream_paper")],
)  # fmt: skip
def test_recorded_reports_render_again_from_their_results(tmp_path, module, stem):
    """``--report`` renders a recorded document again from its results alone, the report
    byte for byte (every number) and the figure, keeping the command the report names; a
    folder without a results document of the experiment is refused."""
    plt = pytest.importorskip("matplotlib.pyplot")
    folder = Path(__file__).resolve().parent.parent / "experiments"
    for suffix in ("_results.json", ".md"):
        shutil.copy(folder / f"{stem}{suffix}", tmp_path / f"{stem}{suffix}")
    preset = "quick" if stem in ("active", "active_stream") else "paper"
    assert module.main(["--report", "--preset", preset, "--out", str(tmp_path)]) == 0
    assert (tmp_path / f"{stem}.md").read_bytes() == (folder / f"{stem}.md").read_bytes()
    # the figure: the same pixels here; other matplotlib or FreeType versions draw text a
    # little differently, so the size must match and the pixels nearly
    got, want = (plt.imread(d / f"{stem}.png") for d in (tmp_path, folder))
    assert got.shape == want.shape and np.abs(got - want).mean() < 0.01
    with pytest.raises(SystemExit) as e:
        module.main(["--report", "--preset", preset, "--out", str(tmp_path / "empty")])
    assert e.value.code == 2


# ---------------------------------------------------------- the one-pass protocol


@pytest.mark.slow
def test_stream_labels_each_motion_once_for_one_update():
    """The paper's Fig. 3 protocol with selected batches: each labelled motion is used for
    exactly one optimiser step, in order (against a hand loop of the optimiser on the
    cross-entropy of the same batches), the oracle picks the batch of largest loss, and
    the same seed gives the same curves."""
    xyz, goals, mask, rng = _tiny_pool(n=400, t=6)
    labels = np.where(mask, rng.dirichlet(np.ones(8), 400), 0.0).astype(np.float32)
    labels /= labels.sum(-1, keepdims=True)
    train, held = (xyz, goals, mask, labels), (xyz[:60], goals[:60], mask[:60], labels[:60])
    # eps = 1 makes RMSprop's step lr·g/(√ν + 1) smooth in g: with the default ε, a unit
    # whose gradient is ~1e-10 (float32 cancellation) moves by lr·g/√ν, any size
    cfg = active_stream.quick(
        strategies=("random", "margin", "oracle_loss"), steps=3, subset=64, every=2, seeds=1,
        stride=1, overrides=("eps=1.0",),
    )  # fmt: skip
    res = active_stream.run_seeds(cfg, train, held, progress=False)
    again = active_stream.run_seeds(cfg, train, held, progress=False)
    assert res["runs"] == again["runs"] and res["examples"] == [0, 64, 96]
    lab = res["labelled"]
    assert lab.shape == (3, 96) and all(np.unique(row).size == 96 for row in lab)
    sel = selection.make_selector(cfg.train_config(), 1, 32)
    pool = selection.make_pool(xyz, goals, mask)
    # hand loop: the random run's three batches, one RMSprop step each on the mean CE
    ens = sel.init(jax.random.key(1000))
    params, opt = ens.params, ens.opt_state

    y_all = jnp.asarray(labels)

    @jax.jit
    def ce(p, idx):  # (len(idx),) cross-entropies −Σ_g y_g log p_g
        lp, y = sel.log_probs(p, pool, idx, chunk=32)[0], y_all[idx]
        return -jnp.sum(jnp.where(y > 0, y * lp, 0.0), -1)

    for u in range(3):
        batch = jnp.asarray(lab[0, u * 32 : (u + 1) * 32])
        grads = jax.grad(lambda p, b=batch: ce(p, b).mean())(params)
        upd, opt = jax.vmap(sel.base.tx.update)(grads, opt, params)
        params = optax.apply_updates(params, upd)
    leaves = zip(*(jax.tree.leaves(p) for p in (ens.params, params, res["params"])), strict=True)
    for p0, hand, run in leaves:  # the steps agree to float32 rounding of the parameters
        p0, hand, run = np.asarray(p0), np.asarray(hand), np.asarray(run)[0]
        assert np.abs(hand - p0).max() > 1e-5  # the steps are not lost in the tolerance
        np.testing.assert_allclose(hand - p0, run - p0, rtol=1e-3, atol=1e-7)
    # the oracle's first batch: the 32 of the first subset the initial observer fits worst
    sub = np.random.default_rng([0, 2, 0]).choice(400, 64, replace=False)
    loss = np.asarray(ce(ens.params, jnp.asarray(sub)))
    assert set(lab[2, :32]) == set(sub[np.argsort(loss)[-32:]])


def test_stream_summary_and_config():
    curves = {("random", 0): [0.1, 0.5, 0.7, 0.85], ("random", 1): [0.1, 0.5, 0.81, 0.9],
              ("margin", 0): [0.1, 0.8, 0.9, 0.9], ("margin", 1): [0.1, 0.5, 0.6, 0.7]}  # fmt: skip
    runs = [{"strategy": s, "seed": sd, "accuracy": a} for (s, sd), a in curves.items()]
    doc = {"config": {"target": 0.8, "strategies": ["random", "margin"]},
           "examples": [0, 32, 64, 96], "runs": runs}  # fmt: skip
    rnd, mar = active_stream.summarise(doc)["summary"]
    assert rnd["per_seed"] == [96, 64] and rnd["examples_to_target"] == 80
    assert mar["per_seed"] == [32, None] and mar["examples_to_target"] is None
    assert rnd["ratio_random_over_this"] == 1.0 and mar["ratio_random_over_this"] is None
    with pytest.raises(ValueError, match="strategies"):
        active_stream.quick(strategies=("random", "bald"))  # an ensemble's criterion
    with pytest.raises(ValueError, match="subset"):
        active_stream.quick(subset=8)
