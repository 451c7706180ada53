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

import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from estimation import tolerances as tol
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
#: Fewer points than this cannot be estimated: the estimator's own floor.
MIN_POINTS = tol.MIN_POINTS
#: A sampled cloud is 24 bytes a point in float64: 10 million is 240 MB per object, already generous.
MAX_POINTS = 10_000_000


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
    """Validate a scene document (the parsed TOML) into a :class:`SceneSpec`.

    Every value is type-checked: numbers must be finite ints or floats (never booleans), vectors lists of
    them, names strings. Any problem is one :class:`SceneError` naming the object and the key.

    Raises:
        SceneError: unknown keys, missing or duplicate ids, wrong types, non-finite or out-of-range values,
            missing files.
    """
    _no_unknown(_table(doc, "scene"), _TOP_KEYS, "scene")
    if "name" not in doc:
        raise SceneError("scene: missing 'name'")
    name = _string(doc["name"], "scene: name")
    table = None
    if "table" in doc:
        t = _table(doc["table"], "table")
        _no_unknown(t, {"size", "height", "material"}, "table")
        table = TableSpec(size=_vec(t.get("size", TableSpec.size), 3, "table.size", positive=True),
                          height=_number(t.get("height", TableSpec.height), "table.height", positive=True),
                          material=_material(t.get("material", TableSpec.material), "table.material"))
    ee = EndEffectorSpec()
    if "end_effector" in doc:
        e = _table(doc["end_effector"], "end_effector")
        _no_unknown(e, {"radius", "position"}, "end_effector")
        ee = EndEffectorSpec(radius=_number(e.get("radius", ee.radius), "end_effector.radius", positive=True),
                             position=_vec(e.get("position", ee.position), 3, "end_effector.position"))
    raw_objects = doc.get("objects", [])
    if not isinstance(raw_objects, list):
        raise SceneError(f"scene: 'objects' must be an array of tables ([[objects]]), got {_kind(raw_objects)}")
    objects = tuple(_parse_object(o, i, base) for i, o in enumerate(raw_objects))
    ids = [o.id for o in objects]
    dupes = {i for i in ids if ids.count(i) > 1}
    if dupes:
        raise SceneError(f"scene: duplicate object id(s) {sorted(dupes)}")
    return SceneSpec(name=name, objects=objects, table=table, end_effector=ee, path=path)


