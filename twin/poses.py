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


def matrix_quat(matrix: np.ndarray) -> np.ndarray:
    """The unit quaternion (4,), w x y z, of a 3x3 rotation matrix (MuJoCo's conversion; either sign)."""
    import mujoco

    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(matrix, dtype=np.float64).ravel())
    return q


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


def _hamilton() -> np.ndarray:
    """(4, 4, 4) coefficients of the quaternion product: ``(a b)_i = sum_jk H[i, j, k] a_j b_k``."""
    h = np.zeros((4, 4, 4))
    for i, j, k, sign in ((0, 0, 0, 1), (0, 1, 1, -1), (0, 2, 2, -1), (0, 3, 3, -1),
                          (1, 0, 1, 1), (1, 1, 0, 1), (1, 2, 3, 1), (1, 3, 2, -1),
                          (2, 0, 2, 1), (2, 1, 3, -1), (2, 2, 0, 1), (2, 3, 1, 1),
                          (3, 0, 3, 1), (3, 1, 2, 1), (3, 2, 1, -1), (3, 3, 0, 1)):
        h[i, j, k] = sign
    return h


_HAMILTON = _hamilton()


def quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`quat_mul` over stacks: the rotations ``a`` (n, 4) after ``b`` (n, 4), w x y z."""
    return np.einsum("ijk,nj,nk->ni", _HAMILTON, a, b)


def to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) (axis times angle, radians, the short way round) of unit quaternions (n, 4)."""
    w = q[:, 0]
    half = np.arctan2(np.sqrt(np.einsum("ij,ij->i", q[:, 1:], q[:, 1:])), np.abs(w))  # in [0, pi/2]
    # angle / sin(half) = 2 half / sin(half) = 2 / sinc(half / pi), finite (2) at the identity
    return q[:, 1:] * (np.copysign(2.0, w) / np.sinc(half / np.pi))[:, None]


def from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4), w x y z, of rotation vectors (n, 3) (radians)."""
    half = 0.5 * np.sqrt(np.einsum("ij,ij->i", r, r))
    out = np.empty((len(r), 4))
    out[:, 0] = np.cos(half)
    out[:, 1:] = r * (0.5 * np.sinc(half / np.pi))[:, None]  # sin(half) / angle, 1/2 at zero
    return out
