"""Point cloud in, geometry and physical properties out. Knows nothing of MuJoCo or Zenoh.

The public names load on first use (PEP 562, ``estimation.lazyexports``), so importing a light module
such as ``estimation.errors`` (the CLI does, before it parses its arguments) does not pull in numpy,
scipy and the whole pipeline.
"""

from __future__ import annotations

import sys
import types

from estimation.lazyexports import lazy_exports

#: public name -> the module that defines it.
_EXPORTS = {
    "PointCloud": "estimation.cloud",
    "check_estimable": "estimation.cloud",
    "make_cloud": "estimation.cloud",
    "load_cloud": "estimation.cloudfile",
    "save_cloud": "estimation.cloudfile",
    "CloudError": "estimation.errors",
    "CloudFileError": "estimation.errors",
    "MaterialError": "estimation.errors",
    "ReconstructionError": "estimation.errors",
    "SettingsError": "estimation.errors",
    "TwinError": "estimation.errors",
    "METHODS": "estimation.estimate",
    "PhysicalEstimate": "estimation.estimate",
    "Timings": "estimation.estimate",
    "estimate": "estimation.estimate",
    "from_mesh": "estimation.estimate",
    "MassProperties": "estimation.inertia",
    "mass_properties": "estimation.inertia",
    "Material": "estimation.materials",
    "material": "estimation.materials",
    "materials": "estimation.materials",
    "OrientedBox": "estimation.obb",
    "oriented_box": "estimation.obb",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports("estimation", _EXPORTS, globals())


class _Package(types.ModuleType):
    """This package's module type: ``estimation.estimate`` (and ``estimation.materials``) stay the functions.

    The submodule ``estimation/estimate.py`` and its function share a name (so do ``materials``'s). Whenever the submodule is
    imported (by anyone, at any time), the import system binds it on the package as ``estimate``, which
    would hide the function from ``from estimation import estimate``. The eager ``__init__`` this
    replaces rebound the function once, after its own import; here every such binding is turned into
    the function (the module itself stays in ``sys.modules['estimation.estimate']``).
    """

    def __setattr__(self, name: str, value: object) -> None:
        if name in _SHADOWED and isinstance(value, types.ModuleType):
            value = getattr(value, name)
        super().__setattr__(name, value)


#: Public functions that share their name with the submodule defining them (the class above).
_SHADOWED = frozenset(name for name, module in _EXPORTS.items() if module == f"estimation.{name}")


sys.modules[__name__].__class__ = _Package
