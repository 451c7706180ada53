"""The local twin C': estimates become MuJoCo bodies, and the simulation loop runs at haptic rate.

The public names below load on first use (PEP 562), so ``import twin`` imports neither MuJoCo nor numpy::

    from twin import Twin, run_paced
    from twin import Local, LocalSettings          # the twin following a remote over a transport

The rest (CoACD caching, the hold, rerun logging) stays in its modules.
"""

from __future__ import annotations

from estimation.lazyexports import lazy_exports

#: public name -> the module that defines it.
_EXPORTS = {
    "Twin": "twin.sim",
    "run_paced": "twin.sim",
    "TwinClosedError": "twin.sim",
    "SettingsError": "twin.settings",
    "TwinObject": "twin.objects",
    "object_at_estimate": "twin.objects",
    "PhysicsSettings": "twin.model",
    "DEFAULT_PHYSICS": "twin.model",
    "TableSpec": "twin.model",
    "EndEffectorSpec": "twin.model",
    "add_object": "twin.model",
    "new_spec": "twin.model",
    "CoacdSettings": "twin.decompose",
    "Local": "twin.runtime",
    "LocalSettings": "twin.runtime",
    "LocalReport": "twin.runtime",
    "OperatorSettings": "twin.runtime",
    "SyncError": "twin.runtime",
    "HoldSettings": "twin.hold",
    "LoopStats": "twin.loop",
    "LoopError": "twin.loop",
    "Waypoints": "twin.trajectory",
    "load_trajectory": "twin.trajectory",
    "push_trajectory": "twin.trajectory",
    "TrajectoryError": "twin.trajectory",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports("twin", _EXPORTS, globals())
