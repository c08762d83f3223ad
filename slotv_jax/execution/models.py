"""The MuJoCo models the execution checks run on, built once from ``franka_assets/``.

All three come from the same MJCF as the rest of the project (the Panda of
:mod:`slotv_jax.robot.kinematics`, in the scene of :mod:`slotv_jax.world.scene`), changed
only in what each check needs, through ``mujoco.MjSpec``; the files stay as they are, so
kinematics and rendering are untouched.

- :func:`kinematic_model`: the Panda alone; :func:`tcp_poses` runs MuJoCo C's
  ``mj_kinematics`` over a batch of configurations (the C API: on a CPU a loop over it is
  faster than a compiled MJX batch, ``experiments/BENCHMARKS.md``).
- :func:`collision_model`: the scene with the Panda's collision shapes (class ``collision``
  of ``panda.xml``) in contact with each other, the two tables and the eight cubes, each
  contact reported up to :data:`CLEARANCE_HORIZON` apart (MuJoCo's contact margin), so the
  contact distance is the clearance. Excluded pairs, which touch by construction: link 1 with
  the world (the robot stands on its table), link 0 with link 1, and the hand with link 7
  (bolted together through the flange); MuJoCo itself excludes every other parent and child.
  Contact bits: the arm (links 0-7) has contype 1, conaffinity 3; the hand contype 2,
  conaffinity 1; the world contype 0, conaffinity 3, except the cube the hand grasps
  (:func:`grasp`), conaffinity 1: so the arm may not touch it, the hand may.
- :func:`dynamics_model`: the Panda with its published inertials (``panda.xml``) and a
  joint impedance controller (:data:`STIFFNESS`, :data:`DAMPING`) at 1 kHz, contacts off.
"""

from __future__ import annotations

import copy
import functools

import mujoco
import numpy as np

from slotv_jax.robot import kinematics

__all__ = [
    "CLEARANCE_HORIZON",
    "DAMPING",
    "DT",
    "RATE",
    "STIFFNESS",
    "collision_model",
    "dynamics_model",
    "grasp",
    "kinematic_model",
    "mass_matrices",
    "tcp_poses",
]

RATE = 1000  # Hz: the Franka Control Interface's control rate
DT = 1.0 / RATE  # s: its period
CLEARANCE_HORIZON = 0.03  # m: contacts are reported up to this far apart (the contact margin;
# 5 cm would cost 19 % more per sample checked for no plan nearer: 18.1 against 15.3 ms)
# The joint impedance gains of Franka's joint impedance example (libfranka
# examples/joint_impedance_control.cpp, franka_ros franka_example_controllers): N m/rad, N m s/rad.
STIFFNESS = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])
DAMPING = np.array([50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0])
COLLISION_CLASS = "collision"
ENVIRONMENT = ("robot_table", "goal_table")  # the scene's geoms a robot may hit, with the cubes
EXCLUDED = (("world", "link1"), ("link0", "link1"), ("link7", "hand"))  # touch by design


@functools.cache
def kinematic_model() -> mujoco.MjModel:
    """The Panda alone (``panda.xml``), for forward kinematics in MuJoCo C."""
    return kinematics.mj_model(kinematics.PANDA_XML)


def tcp_poses(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP positions (N, 3) (m) and world-from-tool rotations (N, 3, 3) of configurations
    ``q`` (N, 7) (rad), by MuJoCo C's ``mj_kinematics`` on :func:`kinematic_model`."""
    m = kinematic_model()
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE)
    q = np.asarray(q, np.float64)
    pos = np.empty((len(q), 3))
    rot = np.empty((len(q), 9))
    qpos, xpos, xmat, kin = d.qpos, d.site_xpos[site], d.site_xmat[site], mujoco.mj_kinematics
    for i, qi in enumerate(q):
        qpos[:] = qi
        kin(m, d)
        pos[i] = xpos
        rot[i] = xmat
    return pos, rot.reshape(-1, 3, 3)


