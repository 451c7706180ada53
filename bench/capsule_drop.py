"""Why thin capsules keep their hulls (``twin.objects.MIN_CAPSULE_RADIUS``): 8 cm capsules of several radii
dropped in 12 seeded orientations onto a 4 cm box table top from several heights (lowest point above the
table), as MuJoCo primitives and as convex meshes, 1.5 s at the twin's 1 kHz with elliptic cones. A row
says in how many of the 12 drops the capsule ended below the table top.

    .venv/bin/python bench/capsule_drop.py | tee bench/results/capsule_drop.txt
"""

from __future__ import annotations

import mujoco
import numpy as np
import trimesh

HALF_LENGTH = 0.08
TOP = 0.75
DROPS = (0.0, 0.01, 0.03, 0.1, 0.3)
RADII = (0.005, 0.0075, 0.01, 0.015, 0.02, 0.03)


def sank(geom: str, asset: str, vertices: np.ndarray, drop: float, quat: np.ndarray) -> bool:
    xml = f"""<mujoco><option timestep="0.001" cone="elliptic"/><asset>{asset}</asset><worldbody>
    <geom name="table" type="box" size="0.6 0.4 0.02" pos="0 0 {TOP - 0.02}"/>
    <body name="rod" pos="0 0 1" quat="{' '.join(map(str, quat))}"><freejoint/>{geom}</body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    lowest = (vertices @ data.xmat[1].reshape(3, 3).T + data.xpos[1])[:, 2].min()
    data.qpos[2] += TOP + drop - lowest
    for _ in range(1500):
        mujoco.mj_step(model, data)
    return bool(data.xpos[1][2] < TOP)


def main() -> None:
    rng = np.random.default_rng(1)
    quats = [q / np.linalg.norm(q) for q in rng.normal(size=(12, 4))]
    print("drops (of 12 orientations) that ended below the table top; columns: drop height of the lowest point")
    print(f"{'capsule':>24s} " + " ".join(f"{100 * d:>6.0f} cm" for d in DROPS))
    for r in RADII:
        mesh = trimesh.creation.capsule(height=2 * HALF_LENGTH, radius=r, count=[16, 16])
        v = np.asarray(mesh.vertices)
        kinds = {
            "primitive": (f'<geom type="capsule" size="{r} {HALF_LENGTH}" density="700"/>', ""),
            "convex mesh": ('<geom type="mesh" mesh="c" density="700"/>',
                            f'<mesh name="c" vertex="{" ".join(map(str, v.ravel()))}" maxhullvert="64"/>'),
        }
        for kind, (geom, asset) in kinds.items():
            counts = [sum(sank(geom, asset, v, d, q) for q in quats) for d in DROPS]
            print(f"{kind:>12s} r {1000 * r:4.1f} mm " + " ".join(f"{c:>6d}/12" for c in counts))


if __name__ == "__main__":
    main()
