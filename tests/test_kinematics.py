"""MJX kinematics and IK against MuJoCo C and an independent float64 DH product.

References: ``mujoco.mj_kinematics`` on the same MJCF (float64), and
``ref_kinematics``, a NumPy product of :ref:`concepts-robot`'s modified DH table. Batches go
through ``jit(vmap(...))`` once per function; the compiled functions count
their traces, so the tests can check that repeated calls do not retrace.
"""

from __future__ import annotations

import collections
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import ref_kinematics as ref
from compile_log import backend_compiles

from slotv_jax.robot import kinematics as K

SEED = 20261121
N_CONFIGS = 1000  # random in-limit configurations for FK
N_JAC = 64  # configurations for the Jacobian checks
N_TARGETS = 1000  # random IK targets per region
N_NEAR_HOME = 500  # IK targets that are FK of in-limit configurations near Q_HOME
N_PATHS = 48  # :ref:`concepts-trajectories` polylines (plus N_LINES straight lines) for path IK
N_LINES = 16
N_POINTS = 100  # points per path, equally spaced by arc length

FK_TOL = 1e-5  # m: MJX (float32) vs MuJoCo C / DH (float64), :ref:`concepts-robot`
ROT_TOL = 1e-5  # rotation-matrix entries; float32 rounding through 8 bodies is ~1e-6
CHECK_TOL = 5e-5  # m: half a unit in the 4th decimal of :ref:`concepts-robot`'s check values
DOWN_TOL = 1e-5  # rad: "straight down" at Q_HOME, up to float32 rounding
JAC_AD_TOL = 1e-5  # geometric Jacobian vs jacfwd, both float32 (entries are O(1))
JAC_FD_TOL = 1e-5  # geometric Jacobian (float32) vs float64 central differences of DH
IK_TOL = 1e-3  # m: worst acceptable IK position residual (issue 2)
LIMIT_TOL = 1e-6  # rad: float32 rounding of the joint limits
HOME_TOL = 1e-5  # rad: path IK at TCP(Q_HOME) must stay at Q_HOME
# rad/m: largest joint change between neighbouring path points per metre of path. Smooth tracking
# stays under ~5 here; a branch switch moves a joint by ~1 rad within one 1–4 cm step.
MAX_JOINT_RATE = 10.0

BOX_LO, BOX_HI = np.array([0.25, -0.50, 0.10]), np.array([0.70, 0.50, 0.40])  # via points
CUBE_LO, CUBE_HI = np.array([0.30, -0.45]), np.array([0.70, 0.45])  # cube centres, z = 0.025
CUBE_Z = 0.025
WORKSPACE_LO, WORKSPACE_HI = np.array([0.25, -0.50, CUBE_Z]), np.array([0.70, 0.50, 0.40])
SPEC_Q_HOME = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])

TRACES: collections.Counter[str] = collections.Counter()


# --------------------------------------------------------------------------- compiled batches


@jax.jit
def fk_batch(qs):
    TRACES["fk"] += 1
    return jax.vmap(K.tcp_pose)(qs)


# IK and Jacobian batches use lax.map, which compiles the unbatched MJX graph: 25–40% less
# compile time than vmap here, for the same results; FK keeps the documented jit(vmap(...)).


@jax.jit
def jacobian_batch(qs):
    TRACES["jac"] += 1

    def one(q):
        def pos_and_axis(q):
            s = K.tcp_state(q)
            return jnp.concatenate([s.pos, s.rot[:, 2]]), s

        ad, s = jax.jacfwd(pos_and_axis, has_aux=True)(q)
        return s.jac_pos, s.jac_axis, ad[:3], ad[3:]

    return jax.lax.map(one, qs)


def _cold_ik(cfg: K.IKConfig, name: str):
    @jax.jit
    def solve(targets):
        TRACES[name] += 1
        q0 = jnp.asarray(K.Q_HOME, targets.dtype)
        return jax.lax.map(lambda t: K.solve_ik(t, q0, cfg), targets)

    return solve


NO_SOFT = K.IKConfig(tool_down_gain=0.0, posture_gain=0.0)
cold_ik = _cold_ik(K.IKConfig(), "ik")
cold_ik_no_soft = _cold_ik(NO_SOFT, "ik_no_soft")


@jax.jit
def path_ik(paths):
    TRACES["path_ik"] += 1
    return jax.lax.map(lambda p: K.solve_path_ik(p, K.Q_HOME, K.IKConfig()), paths)


# --------------------------------------------------------------------------- inputs


