"""Franka Emika Panda kinematics from its MJCF.

Forward kinematics is the product of the MJCF's own frames along the chain from the world
to the TCP site (``franka_assets/panda.xml``, written from Franka's modified DH table,
:ref:`concepts-robot`): for each body, its offset and rotation in its parent
(``body_pos``, ``body_quat``), then its hinge's rotation about the joint's axis through the
joint's anchor (Rodrigues' formula), as MuJoCo's ``mj_kinematics`` composes them
(:func:`_chain`). It is the same pose as ``mjx.kinematics`` on the same model
(:func:`mjx_tcp_state`, the reference the tests and benchmarks compare with), from 210
traced operations instead of about 4,500: the general MJX pipeline (every joint type,
quaternions element by element) costs the planner's programs most of their tracing and
compilation time, which users wait for (``python -m slotv_jax.benchmarks.planning``,
``experiments/BENCHMARKS.md``). The TCP Jacobian is the geometric one built from the same
product's joint anchors and axes: for a hinge j with world axis w_j through anchor a_j,
``∂p/∂q_j = w_j × (p − a_j)`` and ``∂z/∂q_j = w_j × z`` for the tool axis z.

Inverse kinematics is damped least squares on the position task. A soft
tool-down preference and a pull towards ``Q_HOME`` act only in the null space of
the position task, and every solve ends with position-only iterations, so the
soft terms never cost position accuracy. Joint limits are an active set: a joint
on a limit that a step would push outwards is locked for that step, and every
iterate is clipped.

Everything here is a pure function of arrays; nothing is jitted. Batch with
``jax.vmap`` and compile with ``jax.jit`` at the call site:

>>> import jax, slotv_jax.kinematics as K
>>> K.tcp_position(K.Q_HOME)  # doctest: +SKIP
Array([0.3069, 0., 0.4869], dtype=float32)
>>> qs = jax.random.uniform(jax.random.key(0), (1000, 7), minval=K.Q_MIN, maxval=K.Q_MAX)
>>> jax.jit(jax.vmap(K.tcp_position))(qs).shape
(1000, 3)
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, Float, Int

from slotv_jax.core import validation

if TYPE_CHECKING:
    from mujoco import mjx


def _mjx():
    """``mujoco.mjx``, imported on first use: only the MJX reference (:func:`mjx_tcp_state`)
    and :func:`host_eval` need it, and importing it costs every process about a second."""
    with contextlib.redirect_stdout(io.StringIO()):
        # mujoco.mjx prints a notice when the optional warp backend is absent.
        from mujoco import mjx
    return mjx


def __getattr__(name: str):
    if name == "mjx":  # ``kinematics.mjx``, as before the import was deferred
        return _mjx()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: The robot's MJCF files, inside the package so that a wheel carries them: in the repository
#: ``slotv_jax/franka_assets`` is a link to the top-level ``franka_assets/``, their source.
ASSETS_DIR = Path(__file__).resolve().parents[1] / "franka_assets"
PANDA_XML = ASSETS_DIR / "panda.xml"
SCENE_XML = ASSETS_DIR / "scene.xml"
TCP_SITE = "tcp"

NQ = 7
Q_HOME = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])
Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
TOOL_DOWN = np.array([0.0, 0.0, -1.0])


@functools.cache
def mj_model(path: str | Path = PANDA_XML) -> mujoco.MjModel:
    """The compiled MuJoCo model (cached per path)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MJCF not found: {path}")
    return mujoco.MjModel.from_xml_path(str(path))


@functools.cache
def _mjx_panda() -> tuple[mjx.Model, mjx.Data, int]:
    mjx = _mjx()
    m = mj_model(PANDA_XML)
    with jax.ensure_compile_time_eval():  # concrete arrays even if first called under a trace
        mx = mjx.put_model(m)
        d0 = mjx.make_data(mx)
    return mx, d0, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)


class TcpState(NamedTuple):
    """TCP pose and its Jacobians at one configuration."""

    pos: Float[Array, "3"]  # TCP position, world frame (m)
    rot: Float[Array, "3 3"]  # world-from-tool rotation; column 2 is the tool z axis
    jac_pos: Float[Array, "3 7"]  # ∂pos/∂q (m/rad)
    jac_axis: Float[Array, "3 7"]  # ∂(tool z axis)/∂q (1/rad)


def _quat_mat(quat) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat, np.float64))
    return out.reshape(3, 3)


