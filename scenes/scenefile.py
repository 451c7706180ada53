"""Scene files: a small TOML document listing objects, the table, the operator's end effector and the workspace.

The document's shape is a set of msgspec Structs (:class:`SceneDoc` and the classes it holds): the loader
validates a parsed document with ``msgspec.convert`` against them, and :func:`scene_schema` generates the
JSON Schema from the same classes (shipped as ``docs/scene.schema.json``; ``twin schema scene`` prints it).
What a schema cannot say is checked in code after the conversion: every number finite, exactly one source,
files that exist, known materials and paper objects, a rotation matrix that is a rotation, min < max.
Every problem is one :class:`SceneError` naming the object and the key; ``docs/scenes.md`` documents it all.
A short example (SI units)::

    name = "tabletop"
    [table]
    size = [1.2, 0.8, 0.04]
    height = 0.75
    [[objects]]
    id = "mug"
    paper = "mug"
    material = "ceramic"
    position = [0.1, 0.2]
"""

from __future__ import annotations

import difflib
import errno
import json
import math
import os
import re
import stat
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import unquote

import msgspec
import numpy as np
from msgspec import UNSET, Meta, Struct, UnsetType

from estimation import tolerances as tol
from estimation.errors import TwinError
from estimation.materials import MAX_DENSITY, MIN_DENSITY
from sync.keys import ID_PATTERN
from sync.messages import MAX_COORDINATE, MAX_EE_RADIUS
from twin.model import (
    DEFAULT_PHYSICS,
    OPERATOR_REACH,
    RESERVED_IDS,
    SCENE_REACH,
    EndEffectorSpec,
    PhysicsSettings,
    TableSpec,
    new_spec,
    scene_reach_corners,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class SceneError(TwinError, ValueError):
    """A scene file that cannot be used; the message names the object and the problem."""


SOURCES = ("paper", "mesh", "cloud", "primitive")
_ID_PATTERN = ID_PATTERN  # the wire's rule for ids (sync.keys): an object's id is a key chunk
_ID = re.compile(_ID_PATTERN)
#: Fewer points than this cannot be estimated: the estimator's own floor.
MIN_POINTS = tol.MIN_POINTS
#: A sampled cloud is 24 bytes a point in float64: 10 million is 240 MB per object, already generous.
MAX_POINTS = 10_000_000
#: How far a hand-written rotation may be from one: a quaternion's norm from 1, a matrix's R^T R from the
#: identity (largest entry) and its determinant from 1. Four printed decimals (0.7071) are 1e-5 off; a
#: matrix 1e-3 off scales the cloud by at most 0.1 %. Within it, the rotation is made exact (normalised,
#: or the nearest rotation matrix) before use.
ROTATION_TOLERANCE = 1e-3
#: Viewpoints one cloud may list: more sensors than any rig we know of, and a bound on the per-point work.
MAX_VIEWPOINTS = 64
#: Objects one scene may hold: ten times the largest shipped scene (mixed100); every object is estimated,
#: decomposed and simulated, so a scene of 10^6 (which once hung the duplicate-id check) is no scene.
MAX_OBJECTS = 1000
#: Sizes (primitive sizes, table size and height, end-effector radius), metres. 1 mm is about the smallest
#: thing a tabletop twin pushes, and the smallest whose inertia MuJoCo still compiles at water's density
#: (a 0.5 mm box is "inertia must have positive eigenvalues"; a 1e-300 m sphere was a LinAlgError, a
#: 1e-300 m table a MuJoCo error); 100 m is past any table (a 1e10 m sphere failed writing its STL).
SIZE_RANGE_M = (1e-3, 100.0)
#: Mesh formats a ``mesh`` source may have: the ones trimesh reads as a mesh with this project's dependencies.
#: Anything else (/etc/passwd) is refused by name here instead of failing inside trimesh. Not .3mf or .dae:
#: trimesh reads them only with lxml (and pycollada), which the project does not install, so every one failed.
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf")

#: A mesh file larger than this is refused before it is read: 256 MiB is a binary STL of 5M triangles, and the
#: twin samples an object's mesh for its cloud (``ObjectDoc.points``), so it gains nothing from a finer one.
MAX_MESH_BYTES = 256 * 2**20

# -- the document's shape ----------------------------------------------------------------------------------
# Struct defaults are the loader's defaults; UNSET marks a key whose absence means something (no table,
# no source of that kind). TOML has no null, so no field takes None.

Positive = Annotated[float, Meta(gt=0)]
#: What the wire carries (:data:`estimation.materials.MIN_DENSITY` .. ``MAX_DENSITY``): a scene object outside it
#: would be published and then refused by every twin.
Density = Annotated[float, Meta(ge=MIN_DENSITY, le=MAX_DENSITY)]
Size = Annotated[float, Meta(ge=SIZE_RANGE_M[0], le=SIZE_RANGE_M[1])]
#: The end effector's radius: what the wire carries (:data:`sync.messages.MAX_EE_RADIUS`). A 1.5 m one was
#: loaded, and every twin dropped the scene's announcement and gave up after 10 s.
EeRadius = Annotated[float, Meta(ge=SIZE_RANGE_M[0], le=MAX_EE_RADIUS)]
Vec3 = tuple[float, float, float]

#: A turn, degrees: within a full turn either way (1e300 degrees was accepted, an angle whose remainder
#: after whole turns no float holds).
Angle = Annotated[float, Meta(ge=-360.0, le=360.0)]
#: A position in the world, m: within the wire's bound on coordinates (a 1e300 m start built, and its
#: poses could never be sent).
Coordinate = Annotated[float, Meta(ge=-MAX_COORDINATE, le=MAX_COORDINATE)]
Point3 = tuple[Coordinate, Coordinate, Coordinate]
Text = Annotated[str, Meta(min_length=1)]

#: ``twin demo``'s push when a scene does not aim it (``[end_effector] push``): 2.2 m along +x, sinking 12 cm,
#: across the shipped scenes' tables from an end effector at their -x edge.
DEMO_PUSH: tuple[float, float, float] = (2.2, 0.0, -0.12)


class TableDoc(Struct, forbid_unknown_fields=True):
    """A box table whose top is at ``height``; omit ``[table]`` for objects on the floor."""

    size: Annotated[tuple[Size, Size, Size], Meta(description="full extents x, y, z, m")] = TableSpec.size
    height: Annotated[Size, Meta(description="top surface above the floor, m")] = TableSpec.height
    material: Annotated[Text, Meta(description="material name or alias; sets the table's friction")] = \
        TableSpec.material


class EndEffectorDoc(Struct, forbid_unknown_fields=True):
    """The operator's sphere."""

    radius: Annotated[EeRadius, Meta(description="sphere radius, m")] = EndEffectorSpec.radius
    position: Annotated[Point3, Meta(description="start position, world frame, m")] = EndEffectorSpec.position
    push: Annotated[Point3, Meta(description="twin demo's push: the sphere's displacement from its start over the "
                                             "push, world frame, m")] = DEMO_PUSH


class WorkspaceDoc(Struct, forbid_unknown_fields=True):
    """The box, world frame, metres, every object pose must lie in (a twin drops poses outside it)."""

    min: Annotated[Point3, Meta(description="low corner [x, y, z], m")]
    max: Annotated[Point3, Meta(description="high corner [x, y, z], m; each above min")]


class BoxDoc(Struct, tag="box", tag_field="type", forbid_unknown_fields=True):
    """A box of full extents ``size`` = [x, y, z], m."""

    size: tuple[Size, Size, Size]


class CylinderDoc(Struct, tag="cylinder", tag_field="type", forbid_unknown_fields=True):
    """A cylinder along z: ``size`` = [radius, height], m."""

    size: tuple[Size, Size]


class SphereDoc(Struct, tag="sphere", tag_field="type", forbid_unknown_fields=True):
    """A sphere: ``size`` = [radius], m."""

    size: tuple[Size]


class CapsuleDoc(Struct, tag="capsule", tag_field="type", forbid_unknown_fields=True):
    """A capsule along z: ``size`` = [radius, height of the cylinder part], m."""

    size: tuple[Size, Size]


class TorusDoc(Struct, tag="torus", tag_field="type", forbid_unknown_fields=True):
    """A torus about z: ``size`` = [major radius, minor radius], m."""

    size: tuple[Size, Size]


_PRIMITIVE_DOCS = (BoxDoc, CylinderDoc, SphereDoc, CapsuleDoc, TorusDoc)
PrimitiveDoc = BoxDoc | CylinderDoc | SphereDoc | CapsuleDoc | TorusDoc
#: primitive type -> how many ``size`` numbers it takes (from the classes above).
PRIMITIVES: dict[str, int] = {
    str(c.__struct_config__.tag): len(msgspec.inspect.type_info(c).fields[0].type.item_types)  # type: ignore[attr-defined]
    for c in _PRIMITIVE_DOCS
}


class ObjectDoc(Struct, forbid_unknown_fields=True):
    """One object: an id, exactly one source (paper, mesh, cloud or primitive), its mass and its pose."""

    id: Annotated[str, Meta(pattern=_ID_PATTERN, description="unique in the scene")]
    paper: Annotated[Text, Meta(description="one of the paper's objects")] | UnsetType = UNSET
    mesh: Annotated[Text, Meta(description="mesh file beside or below the scene file (no `..`, not absolute), in `units`")] | UnsetType = UNSET
    cloud: Annotated[Text, Meta(description="point-cloud file beside or below the scene file (no `..`, not absolute), in `units`")] | UnsetType = UNSET
    primitive: PrimitiveDoc | UnsetType = UNSET
    units: Annotated[Literal["m", "cm", "mm"], Meta(description="mesh and cloud only: units of the file")] = "m"
    material: Annotated[Text, Meta(description="material name or alias: density and friction")] | UnsetType = UNSET
    density: Annotated[Density, Meta(description="kg/m^3, instead of material")] | UnsetType = UNSET
    position: Annotated[tuple[Coordinate, ...], Meta(
        min_length=2, max_length=3,
        description="world frame, m: [x, y] rests on the table, [x, y, z] exactly there (see docs/scenes.md)")] = (0.0, 0.0)
    rotation_deg: Annotated[tuple[Angle, Angle, Angle], Meta(
        description="degrees about Z, then local X, then local Y, each within [-360, 360]; not for clouds")] = (
        0.0, 0.0, 0.0)
    quat: Annotated[tuple[float, float, float, float], Meta(
        description="cloud only: orientation of the cloud's frame in the world, w x y z")] | UnsetType = UNSET
    rotation: Annotated[tuple[Vec3, Vec3, Vec3], Meta(
        description="cloud only: rotation matrix (rows) of the cloud's frame in the world")] | UnsetType = UNSET
    viewpoints: Annotated[list[Vec3], Meta(
        min_length=1, max_length=MAX_VIEWPOINTS,
        description="cloud only: sensor origins, in the cloud file's frame and units")] | UnsetType = UNSET
    points: Annotated[int, Meta(ge=MIN_POINTS, le=MAX_POINTS,
                                description="paper, mesh and primitive only: cloud size when sampling the source")] = 100_000


class SceneDoc(Struct, forbid_unknown_fields=True):
    """A tactile-twin scene file (TOML). SI units; positions in the world frame, z up, floor at z = 0."""

    # A key chunk, as sync.keys holds it: 'a/*' or '..' built, then twin remote and twin demo died with a
    # ValueError traceback from sync.keys.Keys.
    name: Annotated[str, Meta(pattern=_ID_PATTERN, description="the scene's name (1-64 of A-Z a-z 0-9 _ -); also "
                                                               "its Zenoh key prefix")]
    table: TableDoc | UnsetType = UNSET
    end_effector: EndEffectorDoc | UnsetType = UNSET
    workspace: WorkspaceDoc | UnsetType = UNSET
    objects: Annotated[list[ObjectDoc], Meta(max_length=MAX_OBJECTS)] = []


_TOP_KEYS = set(SceneDoc.__struct_fields__)
_OBJECT_KEYS = set(ObjectDoc.__struct_fields__)
#: Keys only a cloud source takes.
_CLOUD_POSE_KEYS = ("quat", "rotation", "viewpoints")


def scene_schema() -> dict:
    """The JSON Schema (draft 2020-12) of a scene document, generated from :class:`SceneDoc`.

    The paper objects' names are added as an enum here: they live with the meshes (``scenes.paper_objects``,
    which loads trimesh), not in the classes.
    """
    from scenes.paper_objects import NAMES

    schema = msgspec.json.schema(SceneDoc)
    schema["$defs"]["ObjectDoc"]["properties"]["paper"]["enum"] = list(NAMES)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "tactile-twin scene file",
            **schema}


