"""What it costs the twin to make each camera-scanned object: estimate, then what collides.

    .venv/bin/python bench/camera_add.py                    # clutter20; output in bench/results/camera_add.txt
    .venv/bin/python bench/camera_add.py --scene my.toml --cameras 2

The remote scans the scene with its default camera rig (``CameraSensor.for_scene``) and publishes every
object's cloud; each cloud goes through the wire's codec and is made into a twin object as an estimation
worker does (``twin.runtime.build_from_cloud``: estimate, visual mesh, collision shapes). Two ways, in this
process, each with an empty CoACD cache: the current one (``twin.objects.collision_shapes``: an object that
fits a primitive collides as it, and CoACD is not run for it) and the baseline, CoACD for every object (as
before session 38: the hulls were made, then left not colliding under the primitive). Times are one core's
wall seconds; the twin's workers do this while its 1 kHz loop and the remote share the machine, so a live
twin takes longer (``twin demo --json`` -> ``add_latency_s``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from importlib import resources
from pathlib import Path

from rich.console import Console
from rich.progress import track
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def published_clouds(scene, cameras: int) -> dict[str, bytes]:  # type: ignore[no-untyped-def]
    """Every cloud message the remote publishes at start, by object id, as it went on the wire."""
    from scenes.remote import Remote
    from scenes.sensing import CameraSensor
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus
    from sync.messages import Cloud, decode

    clock = SimClock()
    bus = InProcessBus(clock, {})
    clouds: dict[str, bytes] = {}

    def keep(key: str, data: bytes) -> None:
        msg = decode(data)
        if isinstance(msg, Cloud):
            clouds[msg.object_id] = data

    bus.transport("twin").subscribe("**", keep)
    Remote(scene, bus.transport("remote"), clock=clock, sensor=CameraSensor.for_scene(scene, cameras=cameras)).close()
    return clouds


def main() -> None:
    from estimation import estimate, make_cloud
    from scenes.scenefile import load_scene
    from sync.messages import decode, unpack_normals, unpack_points
    from twin.decompose import DEFAULT_SETTINGS, decompose
    from twin.objects import collision_shapes, visual_mesh

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, default=Path(str(resources.files("scenes").joinpath("data/clutter20.toml"))))
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "camera_add.txt")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    clouds = published_clouds(scene, args.cameras)
    table = Table(title=f"{args.scene.name}, {args.cameras} cameras: seconds to make each object from its cloud")
    for col in ("object", "points", "estimate s", "collides as", "shapes s", "CoACD for all s"):
        table.add_column(col, justify="right")
    totals = [0.0, 0.0, 0.0]
    with tempfile.TemporaryDirectory() as now, tempfile.TemporaryDirectory() as before:
        for object_id in track(sorted(clouds), description="objects", console=Console(stderr=True)):
            msg = decode(clouds[object_id])
            points = unpack_points(msg)
            t0 = time.perf_counter()
            est = estimate(make_cloud(points, unpack_normals(msg)), 1000.0)
            visual = visual_mesh(est)
            t1 = time.perf_counter()
            ((hulls, _, primitive),) = collision_shapes([visual], cache_dir=Path(now), progress=False)
            t2 = time.perf_counter()
            decompose(*visual, DEFAULT_SETTINGS, cache_dir=Path(before))
            t3 = time.perf_counter()
            times = (t1 - t0, t2 - t1, t3 - t2)
            totals = [a + b for a, b in zip(totals, times, strict=True)]
            how = primitive.kind if primitive else f"{len(hulls)} hull(s)"
            table.add_row(object_id, f"{len(points):,}", *(f"{t:.2f}" for t in times[:1]), how,
                          *(f"{t:.2f}" for t in times[1:]))
    table.add_row("all", "", f"{totals[0]:.1f}", "", f"{totals[1]:.1f}", f"{totals[2]:.1f}")
    console = Console(record=True, width=120)
    console.print(table)
    console.print(f"estimate + shapes: {totals[0] + totals[1]:.1f} s now, {totals[0] + totals[2]:.1f} s with CoACD "
                  f"for every object ({(totals[0] + totals[2]) / (totals[0] + totals[1]):.2f}x)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(console.export_text())


if __name__ == "__main__":
    main()