def _parse_object(o: object, index: int, base: Path) -> ObjectSpec:
    if not isinstance(o, dict):
        raise SceneError(f"object #{index}: expected a table ([[objects]]), got {_kind(o)}")
    oid = o.get("id")
    where = f"object {oid!r}" if isinstance(oid, str) and _ID.match(oid) else f"object #{index}"
    _no_unknown(o, _OBJECT_KEYS, where)
    if not isinstance(oid, str) or not _ID.match(oid):
        raise SceneError(f"{where}: 'id' must be 1-64 characters of letters, digits, '_' or '-'")
    sources = [s for s in SOURCES if s in o]
    if len(sources) != 1:
        raise SceneError(f"{where}: needs exactly one source of {', '.join(SOURCES)}; got {sources or 'none'}")
    source = sources[0]
    value = o[source]
    if source in ("mesh", "cloud"):
        file = _string(value, f"{where} {source}")
        try:
            value = (base / file).resolve()
            found = value.is_file()
        except (OSError, ValueError) as exc:  # a NUL byte, a loop of links
            raise SceneError(f"{where}: {source} path {file!r} is not usable ({exc})") from None
        if not found:
            raise SceneError(f"{where}: {source} file {value} does not exist")
    elif source == "primitive":
        kind = value.get("type") if isinstance(value, dict) else None
        if not isinstance(kind, str) or kind not in PRIMITIVES:
            raise SceneError(f"{where}: primitive needs type = one of {', '.join(PRIMITIVES)}")
        _no_unknown(value, {"type", "size"}, f"{where} primitive")
        value = {"type": kind, "size": _vec(value.get("size"), PRIMITIVES[kind], f"{where} primitive.size",
                                            positive=True)}
    elif source == "paper":
        from scenes.paper_objects import NAMES

        if not isinstance(value, str) or value not in NAMES:
            raise SceneError(f"{where}: unknown paper object {value!r}; choose from {', '.join(NAMES)}")
    if "material" in o and "density" in o:
        raise SceneError(f"{where}: give 'material' or 'density', not both")
    density = _number(o["density"], f"{where} density", positive=True) if "density" in o else None
    material = _material(o["material"], f"{where} material") if "material" in o else None
    position = o.get("position", (0.0, 0.0))
    if not isinstance(position, list | tuple) or len(position) not in (2, 3):
        raise SceneError(f"{where} position: must be [x, y] (rest on the table) or [x, y, z], got {position!r}")
    units = o.get("units", "m")
    if units not in ("m", "cm", "mm") or not isinstance(units, str):
        raise SceneError(f"{where} units: must be m, cm or mm, got {units!r}")
    points = o.get("points", ObjectSpec.points)
    if isinstance(points, bool) or not isinstance(points, int):
        raise SceneError(f"{where} points: expected a whole number, got {points!r}")
    if not MIN_POINTS <= points <= MAX_POINTS:
        raise SceneError(f"{where} points: must be {MIN_POINTS} to {MAX_POINTS:,}, got {points}")
    return ObjectSpec(
        id=oid, source=source, value=value, material=material, density=density, units=units,
        position=_vec(position, len(position), f"{where} position"),
        rotation_deg=_vec(o.get("rotation_deg", (0, 0, 0)), 3, f"{where} rotation_deg"),  # type: ignore[arg-type]
        points=points,
    )


def _no_unknown(d: dict, allowed: set[str], where: str) -> None:
    unknown = set(d) - allowed
    if unknown:
        import difflib

        key = sorted(map(str, unknown))[0]
        close = difflib.get_close_matches(key, sorted(allowed), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (allowed: {', '.join(sorted(allowed))})"
        raise SceneError(f"{where}: unknown key {key!r}{hint}")


def _kind(value: object) -> str:
    """How an error names a wrong value: its TOML type and a short repr."""
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _table(value: object, where: str) -> dict:
    if not isinstance(value, dict):
        raise SceneError(f"{where}: expected a table, got {_kind(value)}")
    return value


def _string(value: object, where: str) -> str:
    if not isinstance(value, str) or not value:
        raise SceneError(f"{where}: expected a non-empty string, got {_kind(value)}")
    return value


def _material(value: object, where: str) -> str:
    from estimation.materials import material

    name = _string(value, where)
    try:
        material(name)
    except TwinError as exc:
        raise SceneError(f"{where}: {exc}") from exc
    return name


def _number(value: object, where: str, *, positive: bool = False) -> float:
    # bool is an int in Python; `height = true` is a mistake, not 1.0.
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SceneError(f"{where}: expected a number, got {_kind(value)}")
    try:
        x = float(value)
    except OverflowError:  # a TOML integer beyond float range
        raise SceneError(f"{where}: {value} is out of range") from None
    if not math.isfinite(x):
        raise SceneError(f"{where}: must be finite, got {x}")
    if positive and not x > 0:
        raise SceneError(f"{where}: must be positive, got {x}")
    return x


def _vec(value: object, n: int, where: str, *, positive: bool = False) -> tuple[float, ...]:
    if not isinstance(value, list | tuple):
        raise SceneError(f"{where}: expected {n} numbers, got {_kind(value)}")
    if len(value) != n:
        raise SceneError(f"{where}: expected {n} numbers, got {len(value)}")
    out = tuple(_number(x, f"{where}[{i}]") for i, x in enumerate(value))
    if positive and any(x <= 0 for x in out):
        raise SceneError(f"{where}: must be positive, got {list(out)}")
    return out