def random_configs(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(ref.Q_MIN, ref.Q_MAX, (n, 7))


def random_targets(rng: np.random.Generator) -> dict[str, np.ndarray]:
    box = rng.uniform(BOX_LO, BOX_HI, (N_TARGETS, 3))
    cube = np.column_stack(
        [rng.uniform(CUBE_LO, CUBE_HI, (N_TARGETS, 2)), np.full(N_TARGETS, CUBE_Z)]
    )
    # Reachable by construction; kept inside the task workspace (the bounding box of both
    # regions). Targets close to the base, with joint 4 on its limit, are tested below.
    q_near = np.clip(
        SPEC_Q_HOME + rng.normal(0.0, 0.5, (12 * N_NEAR_HOME, 7)), ref.Q_MIN, ref.Q_MAX
    )
    p_near = ref.tcp_positions(q_near)
    inside = np.all((p_near >= WORKSPACE_LO) & (p_near <= WORKSPACE_HI), axis=1)
    assert inside.sum() >= N_NEAR_HOME
    return {"box": box, "cube": cube, "near_home": p_near[inside][:N_NEAR_HOME]}


def resample(waypoints: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced by arc length along a polyline (float64)."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(waypoints, axis=0), axis=1))])
    u = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(u, s, waypoints[:, k]) for k in range(3)])


def random_paths(rng: np.random.Generator) -> np.ndarray:
    """:ref:`concepts-trajectories` polylines TCP(q_home) → 3–5 via points → cube goal, and straight
    lines."""
    start = ref.tcp_positions(SPEC_Q_HOME)
    paths = []
    for i in range(N_PATHS + N_LINES):
        goal = np.append(rng.uniform(CUBE_LO, CUBE_HI), CUBE_Z)
        via = rng.uniform(BOX_LO, BOX_HI, (rng.integers(3, 6), 3)) if i < N_PATHS else []
        paths.append(resample(np.vstack([start, *via, goal]), N_POINTS))
    return np.stack(paths)


