"""What the table's top as a plane (``twin.tabletop``) buys and moves, measured in one process.

1. Where an awake step goes: clutter20's twin as the headless session builds it, sleeping off, every object
   kicked at 0.2-0.4 m/s every 0.5 s and the end effector sweeping, 2 s; MuJoCo's own timers (a timer
   callback costs a little itself: read the shares, not the totals), contacts per step by geom pair, and
   positions + collision alone re-timed over the same states with the table's box turned into a plane.
2. Steps per CPU second with every body awake, the plane dropped ("box") and kept ("plane"), alternating.
3. Where the scenes settle with the plane turned off and on (``PhysicsSettings(table_plane=...)``): the
   largest move of any object of clutter20 and the paper table after 3 s.

    .venv/bin/python bench/table_plane.py [--repeats 4] [--out bench/results/table_plane.txt]
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from collections import Counter
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from replay import _kick, box_table, twin_rates  # noqa: E402

from scenes.headless import Headless  # noqa: E402
from scenes.scenefile import SceneSpec, load_scene  # noqa: E402
from twin.model import DEFAULT_PHYSICS  # noqa: E402
from twin.sim import Twin  # noqa: E402
from twin.tabletop import PLANE_NAME  # noqa: E402
from twin.trajectory import push_trajectory  # noqa: E402

CACHE = ROOT / ".cache" / "bench-headless"
TIMERS = ("STEP", "POS_COLLISION", "COL_NARROW", "CONSTRAINT")


def _clutter_spec():  # type: ignore[no-untyped-def]
    with Headless(load_scene(SCENES["clutter20"]), cache_dir=CACHE) as s:
        s.tick()  # the twin takes in every estimated object at its first tick
        return s.local.twin.spec.copy()


SCENES = {name: Path(str(resources.files("scenes").joinpath(f"data/{name}.toml")))
          for name in ("clutter20", "paper_table")}


def where_it_goes(spec, console: Console) -> None:  # type: ignore[no-untyped-def]
    import mujoco

    awake = spec.copy()
    awake.option.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    box_table(awake)  # every object on the box: the states the plane is then timed over
    with Twin(awake) as twin:
        m, d = twin.model, twin.data
        start = d.mocap_pos[0].copy()
        push = push_trajectory(start, start + np.array([1.0, 0.6, -0.03]), 2.0, start_time=twin.time)
        rng, pairs, states, n = np.random.default_rng(0), Counter(), [], 2000
        mujoco.set_mjcb_time(lambda: time.perf_counter() * 1e3)
        try:
            for k in range(n):
                if k % 500 == 0:
                    _kick(twin, rng)
                twin.set_end_effector(push(twin.time))
                twin.step()
                if k % 10 == 0:
                    states.append((d.qpos.copy(), d.mocap_pos.copy()))
                    for g1, g2 in d.contact.geom[:d.ncon]:
                        names = sorted(mujoco.mjtGeom(m.geom_type[g]).name.removeprefix("mjGEOM_").lower() for g in (g1, g2))
                        pairs["-".join(names)] += 1
            us = {t: d.timer[getattr(mujoco.mjtTimer, f"mjTIMER_{t}")].duration / n * 1e3 for t in TIMERS}
        finally:
            mujoco.set_mjcb_time(None)
        table = Table(title="clutter20, every body awake: MuJoCo's timers, us a step (table as a box)")
        for col in ("step", "collision", "of it narrow phase", "constraint solver"):
            table.add_column(col, justify="right")
        table.add_row(*(f"{us[t]:.0f}" for t in TIMERS))
        console.print(table)
        console.print("contacts a step by pair: " + ", ".join(f"{p} {c / len(states):.1f}" for p, c in pairs.most_common()))

        def collide_us(model) -> float:  # type: ignore[no-untyped-def]
            data = mujoco.MjData(model)
            t0 = time.perf_counter()
            for q, mocap in states * 5:
                data.qpos[:], data.mocap_pos[:] = q, mocap
                mujoco.mj_kinematics(model, data)
                mujoco.mj_comPos(model, data)
                mujoco.mj_collision(model, data)
            return (time.perf_counter() - t0) / (5 * len(states)) * 1e6

        plane = copy.copy(m)
        top = mujoco.mj_name2id(plane, mujoco.mjtObj.mjOBJ_GEOM, "table")
        plane.geom_type[top] = mujoco.mjtGeom.mjGEOM_PLANE  # the same states, the box's top face as a plane
        plane.geom_pos[top][2] += plane.geom_size[top][2]
        plane.geom_rbound[top] = 0.0
        console.print(f"positions + collision over the same {len(states)} states: table a box {collide_us(m):.1f} us, "
                      f"a plane {collide_us(plane):.1f} us")


def rates(spec, repeats: int, console: Console) -> None:  # type: ignore[no-untyped-def]
    box = spec.copy()
    box_table(box)
    table = Table(title="clutter20 twin, steps per CPU second (alternating runs of 2 s, one process)")
    for col in ("run", "awake, box", "awake, plane", "ratio", "asleep, box", "asleep, plane"):
        table.add_column(col, justify="right")
    for k in range(repeats):
        b, p = twin_rates(box, 2.0, repeats=1), twin_rates(spec, 2.0, repeats=1)
        table.add_row(str(k + 1), f"{b['awake']:,.0f}", f"{p['awake']:,.0f}", f"{p['awake'] / b['awake']:.2f}x",
                      f"{b['asleep']:,.0f}", f"{p['asleep']:,.0f}")
    console.print(table)


def settling(console: Console) -> None:
    original = SceneSpec.empty_spec
    table = Table(title="where the scenes settle, 3 s: the plane turned off against on")
    for col in ("scene", "objects", "largest move mm", "largest turn deg"):
        table.add_column(col, justify="right")
    for name, path in SCENES.items():
        poses = []
        for plane in (False, True):
            physics = replace(DEFAULT_PHYSICS, table_plane=plane)
            SceneSpec.empty_spec = lambda self, physics=physics: original(self, physics)  # type: ignore[method-assign]
            try:
                with Headless(load_scene(path), cache_dir=CACHE) as s:
                    s.remote.twin.step(3000)
                    poses.append({i: s.remote.twin.pose(i) for i in s.remote.twin.object_ids()})
            finally:
                SceneSpec.empty_spec = original  # type: ignore[method-assign]
        off, on = poses
        move = max(float(np.linalg.norm(off[i][0] - on[i][0])) for i in off)
        turn = max(float(np.degrees(2 * np.arccos(min(1.0, abs(float(off[i][1] @ on[i][1])))))) for i in off)
        table.add_row(name, str(len(off)), f"{1e3 * move:.3f}", f"{turn:.3f}")
    console.print(table)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=4, help="alternating rate runs (default 4)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "table_plane.txt")
    args = ap.parse_args()
    console = Console(record=True, width=160)
    spec = _clutter_spec()
    assert any(g.name == PLANE_NAME for g in spec.geoms), "the twin's model has no table-top plane"
    where_it_goes(spec, console)
    rates(spec, args.repeats, console)
    settling(console)
    args.out.write_text(console.export_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