class _Link(NamedTuple):
    """One body of the chain: its frame in its parent's, and its hinge (or none)."""

    pos: np.ndarray  # (3,) body_pos
    rot: np.ndarray  # (3, 3) from body_quat
    joint: int | None  # its hinge's index in q (qpos address), or None
    axis: np.ndarray  # (3,) the hinge's axis, in the body's frame (unit)
    anchor: np.ndarray  # (3,) the hinge's anchor, in the body's frame


@functools.cache
def _chain(path: str | Path = PANDA_XML) -> tuple[tuple[_Link, ...], np.ndarray, np.ndarray]:
    """The MJCF's frames from the world to the TCP site, in float64: the links, and the
    site's offset and rotation in the last body. Refuses a model that is not a chain of
    NQ hinges (a body with two joints, another joint type, a joint off the TCP's chain)."""
    m = mj_model(path)
    if m.nq != NQ:
        raise ValueError(f"{path}: expected {NQ} joints, got nq={m.nq}")
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)
    if site < 0:
        raise ValueError(f"{path}: expected a site named {TCP_SITE!r}")
    bodies, b = [], int(m.site_bodyid[site])
    while b != 0:
        bodies.append(b)
        b = int(m.body_parentid[b])
    links, used = [], []
    for b in reversed(bodies):
        n = int(m.body_jntnum[b])
        if n > 1:
            raise ValueError(f"{path}: body {b} has {n} joints; expected at most one hinge")
        joint, axis, anchor = None, np.zeros(3), np.zeros(3)
        if n == 1:
            j = int(m.body_jntadr[b])
            if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                raise ValueError(f"{path}: joint {j} is not a hinge")
            joint, axis, anchor = int(m.jnt_qposadr[j]), m.jnt_axis[j].copy(), m.jnt_pos[j].copy()
            used.append(joint)
        links.append(_Link(m.body_pos[b].copy(), _quat_mat(m.body_quat[b]), joint, axis, anchor))
    if sorted(used) != list(range(NQ)):
        raise ValueError(f"{path}: expected the {NQ} joints on the chain to the TCP site")
    return tuple(links), m.site_pos[site].copy(), _quat_mat(m.site_quat[site])


def _with_jacobians(pos, rot, axes: Float[Array, "7 3"], anchors: Float[Array, "7 3"]) -> TcpState:
    """The TCP's state from its pose and the hinges' world axes w_j and anchors a_j: the
    geometric Jacobians ∂p/∂q_j = w_j × (p − a_j), ∂z/∂q_j = w_j × z."""
    return TcpState(pos, rot, jnp.cross(axes, pos - anchors).T, jnp.cross(axes, rot[:, 2]).T)


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]ₓ, the matrix of v × ·."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def tcp_state(q: Float[Array, "7"]) -> TcpState:
    """TCP pose and Jacobians of ``q`` (rad), by the chain's frames (no validation).

    For each link, in order from the world: p ← p + R·b, R ← R·B (the body's offset b and
    rotation B in its parent); with a hinge of unit axis u through anchor c (body frame),
    the joint's world axis and anchor are w = R·u, a = p + R·c, then
    R ← R·(I + sin q [u]ₓ + (1 − cos q) [u]ₓ²) (Rodrigues) and p ← a − R·c (the rotation
    keeps the anchor in place). The TCP is p + R·s, its rotation R·S (the site's offset and
    rotation). This is MuJoCo's composition of the same frames (``mj_kinematics``; MuJoCo
    documentation, "Computation"), computed in ``q``'s dtype from float64 constants."""
    q = jnp.asarray(q)
    links, site_pos, site_rot = _chain()
    dt = q.dtype

    def c(x):
        return jnp.asarray(x, dt)

    def mm(a, b):  # full precision: a GPU's default float32 matmul may round to TF32
        return jnp.matmul(a, b, precision=jax.lax.Precision.HIGHEST)

    p, R = jnp.zeros(3, dt), jnp.eye(3, dtype=dt)
    axes, anchors = [None] * NQ, [None] * NQ
    for link in links:
        p, R = p + mm(R, c(link.pos)), mm(R, c(link.rot))
        if link.joint is not None:
            k = _skew(link.axis)
            a = p + mm(R, c(link.anchor))
            axes[link.joint], anchors[link.joint] = mm(R, c(link.axis)), a
            qj = q[link.joint]
            R = mm(R, c(np.eye(3)) + jnp.sin(qj) * c(k) + (1 - jnp.cos(qj)) * c(k @ k))
            p = a - mm(R, c(link.anchor))
    pos, rot = p + mm(R, c(site_pos)), mm(R, c(site_rot))
    return _with_jacobians(pos, rot, jnp.stack(axes), jnp.stack(anchors))


