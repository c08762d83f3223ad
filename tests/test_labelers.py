"""Tests for slotv_jax.labelers: properties, an independent float64 reference, hand cases."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import ref_labelers as ref
from compile_log import backend_compiles

import slotv_jax  # noqa: F401  (applies the XLA CPU setting before JAX starts)
from slotv_jax.core.defaults import BETAS_V1
from slotv_jax.labelers import cli as labelers_cli
from slotv_jax.observers import labelers as L
from slotv_jax.observers import labelling
from slotv_jax.robot import kinematics
from slotv_jax.robot.kinematics import SCENE_XML
from slotv_jax.world import scene

REF_TOL = 1e-6  # agreement with the float64 reference (acceptance criterion)
SUM_TOL = 1e-6  # float32 labels sum to 1 over the real goals within this
CAM_TOL = 1e-6  # float32 camera pose against MuJoCo C (float64)
WORLD = ("dragan", "effdist", "fastapp")
ALL = L.LABELER_NAMES
OBSERVER = scene.camera("observer")
SIDE = scene.camera("observer_side")  # built here, not under enable_x64 (a float64 MJX model)


def call(name, xyz, goals, mask, cam=OBSERVER, **kw):
    if name == "nikolaidis":
        return L.nikolaidis(xyz, goals, mask, cam, **kw)
    return L.LABELERS[name](xyz, goals, mask, **kw)


@functools.cache
def _compiled(name):
    def f(xyz, goals, mask, cam, beta, t):
        return call(name, xyz, goals, mask, cam, beta=beta, t=t)

    return jax.jit(f)


def jcall(name, xyz, goals, mask, cam=OBSERVER, *, beta=None, t=None):
    """``call`` through one jitted function per labeler (fewer compiles than eager ops)."""
    beta = L.DEFAULT_BETAS[name] if beta is None else beta
    return _compiled(name)(xyz, goals, mask, cam, beta, t)


def ref_call(name, xyz, goals, mask, cam=OBSERVER, **kw):
    if name == "nikolaidis":
        pos = np.asarray(cam.pos, np.float64)
        rot = np.asarray(cam.rot, np.float64)
        return ref.nikolaidis(xyz, goals, mask, pos, rot, **kw)
    return getattr(ref, name)(xyz, goals, mask, **kw)


def random_case(rng, T=100, n_goals=None, contiguous=False):
    """A random trajectory in the workspace and 2..8 goals in random slots.

    Padded slots hold junk (far away, some behind the observer camera) that must be
    ignored.
    """
    n = int(rng.integers(2, 9)) if n_goals is None else n_goals
    xyz = rng.uniform([0.25, -0.5, 0.1], [0.7, 0.5, 0.4], (T, 3))
    slots = np.arange(n) if contiguous else rng.choice(8, n, replace=False)
    mask = np.zeros(8, bool)
    mask[slots] = True
    goals = rng.uniform(-5.0, 5.0, (8, 3))
    goals[slots, :2] = rng.uniform([0.3, -0.45], [0.7, 0.45], (n, 2))
    goals[slots, 2] = 0.025
    return xyz, goals, mask


def rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ------------------------------------------------------------------ properties


@pytest.mark.parametrize("name", ALL)
def test_probabilities_over_real_goals(name):
    rng = np.random.default_rng(0)
    for _ in range(5):
        xyz, goals, mask = random_case(rng)
        y = np.asarray(call(name, xyz, goals, mask))
        assert y.shape == (8,) and y.dtype == np.float32
        assert np.all(y >= 0)
        assert abs(y[mask].sum() - 1.0) < SUM_TOL
        assert np.all(y[~mask] == 0.0)  # exactly zero


@pytest.mark.parametrize("name", ALL)
def test_permutation_equivariance(name):
    rng = np.random.default_rng(1)
    for _ in range(4):
        xyz, goals, mask = random_case(rng)
        perm = rng.permutation(8)
        y = np.asarray(call(name, xyz, goals, mask))
        y_perm = np.asarray(call(name, xyz, goals[perm], mask[perm]))
        np.testing.assert_allclose(y_perm, y[perm], rtol=0, atol=1e-6)
        assert np.all(y_perm[~mask[perm]] == 0.0)


@pytest.mark.parametrize("name", WORLD)
def test_world_labelers_invariant_to_translation_and_rotation_about_z(name):
    rng = np.random.default_rng(2)
    with jax.enable_x64(True):
        for _ in range(3):
            xyz, goals, mask = random_case(rng)
            R, shift = rot_z(rng.uniform(-np.pi, np.pi)), rng.uniform(-2, 2, 3)
            y = np.asarray(jcall(name, xyz, goals, mask))
            y_moved = np.asarray(jcall(name, xyz @ R.T + shift, goals @ R.T + shift, mask))
            np.testing.assert_allclose(y_moved, y, rtol=0, atol=1e-12)


def test_nikolaidis_depends_on_viewpoint_but_moves_with_the_camera():
    rng = np.random.default_rng(3)
    xyz, goals, mask = random_case(rng, n_goals=4, contiguous=True)
    with jax.enable_x64(True):
        y = np.asarray(jcall("nikolaidis", xyz, goals, mask))
        y_side = np.asarray(jcall("nikolaidis", xyz, goals, mask, cam=SIDE))
        assert np.abs(y - y_side).max() > 1e-3  # a different viewpoint sees a different motion
        # Moving the whole scene, camera included, changes nothing.
        R, shift = rot_z(0.7), np.array([0.3, -1.0, 0.2])
        pos = np.asarray(OBSERVER.pos, np.float64)
        rot = np.asarray(OBSERVER.rot, np.float64)
        cam = OBSERVER.replace(pos=jnp.asarray(R @ pos + shift), rot=jnp.asarray(R @ rot))
        y_moved = np.asarray(jcall("nikolaidis", xyz @ R.T + shift, goals @ R.T + shift, mask, cam))
        y_same_cam = np.asarray(
            jcall("nikolaidis", xyz, goals, mask, OBSERVER.replace(pos=pos, rot=rot))
        )
        np.testing.assert_allclose(y_moved, y_same_cam, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ALL)
def test_vmap_equals_loop(name):
    rng = np.random.default_rng(4)
    cases = [random_case(rng) for _ in range(6)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    if name == "nikolaidis":
        batched = jax.vmap(lambda x, g, m: L.nikolaidis(x, g, m, OBSERVER))(xyz, goals, mask)
    else:
        batched = jax.vmap(L.LABELERS[name])(xyz, goals, mask)
    looped = np.stack([np.asarray(jcall(name, *c)) for c in cases])
    np.testing.assert_allclose(np.asarray(batched), looped, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ALL)
def test_compiled_labeler_traces_once(name):
    traces = 0

    def batch(xyz, goals, mask, beta):
        nonlocal traces
        traces += 1
        return jax.vmap(lambda x, g, m: call(name, x, g, m, beta=beta))(xyz, goals, mask)

    f = jax.jit(batch)
    rng = np.random.default_rng(5)
    for beta in (1.0, 5.0, 9.0):  # new values, same shapes: no retrace
        cases = [random_case(rng) for _ in range(4)]
        xyz, goals, mask = (np.stack(c).astype(np.float32) for c in zip(*cases, strict=True))
        y = f(xyz, goals, mask.astype(bool), jnp.float32(beta))
        np.testing.assert_allclose(np.asarray(y).sum(-1), 1.0, atol=SUM_TOL)
    assert traces == 1


@pytest.mark.parametrize("name", ALL)
def test_grad_is_finite(name):
    rng = np.random.default_rng(6)
    xyz, goals, mask = random_case(rng, n_goals=3, contiguous=True)
    xyz[-1] = goals[0]  # ends exactly on a goal: ‖p − g‖ = 0
    target = np.eye(8)[0]
    g = jax.jit(jax.grad(lambda x: jnp.sum(call(name, x, goals, mask) * target)))(xyz)
    assert g.shape == xyz.shape
    assert np.all(np.isfinite(np.asarray(g)))
    assert np.abs(np.asarray(g)).max() > 0


# ---------------------------------------------------- float64 reference agreement


@pytest.mark.parametrize("name", ALL)
def test_matches_float64_reference(name):
    rng = np.random.default_rng(7)
    with jax.enable_x64(True):
        for T, n in [(100, 2), (100, 3), (100, 5), (100, 6), (100, 8), (2, 4), (3, 7), (17, 8)]:
            xyz, goals, mask = random_case(rng, T=T, n_goals=n)
            beta = float(rng.uniform(1.0, 10.0))
            y = np.asarray(jcall(name, xyz, goals, mask, beta=beta))
            assert y.dtype == np.float64
            np.testing.assert_allclose(
                y, ref_call(name, xyz, goals, mask, beta=beta), rtol=0, atol=REF_TOL
            )


@pytest.mark.parametrize("name", ALL)
def test_matches_float64_reference_in_float32(name):
    rng = np.random.default_rng(8)
    for n in range(2, 9):
        xyz, goals, mask = random_case(rng, n_goals=n)
        beta = BETAS_V1[name]  # the first version's default, at which REF_TOL was set
        y = np.asarray(jcall(name, xyz, goals, mask, beta=beta))
        assert y.dtype == np.float32
        np.testing.assert_allclose(
            y, ref_call(name, xyz, goals, mask, beta=beta), rtol=0, atol=REF_TOL
        )


@pytest.mark.parametrize("name", ALL)
def test_time_stamps_match_reference(name):
    rng = np.random.default_rng(9)
    with jax.enable_x64(True):
        for T in (2, 17, 100):
            xyz, goals, mask = random_case(rng, T=T)
            t = np.cumsum(rng.uniform(0.1, 1.0, T)) + 3.0  # irregular, not starting at 0
            beta = BETAS_V1[name]
            y = np.asarray(jcall(name, xyz, goals, mask, t=t, beta=beta))
            np.testing.assert_allclose(
                y, ref_call(name, xyz, goals, mask, t=t, beta=beta), rtol=0, atol=REF_TOL
            )
            # Stamps are normalised: an affine change of clock changes nothing...
            y_clock = np.asarray(jcall(name, xyz, goals, mask, t=60.0 * t - 7.0, beta=beta))
            np.testing.assert_allclose(y_clock, y, rtol=0, atol=1e-12)
            # ...and uniform stamps give the default.
            t_uniform = np.linspace(0.0, 2.0, T)
            y_uniform = np.asarray(jcall(name, xyz, goals, mask, t=t_uniform, beta=beta))
            y_default = np.asarray(jcall(name, xyz, goals, mask, beta=beta))
            np.testing.assert_allclose(y_uniform, y_default, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ALL)
def test_clock_offsets_do_not_cost_float32_precision(name):
    # Unix-time stamps: 1.7e9 s is beyond float32's resolution of 1 s steps; the
    # stamps are normalised in float64 before the float32 computation.
    rng = np.random.default_rng(18)
    xyz, goals, mask = random_case(rng)
    t = 1.7e9 + 0.01 * np.arange(len(xyz))
    beta = BETAS_V1[name]  # the first version's default, at which the tolerance was set
    y = np.asarray(call(name, xyz, goals, mask, t=t, beta=beta))
    y_uniform = np.asarray(call(name, xyz, goals, mask, beta=beta))
    np.testing.assert_allclose(y, y_uniform, rtol=0, atol=1e-6)
    kw = {"labelers": (name,), f"beta_{name}": beta, "progress": False}
    y_bulk = labelling.label_all(xyz[None], goals, mask, t=t, **kw)[name]
    np.testing.assert_allclose(y_bulk[0], y, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ALL)
def test_extreme_beta_is_stable(name):
    rng = np.random.default_rng(10)
    xyz, goals, mask = random_case(rng)
    for beta in (1e-4, 1e4):
        y = np.asarray(jcall(name, xyz, goals, mask, beta=beta))
        assert np.all(np.isfinite(y)) and abs(y.sum() - 1.0) < SUM_TOL
        assert np.all(y[~mask] == 0.0)
    with jax.enable_x64(True):
        y = np.asarray(jcall(name, xyz, goals, mask, beta=1e3))
        np.testing.assert_allclose(
            y, ref_call(name, xyz, goals, mask, beta=1e3), rtol=0, atol=REF_TOL
        )


def test_dragan_equals_the_authors_formulation_with_beta_half_velocity():
    rng = np.random.default_rng(11)
    with jax.enable_x64(True):
        for velocity in (2.0, 10.0):
            xyz, goals, mask = random_case(rng, T=100)
            y = np.asarray(L.dragan(xyz, goals, mask, beta=velocity / 2))
            y_author = ref.dragan_author_form(xyz, goals, mask, velocity)
            np.testing.assert_allclose(y, y_author, rtol=0, atol=REF_TOL)


# -------------------------------------------------------------- hand-computed cases

LN3 = math.log(3.0)


def two_goals(g0, g1):
    goals = np.zeros((8, 3))
    goals[0], goals[1] = g0, g1
    return goals, np.arange(8) < 2


def test_dragan_symmetric_goals_give_one_half_each():
    # The path runs along the mirror plane y = 0 of the two goals: every P_k(i) = 1/2.
    goals, mask = two_goals([1.0, 0.5, 0.0], [1.0, -0.5, 0.0])
    xyz = np.stack([np.linspace(0.0, 0.9, 100), np.zeros(100), np.linspace(0.3, 0.1, 100)], -1)
    y = np.asarray(L.dragan(xyz, goals, mask))
    np.testing.assert_array_equal(y[:2], [0.5, 0.5])
    np.testing.assert_array_equal(y[2:], 0.0)


def test_dragan_hand_case_T3():
    # t = (0, 1/2, 1): trapezoid × (1 − t) weights (1/4, 1/4, 0) / (1/2), so
    # y = (P(0) + P(1)) / 2. P(0) is uniform; at p_1 the logits are β(1 − 1/2) and
    # β(1 − 3/2), so with β = ln 3, P_0(1) = 1 / (1 + e^−β) = 3/4 and y_0 = 5/8.
    goals, mask = two_goals([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0])
    xyz = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [-3.0, 2.0, 1.0]])  # last point: weight 0
    y = np.asarray(L.dragan(xyz, goals, mask, beta=LN3))
    np.testing.assert_allclose(y[:2], [5 / 8, 3 / 8], rtol=0, atol=1e-7)


def test_effdist_hand_case():
    # The path sits on goal 0 (mean distance 0); goal 1 is ln 3 m away: s = (0, −β ln 3),
    # so with β = 1, y = (3/4, 1/4).
    goals, mask = two_goals([0.5, 0.0, 0.0], [0.5, LN3, 0.0])
    xyz = np.tile(goals[0], (7, 1))
    y = np.asarray(L.effdist(xyz, goals, mask, beta=1.0))
    np.testing.assert_allclose(y[:2], [0.75, 0.25], rtol=0, atol=1e-7)
    # Mean of distances, not distance of the mean: half the points at each goal.
    xyz = np.concatenate([np.tile(goals[0], (5, 1)), np.tile(goals[1], (5, 1))])
    np.testing.assert_allclose(np.asarray(L.effdist(xyz, goals, mask))[:2], 0.5, atol=1e-7)


def test_fastapp_hand_case_T3():
    # t = (0, 1/2, 1): w = (1/2, 0) for i = 1, 2 and Δt = 1/2, so s_k = β (1/2) a_k(1) / (1/4).
    # a(1) = (1 − 3/4, 1 − 5/4) = (1/4, −1/4): s = (β/2, −β/2), y_0 = 1 / (1 + e^−β) = 3/4.
    goals, mask = two_goals([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0])
    xyz = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [-9.0, 4.0, 2.0]])  # last step: weight 0
    y = np.asarray(L.fastapp(xyz, goals, mask, beta=LN3))
    np.testing.assert_allclose(y[:2], [0.75, 0.25], rtol=0, atol=1e-7)


def test_fastapp_T2_uses_the_single_approach_speed():
    # T = 2: s_k = β (d_k(0) − d_k(1)) / Δt with Δt = 1. The step from the origin to
    # goal 0 at (ln 3, 0, 0) approaches it by ln 3; goal 1 is equidistant from both
    # points (no approach). s = (β ln 3, 0) with β = 1 gives y_0 = 3/4.
    goals, mask = two_goals([LN3, 0.0, 0.0], [LN3 / 2, 1.0, 0.0])
    xyz = np.array([[0.0, 0.0, 0.0], [LN3, 0.0, 0.0]])
    y = np.asarray(L.fastapp(xyz, goals, mask, beta=1.0))
    np.testing.assert_allclose(y[:2], [0.75, 0.25], rtol=0, atol=1e-7)


def test_nikolaidis_hand_case_T3():
    # A camera at the origin looking down −z: (u, v) = (x, y) / (−z). The projected
    # problem is the Dragan hand case: S → (0, 0), p_1 → (1/2, 0), goals → (±1, 0).
    cam = OBSERVER.replace(pos=jnp.zeros(3), rot=jnp.eye(3))
    goals, mask = two_goals([2.0, 0.0, -2.0], [-1.0, 0.0, -1.0])
    xyz = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, -2.0], [3.0, -1.0, -0.5]])
    y = np.asarray(L.nikolaidis(xyz, goals, mask, cam, beta=LN3))
    np.testing.assert_allclose(y[:2], [5 / 8, 3 / 8], rtol=0, atol=1e-7)
    # The same 3-D motion seen from the side (camera looking down −x): the goals
    # now project onto the mirror line of the path, and the answer changes.
    side = OBSERVER.replace(
        pos=jnp.array([5.0, 0.0, 0.0]), rot=jnp.array([[0, 0, 1], [1, 0, 0], [0, 1, 0.0]])
    )
    y_side = np.asarray(L.nikolaidis(xyz, goals, mask, side, beta=LN3))
    assert abs(y_side[0] - 5 / 8) > 1e-3


# --------------------------------------------------------------------- cameras


@pytest.fixture(scope="module")
def mj_cameras():
    """Camera poses from MuJoCo C: mj_kinematics then mj_camlight (float64)."""
    m = mujoco.MjModel.from_xml_path(str(SCENE_XML))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    mujoco.mj_camlight(m, d)
    return {
        m.camera(i).name: (d.cam_xpos[i].copy(), d.cam_xmat[i].reshape(3, 3).copy())
        for i in range(m.ncam)
    }


@pytest.mark.parametrize("name", ["observer", "observer_angle", "observer_side"])
def test_camera_matches_mujoco_c(name, mj_cameras):
    pos, xmat = mj_cameras[name]
    cam = scene.camera(name)
    np.testing.assert_allclose(np.asarray(cam.pos), pos, rtol=0, atol=CAM_TOL)
    np.testing.assert_allclose(np.asarray(cam.rot), xmat, rtol=0, atol=CAM_TOL)
    # A point on the optical axis (the camera's −z) projects to the image centre.
    for depth in (0.3, 1.15, 4.0):
        p = pos - depth * xmat[:, 2]
        uv_ref, depth_ref = ref.project(p, pos, xmat)
        assert abs(depth_ref - depth) < 1e-12
        np.testing.assert_allclose(uv_ref, 0.0, atol=1e-12)
        uv, d = scene.project(jnp.asarray(p, jnp.float32), cam)
        np.testing.assert_allclose(np.asarray(uv), 0.0, atol=1e-6)
        assert abs(float(d) - depth) < 1e-5
        uv_l, ok = L._image(jnp.asarray(p, jnp.float32), cam.pos, cam.rot, L.DEPTH_EPS)
        np.testing.assert_allclose(np.asarray(uv_l), 0.0, atol=1e-6)
        assert bool(ok)


def test_cameras_are_posed_and_checked_without_compiling_and_agree_with_mjx(mj_cameras):
    """Every named camera is posed by MuJoCo C, compiling nothing (posing them with MJX cost
    every process 7-13 s on a loaded 2-core CPU), and its pose is MJX's (``mjx.kinematics``
    + ``mjx.camlight``, an independent implementation) within float32 rounding."""
    scene._camera_cached.cache_clear()
    scene.camera_poses.cache_clear()
    with backend_compiles() as compiled:
        [scene.check_camera(n) for n in mj_cameras]
        cams = {n: scene.camera(n) for n in mj_cameras}
    assert compiled == []
    with pytest.raises(ValueError, match="no camera named 'ceiling'"):
        scene.check_camera("ceiling")
    mjx = kinematics.mjx

    def mjx_poses(mx):
        d = mjx.camlight(mx, mjx.kinematics(mx, mjx.make_data(mx)))
        return d.cam_xpos, d.cam_xmat

    m = kinematics.mj_model(SCENE_XML)
    pos, xmat = kinematics.host_eval(mjx_poses, m)
    for i in range(m.ncam):
        cam = cams[m.camera(i).name]
        np.testing.assert_allclose(np.asarray(cam.pos), pos[i], rtol=0, atol=CAM_TOL)
        np.testing.assert_allclose(np.asarray(cam.rot), xmat[i].reshape(3, 3), rtol=0, atol=CAM_TOL)


def test_labelling_bar_shows_before_the_camera_and_the_compilation(monkeypatch, tiny_data):
    """The labelling bar is up, saying that it compiles, while the camera is posed and the
    labelers compile (a silent 14 s on a loaded CPU before the main job's first labels);
    the note goes with the first chunk, and is not shown when nothing compiles."""
    made, seen = [], []

    class Bar:  # a tqdm that records what it was shown (post: the note now)
        def __init__(self, *a, total=None, **kw):
            self.n, self.post, self.notes = 0, "", []
            made.append(self)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def set_postfix_str(self, s, refresh=True):
            self.post = s
            self.notes.append(s)

        def update(self, n):
            self.n += n

    camera = labelling._as_camera

    def posed(c):  # what the bar said while the camera was posed
        seen.append(made[-1].post if made else None)
        return camera(c)

    monkeypatch.setattr(labelling, "tqdm", Bar)
    monkeypatch.setattr(labelling, "_as_camera", posed)
    split = tiny_data["trajectory_test"]
    args = (labelling.LabelConfig(), split.xyz[:3], split.goals[:3], split.goal_mask[:3])
    for compiled in (False, True):
        monkeypatch.setattr(labelling, "has_compiled", lambda fn, c=compiled: c)
        labelling.label_with(*args, progress=True)
    assert seen == ["compiling the labelers", ""]
    assert [b.notes for b in made] == [["compiling the labelers", ""], [""]]
    assert [b.n for b in made] == [3, 3]


def test_observer_camera_geometry_from_spec(mj_cameras):
    # :ref:`concepts-nikolaidis`: at (1.60, 0, 0.80), looking at (0.45, 0, 0.15); x right, y up.
    pos, xmat = mj_cameras["observer"]
    np.testing.assert_allclose(pos, [1.6, 0.0, 0.8], atol=1e-12)
    look = np.array([0.45, 0.0, 0.15]) - pos
    np.testing.assert_allclose(-xmat[:, 2], look / np.linalg.norm(look), atol=1e-9)
    assert abs(xmat[2, 0]) < 1e-12 and xmat[2, 1] > 0  # x horizontal, y up
    # Off-axis known point: the observer faces −x, so world +y is its image +x (right);
    # 0.2 m along +y from the look-at point projects to u = 0.2 / distance, v = 0.
    uv, depth = ref.project([0.45, 0.2, 0.15], pos, xmat)
    np.testing.assert_allclose(uv, [0.2 / np.linalg.norm(look), 0.0], atol=1e-12)
    assert abs(depth - np.linalg.norm(look)) < 1e-12
    uv32, _ = scene.project(jnp.array([0.45, 0.2, 0.15]), scene.camera())
    np.testing.assert_allclose(np.asarray(uv32), uv, atol=1e-6)


def test_nikolaidis_points_behind_the_camera():
    rng = np.random.default_rng(12)
    xyz, goals, mask = random_case(rng, n_goals=3, contiguous=True)
    pos, axis = np.asarray(OBSERVER.pos, np.float64), np.asarray(OBSERVER.rot[:, 2], np.float64)
    behind = xyz.copy()
    behind[40] = pos + 0.5 * axis  # on the camera's +z: behind it
    with pytest.raises(ValueError, match="xyz"):
        L.nikolaidis(behind, goals, mask, OBSERVER)
    on_plane = xyz.copy()
    on_plane[3] = pos + np.asarray(OBSERVER.rot[:, 0], np.float64)  # depth exactly 0
    with pytest.raises(ValueError, match="xyz"):
        L.nikolaidis(on_plane, goals, mask, OBSERVER)
    bad_goals = goals.copy()
    bad_goals[1] = pos + 0.1 * axis
    with pytest.raises(ValueError, match="goals"):
        L.nikolaidis(xyz, bad_goals, mask, OBSERVER)
    # A padded slot behind the camera is ignored.
    padded = goals.copy()
    padded[6] = pos + 0.1 * axis
    y = np.asarray(L.nikolaidis(xyz, padded, mask, OBSERVER))
    assert abs(y.sum() - 1.0) < SUM_TOL and y[6] == 0.0

    # Under jit the check cannot raise: the label is uniform over the real goals,
    # finite, with finite gradients; depth_ok flags it.
    f = jax.jit(lambda x: L.nikolaidis(x, goals, mask, OBSERVER))
    np.testing.assert_array_equal(np.asarray(f(behind)), np.float32([1 / 3] * 3 + [0.0] * 5))
    g = jax.grad(lambda x: f(x)[0])(jnp.asarray(behind, jnp.float32))
    assert np.all(np.isfinite(np.asarray(g)))
    assert not bool(jax.jit(L.depth_ok, static_argnums=3)(behind, goals, mask, "observer"))
    assert bool(L.depth_ok(xyz, goals, mask, OBSERVER))
    with pytest.raises(ValueError, match="xyz"):
        labelling.label_all(behind[None], goals, mask, progress=False)


def test_label_all_nikolaidis_checks_the_points_of_uniform_labels():
    # label_all reads bad points from the labels; a point behind the camera gives a
    # uniform label instead, and so may hide a NaN point: those rows are re-checked.
    rng = np.random.default_rng(23)
    cases = [random_case(rng, n_goals=3, contiguous=True) for _ in range(6)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    pos, axis = np.asarray(OBSERVER.pos, np.float64), np.asarray(OBSERVER.rot[:, 2], np.float64)

    def label(x, g=goals, m=mask):
        return labelling.label_all(x, g, m, chunk_size=4, labelers=("nikolaidis",), progress=False)

    behind = xyz.copy()
    behind[5, 40] = pos + 0.5 * axis  # in the second chunk
    with pytest.raises(ValueError, match=r"xyz: trajectory 5 has point\(s\) at camera depth"):
        label(behind)
    hidden = xyz.copy()
    hidden[2, 10, 0] = np.nan
    goal_behind = goals.copy()
    goal_behind[2, 1] = pos + 0.1 * axis  # makes trajectory 2's label uniform
    with pytest.raises(ValueError, match=r"xyz: expected finite.*trajectory 2\b"):
        label(hidden, goal_behind)
    with pytest.raises(ValueError, match=r"goals: trajectory 2 has real goal"):
        label(xyz, goal_behind)
    # A valid trajectory whose label is exactly uniform (one real goal) passes the recheck.
    one = mask.copy()
    one[3] = np.arange(8) < 1
    y = label(xyz, goals, one)
    np.testing.assert_array_equal(y["nikolaidis"][3], np.float32([1] + [0] * 7))
    # Under jit, a NaN point gives NaN labels, as with the other labelers.
    f = jax.jit(lambda x: L.nikolaidis(x, goals[0], mask[0], OBSERVER))
    assert np.all(np.isnan(np.asarray(f(hidden[2]))[:3]))


# ---------------------------------------------------------------- bad inputs


@pytest.mark.parametrize("name", ALL)
def test_bad_inputs_raise(name):
    rng = np.random.default_rng(13)
    xyz, goals, mask = random_case(rng, n_goals=3, contiguous=True)

    def raises(match, x=xyz, g=goals, m=mask, **kw):
        with pytest.raises(ValueError, match=match):
            call(name, x, g, m, **kw)

    nan_xyz = xyz.copy()
    nan_xyz[5, 1] = np.nan
    raises("xyz", x=nan_xyz)
    inf_goals = goals.copy()
    inf_goals[0, 0] = np.inf
    raises("goals", g=inf_goals)
    raises("xyz", x=xyz[:1])  # T < 2
    raises("xyz", x=xyz[:, :2])
    raises("xyz", x=xyz[None])
    raises("goals", g=np.concatenate([goals, goals[:1]]))  # 9 goals
    raises("goals", g=goals[:, :2])
    raises("goal_mask", m=mask[:7])
    raises("goal_mask", m=np.zeros(8, bool))  # no real goal
    dup = goals.copy()
    dup[1] = dup[0]
    raises("goals", g=dup)
    for beta in (0.0, -1.0, np.nan, np.inf):
        raises("beta", beta=beta)
    raises("^t", t=np.linspace(0, 1, len(xyz) - 1))
    raises("^t", t=np.linspace(1, 0, len(xyz)))
    t_nan = np.linspace(0, 1, len(xyz))
    t_nan[3] = np.nan
    raises("^t", t=t_nan)


@pytest.mark.parametrize("name", ALL)
def test_overflowing_coordinates_raise_naming_xyz(name):
    # Finite, but the float32 distances overflow: the labels would be NaN. Eager calls
    # of the public labeler and label_all both raise instead.
    rng = np.random.default_rng(24)
    xyz, goals, mask = random_case(rng, n_goals=3, contiguous=True)
    cam = OBSERVER.replace(pos=jnp.zeros(3), rot=jnp.eye(3))  # at 0, looking down −z
    xyz[:, 2] -= 1.0  # every point and goal at depth >= 0.6 m in front of cam
    goals[:, 2] = -1.0
    huge = xyz.copy()
    huge[:, 0] *= 1e30  # image plane too: u = x / depth ~ 1e30, and u² overflows
    assert np.all(np.isfinite(huge.astype(np.float32)))
    with pytest.raises(ValueError, match=r"^xyz: .*overflow"):
        call(name, huge, goals, mask, cam)
    with pytest.raises(ValueError, match=r"^xyz: .*trajectory 1\b"):
        labelling.label_all(
            np.stack([xyz, huge]), goals, mask, labelers=(name,), camera=cam, progress=False
        )
    # Under jit nothing can raise: the NaN shows there, as documented.
    assert not np.all(np.isfinite(np.asarray(jcall(name, huge, goals, mask, cam))))
    assert np.all(np.isfinite(np.asarray(call(name, xyz, goals, mask, cam))))


def test_label_all_bad_inputs_raise():
    rng = np.random.default_rng(14)
    cases = [random_case(rng, n_goals=3, contiguous=True) for _ in range(5)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))

    def raises(match, x=xyz, g=goals, m=mask, **kw):
        kw.setdefault("chunk_size", 2)
        with pytest.raises(ValueError, match=match):
            labelling.label_all(x, g, m, progress=False, **kw)

    bad = xyz.copy()
    bad[3, 7, 0] = np.nan
    raises("xyz.*trajectory 3", x=bad)
    bad_g = goals.copy()
    bad_g[4, 1] = np.inf
    raises("goals.*trajectory 4", g=bad_g)
    raises("goals", g=goals[:4])
    raises("goal_mask", m=np.zeros_like(mask))
    raises("xyz", x=xyz[:, :1])
    raises("beta_fastapp", beta_fastapp=-1.0)
    raises("labelers", labelers=("dragan", "nope"))
    raises("^t", t=np.linspace(1, 0, xyz.shape[1]))
    raises("chunk_size", chunk_size=0)
    with pytest.raises(ValueError, match="camera"):
        scene.camera("nope")


@pytest.mark.parametrize("labelers", [(n,) for n in ALL] + [ALL])
def test_label_all_catches_every_non_finite_point(labelers):
    # NaN or ±inf in any coordinate of the first, a middle or the last point (the last
    # point has weight 0 in dragan and fastapp) must raise, never give NaN labels.
    rng = np.random.default_rng(22)
    cases = [random_case(rng, n_goals=4, contiguous=True) for _ in range(4)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    for value in (np.nan, np.inf, -np.inf):
        for point in (0, 37, xyz.shape[1] - 1):
            for coord in range(3):
                bad = xyz.copy()
                bad[2, point, coord] = value
                with pytest.raises(ValueError, match=r"xyz: expected finite.*trajectory 2\b"):
                    labelling.label_all(
                        bad, goals, mask, chunk_size=2, labelers=labelers, progress=False
                    )
    huge = xyz.copy()
    huge[1, 5, 0] = 3e19  # finite, but its squared distances overflow float32
    with pytest.raises(ValueError, match=r"xyz.*trajectory 1\b"):
        labelling.label_all(huge, goals, mask, chunk_size=2, labelers=labelers, progress=False)
    bad_goal = goals.copy()
    bad_goal[3, 1, 2] = np.nan  # a real goal
    with pytest.raises(ValueError, match=r"goals: expected finite.*trajectory 3\b"):
        labelling.label_all(xyz, bad_goal, mask, chunk_size=2, labelers=labelers, progress=False)


def test_label_all_reports_the_first_bad_trajectory_in_input_order():
    # Chunks of 2, bad trajectories of different kinds in different chunks: the error
    # names the first bad trajectory in input order.
    rng = np.random.default_rng(21)
    cases = [random_case(rng, n_goals=3, contiguous=True) for _ in range(24)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    xyz[21, 5, 2] = np.inf
    goals[13, 0] = np.nan
    xyz[9, 0, 0] = np.nan
    for labelers in (("effdist",), ("dragan", "nikolaidis")):
        with pytest.raises(ValueError, match=r"xyz.*trajectory 9\b"):
            labelling.label_all(xyz, goals, mask, chunk_size=2, labelers=labelers, progress=False)
    xyz[9, 0, 0] = 0.5
    with pytest.raises(ValueError, match=r"goals.*trajectory 13\b"):
        labelling.label_all(xyz, goals, mask, chunk_size=2, progress=False)


# ------------------------------------------------------------- bulk labelling


def test_label_all_matches_per_trajectory_labelers_and_compiles_once():
    rng = np.random.default_rng(15)
    N, chunk = 11, 4  # three chunks, the last one padded
    cases = [random_case(rng) for _ in range(N)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    before = labelling._TRACES["label_chunk"]
    y = labelling.label_all(xyz, goals, mask, chunk_size=chunk, progress=False)
    assert labelling._TRACES["label_chunk"] == before + 1  # one trace for all four chunks
    assert sorted(y) == sorted(ALL)
    for name in ALL:
        assert y[name].shape == (N, 8) and y[name].dtype == np.float32
        # Both paths are float32 with their own summation order (the bulk kernel fuses the
        # trajectories; on an AVX2 CPU the two differ by up to 1.4e-6 on FastApp, each
        # within REF_TOL of float64): each against the float64 reference, the acceptance
        # criterion, and so each other within twice it.
        beta = L.DEFAULT_BETAS[name]
        ref64 = np.stack([ref_call(name, *c, beta=beta) for c in cases])
        np.testing.assert_allclose(y[name], ref64, rtol=0, atol=REF_TOL)
        expect = np.stack([np.asarray(jcall(name, *c)) for c in cases])
        np.testing.assert_allclose(y[name], expect, rtol=0, atol=2 * REF_TOL)
        assert np.all(y[name][~mask] == 0.0)

    # New data, new betas, same shapes: no retrace.
    y2 = labelling.label_all(
        xyz[::-1],
        goals[::-1],
        mask[::-1],
        chunk_size=chunk,
        progress=False,
        beta_dragan=2.0,
        beta_nikolaidis=3.0,
        beta_effdist=4.0,
        beta_fastapp=6.0,
    )
    assert labelling._TRACES["label_chunk"] == before + 1
    np.testing.assert_allclose(
        y2["dragan"][0], np.asarray(L.dragan(xyz[-1], goals[-1], mask[-1], beta=2.0)), atol=1e-6
    )


def test_label_all_large_beta_and_far_goals():
    rng = np.random.default_rng(19)
    cases = [random_case(rng, contiguous=True) for _ in range(6)]
    xyz, goals, mask = (np.stack(c) for c in zip(*cases, strict=True))
    goals[4, 1] = [-2.0, 0.0, 0.025]  # a real goal far from the others, in the second chunk
    # Logits up to β · 2 · 2.6 m: beyond float32's exp range without a max shift.
    for beta in (30.0, 1e4):
        y = labelling.label_all(
            xyz,
            goals,
            mask,
            chunk_size=3,
            labelers=("dragan", "nikolaidis"),
            beta_dragan=beta,
            beta_nikolaidis=beta,
            progress=False,
        )
        for name in ("dragan", "nikolaidis"):
            assert np.all(np.isfinite(y[name])) and np.all(y[name][~mask] == 0.0)
            np.testing.assert_allclose(y[name].sum(-1), 1.0, atol=SUM_TOL)
            expect = [jcall(name, xyz[i], goals[i], mask[i], beta=beta) for i in range(6)]
            np.testing.assert_allclose(y[name], expect, rtol=0, atol=1e-6)


def test_label_all_shared_goals_time_stamps_and_subsets():
    rng = np.random.default_rng(16)
    xyz = np.stack([random_case(rng, T=12)[0] for _ in range(5)])
    _, goals, mask = random_case(rng, n_goals=4)
    t = np.cumsum(rng.uniform(0.1, 1.0, (5, 12)), axis=1)
    v1 = {"beta_fastapp": BETAS_V1["fastapp"], "beta_effdist": BETAS_V1["effdist"]}
    y = labelling.label_all(
        xyz, goals, mask, t=t, labelers=("fastapp", "effdist"), progress=False, **v1
    )
    assert sorted(y) == ["effdist", "fastapp"]
    for i in range(5):
        for name in ("fastapp", "effdist"):
            one = jcall(name, xyz[i], goals, mask, t=t[i], beta=BETAS_V1[name])
            np.testing.assert_allclose(y[name][i], np.asarray(one), atol=1e-6)
    empty = labelling.label_all(xyz[:0], goals, mask, progress=False)
    assert all(v.shape == (0, 8) for v in empty.values())


def test_command_line(tmp_path):
    rng = np.random.default_rng(17)
    xyz = np.stack([random_case(rng, T=20)[0] for _ in range(6)])
    _, goals, mask = random_case(rng, n_goals=3, contiguous=True)
    src, dst = tmp_path / "trajs.npz", tmp_path / "labels.npz"
    np.savez(src, xyz=xyz, goals=goals, goal_mask=mask)
    assert (
        labelers_cli.main(["--in", str(src), "--out", str(dst), "--quiet", "--beta-dragan", "2.5"])
        == 0
    )
    with np.load(dst, allow_pickle=False) as f:
        out = {k: f[k] for k in f.files}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labels.npz", "trajs.npz"]  # no temp left
    expect = labelling.label_all(xyz, goals, mask, progress=False, beta_dragan=2.5)
    for name in ALL:
        np.testing.assert_array_equal(out[f"y_{name}"], expect[name])
    assert float(out["beta_dragan"]) == 2.5
    assert float(out["beta_nikolaidis"]) == L.DEFAULT_BETAS["nikolaidis"]

    np.savez(src, xyz=xyz, goals=goals)  # no goal_mask
    with pytest.raises(SystemExit):
        labelers_cli.main(["--in", str(src), "--out", str(dst), "--quiet", "--overwrite"])
    with pytest.raises(SystemExit):  # no such file
        labelers_cli.main(["--in", str(tmp_path / "missing.npz"), "--out", str(dst), "--overwrite"])
    bad = xyz.copy()
    bad[0, 0, 0] = np.nan
    np.savez(src, xyz=bad, goals=goals, goal_mask=mask)
    with pytest.raises(SystemExit):
        labelers_cli.main(["--in", str(src), "--out", str(dst), "--quiet", "--overwrite"])
