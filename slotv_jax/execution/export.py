"""A timed trajectory in the files a lab's controller takes.

- **CSV** (``.csv``): the header ``t,q1,...,q7,dq1,...,dq7,ddq1,...,ddq7``, then one row per
  sample: time (s), joint positions (rad), velocities (rad/s), accelerations (rad/s²). Every
  number is written as Python's ``repr`` of the float, the shortest text that reads back as
  the same float, so the file reads back exactly (:func:`read_csv`).
- **NPZ** (``.npz``): the arrays ``t (N,)``, ``q``, ``dq``, ``ddq (N, 7)``, with
  ``joint_names (7,)``, ``robot``, ``speed``, ``rate`` and where the plan came from
  (``source``), no pickle.
- **ROS** (``.yaml``): a ``control_msgs/action/FollowJointTrajectory`` goal, for
  ``ros2 action send_goal`` or a script that sends it to a joint trajectory controller. Its
  ``trajectory`` (``trajectory_msgs/JointTrajectory``) names the joints ``panda_joint1..7``
  (``fr3_joint1..7`` for the FR3) and holds one point per sample: ``positions``,
  ``velocities``, ``accelerations``, an empty ``effort`` and ``time_from_start``
  (``builtin_interfaces/Duration``: whole seconds and nanoseconds, exact integers). The
  header stamp is zero (start on arrival); ``multi_dof_trajectory`` is empty, and the
  tolerances are left to the controller's own. Floats always carry a decimal point
  (``1.0e-05``, not ``1e-05``), which YAML 1.1 readers (PyYAML, as ``ros2`` uses) need to read
  them as floats.

The samples are the trajectory's at ``rate`` Hz, a divisor of 1000 (the robot's 1 kHz):
:meth:`slotv_jax.execution.timing.Trajectory.at_rate`.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping

import numpy as np

from slotv_jax.core.fileio import atomic_write, read_text
from slotv_jax.execution.timing import Trajectory, rate_step

__all__ = [
    "CSV_HEADER",
    "DEFAULT_RATES",
    "FORMATS",
    "csv_text",
    "read_csv",
    "ros_goal",
    "write_trajectory",
]

FORMATS = {"csv": ".csv", "npz": ".npz", "ros": ".yaml"}  # format -> the file's suffix
# Hz: libfranka's rate for the sample files; 50 Hz for a ROS goal, whose controller
# interpolates between points (a 3 s motion: 151 points, ~60 kB, short enough for one
# `ros2 action send_goal` argument; at 1 kHz it would be 1.2 MB)
DEFAULT_RATES = {"csv": 1000, "npz": 1000, "ros": 50}
CSV_HEADER = ["t", *(f"{k}{j}" for k in ("q", "dq", "ddq") for j in range(1, 8))]


def csv_text(t, q, dq, ddq) -> str:
    """The CSV of samples ``t (N,)``, ``q``, ``dq``, ``ddq (N, 7)`` (the module docstring)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    rows = np.concatenate([np.asarray(t, np.float64)[:, None], q, dq, ddq], axis=1)
    w.writerows([repr(float(v)) for v in row] for row in rows)
    return buf.getvalue()


