"""One place that checks array arguments at the public boundary."""

from __future__ import annotations

import numpy as np

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
