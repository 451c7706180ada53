"""Rigid-body orientation arithmetic on w x y z quaternions (MuJoCo's order), via MuJoCo's own routines."""

from __future__ import annotations

import numpy as np


def rotation(q: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of quaternion ``q`` (normalised here)."""
    import mujoco

    q = np.asarray(q, dtype=np.float64)
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, q / np.linalg.norm(q))
    return m.reshape(3, 3)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation ``a`` after ``b``."""
    import mujoco

    out = np.empty(4)
    mujoco.mju_mulQuat(out, np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return out


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=np.float64)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two orientations, degrees (0 to 180)."""
    return float(2 * np.degrees(np.arccos(min(1.0, abs(float(np.dot(a, b)))))))


def nlerp(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Normalised linear blend from ``a`` (t=0) to ``b`` (t=1) along the short way: slerp for small steps.

    Quaternions (4,) or stacks (n, 4)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    flip = np.einsum("...i,...i->...", a, b) < 0
    out = a + t * (np.where(flip[..., None], -b, b) - a)
    return out / np.sqrt(np.einsum("...i,...i->...", out, out))[..., None]


def blend(position: np.ndarray, quat: np.ndarray, to_position: np.ndarray, to_quat: np.ndarray,
          t: float) -> tuple[np.ndarray, np.ndarray]:
    """A pose ``t`` of the way (0..1) from (``position``, ``quat``) to (``to_position``, ``to_quat``).

    Positions (3,) or (n, 3) metres, quaternions w x y z (4,) or (n, 4): linear in position, :func:`nlerp`
    in orientation. The twin's pull towards C's pose (corrections and the hold) goes through here.
    """
    position = np.asarray(position, dtype=np.float64)
    return position + t * (np.asarray(to_position, dtype=np.float64) - position), nlerp(quat, to_quat, t)


def to_xyzw(q: np.ndarray) -> np.ndarray:
    """MuJoCo's w x y z quaternion in the x y z w order that rerun and scipy use."""
    q = np.asarray(q, dtype=np.float64)
    return np.array([q[1], q[2], q[3], q[0]])


def quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`quat_mul` over stacks: the rotations ``a`` (n, 4) after ``b`` (n, 4), w x y z."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) (axis times angle, radians, the short way round) of quaternions (n, 4)."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.sqrt(np.einsum("...i,...i->...", q[..., 1:], q[..., 1:]))
    angle = 2 * np.arctan2(s, q[..., 0])
    # angle / s tends to 2 / w as s -> 0: no division by zero for the identity
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0 / np.maximum(q[..., 0], 1e-12))
    return q[..., 1:] * scale[..., None]


def from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4), w x y z, of rotation vectors (n, 3) (radians)."""
    r = np.asarray(r, dtype=np.float64)
    angle = np.sqrt(np.einsum("...i,...i->...", r, r))
    half = angle / 2
    sinc = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half)[..., None], r * sinc[..., None]], axis=-1)
