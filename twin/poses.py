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
