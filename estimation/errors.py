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


class ReconstructionError(TwinError, RuntimeError):
    """Surface reconstruction could not produce a usable solid from a valid cloud."""