def mujoco_c_poses(qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    model = mujoco.MjModel.from_xml_path(str(K.PANDA_XML))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tcp")
    pos, rot = np.zeros((len(qs), 3)), np.zeros((len(qs), 3, 3))
    for i, q in enumerate(qs):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        pos[i], rot[i] = data.site_xpos[site], data.site_xmat[site].reshape(3, 3)
    return pos, rot


# --------------------------------------------------------------------------- fixtures


def fk_inputs(rng: np.random.Generator) -> np.ndarray:
    """:ref:`concepts-robot`'s two check configurations, then N_CONFIGS random in-limit ones."""
    return np.vstack([SPEC_Q_HOME, np.zeros(7), random_configs(rng, N_CONFIGS)])


@pytest.fixture(scope="module")
def fk():
    """(q, pos, rot) of the random in-limit configurations, and the same for the check rows."""
    qs = fk_inputs(np.random.default_rng(SEED))
    pos, rot = (np.asarray(a, np.float64) for a in fk_batch(jnp.asarray(qs, jnp.float32)))
    return (qs[2:], pos[2:], rot[2:]), (qs[:2], pos[:2], rot[:2])


@pytest.fixture(scope="module")
def targets():
    return random_targets(np.random.default_rng(SEED + 1))


@pytest.fixture(scope="module")
def cold(targets):
    """Cold-start IK from Q_HOME of every target, with and without the soft terms.

    Returns ``{solver: {region: (targets, q, residual)}}``.
    """
    goals = np.concatenate(list(targets.values()))
    bounds = np.cumsum([0] + [len(v) for v in targets.values()])
    out = {}
    for solver, solve in (("soft", cold_ik), ("no_soft", cold_ik_no_soft)):
        q, res = (np.asarray(a, np.float64) for a in solve(jnp.asarray(goals, jnp.float32)))
        out[solver] = {
            region: (goals[a:b], q[a:b], res[a:b])
            for region, a, b in zip(targets, bounds[:-1], bounds[1:], strict=True)
        }
    return out


@pytest.fixture(scope="module")
def paths():
    p = random_paths(np.random.default_rng(SEED + 2))
    r = path_ik(jnp.asarray(p, jnp.float32))
    return p, np.asarray(r.q, np.float64), np.asarray(r.xyz, np.float64), np.asarray(r.residual)


# --------------------------------------------------------------------------- model facts


def test_constants_and_mjcf_match_spec_table():
    np.testing.assert_array_equal(K.Q_MIN, ref.Q_MIN)
    np.testing.assert_array_equal(K.Q_MAX, ref.Q_MAX)
    np.testing.assert_allclose(K.Q_HOME, SPEC_Q_HOME, rtol=0, atol=1e-15)
    model = mujoco.MjModel.from_xml_path(str(K.PANDA_XML))
    assert model.nq == 7 and model.njnt == 7
    np.testing.assert_allclose(model.jnt_range, np.column_stack([ref.Q_MIN, ref.Q_MAX]), atol=1e-12)
    assert np.all(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)


def test_reference_reproduces_spec_check_values():
    # The reference is only useful if it is right: :ref:`concepts-robot`'s printed values, in
    # float64.
    np.testing.assert_allclose(
        ref.tcp_positions(SPEC_Q_HOME), [0.3069, 0.0, 0.4869], atol=CHECK_TOL
    )
    np.testing.assert_allclose(
        ref.tcp_positions(np.zeros(7)), [0.0880, 0.0, 0.8226], atol=CHECK_TOL
    )
    np.testing.assert_allclose(ref.tcp_axes(SPEC_Q_HOME), [0.0, 0.0, -1.0], atol=1e-12)


def test_home_tcp_is_the_chain_s_and_the_dh_reference_s_and_compiles_nothing():
    """The home TCP (every trajectory's start) is MuJoCo C's, cast to float32: within one
    float32 ulp of the chain's (jitted) and of the float64 DH reference, posed without
    compiling anything."""
    K.home_tcp.cache_clear()
    with backend_compiles() as compiled:
        home = K.home_tcp()
    assert compiled == [] and home.dtype == np.float32 and home.shape == (3,)
    chain = np.asarray(jax.jit(K.tcp_position)(jnp.asarray(K.Q_HOME, jnp.float32)))
    np.testing.assert_allclose(home, chain, rtol=0, atol=1e-7)
    np.testing.assert_allclose(home, ref.tcp_positions(SPEC_Q_HOME), rtol=0, atol=1e-7)


# --------------------------------------------------------------------------- forward kinematics


def test_spec_check_values(fk):
    _, (_, pos, rot) = fk
    np.testing.assert_allclose(pos[0], [0.3069, 0.0, 0.4869], rtol=0, atol=CHECK_TOL)  # Q_HOME
    np.testing.assert_allclose(pos[1], [0.0880, 0.0, 0.8226], rtol=0, atol=CHECK_TOL)  # q = 0
    z = rot[0, :, 2]
    angle = np.arctan2(np.linalg.norm(z[:2]), -z[2])  # from straight down; exact near 0
    assert angle < DOWN_TOL, f"tool z axis at Q_HOME is {np.degrees(angle):.2g}° off straight down"


def test_fk_positions_match_mujoco_c_and_dh(fk):
    (qs, pos, _), _ = fk
    c_pos, _ = mujoco_c_poses(qs)
    dh_pos = ref.tcp_positions(qs)
    # The two float64 references agree with each other far below the tolerance.
    assert np.abs(c_pos - dh_pos).max() < 1e-9
    assert np.linalg.norm(pos - c_pos, axis=1).max() < FK_TOL
    assert np.linalg.norm(pos - dh_pos, axis=1).max() < FK_TOL


def test_fk_orientation_matches_mujoco_c_and_dh(fk):
    (qs, _, rot), _ = fk
    _, c_rot = mujoco_c_poses(qs)
    dh_rot = ref.tcp_transforms(qs)[:, :3, :3]
    assert np.abs(c_rot - dh_rot).max() < 1e-9
    np.testing.assert_allclose(rot, dh_rot, rtol=0, atol=ROT_TOL)
    # The tool z axis alone, as the IK's tool-down term sees it.
    assert np.linalg.norm(rot[:, :, 2] - dh_rot[:, :, 2], axis=1).max() < ROT_TOL


@pytest.mark.slow
def test_jacobians_match_autodiff_and_finite_differences():
    qs = np.vstack([SPEC_Q_HOME, random_configs(np.random.default_rng(SEED + 3), N_JAC - 1)])
    jac_pos, jac_axis, ad_pos, ad_axis = (
        np.asarray(a, np.float64) for a in jacobian_batch(jnp.asarray(qs, jnp.float32))
    )
    np.testing.assert_allclose(jac_pos, ad_pos, rtol=0, atol=JAC_AD_TOL)
    np.testing.assert_allclose(jac_axis, ad_axis, rtol=0, atol=JAC_AD_TOL)
    fd_pos, fd_axis = ref.finite_difference_jacobians(qs)
    np.testing.assert_allclose(jac_pos, fd_pos, rtol=0, atol=JAC_FD_TOL)
    np.testing.assert_allclose(jac_axis, fd_axis, rtol=0, atol=JAC_FD_TOL)


def test_fk_position_derivatives_are_the_jacobian():
    """fk_position's derivative is the geometric Jacobian (custom JVP), so reverse mode
    (what the planner uses) and the second derivative must match independent references:
    float64 central differences of Franka's DH table."""
    qs = random_configs(np.random.default_rng(SEED + 5), 8)

    @jax.jit
    def derivatives(qs):
        def one(q):
            rev = jax.jacrev(K.fk_position)(q)  # (3, 7): transposed JVP, J^T per output
            # ∂²p_x/∂q²: the JVP rule differentiated again (J through MJX)
            hess = jax.hessian(lambda q: K.fk_position(q)[0])(q)
            return rev, hess

        return jax.lax.map(one, qs)

    rev, hess = (np.asarray(a, np.float64) for a in derivatives(jnp.float32(qs)))
    fd_pos, _ = ref.finite_difference_jacobians(qs)
    np.testing.assert_allclose(rev, fd_pos, rtol=0, atol=JAC_FD_TOL)
    # The Hessian of x against float64 differences of the DH Jacobian's first row.
    eps = 1e-5
    fd_hess = np.stack(
        [
            (
                ref.finite_difference_jacobians(qs + eps * np.eye(7)[j])[0][:, 0]
                - ref.finite_difference_jacobians(qs - eps * np.eye(7)[j])[0][:, 0]
            )
            / (2 * eps)
            for j in range(7)
        ],
        axis=1,
    )
    np.testing.assert_allclose(hess, fd_hess, rtol=0, atol=1e-4)


# --------------------------------------------------------------------------- inverse kinematics


def assert_within_limits(q: np.ndarray) -> None:
    assert np.all(np.isfinite(q))
    assert np.all(q >= ref.Q_MIN - LIMIT_TOL), "a joint is below its lower limit"
    assert np.all(q <= ref.Q_MAX + LIMIT_TOL), "a joint is above its upper limit"


@pytest.mark.slow
@pytest.mark.parametrize("region", ["box", "cube", "near_home"])
def test_cold_ik_reaches_random_targets(cold, region):
    goal, q, res = cold["soft"][region]
    assert_within_limits(q)
    # The reported residual is honest: recompute it with the float64 DH product.
    dh_res = np.linalg.norm(ref.tcp_positions(q) - goal, axis=1)
    assert np.abs(res - dh_res).max() < FK_TOL
    assert dh_res.max() <= IK_TOL, f"worst {region} residual {dh_res.max() * 1e3:.3f} mm"


@pytest.mark.slow
def test_soft_terms_cost_no_position_accuracy(cold):
    def stack(solver):
        return (np.concatenate(a) for a in zip(*cold[solver].values(), strict=True))

    goals, q_soft, _ = stack("soft")
    _, q_plain, _ = stack("no_soft")
    assert_within_limits(q_plain)
    dh_soft = np.linalg.norm(ref.tcp_positions(q_soft) - goals, axis=1)
    dh_plain = np.linalg.norm(ref.tcp_positions(q_plain) - goals, axis=1)
    assert dh_plain.max() <= IK_TOL
    assert dh_soft.max() <= IK_TOL
    # Every target that the position-only solve reaches, the soft solve reaches too.
    assert not np.any((dh_plain <= IK_TOL) & (dh_soft > IK_TOL))
    # And the soft terms do act: the tool axis points further down on average.
    assert (
        -ref.tcp_transforms(q_soft)[:, 2, 2].mean() > -ref.tcp_transforms(q_plain)[:, 2, 2].mean()
    )


@pytest.mark.slow
def test_path_ik_is_accurate_and_continuous(paths):
    p, q, xyz, res = paths
    assert q.shape == (N_PATHS + N_LINES, N_POINTS, 7) and res.shape == (
        N_PATHS + N_LINES,
        N_POINTS,
    )
    assert_within_limits(q)
    dh_xyz = ref.tcp_positions(q.reshape(-1, 7)).reshape(xyz.shape)
    assert np.linalg.norm(xyz - dh_xyz, axis=-1).max() < FK_TOL  # xyz is FK(q)
    dh_res = np.linalg.norm(dh_xyz - p, axis=-1)
    assert np.abs(res - dh_res).max() < FK_TOL
    assert dh_res.max() <= IK_TOL, f"worst path residual {dh_res.max() * 1e3:.3f} mm"
    # Every path starts at TCP(Q_HOME), whose solution from Q_HOME is Q_HOME itself.
    assert np.abs(q[:, 0] - SPEC_Q_HOME).max() < HOME_TOL
    # Warm starting keeps the arm on one branch: joints move in proportion to the path.
    arc_step = np.linalg.norm(np.diff(p, axis=1), axis=-1).sum(-1) / (N_POINTS - 1)  # per path
    rate = np.abs(np.diff(q, axis=1)).max(axis=(1, 2)) / arc_step
    assert rate.max() <= MAX_JOINT_RATE, f"a joint moved {rate.max():.1f} rad per m of path"


def test_ik_chain_solves_each_target_from_the_last_with_its_own_counts():
    """solve_ik_chain: each target warm-started from the previous solution with its own
    iteration counts, a count of 0 passing the configuration on; as the separate solves
    (float32 rounding apart: another loop), and within reach by float64 DH."""
    rng = np.random.default_rng(SEED + 7)
    t = random_targets(rng)["cube"][:4].astype(np.float32)
    soft, total = np.array([6, 0, 2, 6]), np.array([10, 0, 3, 10])
    q = np.asarray(jax.jit(K.solve_ik_chain)(t, K.Q_HOME, soft, total))
    np.testing.assert_array_equal(q[1], q[0])  # no step: the first solution, bit for bit
    solve = jax.jit(K.solve_ik, static_argnums=2)
    q0 = np.asarray(solve(t[0], np.float32(K.Q_HOME), K.IKConfig())[0])
    q2 = np.asarray(solve(t[2], q[1], K.IKConfig(iters=2, refine_iters=1))[0])
    q3 = np.asarray(solve(t[3], q[2], K.IKConfig())[0])
    for got, want in ((q[0], q0), (q[2], q2), (q[3], q3)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
    assert_within_limits(q)
    res = np.linalg.norm(ref.tcp_positions(q.astype(np.float64)) - t, axis=-1)
    assert res[[0, 3]].max() <= IK_TOL, res


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("fn", [K.tcp_position, K.tcp_pose])
@pytest.mark.parametrize(
    "q, message",
    [
        (np.full(7, np.nan), "expected finite"),
        (np.r_[SPEC_Q_HOME[:6], np.inf], "expected finite"),
        (np.zeros(6), r"expected shape \(7,?\)"),
        (np.zeros((2, 7)), r"expected shape \(7,?\)"),
    ],
)
def test_fk_rejects_bad_q(fn, q, message):
    with pytest.raises(ValueError, match=rf"^q: {message}"):
        fn(q)


GOOD_PATH = np.linspace([0.3, 0.0, 0.4], [0.5, 0.1, 0.1], 10)


@pytest.mark.parametrize(
    "path, q0, name",
    [
        (np.where(np.arange(30).reshape(10, 3) == 7, np.nan, GOOD_PATH), SPEC_Q_HOME, "path"),
        (GOOD_PATH[:, :2], SPEC_Q_HOME, "path"),
        (GOOD_PATH[0], SPEC_Q_HOME, "path"),
        (GOOD_PATH, np.full(7, np.nan), "q0"),
        (GOOD_PATH, SPEC_Q_HOME[:6], "q0"),
        (GOOD_PATH, np.r_[SPEC_Q_HOME[:3], 0.0, SPEC_Q_HOME[4:]], "q0"),  # joint 4 max −0.0698
        (GOOD_PATH, np.r_[3.0, SPEC_Q_HOME[1:]], "q0"),  # joint 1 max 2.8973
    ],
)
def test_ik_inputs_rejected(path, q0, name):
    with pytest.raises(ValueError, match=rf"^{name}: "):
        K.check_ik_inputs(path, q0)


def test_ik_inputs_accepted():
    K.check_ik_inputs(GOOD_PATH, SPEC_Q_HOME)
    K.check_ik_inputs(GOOD_PATH, ref.Q_MIN)
    K.check_ik_inputs(GOOD_PATH, ref.Q_MAX)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"iters": -1}, "iters"),
        ({"refine_iters": -1}, "refine_iters"),
        ({"damping": 0.0}, "damping"),
        ({"max_step": -0.1}, "max_step"),
        ({"max_step": np.nan}, "max_step"),
        ({"tool_down_gain": -1.0}, "tool_down_gain"),
        ({"posture_gain": np.nan}, "posture_gain"),
    ],
)
def test_ik_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=rf"^IKConfig\.{field}: "):
        K.IKConfig(**kwargs)