def scene_schema_text() -> str:
    """:func:`scene_schema` as the text of ``docs/scene.schema.json`` (what ``twin schema scene`` prints)."""
    return json.dumps(scene_schema(), indent=2) + "\n"


# -- the validated scene -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a scene, as written in the file (paths resolved).

    Attributes:
        frame_rotation: a cloud's frame orientation in the world, (3, 3) rows, an exact rotation; None when
            the file gave no ``quat`` or ``rotation`` (then ``position`` is the centre of mass's, as for
            every other source; with it, ``position`` is the cloud frame's origin's).
        viewpoints: a cloud's sensor origins, in the cloud file's frame and units (empty: none given).
    """

    id: str
    source: str
    value: object
    material: str | None = None
    density: float | None = None
    units: str = "m"
    position: tuple[float, ...] = (0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    points: int = 100_000
    frame_rotation: tuple[Vec3, Vec3, Vec3] | None = None
    viewpoints: tuple[Vec3, ...] = ()

    @property
    def posed(self) -> bool:
        """A cloud whose file gave its frame's orientation (``quat`` or ``rotation``)."""
        return self.frame_rotation is not None


@dataclass(frozen=True)
class SceneSpec:
    """A validated scene. ``workspace``: (low, high) corners, world frame, m, or None for the default box."""

    name: str
    objects: tuple[ObjectSpec, ...]
    table: TableSpec | None = None
    end_effector: EndEffectorSpec | None = field(default_factory=EndEffectorSpec)
    path: Path | None = None
    workspace: tuple[Vec3, Vec3] | None = None
    push: Vec3 = DEMO_PUSH  # twin demo's push: the end effector's displacement over it, world frame, m

    def empty_spec(self, physics: PhysicsSettings = DEFAULT_PHYSICS):  # type: ignore[no-untyped-def]
        """An MjSpec of this scene's floor, table and end effector, with no objects yet."""
        return new_spec(self.name, table=self.table, end_effector=self.end_effector, physics=physics)


