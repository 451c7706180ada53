"""Whether a scene's objects fit where its file puts them: two solids cannot share space.

A scene file places objects and does not promise they rest there (a stack may topple, and the remote lets
it settle), but objects placed inside each other, inside the table or the floor, or round the operator's end
effector are no scene at all: MuJoCo pushes them apart in the first steps, and the scene silently became
another one (a can placed in a crate came to rest on top of it; a 5 cm box whose top was placed 2.5 cm
below the table top, 15 mm into the 4 cm slab, fell through it to the floor). :func:`check_placement` reads a model's contacts at the file's poses before
anything steps, and refuses the scene; ``twin build``, ``twin run`` (of a scene file, or of a folder ``twin build``
wrote, which may have been edited since) and the remote (at start, and for each object added or moved at run
time) all call it.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco

from scenes.scenefile import SceneError
from twin.model import EE_BODY

#: Metres. Objects whose collision shapes (primitives, convex hulls) interpenetrate deeper than this at the
#: file's poses overlap. The slack is for shapes that touch: a hull of a concave part fills its hollows by
#: up to about this (``twin.decompose``'s settings), and objects stacked by hand carry rounding.
OVERLAP_DEPTH = 0.002

#: Metres an object may reach into the table or the floor. A scan placed by its own frame (``position`` with
#: a height) rests where the cameras saw it, and its reconstructed bottom lies within the sensor's noise of
#: the table it stood on: a depth camera at a table's distance has an axial sigma of a few millimetres
#: (``scenes.cameras``' Kinect model, ~5 mm at 1.5 m), so twice that is lifted out, not refused.
SUPPORT_DEPTH = 0.01

#: The scene's world geoms as messages name them, by their ``twin.model`` names.
_FIXED = {"table": "the table", "table/top": "the table", "floor": "the floor"}


@dataclass(frozen=True)
class Overlap:
    """An object and what its collision shapes interpenetrate: another object (``second`` its id) or the
    scene's own geometry (``fixed``: ``second`` is "the table", "the floor" or "the end effector (...)");
    ``depth`` metres at the deepest contact."""

    first: str
    second: str
    depth: float
    fixed: bool = False

    def __str__(self) -> str:
        other = self.second if self.fixed else f"'{self.second}'"
        return f"'{self.first}' and {other} by {1000 * self.depth:.1f} mm"


def overlaps(model: mujoco.MjModel, data: mujoco.MjData, names: set[str], *, depth: float = OVERLAP_DEPTH,
             support_depth: float = SUPPORT_DEPTH, scanned: frozenset[str] | set[str] = frozenset()) -> list[Overlap]:
    """What the bodies named in ``names`` (the objects) interpenetrate in ``data`` (after ``mj_forward``),
    deepest first, each pair once: another object or the end effector deeper than ``depth`` metres, the
    table or the floor deeper than ``support_depth``. A pair with an object in ``scanned`` (a cloud placed by
    its own frame, whose surface is as noisy as its sensor) is held to ``support_depth`` too."""
    n = data.ncon
    if n == 0:
        return []
    ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, EE_BODY)
    deepest: dict[tuple[str, str, bool], float] = {}
    geoms = data.contact.geom[:n]  # (n, 2)
    for pair, dist in zip(geoms.tolist(), data.contact.dist[:n].tolist(), strict=True):
        # The scene's own parts by body id (world geoms: the table and the floor; the end effector's body),
        # never by name: an object may be called 'table'.
        ends = [_part(model, g, ee) for g in pair]
        objects = [name for name, kind in ends if kind == "object" and name in names]
        if len(objects) == 2 and objects[0] != objects[1]:
            first, second = sorted(objects)
            key = (first, second, False)
            limit = support_depth if scanned & {first, second} else depth
        elif len(objects) == 1:
            other = next(((name, kind) for name, kind in ends if kind != "object"), None)
            if other is None:
                continue
            key = (objects[0], other[0], True)
            limit = depth if other[1] == "effector" and objects[0] not in scanned else support_depth
        else:
            continue
        if -dist > limit:
            deepest[key] = max(deepest.get(key, 0.0), -dist)
    found = [Overlap(a, b, d, fixed) for (a, b, fixed), d in deepest.items()]
    return sorted(found, key=lambda o: (-o.depth, o.first, o.second))


def describe(found: list[Overlap]) -> str:
    """One line naming what overlaps (at most three, deepest first), millimetres."""
    shown = "; ".join(str(o) for o in found[:3])
    more = f" (and {len(found) - 3} more)" if len(found) > 3 else ""
    return (f"objects placed inside each other or the scene: {shown}{more}; move them apart (deeper than "
            f"{1000 * OVERLAP_DEPTH:g} mm; {1000 * SUPPORT_DEPTH:g} mm into the table or floor)")


def check_placement(scene: str, model: mujoco.MjModel, names: set[str], data: mujoco.MjData | None = None, *,
                    scanned: frozenset[str] | set[str] = frozenset(), added: str | None = None,
                    moved: bool = False) -> None:
    """Raise :class:`SceneError` (one line, naming the scene) if the objects ``names`` overlap at the model's
    initial poses (:func:`overlaps`; ``scanned``: the objects that are clouds placed by their own frame);
    ``data``: that state already forwarded (else a fresh one is made). ``added``: an object just added to a
    running scene (``moved``: or just moved in it); only what it overlaps counts."""
    if data is None:
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
    found = overlaps(model, data, names, scanned=scanned)
    if added is not None:
        found = [o for o in found if added in (o.first, o.second)]
    if found:
        what = "" if added is None else f"{added!r} {'moved' if moved else 'added'} at run time: "
        raise SceneError(f"{scene}: {what}{describe(found)}")


def _part(model: mujoco.MjModel, geom: int, ee: int) -> tuple[str, str]:
    """(name, kind) of a contact's geom: a world geom ("support": "the table", "the floor"), the end effector
    ("effector", with where it starts: a scene without ``[end_effector]`` has the default one), or an object
    ("object", its body's name)."""
    body = int(model.geom_bodyid[geom])
    if body == 0:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom) or "world"
        return _FIXED.get(name, f"the scene's {name!r}"), "support"
    if body == ee:
        x, y, z = (float(v) for v in model.body_pos[ee])
        return f"the end effector (starting at {x:.3f}, {y:.3f}, {z:.3f} m)", "effector"
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) or "", "object"