def mjx_tcp_state(q: Float[Array, "7"]) -> TcpState:
    """:func:`tcp_state` from one ``mjx.kinematics`` call on the same MJCF: the reference
    that the tests compare the chain with, and the benchmarks' baseline (no validation)."""
    mx, d0, site = _mjx_panda()
    d = _mjx().kinematics(mx, d0.replace(qpos=jnp.asarray(q, d0.qpos.dtype)))
    # d.xaxis, d.xanchor (7, 3): hinge axes and points, world frame
    return _with_jacobians(d.site_xpos[site], d.site_xmat[site].reshape(3, 3), d.xaxis, d.xanchor)


@jax.custom_jvp
def fk_position(q: Float[Array, "7"]) -> Float[Array, "3"]:
    """TCP position (m) of ``q`` (rad) from :func:`tcp_state` (no validation), whose
    derivative is the geometric Jacobian of the same product:

        d pos = J(q) dq,    J_j = w_j × (p − a_j)   (hinge j: world axis w_j through a_j),

    exact for the Panda's hinges (Siciliano et al., *Robotics: Modelling, Planning and
    Control*, 2009, §3.1.3; MuJoCo's ``mj_jacSite`` computes the same). So ``grad``/``vjp``
    of a path never differentiate through the chain's trigonometry: on the 2-core CPU a
    path's gradient compiled 1.3–1.7× and ran 1.1–2.2× faster than autodiff through the
    same product (``python -m slotv_jax.benchmarks.planning``, ``experiments/BENCHMARKS.md``).
    Higher derivatives differentiate J through the chain, so they stay exact too.
    """
    return tcp_state(q).pos


@fk_position.defjvp
def _fk_position_jvp(primals, tangents):
    (q,), (dq,) = primals, tangents
    s = tcp_state(q)
    return s.pos, s.jac_pos @ jnp.asarray(dq, s.jac_pos.dtype)


def _cpu():
    """The CPU device (the default device where JAX_PLATFORMS leaves the CPU out)."""
    try:
        return jax.devices("cpu")[0]
    except RuntimeError:
        return jax.devices()[0]


def host_eval(fn, model: mujoco.MjModel, *args):
    """``fn(mjx.put_model(model), *args)`` as one compiled call on the CPU, as NumPy arrays.

    For constants from MJX (the tests' MJX references). Evaluated op by op, MJX
    compiles every small operation separately, which takes about 10 s on a GPU; one
    compiled CPU call takes about a second, and gives the same constant on every machine.
    Works when first called under a trace (the result is concrete).
    """
    cpu, mjx = _cpu(), _mjx()
    with jax.ensure_compile_time_eval(), jax.default_device(cpu):
        mx = mjx.put_model(model, device=cpu)
        out = jax.jit(fn)(mx, *(jax.device_put(a, cpu) for a in args))
        return jax.tree.map(np.asarray, out)


@functools.cache
def home_tcp() -> np.ndarray:
    """TCP(Q_HOME) (m), as a constant (every trajectory starts here): MuJoCo C's
    ``mj_kinematics`` of the same MJCF in float64, then float32 (the same constant on every
    machine, concrete under a trace). Within one float32 ulp of :func:`tcp_state`; compiling
    that instead cost every process 0.4-1 s (``python -m slotv_jax.benchmarks.startup``)."""
    m = mj_model(PANDA_XML)
    d = mujoco.MjData(m)
    d.qpos[:NQ] = Q_HOME
    mujoco.mj_kinematics(m, d)
    return d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)].astype(np.float32)


@functools.cache
def reach() -> tuple[np.ndarray, float]:
    """A ball that holds every TCP position: its centre (3,) (m), joint 1's anchor (on the
    base, which never moves), and its radius (m), the links laid end to end from joint
    anchor to joint anchor and on to the TCP.

    Each two consecutive anchors (and the last one and the TCP) are fixed in one link, so
    their distance is the same in every configuration (MuJoCo C kinematics at ``Q_HOME``),
    and by the triangle inequality no configuration puts the TCP farther from the centre
    than their sum: a point farther than ``radius + r`` from it is missed by more than r
    whatever the joints (what the planner refuses, checked before anything compiles).
    """
    m = mj_model(PANDA_XML)
    d = mujoco.MjData(m)
    d.qpos[:] = Q_HOME
    mujoco.mj_kinematics(m, d)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)
    points = np.concatenate([d.xanchor, d.site_xpos[site][None]])  # (8, 3) along the chain
    return points[0].copy(), float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def _check_q(q) -> None:
    validation.check_array("q", q, (NQ,))