# --------------------------------------------------------------------------- tracing


@pytest.mark.slow
def test_jitted_kinematics_trace_once(fk, cold, paths):
    rng = np.random.default_rng(SEED + 4)
    for _ in range(3):
        fk_batch(jnp.asarray(fk_inputs(rng), jnp.float32))
    path_ik(jnp.asarray(random_paths(rng), jnp.float32))
    assert TRACES["fk"] == 1
    assert TRACES["ik"] == 1
    assert TRACES["path_ik"] == 1


# --------------------------------------------- joint limits: the active set keeps IK exact


@pytest.mark.slow
def test_soft_terms_cost_no_accuracy_near_joint_limits():
    """Targets near the base put joint 4 on its limit; locking it keeps the soft terms harmless."""
    rng = np.random.default_rng(5)
    q = np.clip(K.Q_HOME + rng.normal(0.0, 0.3, (2000, 7)), ref.Q_MIN, ref.Q_MAX)
    goals = jnp.asarray(ref.tcp_positions(q), jnp.float32)  # reachable by construction
    long = {"iters": 30, "refine_iters": 30}
    soft = np.asarray(_cold_ik(K.IKConfig(**long), "ik_long")(goals)[1])
    plain = np.asarray(
        _cold_ik(K.IKConfig(**long, tool_down_gain=0, posture_gain=0), "p")(goals)[1]
    )
    lost = (plain <= IK_TOL) & (soft > IK_TOL)
    assert not lost.any(), f"{lost.sum()} targets lost to the soft terms"


