"""Trajectories: path construction, arc-length resampling, IK and executed path (SPEC §3)."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from slotv_jax import kinematics as K
from slotv_jax import trajectories as T

MAX_RESIDUAL = 2e-3  # m, SPEC §3 rejection threshold
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


def test_plan_path_structure(tiny_data):
    scene_goals = tiny_data["train"].scene_goals
    scene_mask = tiny_data["train"].scene_mask
    from slotv_jax.scene import Scene

    s = Scene(
        goals=jnp.asarray(scene_goals[0]),
        goal_mask=jnp.asarray(scene_mask[0]),
        n_goals=jnp.int32(scene_mask[0].sum()),
    )
    plan = jax.jit(jax.vmap(lambda k: T.plan_path(k, s)))
    target, n_via, way, path = jax.tree.map(
        np.asarray, plan(jax.random.split(jax.random.key(0), 512))
    )
    assert path.shape == (512, 100, 3)
    assert set(np.unique(n_via)) == {3, 4, 5}
    assert set(np.unique(target)) == set(range(int(scene_mask[0].sum())))
    np.testing.assert_allclose(path[:, 0], np.broadcast_to(K.home_tcp(), (512, 3)), atol=1e-6)
    np.testing.assert_allclose(path[:, -1], scene_goals[0][target], atol=1e-6)
    assert max(_spacing_spread(path[i], way[i]) for i in range(0, 512, 8)) < SPACING_SPREAD


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


def test_sample_trajectory_deterministic_and_tool_down(tiny_data):
    from slotv_jax.scene import Scene

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
