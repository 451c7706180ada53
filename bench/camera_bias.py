"""Where the camera feed's volume error on random tabletops comes from: observed points, or what completes them.

bench/camera_tables.py measures the error; this splits it. Each object of a random tabletop (the same scenes,
``camera_tables.write_scene``) is scanned by N cameras at sigma 1 mm, fused and closed as the remote does
(``CameraSensor.observe``), and estimated four times from the same cloud:

- as the twin gets it;
- with the carved points (the surface of the solid no camera saw through, ``estimation.carving``) moved onto
  the nearest point of the true surface;
- with every completed point (mirror image, half turn, carved surface) moved there;
- with every observed point moved there instead (the noise and the fusion's offsets taken away).

The true surface is used only to measure, as in the other camera benches. Offsets are signed distances from
the true surface, outward positive (Open3D's ray-casting scene).

What moves the carved points, with the same scenes: ``--noise exact`` (no noise at all) or ``axial`` (1 mm axial
noise and nothing else of the sensor model: no dropouts, flying pixels, quantisation or incidence term);
``--margin-sigmas S`` carves with ``estimation.carving.FREE_SIGMAS`` (the noise margin a camera leaves in
front of its depth) set to S.

    .venv/bin/python bench/camera_bias.py [--tables 0 1 2 3] [--cameras 3] [--noise sigma1mm|axial|exact]
        [--margin-sigmas S] [--out bench/results/camera_bias.txt]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from camera_tables import CAMERA, write_scene  # noqa: E402


class _Completions:
    """Keeps the last :class:`estimation.completion.Completion` the sensor made (its counts say which of the
    completed points were carved)."""

    def __init__(self) -> None:
        import estimation.completion as completion

        self.last = None
        original = completion.close_on_plane

        def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
            closed = original(*args, **kwargs)
            self.last = closed.completion
            return closed

        completion.close_on_plane = spy


def _true_surface(mesh, pos: np.ndarray, quat: np.ndarray):  # type: ignore[no-untyped-def]
    """:func:`scenes.shapes.surface_scene` of ``mesh`` (body frame) moved to the pose (position, quaternion w x y z)."""
    from scenes.shapes import surface_scene
    from twin.poses import rotation

    world = mesh.copy()
    world.vertices = np.asarray(mesh.vertices) @ rotation(quat).T + pos
    return surface_scene(world)


def _error(moved: np.ndarray, points: np.ndarray, normals: np.ndarray, on_truth: np.ndarray, density: float,
           truth: float, support) -> float:  # type: ignore[no-untyped-def]
    """Volume error (%) of the cloud ``points`` with the ``moved`` rows replaced by ``on_truth``'s, as the twin gets
    it (through the wire's codec, cut at the ``support`` plane it was closed on)."""
    from estimation import estimate, make_cloud
    from estimation.views import on_support
    from sync.messages import as_received

    cloud = np.where(moved[:, None], on_truth, points)
    return 100 * (on_support(estimate(make_cloud(*as_received(cloud, normals)), density), support).volume / truth - 1)


#: ``--noise``'s names, as the tables' titles say them.
NOISE_LABELS = {"sigma1mm": "sigma 1 mm", "axial": "1 mm axial noise only", "exact": "exact depth"}


def _noise(name: str):  # type: ignore[no-untyped-def]
    """The depth noise model ``--noise`` names."""
    from dataclasses import replace

    from scenes import cameras as cams

    return {"sigma1mm": cams.SIGMA_1MM, "exact": cams.EXACT, "axial": replace(cams.EXACT, axial_const=1e-3)}[name]


def table_rows(seed: int, cameras: int, completions: _Completions, noise: str = "sigma1mm") -> list[dict]:
    """One row per object of random tabletop ``seed``: errors (%) as estimated and with parts moved onto the truth."""
    import open3d as o3d

    from scenes.remote import Remote
    from scenes.scenefile import load_scene
    from scenes.sensing import CameraSensor
    from scenes.sources import reference_estimate
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    with tempfile.TemporaryDirectory() as folder:
        path, _ = write_scene(Path(folder), seed)
        scene = load_scene(path)
        clock = SimClock()
        remote = Remote(scene, InProcessBus(clock, {}).transport("remote"), clock=clock, publish=False)
        sensor = CameraSensor.for_scene(scene, cameras=cameras, seed=1, noise=_noise(noise), rest_window=1, **CAMERA)
        rows = []
        for spec in scene.objects:
            completions.last = None
            seen = sensor.observe(remote, spec.id, 0, shot=1)
            c = completions.last
            completed = np.zeros(len(seen.points), bool) if seen.completed is None else seen.completed
            if len(seen.points) < 100 or c is None or c.mirrored + c.turned + c.carved != completed.sum():
                print(f"table{seed}/{spec.id}: not seen, or its completion not this scan's: left out", file=sys.stderr)
                continue
            ref = reference_estimate(spec)[0]
            truth, density = ref.volume, ref.mass.mass / ref.volume
            surface = _true_surface(remote.true_surface(spec.id), *remote.twin.pose(spec.id))
            query = o3d.core.Tensor(seen.points.astype(np.float32))
            offset = surface.compute_signed_distance(query).numpy().astype(float)  # negative inside
            on_truth = surface.compute_closest_points(query)["points"].numpy().astype(float)
            carved = np.zeros(len(seen.points), bool)
            carved[np.flatnonzero(completed)[c.mirrored + c.turned:]] = True

            observed = ~completed
            cloud = (seen.points, seen.normals, on_truth, density, truth, seen.support)
            rows.append({
                "object": f"table{seed}/{spec.id}",
                "error": _error(np.zeros(len(observed), bool), *cloud),
                "carved on truth": _error(carved, *cloud),
                "completed on truth": _error(completed, *cloud),
                "observed on truth": _error(observed, *cloud),
                "completed share": 100 * completed.mean(),
                "observed offset": 1000 * offset[observed].mean(),
                "carved offset": 1000 * offset[carved].mean() if carved.any() else float("nan"),
                "other completed offset": (1000 * offset[completed & ~carved].mean()
                                           if (completed & ~carved).any() else float("nan")),
            })
            print(f"{rows[-1]['object']}: {rows[-1]['error']:+.2f} %", file=sys.stderr, flush=True)
        remote.close()
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tables", type=int, nargs="+", default=[0, 1, 2, 3], help="random tabletop seeds (default 0-3)")
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--noise", choices=tuple(NOISE_LABELS), default="sigma1mm")
    ap.add_argument("--margin-sigmas", type=float, default=None, help="carve with FREE_SIGMAS set to this")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "camera_bias.txt")
    args = ap.parse_args()
    import estimation.carving as carving

    if args.margin_sigmas is not None:
        carving.FREE_SIGMAS = args.margin_sigmas
    completions = _Completions()
    rows = [row for seed in args.tables for row in table_rows(seed, args.cameras, completions, args.noise)]
    console = Console(record=True, width=200)
    condition = NOISE_LABELS[args.noise]
    if args.margin_sigmas is not None:
        condition += f", carving margin {args.margin_sigmas:g} sigma"
    detail = Table(title=f"{args.cameras} cameras, {condition}: volume error % of each object, as estimated and with "
                         "parts of its cloud moved onto the true surface; offsets mm (outward +)")
    keys = ("error", "carved on truth", "completed on truth", "observed on truth", "completed share",
            "observed offset", "carved offset", "other completed offset")
    detail.add_column("object")
    for key in keys:
        detail.add_column(key, justify="right")
    for row in rows:
        detail.add_row(row["object"], *(f"{row[k]:+.2f}" if k != "completed share" else f"{row[k]:.0f} %" for k in keys))
    console.print(detail)
    summary = Table(title=f"over {len(rows)} objects of tables {' '.join(map(str, args.tables))}")
    for col in ("cloud", "median |error| %", "median signed %", "within 2 %"):
        summary.add_column(col, justify="right")
    for key in keys[:4]:
        values = np.array([row[key] for row in rows])
        summary.add_row(key, f"{np.median(np.abs(values)):.2f}", f"{np.median(values):+.2f}",
                        f"{int((np.abs(values) < 2).sum())} of {len(values)}")
    console.print(summary)
    for key in keys[5:]:
        values = np.array([row[key] for row in rows])
        values = values[np.isfinite(values)]
        console.print(f"{key}: median {np.median(values):+.3f} mm over {len(values)} objects")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
