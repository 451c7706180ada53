"""The project's error hierarchy.

Every error the library raises on bad input derives from :class:`TwinError`, so the CLI can catch one
class and exit 2 with one line. Subclasses also inherit the matching builtin, so callers that already
catch ``ValueError`` or ``LookupError`` keep working.
"""

from __future__ import annotations


class TwinError(Exception):
    """Base class for every error tactile-twin raises on purpose."""


class CloudError(TwinError, ValueError):
    """A point cloud cannot be used: empty, non-finite, too few points, flat, or unreadable."""


class CloudFileError(CloudError, OSError):
    """A cloud file is missing, unreadable, or in a format we do not read."""


class MaterialError(TwinError, LookupError):
    """An unknown material name or a non-physical density."""


class UnknownObjectError(TwinError, KeyError):
    """An object id the running model does not hold; the message names the ids it does (or the closest)."""

    def __str__(self) -> str:
        # KeyError's own str() is the repr of its argument: the one-line error would have come out in quotes.
        return str(self.args[0]) if self.args else ""


class ReconstructionError(TwinError, RuntimeError):
    """Surface reconstruction could not produce a usable solid from a valid cloud."""


class SettingsError(TwinError, ValueError):
    """An option or a settings field outside what it can mean (a seed, :mod:`twin.settings`' records); the
    message names it and the value."""


#: Significant digits that write any double exactly: the most a refused number takes.
_MOST_DIGITS = 17


def refused_number(value: float, *limits: float, digits: int = 6) -> str:
    """``value`` as an error shows it: with ``digits`` significant digits (``:g``'s 6 unless the message is
    written shorter), or as many more as it takes to leave it on the same side of each of ``limits`` as
    ``value`` is, or exactly.

    ``:g`` printed ``--density 100000.0001`` as "got 100000", the limit itself, and ``:.4g`` a quaternion's
    norm of 1.0010001 as "1.001" against a tolerance of 0.001: the reason was rounded away. This keeps
    "got 1e+300" short and writes "got 100000.0001" in full. One rule for every range message.
    """
    def side(x: float, limit: float) -> tuple[bool, bool]:
        return x < limit, x > limit

    for shown_digits in range(digits, _MOST_DIGITS + 1):
        text = f"{value:.{shown_digits}g}"
        shown = float(text)
        if shown == value or all(side(shown, limit) == side(value, limit) for limit in limits):
            return text
    return f"{value:.{_MOST_DIGITS}g}"
