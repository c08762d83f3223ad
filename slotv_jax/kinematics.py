"""Franka Emika Panda kinematics (:ref:`concepts-robot`, :ref:`concepts-public-names`) under their
public name.

The code lives in :mod:`slotv_jax.robot.kinematics`; this module keeps the public names of
:ref:`concepts-public-names` (``slotv_jax.kinematics.tcp_position``,
``slotv_jax.kinematics.Q_HOME``).
"""

from slotv_jax.robot.kinematics import (
    ASSETS_DIR,
    NQ,
    PANDA_XML,
    Q_HOME,
    Q_MAX,
    Q_MIN,
    SCENE_XML,
    TCP_SITE,
    TOOL_DOWN,
    IKConfig,
    PathIK,
    TcpState,
    check_ik_inputs,
    fk_position,
    home_tcp,
    host_eval,
    mj_model,
    solve_ik,
    solve_ik_chain,
    solve_path_ik,
    tcp_pose,
    tcp_position,
    tcp_state,
)

__all__ = [
    "ASSETS_DIR",
    "NQ",
    "PANDA_XML",
    "Q_HOME",
    "Q_MAX",
    "Q_MIN",
    "SCENE_XML",
    "TCP_SITE",
    "TOOL_DOWN",
    "IKConfig",
    "PathIK",
    "TcpState",
    "check_ik_inputs",
    "fk_position",
    "home_tcp",
    "host_eval",
    "mj_model",
    "solve_ik",
    "solve_ik_chain",
    "solve_path_ik",
    "tcp_pose",
    "tcp_position",
    "tcp_state",
]
