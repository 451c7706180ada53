"""One place that checks array arguments at the public boundary."""

from __future__ import annotations

import numpy as np

from estimation import tolerances as tol
from estimation.errors import CloudError


def as_points(array: object, name: str = "points", *, allow_nonfinite: bool = False) -> np.ndarray:
    """Return ``array`` as a C-contiguous ``(n, 3) float64`` array, or raise naming the problem.

    Args:
        array: anything ``np.asarray`` accepts.
        name: the argument's name, used in the error.
        allow_nonfinite: keep NaN/inf rows (the caller drops and reports them).

    Raises:
        CloudError: wrong shape, non-numeric, or non-finite values when not allowed.
    """
    try:
        out = np.ascontiguousarray(array, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{name}: expected a numeric (n, 3) array, got {type(array).__name__}") from exc
    if out.ndim != 2 or out.shape[1] != 3:
        raise CloudError(f"{name}: expected shape (n, 3), got {out.shape}")
    if not allow_nonfinite and not np.isfinite(out).all():
        raise CloudError(f"{name}: contains NaN or inf values")
    return out


def unit_quaternion(wxyz: object, name: str = "quaternion") -> np.ndarray:
    """Return ``wxyz`` (4,) normalised, or raise unless its norm is within ``tol.QUAT_NORM_TOLERANCE`` of 1.

    One rule for every quaternion read from the user (``--viewpoint-pose``, a PCD ``VIEWPOINT``).

    Args:
        wxyz: (4,) w x y z, MuJoCo's and PCD's order.
        name: what the error calls it.

    Raises:
        CloudError: not four finite numbers, or a norm off 1 by more than the tolerance.
    """
    q = np.asarray(wxyz, dtype=np.float64).ravel()
    if q.shape != (4,) or not np.isfinite(q).all():
        raise CloudError(f"{name}: expected four finite numbers w x y z, got {q.tolist()}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1) > tol.QUAT_NORM_TOLERANCE:
        raise CloudError(f"{name} must have norm 1 (within {tol.QUAT_NORM_TOLERANCE:g}), got {norm:.4g}")
    return q / norm
