"""Scene files and where objects come from; building a scene into a twin; the simulated remote C.

The public names below load on first use (PEP 562), so ``import scenes`` imports neither MuJoCo nor
trimesh::

    from scenes import load_scene, build_scene, write_scene
    from scenes import Headless, Remote
"""

from __future__ import annotations

from estimation.lazyexports import lazy_exports

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


__getattr__, __dir__ = lazy_exports("scenes", _EXPORTS, globals())
