"""How auto's volume error grows as clouds get sparse (estimated normals, paper objects at 7 degrees).

    .venv/bin/python bench/sparse_clouds.py
"""

from __future__ import annotations

import sys
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages, not an installed copy

from estimation import estimate
from scenes.paper_objects import paper_object
from scenes.sampling import sample_surface

COUNTS = (1_000, 3_000, 10_000, 30_000)
OBJECTS = ("mug", "box", "torus", "cone")


def main() -> int:
    table = Table(title="auto volume error (%) vs points, estimated normals, rotation 7 deg, seed 2")
    table.add_column("object")
    for n in COUNTS:
        table.add_column(f"{n} pts", justify="right")
    for name in OBJECTS:
        mesh = paper_object(name, 7)
        cells = []
        for n in COUNTS:
            result = estimate(sample_surface(mesh, n, seed=2, with_normals=False), 1000.0)
            cells.append(f"{100 * (result.volume / mesh.volume - 1):+.2f}")
        table.add_row(name, *cells)
    Console().print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