@pytest.mark.slow
def test_cold_ik_reaches_a_target_near_the_base():
    q_true = np.array([-0.09, -0.65, -0.12, -3.07, -0.28, 1.52, 0.85])  # joint 4 near its limit
    target = jnp.asarray(ref.tcp_positions(q_true[None]), jnp.float32)
    q, res = cold_ik(target)
    assert float(res[0]) <= IK_TOL
    assert np.all(np.asarray(q) >= K.Q_MIN - 1e-6) and np.all(np.asarray(q) <= K.Q_MAX + 1e-6)


# ------------------------------------------------------- the chain against mjx.kinematics


def test_the_chain_is_the_pose_mjx_kinematics_computes():
    """tcp_state (the MJCF's frames multiplied along the chain) against one
    ``mjx.kinematics`` call on the same model (``mjx_tcp_state``): the same position,
    rotation, joint axes and anchors (so the same Jacobians), to float32 rounding."""
    qs = jnp.asarray(random_configs(np.random.default_rng(SEED + 11), 64), jnp.float32)
    chain = jax.jit(jax.vmap(K.tcp_state))(qs)
    mjx = jax.jit(jax.vmap(K.mjx_tcp_state))(qs)
    for name in K.TcpState._fields:
        a, b = np.asarray(getattr(chain, name)), np.asarray(getattr(mjx, name))
        assert a.dtype == np.float32 and a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=0, atol=2e-6, err_msg=name)


