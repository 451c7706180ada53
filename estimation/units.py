"""Length units accepted on input, and the check for a cloud that is probably in the wrong ones."""

from __future__ import annotations

import logging

import numpy as np

from estimation import tolerances as tol
from estimation.errors import TwinError

log = logging.getLogger(__name__)

#: Metres per unit.
UNIT_SCALE: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}


class UnitsError(TwinError, ValueError):
    """An unknown unit name."""


def unit_scale(units: str) -> float:
    """Metres per ``units`` ('m', 'cm' or 'mm')."""
    try:
        return UNIT_SCALE[units]
    except KeyError:
        raise UnitsError(f"unknown units {units!r}; use one of {', '.join(UNIT_SCALE)}") from None


def implausible_size(extents_m: np.ndarray) -> int:
    """+1 when an object's largest extent (metres) is above :data:`tolerances.PLAUSIBLE_EXTENT_M`, -1 when below it,
    0 within: the one test of "probably in other units" that ``twin estimate``, scene files and the warning share."""
    largest = float(np.max(extents_m))
    low, high = tol.PLAUSIBLE_EXTENT_M
    return 1 if largest > high else -1 if largest < low else 0


def units_warning(extents_m: np.ndarray) -> str | None:
    """Return a warning when an object's extents (metres) look like the wrong units, else None."""
    largest = float(np.max(extents_m))
    # Said of clouds from files and from the wire alike (a twin passes its estimates' warnings on): the hint names
    # the option of `twin estimate`, where a file's units are chosen.
    side = implausible_size(extents_m)
    if side > 0:
        return (f"object is {largest:.3g} m across; if the points are in mm or cm, scale them to metres "
                f"(twin estimate --units mm or --units cm)")
    if side < 0:
        return (f"object is {largest * 1000:.3g} mm across; if the points are in metres already, check their scale "
                f"(twin estimate --units)")
    return None