def tcp_position(q: Float[Array, "7"]) -> Float[Array, "3"]:
    """TCP position (m, world frame) of joint configuration ``q`` (rad), by :func:`tcp_state`.

    Example: ``tcp_position(Q_HOME) ≈ (0.3069, 0.0, 0.4869)``.
    """
    _check_q(q)
    return fk_position(q)


def tcp_pose(q: Float[Array, "7"]) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """TCP position (m) and world-from-tool rotation matrix of ``q`` (rad), by :func:`tcp_state`."""
    _check_q(q)
    s = tcp_state(q)
    return s.pos, s.rot


# --------------------------------------------------------------------------- IK


@dataclasses.dataclass(frozen=True)
class IKConfig:
    """Damped-least-squares IK settings."""

    iters: int = 6  # iterations with the null-space soft terms, per target
    refine_iters: int = 4  # position-only iterations that finish every solve
    damping: float = 1e-3  # λ (m) in (J Jᵀ + λ² I)⁻¹
    max_step: float = 0.4  # largest joint step per iteration (rad)
    tool_down_gain: float = 0.5  # null-space step towards the tool z axis pointing down
    posture_gain: float = 0.1  # null-space step towards Q_HOME

    def __post_init__(self):
        for f in ("iters", "refine_iters"):
            if int(getattr(self, f)) < 0:
                raise ValueError(f"IKConfig.{f}: expected >= 0, got {getattr(self, f)}")
        for f in ("damping", "max_step"):
            validation.check_positive(f"IKConfig.{f}", getattr(self, f))
        for f in ("tool_down_gain", "posture_gain"):
            if not getattr(self, f) >= 0:
                raise ValueError(f"IKConfig.{f}: expected >= 0, got {getattr(self, f)}")


def _solve_spd3(a: Float[Array, "3 3"], b: Float[Array, "3"]) -> Float[Array, "3"]:
    """Solve a 3×3 symmetric positive-definite system by the adjugate (vmap-friendly)."""
    c0 = jnp.cross(a[1], a[2])
    c1 = jnp.cross(a[2], a[0])
    c2 = jnp.cross(a[0], a[1])
    det = jnp.dot(a[0], c0)
    return (c0 * b[0] + c1 * b[1] + c2 * b[2]) / det


def _ik_step(
    q: Float[Array, "7"], target: Float[Array, "3"], cfg: IKConfig, soft
) -> Float[Array, "7"]:
    """One damped-least-squares step; ``soft`` (0 or 1, may be traced) adds the null-space terms.

    Joint limits are handled as an active set: a joint sitting at a limit that the
    descent direction pushes further out is locked (its Jacobian column and soft-term
    entry zeroed) and the step is solved with the other joints. Clipping alone would
    break the null-space property of the soft terms at a limit.
    """
    s = tcp_state(q)
    eye = jnp.eye(3, dtype=q.dtype)
    err = target - s.pos
    # Secondary objectives: tool axis towards straight down, posture towards Q_HOME.
    axis_err = s.rot[:, 2] - jnp.asarray(TOOL_DOWN, q.dtype)
    secondary = -cfg.tool_down_gain * (s.jac_axis.T @ axis_err)
    secondary = secondary + cfg.posture_gain * (jnp.asarray(Q_HOME, q.dtype) - q)

    def solve(free):  # free: (7,) 1 for joints that may move
        j = s.jac_pos * free
        jjt = j @ j.T + cfg.damping**2 * eye
        dq = j.T @ _solve_spd3(jjt, err)
        dq2 = free * secondary
        dq2 = dq2 - j.T @ _solve_spd3(jjt, j @ dq2)  # project onto the null space of j
        return dq + soft * dq2

    # Active set by the sign of the descent direction at the bound (the KKT rule for box
    # constraints): g = Jᵀ err is the steepest descent of ½‖err‖², plus the soft terms.
    lo, hi = jnp.asarray(Q_MIN, q.dtype), jnp.asarray(Q_MAX, q.dtype)
    g = s.jac_pos.T @ err + soft * secondary
    blocked = ((q <= lo + _AT_LIMIT) & (g < 0)) | ((q >= hi - _AT_LIMIT) & (g > 0))
    dq = solve(1 - blocked.astype(q.dtype))
    step = jnp.max(jnp.abs(dq))
    dq = dq * jnp.minimum(1.0, cfg.max_step / jnp.maximum(step, 1e-12))
    return jnp.clip(q + dq, lo, hi)


_AT_LIMIT = 1e-5  # rad: a joint this close to a limit counts as sitting on it


