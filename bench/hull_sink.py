"""How far objects rest into the table on their collision hulls, on the remote's simulated scene.

An object that collides as one convex part collides as a hull of its surface's hull vertices. MuJoCo's own
cap (``maxhullvert`` 64, qhull's 'TA 64': the first 64 vertices it meets, not the farthest) left the hull of
a smooth 9 cm blob up to 5.8 mm inside its surface, and it rested 2.2 mm into the table: invisible to the
cameras, and the mirror image of its top, reflected at half the height they saw, closed its base 2-4 mm too
high (-6.0 % at 3 cameras). Now the hull is thinned greedily, farthest vertex first, until every vertex lies
within ``twin.objects.HULL_TOLERANCE`` of it (:func:`estimation.hull.simplified_hull`).

For the random tabletops of bench/camera_tables.py (``--scenes`` from ``--seed``), each scene is built and
settled as the remote does, twice in one process: with the hulls as built now, and as before (the full
hull, MuJoCo's 64-vertex cap). Per object: what it collides as, its collision hull's vertices, and its true
mesh's lowest point against the table's top (mm; below zero: inside the table).

    .venv/bin/python bench/hull_sink.py [--scenes 4] [--seed 0] [--out bench/results/hull_sink.txt]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from camera_tables import write_scene  # noqa: E402


@contextmanager
def mujocos_cap():  # type: ignore[no-untyped-def]
    """The hulls as they were: the whole convex hull, cut by MuJoCo to the first 64 vertices qhull meets."""
    import estimation.hull
    import twin.model

    saved = estimation.hull.simplified_hull, twin.model.MAX_HULL_VERTICES
    estimation.hull.simplified_hull = lambda points, tolerance, most: estimation.hull.convex_hull(points)
    twin.model.MAX_HULL_VERTICES = 64
    try:
        yield
    finally:
        estimation.hull.simplified_hull, twin.model.MAX_HULL_VERTICES = saved


def settle(path: Path) -> dict[str, tuple[str, int, float]]:
    """Each object of the scene at ``path``: (what collides, its colliding hull's vertices, lowest point of its
    true mesh above the table's top, mm) once the remote has let it settle."""
    import mujoco

    from scenes.remote import Remote
    from scenes.scenefile import load_scene
    from scenes.sources import reference_estimate
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    scene = load_scene(path)
    clock = SimClock()
    remote = Remote(scene, InProcessBus(clock, {}).transport("remote"), clock=clock, publish=False)
    model, top = remote.twin.model, scene.table.height
    out = {}
    for spec in scene.objects:
        vertices = reference_estimate(spec)[0].vertices
        position, quat = remote.twin.pose(spec.id)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.asarray(quat, dtype=np.float64))
        lowest = float((vertices @ rotation.reshape(3, 3).T + position)[:, 2].min())
        body = model.body(spec.id).id
        colliding = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body and model.geom_contype[g]]
        kinds = {mujoco.mjtGeom(int(model.geom_type[g])).name.removeprefix("mjGEOM_").lower() for g in colliding}
        meshes = [int(model.geom_dataid[g]) for g in colliding if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
        hull_vertices = max((int(model.mesh_graph[model.mesh_graphadr[m]]) for m in meshes), default=0)
        out[spec.id] = ("/".join(sorted(kinds)) + (f" x{len(meshes)}" if len(meshes) > 1 else ""), hull_vertices,
                        1000 * (lowest - top))
    remote.close()
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    console = Console(record=True, width=160)
    table = Table(title="random tabletops: lowest point of each object's true mesh against the table's top, mm "
                        "(below 0: inside it), after the remote lets it settle")
    for col in ("scene", "object", "collides as", "hull vertices", "now mm", "64-vertex cap", "cap mm"):
        table.add_column(col, justify="right")
    now_all, cap_all, one_part = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seed, args.seed + args.scenes):
            folder = Path(tmp) / f"table{seed}"
            folder.mkdir()
            path, _ = write_scene(folder, seed)
            now = settle(path)
            with mujocos_cap():
                cap = settle(path)
            for object_id, (kind, vertices, lowest) in now.items():
                _, vertices_cap, lowest_cap = cap[object_id]
                table.add_row(f"table{seed}", object_id, kind, str(vertices), f"{lowest:+.2f}", str(vertices_cap),
                              f"{lowest_cap:+.2f}")
                now_all.append(lowest)
                cap_all.append(lowest_cap)
                one_part.append(kind == "mesh")
    console.print(table)
    now_a, cap_a, one = np.array(now_all), np.array(cap_all), np.array(one_part)
    for label, rows in (("every object", np.ones_like(one)), ("one convex part", one)):
        console.print(f"{label} ({int(rows.sum())}): lowest point median / deepest, mm: now "
                      f"{np.median(now_a[rows]):+.2f} / {now_a[rows].min():+.2f}; with MuJoCo's 64-vertex cap "
                      f"{np.median(cap_a[rows]):+.2f} / {cap_a[rows].min():+.2f}")
    if args.out is not None:
        args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