def mass_matrices(q: np.ndarray) -> np.ndarray:
    """The joint-space inertia matrices M(q) (N, 7, 7) (kg m²) of configurations ``q``
    (N, 7), from the published inertials (MuJoCo C: ``mj_fwdPosition``, ``mj_fullM``)."""
    m = kinematic_model()
    d = mujoco.MjData(m)
    out = np.empty((len(q), m.nv, m.nv))
    for i, qi in enumerate(np.asarray(q, np.float64)):
        d.qpos[:] = qi
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fullM(m, d, out[i])
    return out


@functools.cache
def collision_model() -> mujoco.MjModel:
    """The scene with the Panda's collision capsules switched on (see the module docstring).

    Only the geoms that take part stay: the capsules, the tables and the cubes (the drawn
    geoms, cameras and lights go), so a check runs no more kinematics than it needs. The
    cubes are mocap bodies ``cube0`` .. ``cube7`` (goal slot k on cube k), placed per scene.
    """
    spec = mujoco.MjSpec.from_file(str(kinematics.SCENE_XML))
    for g in list(spec.geoms):
        cube = g.parent.name.startswith("cube")
        if g.classname.name == COLLISION_CLASS:
            g.contype, g.conaffinity = (2, 1) if g.parent.name == "hand" else (1, 3)
        elif g.name in ENVIRONMENT or cube:
            g.contype, g.conaffinity = 0, 3  # the world: with the robot only
        else:
            spec.delete(g)
            continue
        g.margin = CLEARANCE_HORIZON
    for c in list(spec.cameras):
        spec.delete(c)
    for light in list(spec.lights):
        spec.delete(light)
    for a, b in EXCLUDED:
        spec.add_exclude(bodyname1=a, bodyname2=b)
    return spec.compile()


def grasp(model: mujoco.MjModel, target: int | None) -> mujoco.MjModel:
    """A copy of :func:`collision_model` in which the hand may touch cube ``target`` (the
    cube it reaches for, gripper open: the grasp, not a collision); None: no cube."""
    m = copy.copy(model)
    cubes = np.flatnonzero(m.body_mocapid[m.geom_bodyid] >= 0)
    m.geom_conaffinity[cubes] = 3
    if target is not None:
        body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"cube{int(target)}")
        m.geom_conaffinity[m.geom_bodyid == body] = 1
    return m


@functools.cache
def dynamics_model() -> mujoco.MjModel:
    """The Panda under a joint impedance controller, simulated at 1 kHz (contacts off).

    The controller is τ = K (q_d − q) + D (q̇_d − q̇) + τ_ff, K = :data:`STIFFNESS`,
    D = :data:`DAMPING`, τ_ff the inverse dynamics of the desired motion. MuJoCo takes it as
    one position actuator per joint (gain K, bias −K q) whose control is
    q_d + (D q̇_d + τ_ff) / K, and the −D q̇ term as extra joint damping, which the Euler
    integrator treats implicitly (stable at 1 kHz even for the light wrist). A ``tcp``
    position sensor records where the tool really goes.
    """
    spec = mujoco.MjSpec.from_file(str(kinematics.PANDA_XML))
    spec.option.timestep = DT
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    for g in list(spec.geoms):
        spec.delete(g)  # the inertials are explicit; geoms would only cost kinematics
    for j in range(kinematics.NQ):
        joint = spec.joint(f"joint{j + 1}")
        joint.damping = [joint.damping[0] + DAMPING[j], 0.0, 0.0]
        act = spec.add_actuator()
        act.name, act.target, act.trntype = (
            f"joint{j + 1}",
            f"joint{j + 1}",
            mujoco.mjtTrn.mjTRN_JOINT,
        )
        act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0], act.biasprm[1] = STIFFNESS[j], -STIFFNESS[j]
    sensor = spec.add_sensor()
    sensor.name, sensor.type = "tcp", mujoco.mjtSensor.mjSENS_FRAMEPOS
    sensor.objtype, sensor.objname = mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE
    return spec.compile()
