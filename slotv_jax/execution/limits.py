"""The limits a Franka arm accepts a commanded motion within, and the speed a plan runs at.

Source: Franka's documentation of the Franka Control Interface, "Robot and interface
specifications" (https://frankaemika.github.io/docs/control_parameters.html), sections
"Limits for Panda" and "Limits for Franka Research 3" (their tables are the files
``control-parameters-joint-panda.csv`` and ``control-parameters-joint-fr3.csv`` of the
``frankaemika/docs`` repository). A joint trajectory that breaks a *necessary* condition
(position, velocity, acceleration or jerk, each checked at 1 kHz) is aborted by the robot;
the torque and torque-rate limits are *recommended* conditions. The Cartesian limits bind
the Cartesian interfaces; they are checked here too, as a margin a lab may rely on.

- ``fer``: the Panda (Franka Emika Robot, FER). Its joint positions are the same published
  numbers as the kinematic model's (:data:`slotv_jax.robot.kinematics.Q_MIN`, ``Q_MAX``),
  which the planners keep to.
- ``fr3``: the Franka Research 3. Its velocity limit depends on the joint position; the
  page gives a rectangular box inside that envelope "for motion planners that can only deal
  with fixed velocity limits" (``control-parameters-joint-fr3-rectangular.csv``), used here
  for positions and velocities, with the FR3's acceleration, jerk and torque limits.

**The speed scale** (``speed``, as MoveIt's ``max_velocity_scaling_factor`` and
``max_acceleration_scaling_factor``) multiplies the velocity, acceleration and jerk limits
the timing may use; the checks still hold the motion to the unscaled limits.
:data:`DEFAULT_SPEED` = 0.3: the study shows people a robot moving near them, so most of
each limit stays in reserve, and at 0.3 the recorded plans take 2.2-3.4 s on the Panda,
about the 3 s the study's clips show a whole motion in (``experiments/execution.md``).
MoveIt's own default, 0.1, would make the robot three times slower than the clips people
judged.

>>> FER.dq_max[:2].tolist(), float(FR3.dq_max[4])
([2.175, 2.175], 3.0)
>>> float(FER.scaled(0.5).ddq_max[1])
3.75
"""

from __future__ import annotations

import dataclasses

import numpy as np

from slotv_jax.robot import kinematics

__all__ = ["DEFAULT_SPEED", "FER", "FR3", "ROBOTS", "SOURCE", "Limits", "check_speed"]

SOURCE = "https://frankaemika.github.io/docs/control_parameters.html"
DEFAULT_SPEED = 0.3  # the scale of velocity, acceleration and jerk limits (see above)


@dataclasses.dataclass(frozen=True, eq=False)
class Limits:
    """One robot's joint and Cartesian limits (SI units, per joint where (7,))."""

    name: str  # "fer" or "fr3"
    joint_prefix: str  # its ROS joint names are PREFIX1 .. PREFIX7
    q_min: np.ndarray  # (7,) rad
    q_max: np.ndarray  # (7,) rad
    dq_max: np.ndarray  # (7,) rad/s
    ddq_max: np.ndarray  # (7,) rad/s²
    dddq_max: np.ndarray  # (7,) rad/s³
    tau_max: np.ndarray  # (7,) N m
    dtau_max: np.ndarray  # (7,) N m/s
    translation: tuple[float, float, float]  # TCP speed (m/s), acceleration, jerk
    rotation: tuple[float, float, float]  # TCP angular speed (rad/s), acceleration, jerk

    @property
    def joint_names(self) -> list[str]:
        """``panda_joint1`` .. ``panda_joint7`` (or ``fr3_joint1`` ..): the ROS names."""
        return [f"{self.joint_prefix}{j}" for j in range(1, 8)]

    def scaled(self, speed: float) -> Limits:
        """The limits a timing at ``speed`` may use: velocity, acceleration and jerk (joint
        and Cartesian) times ``speed``; positions and torques as they are."""
        check_speed(speed)
        return dataclasses.replace(
            self,
            dq_max=self.dq_max * speed,
            ddq_max=self.ddq_max * speed,
            dddq_max=self.dddq_max * speed,
            translation=tuple(v * speed for v in self.translation),
            rotation=tuple(v * speed for v in self.rotation),
        )


def _a(*v) -> np.ndarray:
    a = np.array(v, np.float64)
    a.setflags(write=False)
    return a


FER = Limits(
    name="fer",
    joint_prefix="panda_joint",
    q_min=_a(*kinematics.Q_MIN),
    q_max=_a(*kinematics.Q_MAX),
    dq_max=_a(2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100),
    ddq_max=_a(15, 7.5, 10, 12.5, 15, 20, 20),
    dddq_max=_a(7500, 3750, 5000, 6250, 7500, 10000, 10000),
    tau_max=_a(87, 87, 87, 87, 12, 12, 12),
    dtau_max=_a(1000, 1000, 1000, 1000, 1000, 1000, 1000),
    translation=(1.7, 13.0, 6500.0),
    rotation=(2.5, 25.0, 12500.0),
)

FR3 = Limits(
    name="fr3",
    joint_prefix="fr3_joint",
    q_min=_a(-2.3093, -1.5133, -2.4937, -2.7478, -2.4800, 0.8521, -2.6895),
    q_max=_a(2.3093, 1.5133, 2.4937, -0.4461, 2.4800, 4.2094, 2.6895),
    dq_max=_a(2, 1, 1.5, 1.25, 3, 1.5, 3),
    ddq_max=_a(10, 10, 10, 10, 10, 10, 10),
    dddq_max=_a(5000, 5000, 5000, 5000, 5000, 5000, 5000),
    tau_max=_a(87, 87, 87, 87, 12, 12, 12),
    dtau_max=_a(1000, 1000, 1000, 1000, 1000, 1000, 1000),
    translation=(3.0, 9.0, 4500.0),
    rotation=(2.5, 17.0, 8500.0),
)

ROBOTS = {"fer": FER, "fr3": FR3}


def check_speed(speed) -> float:
    """``speed`` as a float in (0, 1]; ValueError naming ``speed`` otherwise."""
    ok = isinstance(speed, int | float | np.floating) and not isinstance(speed, bool)
    if not (ok and 0.0 < float(speed) <= 1.0):
        raise ValueError(f"speed: expected a fraction of the limits in (0, 1], got {speed!r}")
    return float(speed)
