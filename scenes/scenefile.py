"""Scene files: a small TOML document listing objects, the table and the operator's end effector.

Schema (SI units; every key is checked, an unknown one is an error naming it)::

    name = "tabletop"                      # required
    [table]                                # optional; omit for objects on the floor
    size = [1.2, 0.8, 0.04]                # full extents, m
    height = 0.75                          # top surface above the floor, m
    material = "wood_oak"
    [end_effector]                         # optional
    radius = 0.02                          # sphere, m
    position = [0.0, -0.3, 0.85]           # start, world frame, m
    [[objects]]
    id = "mug"                             # unique, [A-Za-z0-9_-]
    paper = "mug"                          # exactly one source: paper | mesh | cloud | primitive
    # mesh = "assets/mug.stl"              # a mesh file (relative to the scene file), sampled to a cloud
    # cloud = "scans/mug.ply"              # a cloud file, estimated as is
    # primitive = { type = "box", size = [0.1, 0.05, 0.03] }   # box|cylinder|sphere|capsule|torus
    units = "m"                            # of the mesh/cloud file: m | cm | mm
    material = "ceramic"                   # or: density = 2400
    position = [0.1, 0.2]                  # [x, y]: rest on the table; [x, y, z]: exactly there
    rotation_deg = [0, 0, 30]              # about Z, then local X, then local Y (the paper's order)
    points = 100000                        # cloud size when sampling a mesh/primitive/paper object
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from estimation.errors import TwinError
from twin.model import DEFAULT_PHYSICS, EndEffectorSpec, PhysicsSettings, TableSpec, new_spec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class SceneError(TwinError, ValueError):
    """A scene file that cannot be used; the message names the object and the problem."""


SOURCES = ("paper", "mesh", "cloud", "primitive")
PRIMITIVES = {"box": 3, "cylinder": 2, "sphere": 1, "capsule": 2, "torus": 2}
_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a scene, as written in the file (paths resolved)."""

    id: str
    source: str
    value: object
    material: str | None = None
    density: float | None = None
    units: str = "m"
    position: tuple[float, ...] = (0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    points: int = 100_000


@dataclass(frozen=True)
class SceneSpec:
    name: str
    objects: tuple[ObjectSpec, ...]
    table: TableSpec | None = None
    end_effector: EndEffectorSpec | None = field(default_factory=EndEffectorSpec)
    path: Path | None = None

    def empty_spec(self, physics: PhysicsSettings = DEFAULT_PHYSICS):  # type: ignore[no-untyped-def]
        """An MjSpec of this scene's floor, table and end effector, with no objects yet."""
        return new_spec(self.name, table=self.table, end_effector=self.end_effector, physics=physics)


_TOP_KEYS = {"name", "table", "end_effector", "objects"}
_OBJECT_KEYS = {"id", *SOURCES, "units", "material", "density", "position", "rotation_deg", "points"}


def load_scene(path: str | Path) -> SceneSpec:
    """Read and validate a scene file.

    Raises:
        SceneError: unreadable TOML, unknown keys, missing or duplicate ids, bad values, missing files.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: no such scene file")
    try:
        doc = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from exc
    return parse_scene(doc, base=path.parent, path=path)


def parse_scene(doc: dict, *, base: Path = Path("."), path: Path | None = None) -> SceneSpec:
    """Validate a scene document (the parsed TOML) into a :class:`SceneSpec`."""
    _no_unknown(doc, _TOP_KEYS, "scene")
    if "name" not in doc:
        raise SceneError("scene: missing 'name'")
    table = None
    if "table" in doc:
        t = doc["table"]
        _no_unknown(t, {"size", "height", "material"}, "table")
        table = TableSpec(size=_vec(t.get("size", TableSpec.size), 3, "table.size", positive=True),
                          height=float(t.get("height", TableSpec.height)),
                          material=str(t.get("material", TableSpec.material)))
    ee = EndEffectorSpec()
    if "end_effector" in doc:
        e = doc["end_effector"]
        _no_unknown(e, {"radius", "position"}, "end_effector")
        ee = EndEffectorSpec(radius=_positive(e.get("radius", ee.radius), "end_effector.radius"),
                             position=_vec(e.get("position", ee.position), 3, "end_effector.position"))
    objects = tuple(_parse_object(o, i, base) for i, o in enumerate(doc.get("objects", [])))
    ids = [o.id for o in objects]
    dupes = {i for i in ids if ids.count(i) > 1}
    if dupes:
        raise SceneError(f"scene: duplicate object id(s) {sorted(dupes)}")
    return SceneSpec(name=str(doc["name"]), objects=objects, table=table, end_effector=ee, path=path)


def _parse_object(o: dict, index: int, base: Path) -> ObjectSpec:
    where = f"object {o.get('id', f'#{index}')!r}"
    if not isinstance(o, dict):
        raise SceneError(f"{where}: expected a table")
    _no_unknown(o, _OBJECT_KEYS, where)
    oid = o.get("id")
    if not isinstance(oid, str) or not _ID.match(oid):
        raise SceneError(f"{where}: 'id' must be 1-64 characters of letters, digits, '_' or '-'")
    sources = [s for s in SOURCES if s in o]
    if len(sources) != 1:
        raise SceneError(f"{where}: needs exactly one source of {', '.join(SOURCES)}; got {sources or 'none'}")
    source = sources[0]
    value = o[source]
    if source in ("mesh", "cloud"):
        value = (base / str(value)).resolve()
        if not value.is_file():
            raise SceneError(f"{where}: {source} file {value} does not exist")
    elif source == "primitive":
        if not isinstance(value, dict) or value.get("type") not in PRIMITIVES:
            raise SceneError(f"{where}: primitive needs type = one of {', '.join(PRIMITIVES)}")
        _no_unknown(value, {"type", "size"}, f"{where} primitive")
        value = {"type": value["type"],
                 "size": _vec(value.get("size"), PRIMITIVES[value["type"]], f"{where} primitive.size", positive=True)}
    elif source == "paper":
        from scenes.paper_objects import NAMES

        if value not in NAMES:
            raise SceneError(f"{where}: unknown paper object {value!r}; choose from {', '.join(NAMES)}")
    if "material" in o and "density" in o:
        raise SceneError(f"{where}: give 'material' or 'density', not both")
    if "density" in o:
        _positive(o["density"], f"{where} density")
    if "material" in o:
        from estimation.materials import material

        try:
            material(str(o["material"]))
        except TwinError as exc:
            raise SceneError(f"{where}: {exc}") from exc
    position = o.get("position", (0.0, 0.0))
    if not isinstance(position, list | tuple) or len(position) not in (2, 3):
        raise SceneError(f"{where}: position must be [x, y] (rest on the table) or [x, y, z]")
    units = str(o.get("units", "m"))
    if units not in ("m", "cm", "mm"):
        raise SceneError(f"{where}: units must be m, cm or mm, got {units!r}")
    points = int(o.get("points", ObjectSpec.points))
    if points < 100:
        raise SceneError(f"{where}: points must be at least 100, got {points}")
    return ObjectSpec(
        id=oid, source=source, value=value, material=o.get("material"),
        density=float(o["density"]) if "density" in o else None, units=units,
        position=tuple(float(x) for x in position),
        rotation_deg=_vec(o.get("rotation_deg", (0, 0, 0)), 3, f"{where} rotation_deg"), points=points,
    )


def _no_unknown(d: dict, allowed: set[str], where: str) -> None:
    unknown = set(d) - allowed
    if unknown:
        import difflib

        key = sorted(unknown)[0]
        close = difflib.get_close_matches(key, sorted(allowed), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (allowed: {', '.join(sorted(allowed))})"
        raise SceneError(f"{where}: unknown key {key!r}{hint}")


def _vec(value: object, n: int, where: str, *, positive: bool = False) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise SceneError(f"{where}: expected {n} numbers, got {value!r}") from None
    if len(out) != n:
        raise SceneError(f"{where}: expected {n} numbers, got {len(out)}")
    if positive and any(x <= 0 for x in out):
        raise SceneError(f"{where}: must be positive, got {list(out)}")
    return out


def _positive(value: object, where: str) -> float:
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise SceneError(f"{where}: expected a number, got {value!r}") from None
    if not x > 0:
        raise SceneError(f"{where}: must be positive, got {x}")
    return x
