"""The ``twin`` command line: the top of the stack. It wires estimation, the wire, the twin and the scenes
together; nothing below imports it.

The entry point is ``cli.main:main``. It is deliberately not re-exported here: ``cli.main`` is the module,
and a function of the same name on the package would hide it (``import cli.main as m`` would give the
function). The names below load on first use (PEP 562).
"""

from __future__ import annotations

from estimation.lazyexports import lazy_exports

#: public name -> the module that defines it.
_EXPORTS = {
    "EXIT_BAD_INPUT": "cli.main",
    "to_json": "cli.main",
    "estimate_to_json": "cli.main",
    "run_demo": "cli.demo",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports("cli", _EXPORTS, globals())
