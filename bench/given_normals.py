"""Given normals as files carry them: outward, inward, unoriented, partly flipped; checked against trusted as given.

    .venv/bin/python bench/given_normals.py [--points 30000] | tee bench/results/given_normals.txt
    .venv/bin/python bench/given_normals.py --timing | tee bench/results/given_normals_timing.txt

Every shape of ``scenes.shapes.make_shapes(44, 11)`` and part of ``make_parts(16, 7)``, sampled with their
true outward normals, then spoiled: all flipped (another tool's inward convention), unoriented (each sign at
random, as PCA normals come), a tenth flipped at random (point by point: the spoiling draws its own seed, as
the sampler's would flip whole patches together, which the check does not see); and the outward ones again
with sigma 0.5 mm on the points (walls of 3 mm and more). Each cloud is estimated twice in this process: as the pipeline does
(``estimation.normals.orient_given`` checks them) and with the normals trusted as they came (the check
replaced by the identity: the behaviour before it). Volume error against the true mesh, median / p90 / max
over the clouds, and how many clouds the check acted on (said in the warnings).

With ``--timing``: what the check costs when it finds nothing to do (outward normals, the common case) and
when it re-signs unoriented ones, against the whole estimate of the same cloud, best of three.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import estimation.normals as normals_module
from estimation import estimate, make_cloud
from scenes.sampling import sample_surface
from scenes.shapes import make_parts, make_shapes

CONDITIONS = ("outward", "inward", "unoriented", "a tenth flipped", "outward, sigma 0.5 mm")


def spoil(normals: np.ndarray, condition: str, rng: np.random.Generator) -> np.ndarray:
    if condition == "inward":
        return -normals
    if condition == "unoriented":
        return normals * rng.choice([-1.0, 1.0], size=(len(normals), 1))
    if condition == "a tenth flipped":
        return normals * np.where(rng.uniform(size=(len(normals), 1)) < 0.1, -1.0, 1.0)
    return normals


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=30_000)
    parser.add_argument("--timing", action="store_true", help="time the check instead")
    args = parser.parse_args(argv)
    if args.timing:
        return timing()
    shapes = make_shapes(44, 11) + make_parts(16, 7)
    checked = normals_module.orient_given
    rows: dict[str, dict[str, list[float]]] = {c: {"checked": [], "trusted": [], "acted": []} for c in CONDITIONS}
    with Progress(console=Console(stderr=True), transient=True) as progress:
        task = progress.add_task("clouds", total=len(shapes) * len(CONDITIONS))
        for i, shape in enumerate(shapes):
            for c, condition in enumerate(CONDITIONS):
                noisy = condition.endswith("mm")
                if noisy and shape.min_wall < 0.003:
                    progress.advance(task)
                    continue
                cloud = sample_surface(shape.mesh, args.points, seed=[i, c], with_normals=True,
                                       noise_sigma=0.0005 if noisy else 0.0)
                spoiled = make_cloud(cloud.points, spoil(cloud.normals, condition, np.random.default_rng([i, c, 1])))
                for mode in ("checked", "trusted"):
                    normals_module.orient_given = checked if mode == "checked" else (lambda p, n, g, o: (n, None))
                    try:
                        est = estimate(spoiled, 1000.0)
                    finally:
                        normals_module.orient_given = checked
                    rows[condition][mode].append(100 * abs(est.mass.volume / shape.volume - 1))
                    if mode == "checked":
                        rows[condition]["acted"].append(any("given normals" in w for w in est.warnings))
                progress.advance(task)
    console = Console(width=160)
    table = Table(title=f"given normals, {args.points:,} points: |volume error| % over {len(shapes)} shapes and parts")
    for col in ("normals", "clouds", "check acted on", "checked: median", "p90", "max", "trusted: median", "p90 ",
                "max "):
        table.add_column(col, justify="right")
    for condition, r in rows.items():
        checked_e, trusted_e = np.array(r["checked"]), np.array(r["trusted"])
        stats = lambda e: [f"{np.median(e):.2f}", f"{np.percentile(e, 90):.2f}", f"{e.max():.2f}"]  # noqa: E731
        table.add_row(condition, str(len(checked_e)), str(int(np.sum(r["acted"]))), *stats(checked_e), *stats(trusted_e))
    console.print(table)
    return 0


def timing() -> int:
    import time

    from estimation.grid import grid_around, occupancy
    from estimation.obb import oriented_box_local

    table = Table(title="the check's cost: orient_given against the whole estimate (best of 3, ms)")
    for col in ("shape", "points", "outward: check", "unoriented: check", "estimate (outward)"):
        table.add_column(col, justify="right")
    for shape in make_shapes(20, 11)[::4]:
        for n in (30_000, 120_000):
            cloud = sample_surface(shape.mesh, n, seed=[n, 1], with_normals=True)
            box, local = oriented_box_local(cloud.points)
            normals = box.to_local(cloud.normals, direction=True)
            grid = grid_around(local, float(box.extents.max()) / 128)
            occ = occupancy(local, grid)
            unoriented = spoil(normals, "unoriented", np.random.default_rng(n))

            def best(run) -> float:  # type: ignore[no-untyped-def]
                times = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    run()
                    times.append(time.perf_counter() - t0)
                return 1e3 * min(times)

            check = normals_module.orient_given
            table.add_row(shape.name, f"{n:,}",
                          f"{best(lambda p=local, v=normals, g=grid, o=occ, f=check: f(p, v, g, o)):.0f}",
                          f"{best(lambda p=local, v=unoriented, g=grid, o=occ, f=check: f(p, v, g, o)):.0f}",
                          f"{best(lambda c=cloud: estimate(c, 1000.0)):.0f}")
    Console(width=160).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
