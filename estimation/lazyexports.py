"""Package-level names that load on first use (PEP 562), for the packages above ``estimation``.

``twin``, ``sync``, ``scenes`` and ``cli`` re-export their public names from their ``__init__`` like
MuJoCo's subpackages do, without importing MuJoCo, Zenoh or rerun until a name is asked for. It lives in
the bottom layer so every package may use it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_exports(package: str, exports: dict[str, str], namespace: dict[str, object]
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``, whose public ``name`` lives in ``exports[name]``.

    A name is imported once, then stored in ``namespace`` (the package's ``globals()``), so later look-ups
    do not come back here.
    """

    def __getattr__(name: str) -> object:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *exports})

    return __getattr__, __dir__