def scene_data() -> Path:
    """The folder of the scene files that ship with the package (``scenes/data``), resolved."""
    from importlib import resources

    return Path(str(resources.files("scenes").joinpath("data"))).resolve()


def load_scene(path: str | os.PathLike[str]) -> SceneSpec:
    """Read and validate a scene file.

    Raises:
        TypeError: ``path`` is not a str or ``os.PathLike``.
        SceneError: TOML text given for the path, a missing file (a dangling symlink or a symlink loop said so),
            unreadable TOML, unknown keys, missing or duplicate ids, bad values, missing files.
    """
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"load_scene takes a path (str or os.PathLike), got {type(path).__name__}")
    if isinstance(path, str) and _looks_like_toml(path):  # the whole text went into the "cannot read" line
        raise SceneError("load_scene takes a path, got TOML text: "
                         "use parse_scene(tomllib.loads(text), base=FOLDER)")
    path = Path(path)
    try:
        if not path.is_file():
            what = ("is a folder, not a scene file" if path.is_dir() else "is not a regular file (a device or a pipe?)"
                    if path.exists() else _missing(path))
            raise SceneError(f"{path}: {what}")
        data = path.read_bytes()
    except OSError as exc:  # a name too long, a permission denied
        raise SceneError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        # TOML is UTF-8; a byte-order mark (what Windows editors put first) is dropped, not "Invalid statement".
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:  # read_text() let it out as a traceback
        raise SceneError(f"{path}: not UTF-8 text, so not TOML ({exc.reason} at byte {exc.start})") from None
    return parse_scene(scene_document(text, str(path)), base=path.parent, path=path)


#: The start of a one-line TOML document: a table header, or a key and "=" (bare or quoted).
_TOML_START = re.compile(r'\s*(\[|[A-Za-z0-9_"\'-]+\s*=)')