def read_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A trajectory CSV back: ``t (N,)``, ``q``, ``dq``, ``ddq (N, 7)`` (float64, exactly the
    numbers written). ValueError naming the file and line if it is not one."""
    rows = list(csv.reader(io.StringIO(read_text(path))))
    if not rows or rows[0] != CSV_HEADER:
        raise ValueError(f"{path}: expected the header {','.join(CSV_HEADER)}")
    try:
        a = np.array([[float(v) for v in r] for r in rows[1:] if r], np.float64)
    except ValueError as e:
        raise ValueError(f"{path}: not a trajectory CSV ({e})") from None
    if a.ndim != 2 or a.shape[1] != len(CSV_HEADER):
        raise ValueError(f"{path}: expected {len(CSV_HEADER)} numbers per row")
    return {"t": a[:, 0], "q": a[:, 1:8], "dq": a[:, 8:15], "ddq": a[:, 15:22]}


def _yaml_float(x: float) -> str:
    """``repr`` of a float with a decimal point in its mantissa (YAML 1.1 floats need one)."""
    r = repr(float(x))
    mant, e, exp = r.partition("e")
    return f"{mant}.0{e}{exp}" if e and "." not in mant else r


def _floats(v) -> str:
    return "[" + ", ".join(_yaml_float(x) for x in v) + "]"


def ros_goal(t_ns: np.ndarray, q, dq, ddq, joint_names: list[str], comment: str = "") -> str:
    """The YAML of a ``FollowJointTrajectory`` goal through the samples (the module
    docstring); ``t_ns`` (N,) are the samples' times from the start, integer nanoseconds."""
    lines = [f"# {c}" for c in comment.splitlines()] + [
        "trajectory:",
        "  header:",
        "    stamp: {sec: 0, nanosec: 0}",
        "    frame_id: ''",
        f"  joint_names: [{', '.join(joint_names)}]",
        "  points:",
    ]
    for k, ns in enumerate(np.asarray(t_ns, np.int64)):
        sec, nsec = divmod(int(ns), 1_000_000_000)
        lines += [
            f"  - positions: {_floats(q[k])}",
            f"    velocities: {_floats(dq[k])}",
            f"    accelerations: {_floats(ddq[k])}",
            "    effort: []",
            f"    time_from_start: {{sec: {sec}, nanosec: {nsec}}}",
        ]
    lines += [
        "multi_dof_trajectory:",
        "  header:",
        "    stamp: {sec: 0, nanosec: 0}",
        "    frame_id: ''",
        "  joint_names: []",
        "  points: []",
        "path_tolerance: []",
        "goal_tolerance: []",
        "goal_time_tolerance: {sec: 0, nanosec: 0}",
    ]
    return "\n".join(lines) + "\n"


def write_trajectory(
    path: str | os.PathLike,
    traj: Trajectory,
    fmt: str,
    rate: int | None = None,
    source: Mapping[str, object] | None = None,
) -> int:
    """Write ``traj`` at ``rate`` Hz (default :data:`DEFAULT_RATES`) as ``fmt`` (csv, npz,
    ros) to ``path``, atomically; returns the number of samples written."""
    if fmt not in FORMATS:
        raise ValueError(f"format: expected one of {sorted(FORMATS)}, got {fmt!r}")
    rate = DEFAULT_RATES[fmt] if rate is None else rate
    step = rate_step(rate)
    t, q, dq, ddq = traj.at_rate(rate)
    cfg, names = traj.config, traj.config.limits.joint_names
    src = ", ".join(f"{k} {v}" for k, v in (source or {}).items())
    what = (f"{cfg.limits.name.upper()} at speed {cfg.speed:g} of its limits, {rate} Hz, "
            f"{traj.duration:.3f} s" + (f"; {src}" if src else ""))  # fmt: skip
    if fmt == "csv":
        text = csv_text(t, q, dq, ddq)
        atomic_write(path, lambda f: f.write(text.encode()))
    elif fmt == "npz":
        arrays = {"t": t, "q": q, "dq": dq, "ddq": ddq, "joint_names": np.array(names),
                  "robot": np.array(cfg.limits.name), "speed": np.array(cfg.speed),
                  "rate": np.array(rate), "source": np.array(src)}  # fmt: skip
        atomic_write(path, lambda f: np.savez(f, **arrays))
    else:
        t_ns = np.arange(len(t), dtype=np.int64) * step * 1_000_000
        comment = f"control_msgs/action/FollowJointTrajectory goal (slotv_jax): {what}"
        text = ros_goal(t_ns, q, dq, ddq, names, comment)
        atomic_write(path, lambda f: f.write(text.encode()))
    return len(t)