def test_the_chain_refuses_a_model_that_is_not_a_chain_of_hinges(tmp_path):
    """Another joint type, two joints on one body, or no TCP site: one line naming the file."""

    def mjcf(body: str) -> Path:  # a new name each (the models are cached by path)
        path = tmp_path / f"robot{len(list(tmp_path.iterdir()))}.xml"
        path.write_text(f"<mujoco><worldbody>{body}</worldbody></mujoco>")
        return path

    def links(joints):  # seven bodies in a chain, the last with the TCP site
        xml = ""
        for j in joints:
            xml += f'<body pos="0 0 0.1">{j}<geom size="0.01"/>'
        return xml + '<site name="tcp"/>' + "</body>" * len(joints)

    hinge = '<joint type="hinge" axis="0 0 1"/>'
    cases = {
        "is not a hinge": links([hinge] * 6 + ['<joint type="slide" axis="0 0 1"/>']),
        "expected at most one hinge": links([hinge] * 5 + [hinge * 2]),
        "expected a site named": links([hinge] * 7).replace('<site name="tcp"/>', ""),
    }
    for says, body in cases.items():
        path = mjcf(body)
        K._chain.cache_clear()
        with pytest.raises(ValueError, match=says) as e:
            K._chain(path)
        assert str(path) in str(e.value)
    K._chain.cache_clear()