def _looks_like_toml(text: str) -> bool:
    """``text`` is TOML rather than a path: several lines, or a ``key =`` start naming no file there is."""
    if "\n" in text:
        return True
    if not _TOML_START.match(text):
        return False
    try:
        return not os.path.lexists(text)
    except (OSError, ValueError):  # a NUL, a name too long: no file either
        return True


def _missing(path: Path) -> str:
    """Why ``path``, which is no file, is missing: a symlink loop and a dangling symlink read as absent."""
    try:
        path.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "symlink loop (a link leads back to itself)"
        if path.is_symlink():
            return f"a symlink to {os.readlink(path)}, which does not exist"
    except ValueError:  # a NUL in the name
        pass
    return "no such scene file"


def scene_document(text: str, where: str) -> dict:
    """The TOML document of a scene file's ``text``; ``where`` starts the error message.

    Raises:
        SceneError: not TOML, or TOML Python will not hold (nested too deeply, an integer of over 4,300 digits).
    """
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{where}: not valid TOML ({exc})") from None
    except ValueError as exc:  # Python's cap on int() of a long digit string: 4,300 digits
        # Its advice (sys.set_int_max_str_digits) is for programmers, not for whoever wrote the file.
        reason = next((line for line in str(exc).splitlines() if line.strip()), type(exc).__name__).split(";")[0]
        raise SceneError(f"{where}: not a scene file Python can read ({reason})") from None
    except RecursionError:  # tomllib recurses once per level of nesting: 5000 levels of [[[...
        raise SceneError(f"{where}: nested too deeply to be a scene file") from None


def _plain(value: object, depth: int = 0) -> object:
    """``value`` with numpy scalars as the Python numbers they hold (a document built in Python, not read from
    TOML: ``np.float64(0.1)`` was "expected a number"). Deeper than any scene is left as it is, for the
    conversion to refuse."""
    if depth > 32:
        return value
    if isinstance(value, dict):
        return {k: _plain(v, depth + 1) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_plain(v, depth + 1) for v in value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray) and value.size <= 16:  # a position or size as an array
        return value.tolist()
    return value


def parse_scene(doc: dict, *, base: str | os.PathLike[str] = Path("."),
                path: str | os.PathLike[str] | None = None) -> SceneSpec:
    """Validate a scene document (the parsed TOML) into a :class:`SceneSpec`.

    Types, lengths and ranges are checked by ``msgspec.convert`` against :class:`SceneDoc` (numbers are
    ints or floats, never booleans); then, in code, what a schema cannot say. Any problem is one
    :class:`SceneError` naming the object and the key.

    ``base`` is the folder relative file names in ``doc`` start from; ``path`` the file it was read from
    (None: none).

    Raises:
        TypeError: ``base`` not a path, or ``path`` neither a path nor None.
        SceneError: unknown keys, missing or duplicate ids, wrong types, non-finite or out-of-range values,
            no or several sources, pose keys on a non-cloud, ``units`` on a source with no file, ``points`` on a
            cloud, a matrix that is no rotation, missing files.
    """
    if not isinstance(base, str | os.PathLike):
        raise TypeError(f"parse_scene: base must be a folder path (str or os.PathLike), got {type(base).__name__}")
    if path is not None and not isinstance(path, str | os.PathLike):
        raise TypeError(f"parse_scene: path must be a file path or None, got {type(path).__name__}")
    base, path = Path(base), None if path is None else Path(path)
    if not isinstance(doc, dict):
        raise SceneError(f"scene: expected a table, got {_kind(doc)}")
    try:
        scene = msgspec.convert(_plain(doc), SceneDoc)
    except msgspec.ValidationError as exc:
        raise SceneError(_translate(str(exc), doc)) from None
    _check_finite(scene, [], doc)
    table = None
    if scene.table is not UNSET:
        t = scene.table
        table = TableSpec(size=t.size, height=t.height, material=_material(t.material, "table.material"))
    ee, push = EndEffectorSpec(), DEMO_PUSH
    if scene.end_effector is not UNSET:
        ee = EndEffectorSpec(radius=scene.end_effector.radius, position=scene.end_effector.position)
        push = tuple(float(x) for x in scene.end_effector.push)
        _check_reach(ee, table)
        if push != DEMO_PUSH:  # the default is the shipped scenes' and is not checked (a floor scene's reach is 2 m)
            _check_reach(ee, table, push)
    workspace = None
    if scene.workspace is not UNSET:
        low, high = scene.workspace.min, scene.workspace.max
        if not all(a < b for a, b in zip(low, high, strict=True)):
            raise SceneError(f"workspace: min must be below max on every axis, got min {list(low)}, max {list(high)}")
        workspace = (low, high)
    objects = tuple(_object(o, i, base, doc) for i, o in enumerate(scene.objects))
    counts = Counter(o.id for o in objects)  # ids.count(i) for each i was quadratic: 25 s at 40k objects
    dupes = {i for i, n in counts.items() if n > 1}
    if dupes:
        raise SceneError(f"scene: duplicate object id(s) {sorted(dupes)}")
    if taken := sorted(RESERVED_IDS.intersection(counts)):
        raise SceneError(f"scene: object id(s) {taken} are names the twin's model uses itself "
                         f"({', '.join(sorted(RESERVED_IDS))}); rename them")
    # Without a declared workspace, the twin's default box: SCENE_REACH around the table (an object 999 m off
    # was built, then dropped).
    low, high = workspace or scene_reach_corners(table, ee, SCENE_REACH)
    _check_inside(objects, (tuple(np.asarray(low).tolist()), tuple(np.asarray(high).tolist())))
    return SceneSpec(name=scene.name, objects=objects, table=table, end_effector=ee, path=path, workspace=workspace,
                     push=push)  # type: ignore[arg-type]


