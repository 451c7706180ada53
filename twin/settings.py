"""The one check the twin's settings records run on their fields, and the error it raises.

Settings are frozen dataclasses (:class:`twin.runtime.LocalSettings`, :class:`twin.runtime.OperatorSettings`,
:class:`twin.hold.HoldSettings`); each refuses in ``__post_init__`` what it cannot mean, so a bad value fails
where it is written, not as a ZeroDivisionError, a 75 GiB allocation or an empty twin minutes later.
"""

from __future__ import annotations

import math

from estimation.contracts import check_number as number
from estimation.contracts import shown
from estimation.errors import SettingsError

__all__ = ["SettingsError", "check_number", "check_type"]


def check_number(record: object, name: str, *, low: float = 0.0, low_ok: bool = True, high: float = math.inf,
                 whole: bool = False) -> None:
    """Refuse ``record.name`` unless it is a finite number from ``low`` to ``high``
    (:func:`estimation.contracts.check_number`, the record's class name and the field in the message).

    Raises:
        SettingsError: not a number (a bool, a string, None), not whole when ``whole``, NaN or infinite, or
            outside the range.
    """
    number(getattr(record, name), f"{type(record).__name__}.{name}", low=low, low_ok=low_ok, high=high, whole=whole,
           error=SettingsError)


def check_type(record: object, name: str, kind: type | tuple[type, ...], expected: str) -> None:
    """Refuse ``record.name`` unless it is a ``kind`` (``expected`` says what that is in the message).

    Raises:
        SettingsError: naming the record, the field and the type that came.
    """
    value = getattr(record, name)
    if not isinstance(value, kind):
        raise SettingsError(f"{type(record).__name__}.{name} must be {expected}, got {type(value).__name__} "
                            f"{shown(value)}")


#: The loop's ceiling, Hz, and so the most force messages a second: one step of the smallest scene takes
#: ~10 us, so faster asks only queue work (1e9 Hz grew memory without bound). The CLI's --rate and
#: --force-rate take at most this too.
MAX_RATE_HZ = 100_000.0

#: Worker processes one twin or one experiment sweep may start (each a Python with MuJoCo, ~200 MB): 100,000
#: were accepted. :class:`twin.runtime.LocalSettings` and ``twin experiment --workers`` take at most this.
MAX_WORKERS = 256
