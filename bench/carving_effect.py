"""What carving does to camera-built volumes: the random tabletops of bench/camera_tables.py, each object's
fused segment closed with and without carving (``CameraSensor._fuse``, which closes it with the scan's
depth views, or with none: mirror image and base only), estimated ('auto') through the wire's codec.

    .venv/bin/python bench/carving_effect.py [--scenes 4] [--cameras 1 3] | tee bench/results/carving_effect.txt
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from camera_tables import CAMERA, write_scene  # noqa: E402


def main() -> int:
    from estimation import estimate, make_cloud
    from estimation.errors import TwinError
    from scenes import cameras as cams
    from scenes.remote import Remote
    from scenes.scenefile import load_scene
    from scenes.sensing import CameraSensor
    from scenes.sources import reference_estimate
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus
    from sync.messages import as_received

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 3])
    args = ap.parse_args()
    logging.disable(logging.WARNING)  # the feed's unseen-object lines; the table says it
    errors: dict[int, list[tuple[float, float]]] = {k: [] for k in args.cameras}
    print(f"{'scene':>7s} {'cams':>4s} {'object':>24s} {'fill':>5s} {'no carving %':>13s} {'carving %':>10s}")
    for seed in range(args.scenes):
        with tempfile.TemporaryDirectory(prefix="carving-") as tmp:
            path, fills = write_scene(Path(tmp), seed)
            scene = load_scene(path)
            for k in args.cameras:
                clock = SimClock()
                remote = Remote(scene, InProcessBus(clock, {}).transport("remote"), clock=clock, publish=False)
                sensor = CameraSensor.for_scene(scene, cameras=k, seed=1, noise=cams.SIGMA_1MM, **CAMERA)
                scan = sensor._current(remote, force=True)
                for spec in scene.objects:
                    at = sensor._associate(remote, scan, spec.id)
                    if at is None:
                        continue
                    truth = reference_estimate(spec)[0].volume
                    out = []
                    for carve in (False, True):
                        closed = sensor._fuse(scan, scan.segments[at], carve=carve)
                        try:
                            volume = estimate(make_cloud(*as_received(closed.points, closed.normals)), 1000.0).volume
                            out.append(100 * (volume / truth - 1))
                        except TwinError:
                            out.append(float("nan"))
                    errors[k].append((out[0], out[1]))
                    print(f"table{seed:<2d} {k:>4d} {spec.id:>24s} {fills[spec.id]:5.2f} {out[0]:+13.1f} {out[1]:+10.1f}",
                          flush=True)
                remote.close()
    for k, rows in errors.items():
        a = np.abs(np.array(rows))
        print(f"{k} camera(s), {len(a)} objects: median |error| {np.nanmedian(a[:, 0]):.1f} % without carving, "
              f"{np.nanmedian(a[:, 1]):.1f} % with; max {np.nanmax(a[:, 0]):.1f} / {np.nanmax(a[:, 1]):.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