def _object(o: ObjectDoc, index: int, base: Path, doc: dict) -> ObjectSpec:
    """The checks a schema cannot make, on one converted object."""
    where = _label(index, doc)
    sources = [s for s in SOURCES if getattr(o, s) is not UNSET]
    if len(sources) != 1:
        raise SceneError(f"{where}: needs exactly one source of {', '.join(SOURCES)}; got {sources or 'none'}")
    source = sources[0]
    value: object = getattr(o, source)
    if source in ("mesh", "cloud"):
        file = str(value)
        _check_beside(file, f"{where}: {source} path")
        try:
            value = (base / file).resolve()
            found = value.is_file()  # type: ignore[attr-defined]
        except (OSError, ValueError, RuntimeError) as exc:  # a NUL byte; a loop of links (RuntimeError on 3.11)
            raise SceneError(f"{where}: {source} path {file!r} is not usable ({exc})") from None
        if not found:
            what = ("is a directory" if value.is_dir() else "is not a regular file" if value.exists()  # type: ignore[attr-defined]
                    else "does not exist")
            raise SceneError(f"{where}: {source} file {value} {what}")
        if source == "mesh":
            _check_mesh_file(value, where)  # type: ignore[arg-type]
    elif source == "primitive":
        value = {"type": o.primitive.__struct_config__.tag, "size": o.primitive.size}  # type: ignore[union-attr]
        if isinstance(o.primitive, TorusDoc) and o.primitive.size[1] >= o.primitive.size[0]:
            # Its tube would cross the axis: a self-intersecting mesh whose signed volume is not the solid's.
            raise SceneError(f"{where} primitive.size: a torus's minor radius must be less than its major radius "
                             f"(size = [major, minor]), got {list(o.primitive.size)}")
    else:
        _paper(value, where)
    _check_source_keys(source, index, doc, where)
    if o.material is not UNSET and o.density is not UNSET:
        raise SceneError(f"{where}: give 'material' or 'density', not both")
    material = None if o.material is UNSET else _material(o.material, f"{where} material")
    frame_rotation = _frame_rotation(o, source, where)
    return ObjectSpec(
        id=o.id, source=source, value=value, material=material, density=None if o.density is UNSET else o.density,
        units=o.units, position=o.position, rotation_deg=o.rotation_deg, points=o.points,
        frame_rotation=frame_rotation, viewpoints=() if o.viewpoints is UNSET else tuple(o.viewpoints),
    )


def _check_source_keys(source: str, index: int, doc: dict, where: str) -> None:
    """Refuse ``units`` on a source that has no file and ``points`` on a cloud: keys that would be ignored.

    Both have defaults, so whether the file wrote them is read from the document itself. Ignored, they misled:
    ``units = "mm"`` on a 5 m primitive box built a 21 t box and recorded "mm" in estimates.json.

    Raises:
        SceneError: either key written where it does not apply (``where`` starts the message).
    """
    def written(key: str) -> bool:
        return _lookup(doc, ["objects", index, key])[0]

    if source not in ("mesh", "cloud") and written("units"):
        size = "in metres" if source == "primitive" else "the paper's"
        raise SceneError(f"{where}: 'units' is for mesh and cloud sources only (a {source} object has no file: its "
                         f"size is {size})")
    if source == "cloud" and written("points"):
        raise SceneError(f"{where}: 'points' does not apply to a cloud source: its points are the file's")


def _check_beside(file: str, what: str) -> None:
    """Refuse a path that is absolute or climbs out of its folder (``..``).

    A scene file is data people hand around. One that named ``/home/you/design.stl`` or ``../../design.stl``
    would have the remote sample that file and publish its points to whoever subscribes. A link put in the
    scene's folder is followed: putting it there was the folder owner's choice.
    """
    path = Path(file)
    if path.is_absolute() or path.drive or ".." in path.parts:
        raise SceneError(f"{what} {file!r} is absolute or has '..' in it: a scene names files only by a path down "
                         f"from its own folder (copy or link the file there)")


def _check_mesh_file(path: Path, where: str) -> None:
    """Refuse a mesh file we do not read and one too large to be one object's.

    A glTF's buffers and images outside its own folder are refused by trimesh's loader (its ``FilePathResolver``
    as of trimesh 5.2; ``tests/test_scenefile.py`` holds it to that).
    """
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{where}: mesh file {path} is not a mesh format we read; use one of "
                         f"{', '.join(MESH_SUFFIXES)}")
    size = path.stat().st_size + sum(_gltf_files(path, where))
    if size > MAX_MESH_BYTES:
        raise SceneError(f"{where}: mesh file {path} is {size / 2**20:,.0f} MiB, more than the "
                         f"{MAX_MESH_BYTES / 2**20:,.0f} MiB one object's mesh may take (simplify it first)")


