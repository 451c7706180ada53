"""Scene files and where objects come from; building a scene into a twin; the simulated remote C.

The public names below load on first use (PEP 562), so ``import scenes`` imports neither MuJoCo nor
trimesh::

    from scenes import load_scene, build_scene, write_scene
    from scenes import Headless, Remote
"""

from __future__ import annotations

import importlib

#: public name -> the module that defines it.
_EXPORTS = {
    "SceneSpec": "scenes.scenefile",
    "ObjectSpec": "scenes.scenefile",
    "SceneError": "scenes.scenefile",
    "load_scene": "scenes.scenefile",
    "parse_scene": "scenes.scenefile",
    "BuiltScene": "scenes.build",
    "BuildError": "scenes.build",
    "build_scene": "scenes.build",
    "write_scene": "scenes.build",
    "check_output": "scenes.build",
    "estimate_object": "scenes.sources",
    "reference_estimate": "scenes.sources",
    "source_mesh": "scenes.sources",
    "Remote": "scenes.remote",
    "Deadband": "scenes.remote",
    "Headless": "scenes.headless",
    "Sensor": "scenes.sensing",
    "SurfaceSensor": "scenes.sensing",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> object:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'scenes' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # once: later lookups do not come back here
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
