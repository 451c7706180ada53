"""What aligning C's poses with C' at the moment they answer to (twin/history.py) does to the force the
operator feels, with and without deferring touched objects.

    .venv/bin/python bench/alignment.py [--delays 0,50,100,200] [--task push] | tee bench/results/alignment.txt

One headless session (scenes/experiment.py's ``run_session``, small scene, clean link) per delay and setting.
"force change vs 0 ms": the RMS over the task of the twin's force magnitude at that delay less its force at
0 ms with the same setting, in % of the 0 ms peak: 0 means the network does not change what the operator
feels. ``align_window`` 0 compares every pose with C' now (no alignment); ``defer_touched`` leaves objects
the operator touches to the twin's physics until 0.5 s after release.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scenes.experiment import Condition, run_session
from scenes.scenefile import load_scene
from twin.runtime import LocalSettings

SMALL = Path(__file__).resolve().parents[1] / "tests" / "data" / "small.toml"
SETTINGS = {
    "aligned, defer touched (default)": LocalSettings(),
    "not aligned, defer touched": LocalSettings(align_window=0.0),
    "aligned, no deferring": LocalSettings(defer_touched=False),
    "not aligned, no deferring": LocalSettings(align_window=0.0, defer_touched=False),
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--delays", default="0,50,100,200", help="one-way delays, ms (0 first: the reference)")
    p.add_argument("--task", default="push")
    args = p.parse_args(argv)
    delays = [float(d) for d in args.delays.split(",")]
    scene = load_scene(SMALL)
    table = Table(title=f"twin force change against its own 0 ms force, {args.task}, % of the 0 ms peak")
    table.add_column("setting")
    for d in delays[1:]:
        table.add_column(f"{d:g} ms", justify="right")
    with tempfile.TemporaryDirectory() as cache:
        for label, settings in SETTINGS.items():
            forces = [np.linalg.norm(run_session(scene, Condition(task=args.task, delay=d / 1e3), settings=settings,
                                                 cache_dir=Path(cache)).force_twin, axis=1) for d in delays]
            peak = forces[0].max()
            table.add_row(label, *(f"{100 * np.sqrt(np.mean((f - forces[0]) ** 2)) / peak:.1f}" for f in forces[1:]))
            print(f"{label}: done", file=sys.stderr)
    Console(width=120).print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
