"""The debug-log seam: what the twin's loops tell a visual debugger, and the log that tells nobody.

The simulator core and the runtime take a log object and never import a viewer: :data:`OFF` by default,
:class:`twin.rerunlog.RerunLog` when a command asks for rerun. Every method is cheap when the log is off,
and callers that would build strings or copy arrays first check :attr:`DebugLog.enabled`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

#: Points of a cloud shown in a viewer: enough to see the shape, few enough to send at once.
DISPLAY_POINTS = 20_000


class DebugLog(Protocol):
    """What loops and runtimes log. :class:`twin.rerunlog.RerunLog` implements it."""

    enabled: bool

    def due(self, sim_time: float) -> bool: ...
    def frame(self, twin, *, side: str = "twin", remote=None) -> None: ...  # type: ignore[no-untyped-def]
    def object(self, side: str, obj, *, sim_time: float = 0.0, cloud=None, pose=None) -> None: ...  # type: ignore[no-untyped-def]
    def ghost(self, obj, *, sim_time: float = 0.0) -> None: ...  # type: ignore[no-untyped-def]
    def removed(self, side: str, object_id: str, sim_time: float) -> None: ...
    def table(self, size: tuple[float, float, float], height: float) -> None: ...
    def event(self, sim_time: float, text: str, level: str = "INFO") -> None: ...


class _Off:
    """Logs nothing."""

    enabled = False

    def due(self, sim_time: float) -> bool:
        return False

    def frame(self, *args: object, **kwargs: object) -> None:
        pass

    object = ghost = removed = table = event = estimate = model_geometry = frame

    def close(self) -> None:
        pass

    def __enter__(self) -> _Off:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


#: The log that logs nothing: the default everywhere.
OFF: DebugLog = _Off()


def display_subset(points: np.ndarray, cap: int = DISPLAY_POINTS, *, seed: int = 0) -> np.ndarray:
    """At most ``cap`` of ``points`` ((n, 3)), a seeded random choice, as float32 (for display only)."""
    points = np.asarray(points)
    if len(points) > cap:
        points = points[np.random.default_rng(seed).choice(len(points), cap, replace=False)]
    return points.astype(np.float32)
