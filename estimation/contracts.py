"""One place that checks array arguments at the public boundary."""

from __future__ import annotations

import math
import numbers

import numpy as np

from estimation import tolerances as tol
from estimation.errors import CloudError, TwinError, refused_number


def as_points(array: object, name: str = "points", *, allow_nonfinite: bool = False, min_rows: int = 0) -> np.ndarray:
    """Return ``array`` as a C-contiguous ``(n, 3) float64`` array, or raise naming the problem.

    Args:
        array: anything ``np.asarray`` accepts.
        name: the argument's name, used in the error.
        allow_nonfinite: keep NaN/inf rows (the caller drops and reports them).
        min_rows: fewest rows the caller can use (an empty array made numpy warn "Mean of empty slice").

    Raises:
        CloudError: wrong shape, non-numeric, fewer than ``min_rows`` rows, or non-finite values when not
            allowed.
    """
    if getattr(getattr(array, "dtype", None), "kind", None) == "c":  # numpy drops the imaginary part, with a warning
        raise CloudError(f"{name}: expected real coordinates, got a {array.dtype} array")  # type: ignore[attr-defined]
    try:
        out = np.ascontiguousarray(array, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CloudError(f"{name}: expected a numeric (n, 3) array, got {type(array).__name__}") from exc
    if out.ndim != 2 or out.shape[1] != 3:
        raise CloudError(f"{name}: expected shape (n, 3), got {out.shape}")
    if len(out) < min_rows:
        raise CloudError(f"{name}: expected at least {min_rows} row(s), got {len(out)}")
    if not allow_nonfinite and not all_finite(out):
        raise CloudError(f"{name}: contains NaN or inf values")
    return out


def all_finite(values: np.ndarray) -> bool:
    """True when every entry of ``values`` ((n, d) float) is finite.

    A finite sum proves it at half the cost of ``np.isfinite`` (0.5 against 0.9 ms on a million points, which
    every estimate checks more than once); only a sum that overflows or holds a NaN takes the exact check.
    """
    return bool(np.isfinite(np.einsum("ij->", values)) or np.isfinite(values).all())


def as_faces(array: object, vertex_count: int, name: str = "faces") -> np.ndarray:
    """Return ``array`` as ``(f, 3) int64`` indices into ``vertex_count`` vertices, or raise naming the problem.

    Args:
        array: triangles as rows of three vertex indices (any integer type).
        vertex_count: how many vertices the indices may name (0 to ``vertex_count - 1``).
        name: the argument's name, used in the error.

    Raises:
        CloudError: not whole numbers in rows of three (floats were truncated), or an index outside the
            vertices (past them was an IndexError; a negative one, numpy counted from the end without a word).
    """
    raw = np.asarray(array)
    if raw.ndim != 2 or raw.shape[1:] != (3,) or not (np.issubdtype(raw.dtype, np.integer) or raw.size == 0):
        raise CloudError(f"{name}: expected (f, 3) whole vertex indices, got {raw.dtype} {raw.shape}")
    faces = raw.astype(np.int64, copy=False)
    if faces.size:
        low, high = int(faces.min()), int(faces.max())
        if not vertex_count:
            raise CloudError(f"{name}: vertex indices {low} to {high}, but there are no vertices")
        if low < 0 or high >= vertex_count:
            raise CloudError(f"{name}: vertex indices must be 0 to {vertex_count - 1}, got {low} to {high}")
    return faces


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
        raise CloudError(f"{name} must have norm 1 (within {tol.QUAT_NORM_TOLERANCE:g}), got "
                         f"{refused_number(norm, 1 - tol.QUAT_NORM_TOLERANCE, 1 + tol.QUAT_NORM_TOLERANCE, digits=4)}")
    return q / norm


def check_number(value: object, label: str, *, low: float = 0.0, low_ok: bool = True, high: float = math.inf,
                 whole: bool = False, error: type[TwinError] = CloudError) -> float:
    """``value`` as a float if it is a finite number from ``low`` to ``high``, else ``error`` naming ``label``.

    The one range check of settings records, loop rates, remote options and command-line numbers. Huge Python
    integers are refused by size, not converted: ``float(10**400)`` raises OverflowError.

    Args:
        value: what came.
        label: how the message names it (a field, a flag).
        low, low_ok: the smallest value, and whether ``low`` itself is allowed.
        high: the largest value allowed (inf: any finite number).
        whole: it counts something (a whole number, not a bool).
        error: the error type to raise (a :class:`TwinError`).

    Raises:
        ``error``: not a number (a bool, a string, None), not whole when ``whole``, NaN or infinite, or outside
            the range.
    """
    kind = numbers.Integral if whole else numbers.Real
    if isinstance(value, bool) or not isinstance(value, kind):
        raise error(f"{label} must be a {'whole number' if whole else 'number'}, got {type(value).__name__} "
                    f"{shown(value)}")
    bounds = " and ".join(([f"{'>=' if low_ok else '>'} {low:g}"] if math.isfinite(low) else [])
                          + ([f"<= {high:g}"] if math.isfinite(high) else [])) or "a finite number"
    if isinstance(value, numbers.Integral) and abs(int(value)) > 2**1023:  # past any float: past any bound
        raise error(f"{label} must be {bounds}, got {shown(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise error(f"{label} must be a finite number, got {number}")
    if number < low or (number == low and not low_ok) or number > high:
        raise error(f"{label} must be {bounds}, got {value if whole else refused_number(number, low, high)}")
    return number


def shown(value: object) -> str:
    """``value`` for a one-line message: a short repr (a megabyte string stays out of the line), a huge integer
    by its size (the repr of 5000 digits is an error itself)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool) and abs(int(value)).bit_length() > 128:
        return f"an integer of {abs(int(value)).bit_length()} bits"
    text = repr(value)
    return text[:40] + "..." if len(text) > 40 else text