def _gltf_files(path: Path, where: str) -> list[int]:
    """The sizes (bytes) of the files a .gltf's buffers and images name beside it, each checked to be a regular
    file: one named as a FIFO blocked the loader for ever, and a sparse 2.6 GB buffer passed the mesh's size
    limit (the .gltf's own 554 bytes) and took 2.7 GB to load. Names outside its folder are trimesh's to refuse."""
    if path.suffix.lower() != ".gltf":
        return []
    try:
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise SceneError(f"{where}: mesh file {path} is not a glTF's JSON ({exc})") from None
    lists = [doc.get(key) for key in ("buffers", "images")] if isinstance(doc, dict) else []
    parts = [item for items in lists if isinstance(items, list) for item in items]  # other shapes: the loader's error
    sizes = []
    for part in parts:
        uri = part.get("uri") if isinstance(part, dict) else None
        if not isinstance(uri, str) or uri.startswith("data:"):
            continue
        named = path.parent / unquote(uri)
        try:
            st = named.stat()
        except OSError:
            continue  # missing, or a name the loader refuses: its own error
        if not stat.S_ISREG(st.st_mode):
            raise SceneError(f"{where}: mesh file {path} names {uri!r}, which is not a regular file (a folder, device "
                             f"or pipe)")
        sizes.append(st.st_size)
    return sizes


def _frame_rotation(o: ObjectDoc, source: str, where: str) -> tuple[Vec3, Vec3, Vec3] | None:
    """A cloud's frame orientation as an exact rotation matrix, from ``quat`` or ``rotation``; None without."""
    given = [k for k in _CLOUD_POSE_KEYS if getattr(o, k) is not UNSET]
    if source != "cloud":
        if given:
            raise SceneError(f"{where}: '{given[0]}' is for cloud sources only (a {source} turns by rotation_deg)")
        return None
    if any(o.rotation_deg):
        raise SceneError(f"{where}: rotation_deg does not turn a cloud; give its frame's orientation as "
                         f"quat = [w, x, y, z] or rotation = [[...], [...], [...]]")
    if o.quat is not UNSET and o.rotation is not UNSET:
        raise SceneError(f"{where}: give 'quat' or 'rotation', not both")
    if o.quat is not UNSET:
        from twin.poses import rotation

        norm = math.sqrt(sum(x * x for x in o.quat))
        if not abs(norm - 1.0) <= ROTATION_TOLERANCE:
            raise SceneError(f"{where} quat: must be a unit quaternion [w, x, y, z], got norm {norm:.6g}")
        m = rotation(np.asarray(o.quat))  # w x y z, MuJoCo's order; normalised there
    elif o.rotation is not UNSET:
        m = np.asarray(o.rotation, dtype=np.float64)
        with np.errstate(over="ignore", invalid="ignore"):  # entries of 1e200 overflow: inf or NaN, refused below
            off = float(np.abs(m.T @ m - np.eye(3)).max())
            det = float(np.linalg.det(m))
        if not (off <= ROTATION_TOLERANCE and abs(det - 1.0) <= ROTATION_TOLERANCE):  # NaN-safe
            raise SceneError(f"{where} rotation: must be a rotation matrix (orthonormal rows, determinant +1); "
                             f"R^T R is {off:.3g} off the identity, determinant {det:.6g}")
        u, _, vt = np.linalg.svd(m)
        m = u @ vt  # the nearest rotation: the matrix was within tolerance of one
    else:
        return None
    r0, r1, r2 = (tuple(float(x) for x in row) for row in m)
    return r0, r1, r2  # type: ignore[return-value]


# -- errors: msgspec's path into today's naming ------------------------------------------------------------

