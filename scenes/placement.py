"""Whether a scene's objects fit where its file puts them: two solids cannot share space.

A scene file places objects and does not promise they rest there (a stack may topple, and the remote lets
it settle), but objects placed inside each other are no scene at all: MuJoCo pushes them apart in the first
steps, and the remote scene C silently became another one (a can placed in a crate came to rest on top of
it). The remote checks its model's contacts at the file's poses before it steps, and refuses the scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

#: Metres. Objects whose collision shapes (primitives, convex hulls) interpenetrate deeper than this at the
#: file's poses overlap. The slack is for shapes that touch: a hull of a concave part fills its hollows by
#: up to about this (``twin.decompose``'s settings), and objects stacked by hand carry rounding.
OVERLAP_DEPTH = 0.002


@dataclass(frozen=True)
class Overlap:
    """Two objects whose collision shapes interpenetrate: ``depth`` metres at the deepest contact."""

    first: str
    second: str
    depth: float


def overlaps(model: mujoco.MjModel, data: mujoco.MjData, names: set[str], *,
             depth: float = OVERLAP_DEPTH) -> list[Overlap]:
    """Pairs of the bodies named in ``names`` whose contacts in ``data`` (after ``mj_forward``) are deeper
    than ``depth`` metres, deepest first; each pair once. Contacts with other bodies (the table) are not
    looked at."""
    n = data.ncon
    if n == 0:
        return []
    bodies = model.geom_bodyid[data.contact.geom[:n]]  # (n, 2)
    deepest: dict[tuple[str, str], float] = {}
    for (a, b), dist in zip(bodies.tolist(), data.contact.dist[:n].tolist(), strict=True):
        if -dist <= depth or a == b:
            continue
        pair = tuple(sorted((mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, a) or "",
                             mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or "")))
        if pair[0] in names and pair[1] in names:
            deepest[pair] = max(deepest.get(pair, 0.0), -dist)
    found = [Overlap(a, b, d) for (a, b), d in deepest.items()]
    return sorted(found, key=lambda o: (-o.depth, o.first, o.second))


def describe(found: list[Overlap]) -> str:
    """One line naming the overlapping pairs (at most three, deepest first), millimetres."""
    shown = "; ".join(f"'{o.first}' and '{o.second}' by {1000 * o.depth:.1f} mm" for o in found[:3])
    more = f" (and {len(found) - 3} more pairs)" if len(found) > 3 else ""
    return f"objects placed inside each other: {shown}{more}; move them apart (deeper than {1000 * OVERLAP_DEPTH:g} mm)"
