"""Dependencies point one way: estimation <- sync <- twin <- scenes <- cli, imports inside functions included."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
LAYERS = ["estimation", "sync", "twin", "scenes", "cli"]


def _imports(package: str) -> list[tuple[str, int, str]]:
    """(file, line, imported top-level package) for every import statement in ``package``, at any depth."""
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            found += [(str(path.relative_to(ROOT)), node.lineno, n.split(".")[0]) for n in names]
    return found


@pytest.mark.parametrize("package", LAYERS)
def test_a_layer_imports_only_the_layers_below_it(package):
    above = set(LAYERS[LAYERS.index(package) + 1:])
    wrong = [f"{f}:{line} imports {top}" for f, line, top in _imports(package) if top in above]
    assert not wrong, "\n".join(wrong)


def test_the_simulator_core_does_not_import_the_viewer():
    core = [p for p in (ROOT / "twin").glob("*.py") if p.name not in ("rerunlog.py",)]
    for path in core:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                assert not any(n.split(".")[0] == "rerun" or n == "twin.rerunlog" for n in names), path.name


def test_the_check_sees_function_level_imports():
    # The walk must find imports inside functions, or the layer test could pass on a hidden cycle.
    lines = [line for f, line, top in _imports("twin") if f == "twin/sim.py" and top == "mujoco"]
    assert len(lines) > 1
