"""The legible planner (slotv_jax.planning) against independent references.

- gradient: float64 central finite differences of the planner's objective (MJX in float64);
- constraints: re-checked on the returned plans with MuJoCo C forward kinematics (float64)
  and NumPy: endpoints, joint limits, table clearance, the trust region;
- the oracle test: the true Dragan y_target (the float64 NumPy reference labeler of
  tests/ref_labelers.py) rises above the straight line's on >= 95 % of 200 problems.

One compiled planner (200 problems, the default PlannerConfig) serves most tests: the
planner's compilation dominates their time.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import ref_labelers
from docs_pages import marked_block

from slotv_jax import data, planning
from slotv_jax.core.defaults import BETAS_V1
from slotv_jax.observers import common, labelers
from slotv_jax.planning import planner as planning_planner
from slotv_jax.robot import kinematics
from slotv_jax.world import scene

REPO = Path(__file__).resolve().parent.parent
# Every test here shares one pytest-xdist worker (--dist loadgroup), so that the module's
# planner is compiled and its straight lines and 200 plans are computed once, not once
# per worker.
pytestmark = pytest.mark.xdist_group("planning")
N_PROBLEMS = 200
GOAL_COUNTS = (
    2,
    3,
    4,
    5,
    6,
    8,
)  # the held-out splits' counts (position {2,3,5,6}, goal count {4,8})
RISE_RATE = 0.95  # issue 14: the oracle beats the straight line on >= 95 % of problems
FK_TOL = 1e-5  # m: MJX (float32) vs MuJoCo C (float64), as in test_kinematics
COST_TOL = 1e-5  # m²: float32 rounding of C (a sum of 99 terms of ~1e-3 m² · 99)
FD_TOL = 1e-6  # relative: float64 central differences vs autodiff
# The oracle plans and is scored at one temperature: the first version's default, at which
# RISE_RATE and the tolerances above were set.
BETA = BETAS_V1["dragan"]


def sample_problems(n: int, seed: int = 0):
    """Scenes with the held-out goal counts and a uniform real target (quick-preset-like)."""
    k_count, k_scene, k_target = jax.random.split(jax.random.key(seed), 3)
    counts = jax.vmap(lambda k: scene.sample_goal_count(k, GOAL_COUNTS))(
        jax.random.split(k_count, n)
    )
    s = jax.jit(jax.vmap(scene.sample_scene))(jax.random.split(k_scene, n), counts)
    target = jax.vmap(lambda k, c: jax.random.randint(k, (), 0, c))(
        jax.random.split(k_target, n), counts
    )
    return np.asarray(s.goals), np.asarray(s.goal_mask), np.asarray(target)


class Counter:
    """An observer that counts how often it is traced (Dragan underneath)."""

    def __init__(self):
        self.calls = 0
        self.inner = planning.labeler_observer("dragan", beta=BETA)

    def __call__(self, xyz, goals, goal_mask):
        self.calls += 1
        return self.inner(xyz, goals, goal_mask)


@pytest.fixture(scope="module")
def counter():
    return Counter()


@pytest.fixture(scope="module")
def planner(counter):
    observers = {"dragan": planning.labeler_observer("dragan", beta=BETA), "counted": counter}
    return planning.make_planner(observers, planning.PlannerConfig())


@pytest.fixture(scope="module")
def problems():
    return sample_problems(N_PROBLEMS)


@pytest.fixture(scope="module")
def straight(planner, problems):
    """The straight-line problems (tests that need no plans use only these: planning all
    200 takes about a minute on the 2-core CPU)."""
    return planner.straight_line(*problems)


@pytest.fixture(scope="module")
def solved(planner, straight):
    return straight, jax.device_get(planner.plan_problems(straight, observer="dragan"))


def mj_fk(q: np.ndarray) -> np.ndarray:
    """TCP positions from MuJoCo C ``mj_kinematics`` in float64."""
    m = kinematics.mj_model()
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE)
    out = np.empty((len(q), 3))
    for i, qi in enumerate(np.asarray(q, np.float64)):
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        out[i] = d.site_xpos[site]
    return out


def cost64(xyz) -> np.ndarray:
    x = np.asarray(xyz, np.float64)
    return 0.5 * (x.shape[-2] - 1) * np.sum(np.diff(x, axis=-2) ** 2, axis=(-2, -1))


# ----------------------------------------------------------------- the oracle


@pytest.mark.slow
def test_oracle_raises_true_legibility_within_budget(problems, solved):
    goals, mask, target = problems
    straight, res = solved
    cfg = planning.PlannerConfig()
    y_plan = np.array([ref_labelers.dragan(res.xyz[i], goals[i], mask[i], beta=BETA)[target[i]]
                       for i in range(N_PROBLEMS)])  # fmt: skip
    y_line = np.array([ref_labelers.dragan(straight.xyz[i], goals[i], mask[i], beta=BETA)
                       [target[i]] for i in range(N_PROBLEMS)])  # fmt: skip
    rate = np.mean(y_plan > y_line)
    assert rate >= RISE_RATE, rate
    # Within the budget, recomputed in float64 from the returned paths.
    assert np.all(cost64(res.xyz) <= cost64(straight.xyz) + cfg.budget + COST_TOL)
    assert np.all(res.diagnostics.feasible)


# ------------------------------------------------------------- constraints


@pytest.mark.slow
def test_endpoints_limits_table(problems, solved):
    goals, _, target = problems
    straight, res = solved
    cfg = planning.PlannerConfig()
    q, xyz = np.asarray(res.q), np.asarray(res.xyz)
    # The start configuration is Q_HOME exactly and the last one is the straight line's IK.
    np.testing.assert_array_equal(
        q[:, 0], np.broadcast_to(np.float32(kinematics.Q_HOME), (N_PROBLEMS, 7))
    )
    np.testing.assert_array_equal(q[:, -1], np.asarray(straight.q)[:, -1])
    # The path is the arm's: MuJoCo C FK of the joints, for a few problems.
    for i in (0, 57, 199):
        np.testing.assert_allclose(mj_fk(q[i]), xyz[i], atol=FK_TOL)
    goal = goals[np.arange(N_PROBLEMS), target]
    assert np.all(np.linalg.norm(mj_fk(q[:, -1]) - goal, axis=-1) <= 2e-3)
    assert np.all(np.linalg.norm(xyz[:, 0] - kinematics.home_tcp(), axis=-1) <= 2e-3)
    # Joint limits, table clearance outside the exempt radius.
    assert np.all(q >= kinematics.Q_MIN) and np.all(q <= kinematics.Q_MAX)
    far = np.linalg.norm(xyz - goal[:, None], axis=-1) >= cfg.exempt_radius
    assert np.all(xyz[..., 2][far] >= cfg.clearance)
    d = res.diagnostics
    np.testing.assert_allclose(d.joint_margin, np.minimum(q - kinematics.Q_MIN,
                               kinematics.Q_MAX - q).min(axis=(1, 2)), atol=1e-6)  # fmt: skip
    assert np.all(d.table_clearance >= 0)
    assert d.objective.shape == (N_PROBLEMS, cfg.iters + 1)


@pytest.mark.slow
def test_deterministic_and_traces_once(planner, straight, counter):
    few = jax.tree.map(lambda a: a[:8], straight)
    first = jax.device_get(planner.plan_problems(few, observer="dragan"))
    traced = counter.calls
    assert traced >= 1  # the switch traced every observer once, at the compilation
    again = jax.device_get(planner.plan_problems(few, observer="dragan"))
    jax.tree.map(np.testing.assert_array_equal, again, first)
    # Other values (the other goals moved), the other observer: the same compiled program.
    shifted = few._replace(goals=few.goals * np.float32(1.01))
    planner.plan_problems(shifted, observer="counted")
    assert counter.calls == traced


@pytest.mark.slow
def test_vmap_equals_loop(straight):
    # Few iterations: the batched and the single program round differently in float32
    # (~1e-7 per operation), and many nonlinear steps with normalised lengths amplify
    # that (to ~1e-4 m after 50 steps); over 3 steps the results must agree to rounding.
    cfg = planning.PlannerConfig(iters=3)
    obs = planning.labeler_observer("dragan", beta=BETA)
    batch = jax.tree.map(lambda a: a[:4], straight)
    many = jax.jit(jax.vmap(lambda p: planning.plan(obs, p, cfg)))(batch)
    one = jax.jit(lambda p: planning.plan(obs, p, cfg))
    for i in range(4):
        r = one(jax.tree.map(lambda a, i=i: a[i], batch))
        np.testing.assert_allclose(r.xyz, many.xyz[i], atol=1e-6)
        np.testing.assert_allclose(r.q, many.q[i], atol=1e-6)
        np.testing.assert_allclose(
            r.diagnostics.objective, many.diagnostics.objective[i], atol=1e-6
        )
        assert int(r.diagnostics.best_iter) == int(many.diagnostics.best_iter[i])


# ----------------------------------------------------------------- gradient


@pytest.mark.slow
def test_gradient_matches_finite_differences_float64(straight):
    i = 7
    with jax.enable_x64(True):
        p64 = jax.tree.map(
            lambda a: jnp.asarray(a[i], jnp.float64) if a.dtype == np.float32 else a[i],
            straight,
        )
        cfg = planning.PlannerConfig()
        obs = planning.labeler_observer("dragan", beta=BETA)
        f = jax.jit(jax.value_and_grad(lambda z: planning.objective(obs, p64, z, cfg)))
        z0 = planning_planner._initial_z(p64.q)
        rng = np.random.default_rng(0)
        t = np.linspace(0, np.pi, z0.shape[0])[:, None]
        # At the straight line, and bent so far that the table penalty is active.
        bend = np.sin(t) * np.array([0.0, 0.6, 0.0, -0.8, 0.0, 0.9, 0.0])
        for z in (z0, z0 + bend):
            _, g = f(z)
            assert g.dtype == np.float64 and np.all(np.isfinite(np.asarray(g)))
            for _ in range(3):
                v = rng.normal(size=z0.shape)
                v /= np.linalg.norm(v)
                h = 1e-6
                fd = (f(z + h * v)[0] - f(z - h * v)[0]) / (2 * h)
                assert float(fd) == pytest.approx(float(jnp.sum(g * v)), rel=FD_TOL, abs=1e-9)
        xyz = planning_planner._fk(planning_planner._joints(z0 + bend, p64.q[0], p64.q[-1]))
        assert planning_planner._table_penalty(xyz, p64, cfg) > 0  # the penalty term was tested


def test_predictability_cost_and_metric():
    # C = ½ ℓ² for a straight line at constant speed; A⁻¹ is the inverse of tridiag(−1, 2, −1).
    line = np.linspace([0.0, 0.0, 0.0], [0.3, 0.4, 0.0], 50)
    assert float(planning.predictability_cost(jnp.asarray(line))) == pytest.approx(0.125, rel=1e-6)
    n = 9
    a = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    np.testing.assert_allclose(planning.metric_inverse(n) @ a, np.eye(n), atol=1e-12)


def test_labeler_observer_is_log_y():
    goals, mask, target = sample_problems(1, seed=3)
    xyz = np.linspace(kinematics.home_tcp(), goals[0, target[0]], 100)
    for name in ("dragan", "nikolaidis"):
        logits = planning.labeler_observer(name)(xyz, goals[0], mask[0])
        y = labelers.LABELERS[name](xyz, goals[0], mask[0], **({"camera": scene.camera()}
                                     if name == "nikolaidis" else {}))  # fmt: skip
        np.testing.assert_allclose(jax.nn.softmax(logits), y, atol=1e-6)
        assert np.all(np.isneginf(np.asarray(logits)[~mask[0]]))


# --------------------------------------------------------------- bad input


def test_bad_input(planner, problems):
    goals, mask, target = (np.array(a) for a in problems)
    obs = planning.labeler_observer("dragan")
    with pytest.raises(ValueError, match="budget"):
        planning.PlannerConfig(budget=0.0)
    with pytest.raises(ValueError, match="budget"):
        planning.PlannerConfig(budget=-0.1)
    with pytest.raises(ValueError, match="observer"):
        planning.make_planner(lambda x, g, m: jnp.zeros(5))
    with pytest.raises(ValueError, match="observer"):
        planning.make_planner(lambda x, g, m: jnp.zeros((2, 8)))
    bad_t = target.copy()
    bad_t[4] = mask[4].sum()  # a padded slot
    with pytest.raises(ValueError, match="target: problem 4"):
        planner(goals, mask, bad_t)
    with pytest.raises(ValueError, match="target"):
        planner(goals, mask, np.full_like(target, 9))
    nan = goals.copy()
    nan[2, 0, 0] = np.nan
    with pytest.raises(ValueError, match="goals: expected finite"):
        planner(nan, mask, target)
    with pytest.raises(ValueError, match="observer"):
        planner(goals, mask, target, observer="nobody")
    far = goals.copy()
    far[5, target[5]] = [1.6, 0.0, 0.025]  # beyond the Panda's reach (~0.855 m + links)
    with pytest.raises(ValueError, match=r"target: problem 5 .* out of reach"):
        planner(far, mask, target)
    start = np.broadcast_to(kinematics.home_tcp(), (N_PROBLEMS, 3)).copy()
    start[8] = [0.0, 0.0, 1.6]
    with pytest.raises(ValueError, match=r"start: problem 8 .* out of reach"):
        planner(goals, mask, target, start=start)
    start[8] = np.nan
    with pytest.raises(ValueError, match="start: expected finite"):
        planner(goals, mask, target, start=start)
    del obs


def test_reach_holds_every_tcp_position():
    """kinematics.reach(): every TCP position of 20000 configurations within the joint limits
    (MuJoCo C, float64) lies in its ball, and the ball is not loose (the farthest of them
    within 15 % of its radius)."""
    centre, radius = kinematics.reach()
    m = kinematics.mj_model()
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE)
    qs = np.random.default_rng(0).uniform(kinematics.Q_MIN, kinematics.Q_MAX, (20000, 7))
    dist = []
    for q in qs:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        dist.append(np.linalg.norm(d.site_xpos[site] - centre))
    assert max(dist) <= radius and max(dist) > 0.85 * radius, (max(dist), radius)


def test_an_unreachable_goal_is_refused_before_anything_compiles(monkeypatch):
    """A target or a start farther from the shoulder than the arm reaches: the planner's
    refusal, before the straight lines (or the home TCP's constant) compile: it came after
    30-53 s of compiling, and comes after 0.1 s."""
    from slotv_jax.planning import compiled

    def compiling(cfg):
        def straight(*a):
            raise AssertionError("the straight lines ran before the reach was checked")

        return straight

    start = np.broadcast_to(kinematics.home_tcp(), (8, 3)).copy()
    start[2] = [0.0, 0.0, 1.6]
    monkeypatch.setattr(compiled, "_straight_program", compiling)
    monkeypatch.setattr(kinematics, "home_tcp", lambda: pytest.fail("MJX compiled first"))
    goals, mask, target = sample_problems(8, seed=4)
    far = goals.copy()
    far[5, target[5]] = [1.6, 0.0, 0.025]  # hypot(1.6, 0.333 - 0.025) = 1.629 m away
    planner = planning.make_planner(planning.labeler_observer("dragan"))
    with pytest.raises(ValueError, match=r"target: problem 5 at \[1\.6, 0\.0, 0\.025\] m "
                       r"is out of reach \(1\.629 m from the Panda's shoulder"):  # fmt: skip
        planner(far, mask, target)
    with pytest.raises(ValueError, match=r"target: problem 5 .* out of reach"):
        planning.straight_lines(far, mask, target)  # what study pick and the people loop use
    with pytest.raises(ValueError, match=r"start: problem 2 .* out of reach"):
        planner(goals, mask, target, start=start)


# ------------------------------------------------------------------- README


@pytest.mark.slow
def test_readme_example(tmp_path, monkeypatch, tiny_data, capsys):
    """Runs the planning guide's example block verbatim, with a tiny observer at ckpt/dragan. Its
    planner call compiles for 10–30 s on a CPU, silent but for one line that says so
    first."""
    from slotv_jax.training import checkpoint, types
    from slotv_jax.training import config as train_config
    from slotv_jax.training import trainer as train

    block = marked_block("docs/guides/planning.md", "planning-example", "python")
    cfg = train_config.quick("slotv", hidden=(16, 8), epochs=1, train_size=None)
    state, _ = train.train_trials(cfg, types.prepare(tiny_data["train"], "dragan"), [0],
                                  progress=False)  # fmt: skip
    monkeypatch.chdir(tmp_path)
    checkpoint.save(tmp_path / "ckpt" / "dragan", cfg, train.select_trial(state, 0))
    env: dict = {}
    capsys.readouterr()
    exec(compile(block, "docs/guides/planning.md", "exec"), env)
    res = env["result"]
    assert res.xyz.shape == (4, 100, 3) and bool(np.all(res.feasible))
    assert np.all(np.isfinite(env["y"]))
    note = "planning: compiling the straight lines and the planner for 4 problems"
    assert capsys.readouterr().err.count(note) == 1
    env["planner"](env["scenes"].goals, env["scenes"].goal_mask, env["target"])
    assert note not in capsys.readouterr().err  # compiled: no second note


# --------------------------------------------------------------- experiment


def test_experiment_problems_from_held_out_scenes(tiny_cfg, tiny_data):
    """Extended held-out scene sets start with the stored scenes; problems are every
    (scene, real goal) pair."""
    from slotv_jax.experiments import planning as exp

    scenes = data.held_out_scenes(tiny_cfg, tiny_data, 6, exp.SPLITS)
    for s in exp.SPLITS:
        goals, mask = scenes[s]
        k = tiny_cfg.n_new_scenes
        assert goals.shape == (6, 8, 3)
        np.testing.assert_array_equal(goals[:k], tiny_data[s].scene_goals)
        np.testing.assert_array_equal(mask[:k], tiny_data[s].scene_mask)
    p = exp.make_problems(scenes)
    n = sum(int(scenes[s][1].sum()) for s in exp.SPLITS)
    assert p["target"].shape == (n,)
    assert np.all(p["goal_mask"][np.arange(n), p["target"]])
    pairs = set(zip(p["split"].tolist(), p["scene"].tolist(), p["target"].tolist(), strict=True))
    assert len(pairs) == n  # no duplicates


def test_experiment_observers():
    """Each family gets SLOT-V and T-REX (the paper's networks), SLOT-V+ and T-REX+ (the
    same with the learned start term and time weights) and SLOT-V's loss with its own
    archetype; --no-plus and --no-archetypes leave those out."""
    from slotv_jax.experiments import planning as exp

    for preset in ("quick", "paper", "tiny"):
        cfg = exp.PRESETS[preset]()
        learned = cfg.learned()
        assert len(learned) == 10 and set(learned) == {
            (m, f) for m in exp.LEARNED for f in exp.FAMILIES
        }
        for family, model in exp.ARCHETYPES.items():
            tc = cfg.observer_config("archetype", family)
            assert tc.model == model and tc.method == "slotv"
        assert cfg.observer_config("trex", "dragan") is cfg.train["trex"]
        for plus, method in exp.PLUS.items():
            tc = cfg.observer_config(plus, "nikolaidis")
            assert tc.start_term and tc.time_weight and tc.method == method
            epochs = cfg.plus_epochs.get(plus, cfg.train[method].epochs)
            assert tc.epochs == epochs
            bare = dataclasses.replace(tc, start_term=False, time_weight=False, epochs=epochs)
            assert bare == dataclasses.replace(cfg.train[method], epochs=epochs)
            base = cfg.train[method]
            assert not base.start_term and not base.time_weight and base.activation == "relu"
        # the paper preset trains SLOT-V+ for 5 of the paper's 15 epochs (planning_paper.md)
        if preset == "paper":
            assert cfg.observer_config("slotv_plus", "dragan").epochs == 5
            assert cfg.observer_config("trex_plus", "dragan").epochs == cfg.train["trex"].epochs
        assert "archetype" in cfg.to_json() and cfg.to_json()["plus"] is True
    bare = dataclasses.replace(exp.quick(), archetype={}, plus=False)
    assert bare.learned() == [(m, f) for f in exp.FAMILIES for m in exp.METHODS]
    assert exp.observer_key("archetype", "nikolaidis") == "archetype/nikolaidis"
    assert exp.observer_key("slotv_plus", "dragan") == "slotv_plus/dragan"


# ------------------------------------------------------- planning for what people read early


def test_prefix_objective_by_hand():
    """A 5-point path between two goals: the prefix legibility is the mean over the stop
    times of log y_target of the float64 NumPy Dragan labeler on the points seen so far."""
    goals = np.zeros((8, 3))
    goals[:2] = [[0.5, 0.2, 0.025], [0.5, -0.2, 0.025]]
    mask = np.arange(8) < 2
    xyz = np.array([[0.31, 0.0, 0.49], [0.38, 0.02, 0.4], [0.43, 0.1, 0.3],
                    [0.47, 0.16, 0.15], [0.5, 0.2, 0.025]])  # fmt: skip
    taus = (0.3, 0.6, 1.0)  # t_i = 0, 1/4, 1/2, 3/4, 1: L = 2, 3, 5 points seen
    assert common.seen_points(taus, 5).tolist() == [2, 3, 5]
    obs = planning.labeler_observer("dragan", beta=10.0)
    for target in (0, 1):
        logs = [np.log(ref_labelers.dragan(xyz[:n], goals, mask, beta=10.0)[target])
                for n in (2, 3, 5)]  # fmt: skip
        cfg = planning.PlannerConfig(n_points=5, taus=taus)
        got = planning.legibility(obs, jnp.asarray(xyz, jnp.float32), goals, mask, target, cfg)
        assert float(got) == pytest.approx(np.mean(logs), abs=1e-6)
        # L = 2: the first point alone is exactly uniform (log 1/2), whatever the path
        assert logs[0] == pytest.approx(np.log(0.5), abs=1e-12)
        whole = planning.legibility(obs, xyz, goals, mask, target, planning.PlannerConfig(5))
        assert float(whole) == pytest.approx(logs[-1], abs=1e-6)


@pytest.mark.slow
def test_whole_motion_objective_unchanged(straight):
    """taus=None (the default) is log softmax(observer(ξ))[target], bit for bit; taus=(1,)
    scores the whole motion through the prefix (the same value up to rounding)."""
    assert planning.PlannerConfig().taus is None
    p = jax.tree.map(lambda a: a[3], straight)
    obs = planning.labeler_observer("dragan", beta=BETA)
    z = planning_planner._initial_z(p.q)
    xyz = planning_planner._fk(planning_planner._joints(z, p.q[0], p.q[-1]))
    cfg = planning.PlannerConfig()
    got = planning.objective(obs, p, z, cfg) + planning_planner._table_penalty(xyz, p, cfg)
    want = jax.nn.log_softmax(obs(xyz, p.goals, p.goal_mask))[p.target]
    np.testing.assert_array_equal(
        planning.legibility(obs, xyz, p.goals, p.goal_mask, p.target, cfg), want
    )
    assert float(got) == pytest.approx(float(want), abs=1e-6)
    one = planning.PlannerConfig(taus=(1.0,))
    full = planning.legibility(obs, xyz, p.goals, p.goal_mask, p.target, one)
    assert float(full) == pytest.approx(float(want), abs=1e-5)


def test_prefix_objective_bad_input():
    obs = planning.labeler_observer("dragan")
    for bad in ((), (0.0,), (1.5,), "0.5", (True,), (np.nan,)):
        with pytest.raises(ValueError, match=r"PlannerConfig\.taus"):
            planning.PlannerConfig(taus=bad)
    assert planning.PlannerConfig(taus=[0.5, 1]).taus == (0.5, 1.0)  # a list becomes a tuple
    cfg = planning.PlannerConfig(iters=1, taus=(0.5, 1.0))

    def plain(xyz, goals, goal_mask):  # an observer that scores whole motions only
        return obs(xyz, goals, goal_mask)

    with pytest.raises(ValueError, match=r"observer 'plain'.*\.prefix.*'plain' has none"):
        planning.make_planner({"plain": plain}, cfg)
    with pytest.raises(ValueError, match="prefix"):
        planning.make_family_planner(lambda b: plain, 1.0, cfg)
    planning.make_planner({"plain": plain}, dataclasses.replace(cfg, taus=None))  # fine


@pytest.mark.slow
def test_family_planner_compiles_once_and_plans_each_parameter_set(straight):
    """Observers built from traced parameters inside one compiled program: the plans equal
    those of each observer planned alone, and new values do not recompile. Two families
    reading one parameter pytree share that program (``family=``, a switch): each plan,
    the first family's and the last's by name, is its own family's (the plans of the one
    equal its observers planned alone, the objective of the other is its legibility)."""
    cfg = planning.PlannerConfig(iters=3, taus=(0.4, 0.7, 1.0))
    traces = []

    def build(p):
        traces.append(1)
        return planning.labeler_observer("dragan", beta=p[0])

    def nikolaidis(p):
        return planning.labeler_observer("nikolaidis", beta=p[1])

    fam = planning.make_family_planner({"dragan": build, "nik": nikolaidis}, jnp.ones(2), cfg)
    assert fam.families == ("dragan", "nik")
    few = jax.tree.map(lambda a: a[:2], straight)
    params = jnp.array([[5.0, 7.5], [20.0, 30.0]], jnp.float32)
    res = jax.device_get(fam.plan_problems(params, few, family="dragan"))
    assert res.xyz.shape == (2, 2, cfg.n_points, 3)
    n = len(traces)
    fam.plan_problems(params * 1.5, few)
    nik = jax.device_get(fam.plan_problems(params, few, family="nik"))
    assert len(traces) == n  # other values, another family: the same compiled program
    # every family by its name, the first and the last (a switch clamps an index past the
    # last back to it, so only the first shows an index one too high): the default is the
    # first family, and the two families' plans differ
    default = jax.device_get(fam.plan_problems(params, few))
    np.testing.assert_array_equal(default.xyz, res.xyz)
    assert np.abs(nik.xyz - res.xyz).max() > 1e-3
    with pytest.raises(ValueError, match=r"family: expected one of \['dragan', 'nik'\], got 'x'"):
        fam.plan_problems(params, few, family="x")
    with pytest.raises(ValueError, match=r"build 'nik': expected a function"):
        planning.make_family_planner({"dragan": build, "nik": 3}, jnp.ones(2), cfg)
    # each observer planned alone (planning.plan; one program for both temperatures)
    alone = jax.jit(
        jax.vmap(
            lambda p, b: planning.plan(planning.labeler_observer("dragan", beta=b), p, cfg),
            in_axes=(0, None),
        )
    )
    for f, (beta, beta_n) in enumerate([(5.0, 7.5), (20.0, 30.0)]):
        obs = planning.labeler_observer("dragan", beta=beta)
        obs_n = planning.labeler_observer("nikolaidis", beta=beta_n)
        one = alone(few, jnp.float32(beta))
        np.testing.assert_allclose(res.xyz[f], one.xyz, atol=1e-5)
        np.testing.assert_allclose(res.diagnostics.objective[f], one.diagnostics.objective,
                                   atol=1e-5)  # fmt: skip
        # the prefix objective of the plan, recomputed: at least the straight line's; the
        # other family's plan reports its own family's legibility
        for b in range(2):
            p = jax.tree.map(lambda a, b=b: a[b], few)
            val = planning.legibility(obs, res.xyz[f, b], p.goals, p.goal_mask, p.target, cfg)
            assert float(val) >= float(res.diagnostics.objective_straight[f, b]) - 1e-6
            val_n = planning.legibility(obs_n, nik.xyz[f, b], p.goals, p.goal_mask, p.target,
                                        cfg)  # fmt: skip
            iterates = np.asarray(nik.diagnostics.objective[f, b])  # the plan is one of them
            assert np.abs(iterates - float(val_n)).min() < 1e-4, (float(val_n), iterates)
            assert float(val_n) >= float(nik.diagnostics.objective_straight[f, b]) - 1e-6


# Plans the population's quadrature as the family planner's one parameter set (the people
# loop's oracle) and as make_planner's closed-over constant, and saves both (a subprocess:
# jaxlib 0.10.2 segfaulted on the first here, see make_family_planner's plan_grid).
ONE_SET_POPULATION = textwrap.dedent("""
    import sys
    import jax, numpy as np
    from slotv_jax import planning, scene
    from slotv_jax.observers import population

    cfg = planning.PlannerConfig(n_points=20, iters=3, taus=(0.5, 1.0))
    quad = population.quadrature(population.default())
    scenes = [scene.sample_scene(jax.random.key(i), 3) for i in range(3)]
    goals = np.stack([np.asarray(s.goals) for s in scenes])
    mask = np.stack([np.asarray(s.goal_mask) for s in scenes])
    straight = planning.straight_lines(goals, mask, np.zeros(3, np.int32), cfg=cfg)
    fam = planning.make_family_planner(population.quadrature_observer, quad, cfg)
    one = fam.plan_problems(jax.tree.map(lambda a: a[None], quad), straight)
    direct = planning.make_planner(population.quadrature_observer(quad), cfg)
    ref = direct.plan_problems(straight)
    np.savez(sys.argv[1], xyz=one.xyz, q=one.q, best=one.diagnostics.best_iter,
             ref_xyz=ref.xyz, ref_q=ref.q, ref_best=ref.diagnostics.best_iter,
             straight=straight.xyz)
""")


@pytest.mark.slow
def test_family_planner_plans_one_population_parameter_set_as_its_constant(tmp_path):
    """The people loop's oracle: the population's quadrature as the one parameter set of a
    family planner (leading axis 1) plans as make_planner with the quadrature closed over,
    to float32 rounding. On jaxlib 0.10.2 (CPU, AMD EPYC with AVX2) the vmap over the one
    set crashed the process with a segfault in a YNNPACK reduce fusion; the planner now
    plans a single set without that vmap."""
    out = tmp_path / "plans.npz"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    r = subprocess.run([sys.executable, "-c", ONE_SET_POPULATION, str(out)], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert r.returncode == 0, f"exit status {r.returncode} (-11: segfault): {r.stderr[-2000:]}"
    res = np.load(out)
    assert res["xyz"].shape == (1, 3, 20, 3)
    np.testing.assert_array_equal(res["best"][0], res["ref_best"])
    np.testing.assert_allclose(res["xyz"][0], res["ref_xyz"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(res["q"][0], res["ref_q"], rtol=0, atol=1e-6)
    assert np.abs(res["ref_xyz"] - res["straight"]).max() > 1e-2  # the plans moved
