"""Independent float64 forward kinematics of the Panda, written from :ref:`concepts-robot`'s DH
table.

Franka's published modified (Craig) Denavit–Hartenberg parameters: link frame i
is ``RotX(α_i) · TransX(a_i) · RotZ(q_i) · TransZ(d_i)`` of frame i−1. The flange
is a further ``TransZ(0.107)``; the hand is rotated −π/4 about the flange z axis,
and the tool centre point lies 0.1034 m along the hand's z axis.

Plain NumPy with 4×4 homogeneous matrices, batched over leading axes. It shares
no code or numbers with ``slotv_jax`` or the MJCF, so the tests can compare MJX
against it.
"""

from __future__ import annotations

import numpy as np

# (a, d, alpha) per joint, from the table in :ref:`concepts-robot`.
DH = np.array(
    [
        [0.0, 0.333, 0.0],
        [0.0, 0.0, -np.pi / 2],
        [0.0, 0.316, np.pi / 2],
        [0.0825, 0.0, np.pi / 2],
        [-0.0825, 0.384, -np.pi / 2],
        [0.0, 0.0, np.pi / 2],
        [0.088, 0.0, np.pi / 2],
    ]
)
FLANGE_D = 0.107
HAND_YAW = -np.pi / 4
TCP_OFFSET = 0.1034
Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])


def rot_x(t) -> np.ndarray:
    """Homogeneous rotations about x, shape ``t.shape + (4, 4)``."""
    c, s = np.cos(t), np.sin(t)
    m = np.zeros((*np.shape(t), 4, 4))
    m[..., 0, 0] = m[..., 3, 3] = 1.0
    m[..., 1, 1], m[..., 1, 2], m[..., 2, 1], m[..., 2, 2] = c, -s, s, c
    return m


def rot_z(t) -> np.ndarray:
    """Homogeneous rotations about z, shape ``t.shape + (4, 4)``."""
    c, s = np.cos(t), np.sin(t)
    m = np.zeros((*np.shape(t), 4, 4))
    m[..., 2, 2] = m[..., 3, 3] = 1.0
    m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1] = c, -s, s, c
    return m


def trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def tcp_transforms(qs) -> np.ndarray:
    """World-from-TCP homogeneous transforms (..., 4, 4) of configurations (..., 7)."""
    qs = np.asarray(qs, np.float64)
    if qs.shape[-1:] != (7,):
        raise ValueError(f"qs: expected shape (..., 7), got {qs.shape}")
    t = np.broadcast_to(np.eye(4), (*qs.shape[:-1], 4, 4))
    for i, (a, d, alpha) in enumerate(DH):
        t = t @ rot_x(alpha) @ trans(a, 0, 0) @ rot_z(qs[..., i]) @ trans(0, 0, d)
    return t @ trans(0, 0, FLANGE_D) @ rot_z(HAND_YAW) @ trans(0, 0, TCP_OFFSET)


def tcp_positions(qs) -> np.ndarray:
    """TCP positions (..., 3) in metres."""
    return tcp_transforms(qs)[..., :3, 3]


def tcp_axes(qs) -> np.ndarray:
    """Tool z axes (..., 3), unit vectors in the world frame."""
    return tcp_transforms(qs)[..., :3, 2]


def finite_difference_jacobians(qs, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference Jacobians (..., 3, 7) of the TCP position and of the tool z axis."""
    qs = np.asarray(qs, np.float64)[..., None, :]  # (..., 1, 7)
    dq = eps * np.eye(7)  # one column perturbed per row
    tp, tm = tcp_transforms(qs + dq), tcp_transforms(qs - dq)  # (..., 7, 4, 4)
    jp = (tp[..., :3, 3] - tm[..., :3, 3]) / (2 * eps)  # (..., 7, 3)
    ja = (tp[..., :3, 2] - tm[..., :3, 2]) / (2 * eps)
    return np.swapaxes(jp, -1, -2), np.swapaxes(ja, -1, -2)