def _iterate(
    q: Float[Array, "7"], target: Float[Array, "3"], cfg: IKConfig, n_soft=None, n_total=None
) -> Float[Array, "7"]:
    """``n_total`` steps (default ``cfg.iters + cfg.refine_iters``), the first ``n_soft``
    (default ``cfg.iters``) with the soft terms; the counts may be traced."""
    n_soft = cfg.iters if n_soft is None else n_soft
    n_total = cfg.iters + cfg.refine_iters if n_total is None else n_total

    # One loop (one trace of the kinematics): soft iterations first, then position-only ones.
    def body(i, q):
        return _ik_step(q, target, cfg, (i < n_soft).astype(q.dtype))

    return jax.lax.fori_loop(0, n_total, body, q)


def solve_ik(
    target: Float[Array, "3"], q0: Float[Array, "7"], cfg: IKConfig = IKConfig()
) -> tuple[Float[Array, "7"], Float[Array, ""]]:
    """Joint configuration reaching ``target`` (m), started from ``q0`` (rad).

    Returns ``(q, residual)`` with ``residual = ‖tcp_position(q) − target‖`` (m).
    Pure; batch with ``vmap``. Joint limits hold exactly: a joint on a limit that the
    step would push outwards is locked for that step (an active set), and iterates are
    clipped.
    """
    validation.check_array("target", target, (3,))
    _check_q0(q0)
    q = _iterate(jnp.asarray(q0), target, cfg)
    return q, jnp.linalg.norm(tcp_state(q).pos - target)


class PathIK(NamedTuple):
    """Result of :func:`solve_path_ik`."""

    q: Float[Array, "T 7"]  # joint configurations (rad)
    xyz: Float[Array, "T 3"]  # executed TCP positions FK(q) (m)
    residual: Float[Array, " T"]  # ‖xyz − path‖ per point (m)


def solve_path_ik(
    path: Float[Array, "T 3"], q0: Float[Array, "7"] = Q_HOME, cfg: IKConfig = IKConfig()
) -> PathIK:
    """IK for every point of a path, warm-started along it from ``q0``.

    Each solve starts from the previous point's solution, so a few iterations
    per point suffice for densely sampled paths. Returns the joint configurations, the executed TCP
    positions and the per-point position residuals.
    """
    check_ik_inputs(path, q0)
    path = jnp.asarray(path)
    q0 = jnp.asarray(q0, path.dtype)

    def body(q, target):
        q = _iterate(q, target, cfg)
        return q, q

    _, qs = jax.lax.scan(body, q0, path)
    xyz = jax.vmap(lambda q: tcp_state(q).pos)(qs)
    return PathIK(qs, xyz, jnp.linalg.norm(xyz - path, axis=-1))


def solve_ik_chain(
    targets: Float[Array, "K 3"],
    q0: Float[Array, "7"],
    soft_iters: Int[Array, " K"],
    total_iters: Int[Array, " K"],
    cfg: IKConfig = IKConfig(),
) -> Float[Array, "K 7"]:
    """IK for targets in turn, each started from the previous solution (the first from
    ``q0``), target k with its own iteration counts: ``total_iters[k]`` damped-least-squares
    steps (:func:`solve_ik`'s), the first ``soft_iters[k]`` of them with the null-space
    terms. A count of 0 passes the previous configuration on unchanged. The counts may be
    traced; the steps take ``cfg``'s gains (its own counts are not used). Returns the
    configurations (K, 7). One loop, so the forward kinematics is traced and compiled once
    whatever the mix of solves (the planner's straight line: the start, the path and the goal
    in one chain). No validation (pure; batch with ``vmap``)."""
    targets = jnp.asarray(targets)
    q0 = jnp.asarray(q0, targets.dtype)

    def body(q, x):
        target, n_soft, n_total = x
        q = _iterate(q, target, cfg, n_soft, n_total)
        return q, q

    counts = (jnp.asarray(soft_iters, jnp.int32), jnp.asarray(total_iters, jnp.int32))
    return jax.lax.scan(body, q0, (targets, *counts))[1]


def check_ik_inputs(path, q0) -> None:
    """Boundary checks of the IK functions (values only when concrete, so jit/vmap work)."""
    validation.check_array("path", path, (None, 3))
    _check_q0(q0)


def _check_q0(q0) -> None:
    validation.check_array("q0", q0, (NQ,))
    if validation.is_concrete(q0):
        q = np.asarray(q0)
        if np.any(q < Q_MIN - 1e-9) or np.any(q > Q_MAX + 1e-9):
            raise ValueError("q0: expected joint values within the Panda's limits Q_MIN..Q_MAX")
