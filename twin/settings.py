"""The one check the twin's settings records run on their fields, and the error it raises.

Settings are frozen dataclasses (:class:`twin.runtime.LocalSettings`, :class:`twin.runtime.OperatorSettings`,
:class:`twin.hold.HoldSettings`); each refuses in ``__post_init__`` what it cannot mean, so a bad value fails
where it is written, not as a ZeroDivisionError, a 75 GiB allocation or an empty twin minutes later.
"""

from __future__ import annotations

import math
import numbers

from estimation.errors import SettingsError, refused_number

__all__ = ["SettingsError", "check_number", "check_type"]


def check_number(record: object, name: str, *, low: float = 0.0, low_ok: bool = True, high: float = math.inf,
                 whole: bool = False) -> None:
    """Refuse ``record.name`` unless it is a finite number from ``low`` to ``high``.

    Args:
        record: the settings record (its class name starts the message).
        name: the field.
        low, low_ok: the smallest value, and whether ``low`` itself is allowed.
        high: the largest value allowed (inf: any finite number).
        whole: the field counts something (a whole number, not a bool).

    Raises:
        SettingsError: not a number (a bool, a string, None), not whole when ``whole``, NaN or infinite, or
            outside the range.
    """
    value = getattr(record, name)
    where = f"{type(record).__name__}.{name}"
    kind = numbers.Integral if whole else numbers.Real
    if isinstance(value, bool) or not isinstance(value, kind):
        raise SettingsError(f"{where} must be a {'whole number' if whole else 'number'}, got {_shown(value)}")
    if not math.isfinite(value):
        raise SettingsError(f"{where} must be a finite number, got {value}")
    if value < low or (value == low and not low_ok) or value > high:
        bounds = f"{'>=' if low_ok else '>'} {low:g}" + (f" and <= {high:g}" if math.isfinite(high) else "")
        shown = value if whole else refused_number(float(value), low, high)
        raise SettingsError(f"{where} must be {bounds}, got {shown}")


def check_type(record: object, name: str, kind: type | tuple[type, ...], expected: str) -> None:
    """Refuse ``record.name`` unless it is a ``kind`` (``expected`` says what that is in the message).

    Raises:
        SettingsError: naming the record, the field and the type that came.
    """
    value = getattr(record, name)
    if not isinstance(value, kind):
        raise SettingsError(f"{type(record).__name__}.{name} must be {expected}, got {_shown(value)}")


def _shown(value: object) -> str:
    """``value`` for a message: its type and a short repr (a megabyte string stays out of the line)."""
    text = repr(value)
    return f"{type(value).__name__} {text[:40] + '...' if len(text) > 40 else text}"


#: The loop's ceiling, Hz, and so the most force messages a second: one step of the smallest scene takes
#: ~10 us, so faster asks only queue work (1e9 Hz grew memory without bound). The CLI's --rate and
#: --force-rate take at most this too.
MAX_RATE_HZ = 100_000.0

#: Worker processes one twin or one experiment sweep may start (each a Python with MuJoCo, ~200 MB): 100,000
#: were accepted. :class:`twin.runtime.LocalSettings` and ``twin experiment --workers`` take at most this.
MAX_WORKERS = 256