_AT = re.compile(r"^(?P<what>.*?)(?: - at `(?P<path>\$[^`]*)`)?$", re.S)
_TOKEN = re.compile(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")


def _translate(message: str, doc: dict) -> str:
    """A msgspec ValidationError (``Expected `float`, got `str` - at `$.objects[0].position[1]```) as one line
    naming the object and the key (``object 'mug' position[1]: expected a number, got str 'b'``)."""
    m = _AT.match(message)
    what, path = (m.group("what"), m.group("path")) if m else (message, None)
    tokens: list[str | int] = []
    if path is not None:
        tokens = [name if name else int(index) for name, index in _TOKEN.findall(path)]
    found, value = _lookup(doc, tokens)
    where = _where(tokens, doc)
    last = next((t for t in reversed(tokens) if isinstance(t, str)), None)
    in_primitive = len(tokens) >= 3 and tokens[0] == "objects" and tokens[2] == "primitive"

    if what.startswith("Object contains unknown field"):
        allowed = _fields_at(tokens, doc)
        unknown = sorted(map(str, set(value) - allowed)) if isinstance(value, dict) and allowed else []
        key = unknown[0] if unknown else what.partition("`")[2].rpartition("`")[0]
        close = difflib.get_close_matches(key, sorted(allowed), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (allowed: {', '.join(sorted(allowed))})"
        return f"{where}: unknown key {key!r}{hint}"
    if what.startswith("Object missing required field"):
        key = what.partition("`")[2].rpartition("`")[0]
        if key == "id" and tokens[:1] == ["objects"]:
            return f"{where}: 'id' must be 1-64 characters of letters, digits, '_' or '-'"
        if in_primitive and key == "type":
            return f"{_where(tokens[:2], doc)}: primitive needs type = one of {', '.join(PRIMITIVES)}"
        return f"{where}: missing {key!r}"
    if found and isinstance(value, float | int) and not isinstance(value, bool) and not _finite(value):
        return f"{where}: must be finite, got {_number(value)}"
    if tokens == ["objects"] and what.startswith("Expected `array` of length <="):
        return f"scene: at most {MAX_OBJECTS} objects, got {len(value)}"  # type: ignore[arg-type]
    if tokens == ["objects"]:
        return f"scene: 'objects' must be an array of tables ([[objects]]), got {_kind(value)}"
    if len(tokens) == 2 and tokens[0] == "objects":
        return f"{where}: expected a table ([[objects]]), got {_kind(value)}"
    if in_primitive and (len(tokens) == 3 or last == "type"):
        return f"{_where(tokens[:2], doc)}: primitive needs type = one of {', '.join(PRIMITIVES)}"
    if tokens == ["name"] and isinstance(value, str):
        return f"scene: 'name' must be 1-64 characters of letters, digits, '_' or '-' (a Zenoh key chunk), got {value!r}"
    if last == "id" and len(tokens) == 3 and tokens[0] == "objects":
        return f"{_where(tokens[:2], doc)}: 'id' must be 1-64 characters of letters, digits, '_' or '-'"
    if last == "paper" and len(tokens) == 3:
        _paper(value, _where(tokens[:2], doc))
    if last == "units" and len(tokens) == 3:
        return f"{where}: must be m, cm or mm, got {value!r}"
    if last == "points" and len(tokens) == 3:
        if what.startswith("Expected `int`,"):
            return f"{where}: expected a whole number, got {value!r}"
        return f"{where}: must be {MIN_POINTS} to {MAX_POINTS:,}, got {value}"
    if last == "position" and len(tokens) == 3 and tokens[0] == "objects":
        return f"{where}: must be [x, y] (rest on the table) or [x, y, z], got {value!r}"
    expected = what.partition(",")[0]
    if tokens == ["end_effector", "radius"] and expected.startswith(("Expected `float` >=", "Expected `float` <=")):
        return (f"{where}: must be {SIZE_RANGE_M[0]:g} to {MAX_EE_RADIUS:g} m (a fingertip or a tool; what the wire "
                f"carries), got {_number(value)}")
    if expected.startswith((f"Expected `float` >= {SIZE_RANGE_M[0]}", f"Expected `float` <= {SIZE_RANGE_M[1]}")):
        low, high = SIZE_RANGE_M
        return f"{where}: must be {low:g} to {high:g} m, got {_number(value)}"
    if last == "density" and expected.startswith(("Expected `float` >=", "Expected `float` <=")):
        if isinstance(value, int | float) and value <= 0:
            return f"{where}: must be positive, got {_number(value)}"
        return f"{where}: must be {MIN_DENSITY:g} to {MAX_DENSITY:g} kg/m^3, got {_number(value)}"
    if last == "rotation_deg" and expected.startswith(("Expected `float` >=", "Expected `float` <=")):
        return f"{where}: must be within a turn, -360 to 360 degrees, got {_number(value)}"
    if expected.startswith((f"Expected `float` >= {-MAX_COORDINATE}", f"Expected `float` <= {MAX_COORDINATE}")):
        return f"{where}: must be within {MAX_COORDINATE:g} m of the origin, got {_number(value)}"
    if expected.startswith("Expected `float` >"):
        return f"{where}: must be positive, got {_number(value)}"
    if expected.startswith(("Expected `float`", "Expected `int`")):
        return f"{where}: expected a number, got {_kind(value)}"
    if expected.startswith("Expected `str`"):
        return f"{where}: expected a non-empty string, got {_kind(value)}"
    if expected.startswith("Expected `object"):
        return f"{where}: expected a table, got {_kind(value)}"
    if expected.startswith("Expected `array"):
        shape = _shape(tokens, doc)
        got = f"{len(value)}" if isinstance(value, list | tuple) else _kind(value)
        return f"{where}: expected {shape}, got {got}"
    return f"{where}: {what[:1].lower()}{what[1:]}"  # anything else, in msgspec's own words


def _check_reach(ee: EndEffectorSpec, table: TableSpec | None, push: Vec3 | None = None) -> None:
    """Raise a :class:`SceneError` when the end effector starts outside the operator's reach
    (:data:`twin.model.OPERATOR_REACH` beyond the table's edges and above its top): the remote drops every
    operator command outside it, and an experiment from there ran and reported its runs blown up, exit 0.
    With ``push``: when the demo's push ends outside it (the rest of the push would be dropped)."""
    low, high = scene_reach_corners(table, ee, OPERATOR_REACH)  # without a table, around the start
    p = np.asarray(ee.position, dtype=float)
    if push is not None:
        p = p + np.asarray(push, dtype=float)
    if (p < low).any() or (p > high).any():
        what = (f"end_effector.position {list(ee.position)}" if push is None else
                f"end_effector.push {list(push)} ends at {np.round(p, 3).tolist()}, which")
        around = "beyond the table's edges and above its top" if table is not None else "around the end effector's start"
        raise SceneError(f"{what} lies outside the operator's reach ({OPERATOR_REACH:g} m {around}: min "
                         f"{np.round(low, 3).tolist()}, max {np.round(high, 3).tolist()}); the remote would drop "
                         f"{'every operator command' if push is None else 'the push past it'}")


def _check_inside(objects: tuple[ObjectSpec, ...], workspace: tuple[Vec3, Vec3]) -> None:
    """Raise a :class:`SceneError` for the first object placed outside the declared ``workspace`` (on x and y,
    and z when given): the twin drops every pose and cloud outside it, so such an object was built, sensed and
    never shown (a fuzz finding)."""
    for o in objects:
        check_in_workspace(o.id, o.position, workspace, what=f"position {list(o.position)}")


def check_in_workspace(object_id: str, position: Sequence[float], workspace: tuple[Vec3, Vec3], *, what: str) -> None:
    """Raise a :class:`SceneError` naming ``what`` placed the object when ``position`` (metres, world; its first
    two or three coordinates) lies outside ``workspace`` (low and high corners): the twin would drop its poses."""
    low, high = workspace
    if not all(low[k] <= position[k] <= high[k] for k in range(len(position))):
        raise SceneError(f"object {object_id!r}: {what} lies outside the workspace (min {list(low)}, max "
                         f"{list(high)}); the twin would drop its poses")


def _lookup(doc: object, tokens: list[str | int]) -> tuple[bool, object]:
    """(found, value) at ``tokens`` in the raw document."""
    node = doc
    for t in tokens:
        try:
            node = node[t]  # type: ignore[index]
        except (KeyError, IndexError, TypeError):
            return False, None
    return True, node


def _label(index: int, doc: dict) -> str:
    """How messages name the object at ``objects[index]``: by its id when that is a valid one."""
    _, oid = _lookup(doc, ["objects", index, "id"])
    return f"object {oid!r}" if isinstance(oid, str) and _ID.match(oid) else f"object #{index}"


def _where(tokens: list[str | int], doc: dict) -> str:
    """``object 'mug' position[1]``, ``table.size[0]``, ``scene: name``, ``scene``."""
    if len(tokens) >= 2 and tokens[0] == "objects" and isinstance(tokens[1], int):
        rest = _dotted(tokens[2:])
        return _label(tokens[1], doc) + (f" {rest}" if rest else "")
    if not tokens or tokens == ["objects"]:
        return "scene"
    if tokens[0] in ("table", "end_effector", "workspace"):
        return _dotted(tokens)
    return f"scene: {_dotted(tokens)}"


def _dotted(tokens: list[str | int]) -> str:
    return "".join(f"[{t}]" if isinstance(t, int) else f".{t}" for t in tokens).lstrip(".")


def _type_at(tokens: list[str | int], doc: dict) -> msgspec.inspect.Type:
    """The declared type at ``tokens`` (a tagged primitive resolved by the document's ``type``)."""
    t: msgspec.inspect.Type = msgspec.inspect.type_info(SceneDoc)
    for depth, tok in enumerate(tokens):
        t = _unwrap(t, _lookup(doc, tokens[:depth])[1])
        if isinstance(t, msgspec.inspect.StructType):
            t = next(f.type for f in t.fields if f.name == tok)
        elif isinstance(t, msgspec.inspect.TupleType):
            t = t.item_types[int(tok)]
        elif isinstance(t, msgspec.inspect.ListType | msgspec.inspect.VarTupleType):
            t = t.item_type
    return _unwrap(t, _lookup(doc, tokens)[1])


def _unwrap(t: msgspec.inspect.Type, value: object) -> msgspec.inspect.Type:
    while True:
        if isinstance(t, msgspec.inspect.Metadata):
            t = t.type
        elif isinstance(t, msgspec.inspect.UnionType):
            members = t.types  # UNSET is not a member: type_info leaves it out
            kind = value.get("type") if isinstance(value, dict) else None
            t = next((m for m in members if isinstance(m, msgspec.inspect.StructType) and m.tag == kind), members[0])
        else:
            return t


def _fields_at(tokens: list[str | int], doc: dict) -> set[str]:
    t = _type_at(tokens, doc)
    if not isinstance(t, msgspec.inspect.StructType):
        return set()
    return {f.name for f in t.fields} | ({t.tag_field} if t.tag_field else set())


def _shape(tokens: list[str | int], doc: dict) -> str:
    """What an array at ``tokens`` must hold, in words: ``3 numbers``, ``3 rows of 3 numbers``."""
    t = _type_at(tokens, doc)
    if isinstance(t, msgspec.inspect.TupleType):
        inner = _unwrap(t.item_types[0], None)
        if isinstance(inner, msgspec.inspect.TupleType):
            return f"{len(t.item_types)} rows of {len(inner.item_types)} numbers"
        return f"{len(t.item_types)} numbers"
    if isinstance(t, msgspec.inspect.ListType):
        return f"a list of 1 to {MAX_VIEWPOINTS} [x, y, z] points"
    return "an array"


def _check_finite(node: object, tokens: list[str | int], doc: dict) -> None:
    """Every float in the converted document finite (msgspec takes NaN and inf for a float)."""
    if isinstance(node, float):
        if not math.isfinite(node):
            raise SceneError(f"{_where(tokens, doc)}: must be finite, got {node}")
    elif isinstance(node, Struct):
        for name in node.__struct_fields__:
            _check_finite(getattr(node, name), [*tokens, name], doc)
    elif isinstance(node, list | tuple):
        for i, x in enumerate(node):
            _check_finite(x, [*tokens, i], doc)


def _finite(value: float | int) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond float range
        return False


def _number(value: object) -> str:
    """A number for a message: ``float(value)`` overflows on a TOML integer like 10**400."""
    try:
        return str(float(value))  # type: ignore[arg-type]
    except (OverflowError, TypeError, ValueError):
        text = repr(value)
        return text if len(text) <= 40 else f"{text[:12]}... ({len(text)} digits)"


def _kind(value: object) -> str:
    """How an error names a wrong value: its TOML type and a short repr."""
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _paper(value: object, where: str) -> None:
    from scenes.paper_objects import NAMES

    if not isinstance(value, str) or value not in NAMES:
        raise SceneError(f"{where}: unknown paper object {value!r}; choose from {', '.join(NAMES)}")


def _material(value: str, where: str) -> str:
    from estimation.materials import material

    try:
        material(value)
    except TwinError as exc:
        raise SceneError(f"{where}: {exc}") from exc
    return value
