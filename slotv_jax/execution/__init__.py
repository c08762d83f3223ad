"""Run a plan on a real Franka arm: a timed joint trajectory within the robot's published
limits, at rest at both ends, its path kept as planned, checked for collisions and dynamics,
in the files a controller takes (:ref:`concepts-execution`, "Execution on a robot").

- :mod:`.limits`: Franka's published limits (Panda / FER and FR3) and the speed scale;
- :mod:`.path`: the plan as a smooth joint path, and its TCP's deviation from the planned path;
- :mod:`.timing`: TOPP-RA under the scaled limits, jerk bounded, sampled at 1 kHz;
- :mod:`.models`: the MuJoCo models the checks run on (kinematics, collisions, dynamics);
- :mod:`.checks`: limits at 1 kHz, collisions, MuJoCo dynamics, each able to refuse;
- :mod:`.run`: all of it on one plan, and what a report keeps;
- :mod:`.export`: CSV, NPZ and a ROS ``FollowJointTrajectory`` goal;
- :mod:`.cli`: ``python -m slotv_jax.execution export|check``.

>>> from slotv_jax.execution import execute
>>> e = execute(q, goals, goal_mask, target)            # doctest: +SKIP
>>> e.refusal or e.trajectory.duration                  # doctest: +SKIP
2.714
"""

from slotv_jax.execution.export import read_csv, write_trajectory
from slotv_jax.execution.limits import DEFAULT_SPEED, FER, FR3, ROBOTS, Limits
from slotv_jax.execution.refusal import Refused
from slotv_jax.execution.run import Execution, execute, summary
from slotv_jax.execution.timing import TimingConfig, Trajectory, time_plan

__all__ = [
    "DEFAULT_SPEED",
    "FER",
    "FR3",
    "ROBOTS",
    "Execution",
    "Limits",
    "Refused",
    "TimingConfig",
    "Trajectory",
    "execute",
    "read_csv",
    "summary",
    "time_plan",
    "write_trajectory",
]
