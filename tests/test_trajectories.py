"""Trajectories: path construction, arc-length resampling, IK and executed path
(:ref:`concepts-trajectories`)."""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from slotv_jax.robot import kinematics as K
from slotv_jax.world import trajectories as T

MAX_RESIDUAL = 2e-3  # m, :ref:`concepts-trajectories` rejection threshold
SPACING_SPREAD = 1e-3  # relative spread of arc-length spacing, issue 2


def _arc_coordinates(points: np.ndarray, waypoints: np.ndarray) -> np.ndarray:
    """Arc length along the polyline of each point, by projection onto its nearest segment."""
    w = waypoints.astype(np.float64)
    a, b = w[:-1], w[1:]
    seg = np.linalg.norm(b - a, axis=-1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.empty(len(points))
    for i, p in enumerate(points.astype(np.float64)):
        u = np.clip(np.einsum("kj,kj->k", p - a, b - a) / np.maximum(seg**2, 1e-300), 0, 1)
        dist = np.linalg.norm(a + u[:, None] * (b - a) - p, axis=-1)
        k = int(np.argmin(np.where(seg > 0, dist, np.inf)))
        assert dist[k] < 1e-5, "point not on the polyline"
        s[i] = cum[k] + u[k] * seg[k]
    return s


def _spacing_spread(points: np.ndarray, waypoints: np.ndarray) -> float:
    d = np.diff(_arc_coordinates(points, waypoints))
    return float((d.max() - d.min()) / d.mean())


def test_resample_polyline_equal_spacing_with_zero_length_segments():
    rng = np.random.default_rng(0)
    for _ in range(20):
        w = rng.uniform(-1, 1, (7, 3))
        w[3] = w[2]  # a zero-length segment
        w[5:] = w[4]  # collapsed tail, as unused via slots are
        p = np.asarray(T.resample_polyline(jnp.asarray(w, jnp.float32), 100))
        assert p.shape == (100, 3)
        np.testing.assert_allclose(p[0], w[0], atol=1e-6)
        np.testing.assert_allclose(p[-1], w[-1], atol=1e-6)
        assert _spacing_spread(p, w) < SPACING_SPREAD
        # Every sample lies on the polyline, and the samples run from arc length 0 to the end.
        total = np.linalg.norm(np.diff(w, axis=0), axis=-1).sum()
        s = _arc_coordinates(p, w)
        np.testing.assert_allclose(s[[0, -1]], [0.0, total], atol=1e-5)


def test_resample_polyline_hand_case():
    # An L-shaped path of total length 2: 5 points land at arc lengths 0, .5, 1, 1.5, 2.
    w = jnp.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    p = np.asarray(T.resample_polyline(w, 5))
    np.testing.assert_allclose(p, [[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [1, 0.5, 0], [1, 1, 0]])


def _scene(split, i=0):
    from slotv_jax.world.scene import Scene

    return Scene(
        goals=jnp.asarray(split.scene_goals[i]),
        goal_mask=jnp.asarray(split.scene_mask[i]),
        n_goals=jnp.int32(split.scene_mask[i].sum()),
    )


def _plans(scene, cfg, n=512, seed=0):
    plan = jax.jit(jax.vmap(lambda k: T.plan_path(k, scene, cfg)))
    return jax.tree.map(np.asarray, plan(jax.random.split(jax.random.key(seed), n)))


@pytest.mark.parametrize("counts", [(0,), (1,), (2,), (3,), (1, 2, 3), (3, 4, 5)])
def test_plan_path_structure(tiny_data, counts):
    """Every via count, 0 included: the counts drawn, targets, endpoints, equal arc spacing."""
    scene_goals = tiny_data["train"].scene_goals
    scene_mask = tiny_data["train"].scene_mask
    cfg = T.TrajectoryConfig(via_counts=counts)
    target, n_via, way, path = _plans(_scene(tiny_data["train"]), cfg)
    assert path.shape == (512, 100, 3)
    assert way.shape == (512, max(counts) + 2, 3)
    assert set(np.unique(n_via)) == set(counts)
    assert set(np.unique(target)) == set(range(int(scene_mask[0].sum())))
    np.testing.assert_allclose(path[:, 0], np.broadcast_to(K.home_tcp(), (512, 3)), atol=1e-6)
    np.testing.assert_allclose(path[:, -1], scene_goals[0][target], atol=1e-6)
    assert max(_spacing_spread(path[i], way[i]) for i in range(0, 512, 8)) < SPACING_SPREAD
    # Unused via slots collapse onto the goal; used ones lie in the via box.
    slot = np.arange(max(counts))[None, :]
    used = slot < n_via[:, None]
    via = way[:, 1:-1]
    goal = scene_goals[0][target]
    np.testing.assert_array_equal(via[~used], np.broadcast_to(goal[:, None], via.shape)[~used])
    assert np.all(via[used] >= np.asarray(cfg.via_low) - 1e-7)
    assert np.all(via[used] <= np.asarray(cfg.via_high) + 1e-7)
    if counts == (0,):  # straight from the start to the goal
        line = np.linspace(0, 1, 100)[None, :, None]
        start = np.asarray(K.home_tcp())[None, None]
        np.testing.assert_allclose(path, start + line * (goal[:, None] - start), atol=2e-6)


def test_default_and_named_distributions():
    assert T.TrajectoryConfig() == T.DISTRIBUTIONS["default"] == T.distribution("default")
    v1 = T.distribution("spec_v1")
    assert v1.via_counts == (3, 4, 5) and v1.timing == "arc_length"
    assert T.distribution("spec_v1", timing="segment").timing == "segment"
    with pytest.raises(ValueError, match="distribution"):
        T.distribution("paper_v0")


def test_resample_segments_hand_case():
    # Segments of length 1 and 3 get equal time: 5 points at u = 0, .5, 1, 1.5, 2.
    w = jnp.array([[0.0, 0, 0], [1, 0, 0], [1, 3, 0], [1, 3, 0]])  # last: a collapsed slot
    p = np.asarray(T.resample_segments(w, jnp.int32(2), 5))
    np.testing.assert_allclose(p, [[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [1, 1.5, 0], [1, 3, 0]])
    # One segment: equal spacing along the line, the same as arc length.
    q = np.asarray(T.resample_segments(w, jnp.int32(1), 3))
    np.testing.assert_allclose(q, [[0, 0, 0], [0.5, 0, 0], [1, 0, 0]])


@pytest.mark.parametrize("counts", [(1,), (3, 4, 5)])
def test_segment_timing_spends_equal_time_per_segment(tiny_data, counts):
    """Equal time per segment: each of the n_via + 1 segments holds 99 / (n_via + 1) steps,
    spaced evenly within the segment (checked against a float64 re-derivation)."""
    cfg = T.TrajectoryConfig(via_counts=counts, timing="segment")
    target, n_via, way, path = _plans(_scene(tiny_data["train"], 2), cfg, n=64, seed=3)
    for i in range(64):
        k = int(n_via[i]) + 1
        u = np.linspace(0.0, 1.0, 100) * k
        seg = np.minimum(np.floor(u).astype(int), k - 1)
        w = way[i].astype(np.float64)
        ref = w[seg] + (u - seg)[:, None] * (w[seg + 1] - w[seg])
        np.testing.assert_allclose(path[i], ref, atol=2e-6)
        np.testing.assert_allclose(path[i, 0], w[0], atol=1e-6)
        np.testing.assert_allclose(path[i, -1], w[k], atol=1e-6)
    # Same draws as arc-length timing: the timing changes only where the points sit.
    t2, n2, w2, _ = _plans(
        _scene(tiny_data["train"], 2), dataclasses.replace(cfg, timing="arc_length"), n=64, seed=3
    )
    np.testing.assert_array_equal(target, t2)
    np.testing.assert_array_equal(n_via, n2)
    np.testing.assert_array_equal(way, w2)


@pytest.mark.slow
def test_sample_trajectory_deterministic_with_new_options(tiny_data):
    """0 via points and equal time per segment (arc length: the test above)."""
    cfg = T.TrajectoryConfig(via_counts=(0, 2), timing="segment")
    f = jax.jit(jax.vmap(lambda k: T.sample_trajectory(k, _scene(tiny_data["train"], 1), cfg)))
    keys = jax.random.split(jax.random.key(9), 16)
    a, b = f(keys), f(keys)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.q, b.q)
    assert set(np.unique(np.asarray(a.n_via))) <= {0, 2}
    assert float(jnp.max(a.residual)) <= MAX_RESIDUAL


def test_dataset_trajectories_are_executed_paths(tiny_data):
    """xyz = FK(q) (recomputed with MuJoCo C), start at TCP(q_home), end at the target goal."""
    m = mujoco.MjModel.from_xml_path(str(K.PANDA_XML))
    d = mujoco.MjData(m)
    site = m.site("tcp").id
    for split in tiny_data.values():
        assert split.xyz.shape[1:] == (100, 3) and split.q.shape[1:] == (100, 7)
        assert np.all(split.q >= K.Q_MIN - 1e-6) and np.all(split.q <= K.Q_MAX + 1e-6)
        assert split.residual.max() <= MAX_RESIDUAL
        goal = split.goals[np.arange(len(split)), split.target]
        assert np.linalg.norm(split.xyz[:, 0] - K.home_tcp(), axis=-1).max() <= MAX_RESIDUAL
        assert np.linalg.norm(split.xyz[:, -1] - goal, axis=-1).max() <= MAX_RESIDUAL
        assert split.goal_mask[np.arange(len(split)), split.target].all()
    split = tiny_data["train"]
    for i in range(0, len(split), 37):
        for j in range(0, 100, 9):
            d.qpos[:] = split.q[i, j]
            mujoco.mj_kinematics(m, d)
            np.testing.assert_allclose(split.xyz[i, j], d.site_xpos[site], atol=1e-5)


@pytest.mark.slow
def test_sample_trajectory_deterministic_and_tool_down(tiny_data):
    from slotv_jax.world.scene import Scene

    s = Scene(
        goals=jnp.asarray(tiny_data["train"].scene_goals[1]),
        goal_mask=jnp.asarray(tiny_data["train"].scene_mask[1]),
        n_goals=jnp.int32(tiny_data["train"].scene_mask[1].sum()),
    )
    f = jax.jit(lambda k: T.sample_trajectory(k, s))
    a, b, c = f(jax.random.key(5)), f(jax.random.key(5)), f(jax.random.key(6))
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.q, b.q)
    assert not np.array_equal(a.xyz, c.xyz)
    assert float(a.residual) <= MAX_RESIDUAL
    # The soft null-space preference keeps the tool roughly pointing down.
    z = jax.vmap(lambda q: K.tcp_state(q).rot[:, 2])(a.q)
    assert float(jnp.min(-z[:, 2])) > 0.8


@pytest.mark.parametrize(
    "kw",
    [
        {"n_points": 1},
        {"via_counts": ()},
        {"via_counts": (1, -1)},
        {"via_counts": (1.5,)},
        {"timing": "equal_time"},
        {"via_low": (0.7, 0.0, 0.1), "via_high": (0.25, 0.5, 0.4)},
        {"max_residual": 0.0},
    ],
)
def test_trajectory_config_validation(kw):
    with pytest.raises(ValueError, match="TrajectoryConfig"):
        T.TrajectoryConfig(**kw)


def test_ik_entry_points_validate_their_input():
    bad_q0 = np.r_[K.Q_HOME[:3], 0.5, K.Q_HOME[4:]]  # joint 4 above its upper limit
    with pytest.raises(ValueError, match=r"^q0: "):
        K.solve_path_ik(np.full((2, 3), 0.4), bad_q0)
    with pytest.raises(ValueError, match=r"^path: expected finite"):
        K.solve_path_ik(np.array([[0.4, 0.0, np.nan]]), K.Q_HOME)
    with pytest.raises(ValueError, match=r"^q0: expected shape \(7"):
        K.solve_path_ik(np.full((2, 3), 0.4), K.Q_HOME[:6])
    with pytest.raises(ValueError, match=r"^target: expected finite"):
        K.solve_ik(np.array([0.4, np.inf, 0.2]), K.Q_HOME)
    # Traced inputs skip the value checks, so the functions still batch and compile.
    q, r = jax.jit(jax.vmap(lambda t: K.solve_ik(t, K.Q_HOME)))(jnp.full((2, 3), 0.4))
    assert q.shape == (2, 7) and float(r.max()) < 1e-3
