"""Fidelity of the twin on the paper's eight objects: estimated record vs the true mesh, and rest pose.

    .venv/bin/python bench/fidelity.py

The comparison tests/test_fidelity.py asserts (mass 0.5 %, COM 1 mm, inertia 2 % Frobenius, rest pose
within 1.5 % of the object's size and 3 degrees), printed with the measured values so the margins show.
"""

from __future__ import annotations

import sys
from importlib import resources
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scenes.fidelity import compare
from scenes.scenefile import load_scene
from scenes.sources import estimate_object, prepare_objects, reference_estimate


def main() -> int:
    scene = load_scene(str(resources.files("scenes").joinpath("data/paper_table.toml")))
    top = scene.table.height if scene.table else None
    est = prepare_objects(scene.objects, table_top=top, estimates=[estimate_object(s) for s in scene.objects])
    ref = prepare_objects(scene.objects, table_top=top, estimates=[reference_estimate(s) for s in scene.objects])
    table = Table(title="twin from 100k-point clouds vs reference from the true meshes (paper_table)")
    for col in ("object", "size m", "mass err %", "COM err mm", "inertia err %", "hulls est/ref",
                "rest diff mm", "rest diff % size", "rest angle deg"):
        table.add_column(col, justify="right")
    for e, r in zip(est, ref, strict=True):
        f = compare(scene, e, r)
        table.add_row(e.id, f"{f.size:.2f}", f"{100 * f.mass_error:+.3f}", f"{1e3 * f.com_error:.3f}",
                      f"{100 * f.inertia_error:.3f}", f"{len(e.hulls)}/{len(r.hulls)}",
                      f"{1e3 * f.rest_distance:.2f}", f"{100 * f.rest_distance / f.size:.2f}", f"{f.rest_angle:.2f}")
    Console(width=200).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
