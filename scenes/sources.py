"""Where scene objects come from, and their truth: true meshes, primitives, the paper's objects.

Mesh, primitive and paper sources stand for the remote object: the twin gets them as a cloud sampled off
the true surface (seeded) and estimated like any scan, so a twin is always built from estimates. The
truth (:func:`source_mesh`, :func:`reference_estimate`) is for the simulated remote scene and for
measuring the twin against, never for the twin itself.
"""

from __future__ import annotations

import io
import logging
import re
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from estimation import PhysicalEstimate, PointCloud, estimate, from_mesh, load_cloud
from estimation import tolerances as tol
from estimation.cloud import is_single_origin
from estimation.errors import TwinError
from estimation.fusion import oriented_normals
from estimation.materials import resolve_density
from estimation.units import unit_scale, units_warning
from scenes.scenefile import ObjectSpec, SceneError
from sync.messages import MAX_COORDINATE
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.objects import DEFAULT_FRICTION, TwinObject, collision_shapes, lowest_point, visual_mesh

log = logging.getLogger(__name__)

#: Gap left between a resting object and the table when it is placed, metres.
PLACEMENT_GAP = 0.001


def source_mesh(spec: ObjectSpec) -> trimesh.Trimesh | None:
    """The true mesh of a mesh/primitive/paper object, rotated as the scene says (metres); None for clouds."""
    from scenes.paper_objects import paper_object

    if spec.source == "cloud":
        return None
    if spec.source == "paper":
        mesh = paper_object(str(spec.value))
    elif spec.source == "primitive":
        mesh = _primitive(spec.value)  # type: ignore[arg-type]
    else:
        mesh = _load_mesh(spec)
        mesh.apply_scale(unit_scale(spec.units))
        if not mesh.is_watertight:
            log.warning("object %r: mesh %s is not watertight", spec.id, spec.value)
    if any(spec.rotation_deg):
        from scipy.spatial.transform import Rotation

        transform = np.eye(4)
        # rotation_deg is [about Z, about local X, about local Y], the paper's order.
        transform[:3, :3] = Rotation.from_euler("ZXY", spec.rotation_deg, degrees=True).as_matrix()
        mesh.apply_transform(transform)
    return mesh


def _load_mesh(spec: ObjectSpec) -> trimesh.Trimesh:
    """A mesh object's file as trimesh processes it by default, in the file's units.

    Raises:
        SceneError: the file cannot be read, holds no triangles, has non-finite vertices or faces that index
            past its vertices (with the object's id and the file).
    """
    # A third-party loader raises almost anything on a damaged file: IndexError (an .stl holding text),
    # AssertionError (a glTF byteStride of 0), KeyError, struct.error, EOFError, NotImplementedError (no loader
    # for the format), besides OSError and ValueError. Any of them means the same: the file cannot be read.
    source: object = spec.value
    kind = None
    if str(spec.value).lower().endswith(".obj"):
        source, kind = io.BytesIO(_obj_text(spec)), "obj"
    try:
        # Unprocessed first: processing drops the faces of NaN vertices without a word (a box built at 45 %),
        # and indexes vertices by faces that nothing has checked yet.
        mesh = trimesh.load_mesh(source, file_type=kind, force="mesh", process=False)
    except MemoryError:
        raise  # not the file's fault alone: the CLI says the machine ran out of memory
    except Exception as exc:
        raise _unreadable(spec, exc) from exc
    if str(spec.value).lower().endswith(".stl") and len(getattr(mesh, "faces", ())) == 0:
        _check_stl_size(spec)
    _check_mesh(mesh, f"object {spec.id!r}: mesh {spec.value}")
    try:
        mesh.process()  # what load_mesh does by default: merge duplicate vertices (an STL's), drop degenerate faces
    except MemoryError:
        raise
    except Exception as exc:
        raise _unreadable(spec, exc) from exc
    return mesh


#: A face line's vertex index 0 (``f 0 2 3``, ``f 1/1 0/2 3``): OBJ counts vertices from 1 (or from -1 back).
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f(?:[ \t]+[^ \t\r\n#]+)*?[ \t]+-?0+(?=[/ \t\r\n#]|$)", re.MULTILINE)


def _obj_text(spec: ObjectSpec) -> bytes:
    """An OBJ file's text as trimesh reads it: a face with vertex index 0 refused (trimesh read it as -1, the last
    vertex, and built a wrong triangle without a word); a byte-order mark, tabs, indented lines and comments after
    a statement, all valid OBJ, evened out (trimesh found no triangles in the first three and could not read the
    fourth). Geometry only: its ``mtllib`` materials are not read.

    Raises:
        SceneError: the file cannot be read, or a face has vertex index 0 (with its line).
    """
    try:
        data = Path(spec.value).read_bytes()
    except OSError as exc:
        raise SceneError(f"object {spec.id!r}: cannot read mesh {spec.value} ({exc.strerror or exc})") from None
    match = _OBJ_ZERO_INDEX.search(data)
    if match is not None:
        line = data.count(b"\n", 0, match.start()) + 1
        raise SceneError(f"object {spec.id!r}: mesh {spec.value} line {line}: a face with vertex index 0 "
                         f"(OBJ counts vertices from 1)")
    data = data.removeprefix(b"\xef\xbb\xbf").replace(b"\t", b" ")
    return _OBJ_COMMENT.sub(b"", _OBJ_INDENT.sub(b"", data))


#: Whitespace at the start of an OBJ line; a comment, with the spaces before it, to the end of its line.
_OBJ_INDENT = re.compile(rb"^[ ]+", re.MULTILINE)
_OBJ_COMMENT = re.compile(rb"[ ]*#[^\r\n]*")


def _check_stl_size(spec: ObjectSpec) -> None:
    """Say why an STL that read as no triangles is not one, where its size tells: a binary STL is an 84-byte
    header counting its triangles, then 50 bytes each (trimesh reads a torn one as an empty text STL)."""
    path = Path(spec.value)
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            start = f.read(4096)
    except OSError:
        return
    head = start[:84]
    # A text STL starts "solid" (after a byte-order mark, maybe) and its first 84 bytes are printable, the count's
    # four included, unless its name holds UTF-8 (then its facets give it away); "holds no triangles" is what is
    # wrong with it. A binary STL's header may start "solid" too (SolidWorks), but not its count's bytes.
    if start.removeprefix(b"\xef\xbb\xbf").lstrip()[:5].lower() == b"solid" and (
            all(32 <= c < 127 or c in b"\t\r\n" for c in head) or b"facet normal" in start.lower()):
        return
    where = f"object {spec.id!r}: mesh {spec.value}"
    if size < 84:
        raise SceneError(f"{where} is {size} bytes: shorter than a binary STL's 84-byte header, and not a text STL")
    count = int(np.frombuffer(head, dtype="<u4", count=1, offset=80)[0])
    expected = 84 + 50 * count
    if size < expected:
        raise SceneError(f"{where} is cut short: its header counts {count:,} triangles ({expected:,} bytes), "
                         f"the file has {size:,} bytes")
    if size > expected:
        raise SceneError(f"{where} has {size - expected:,} bytes past the {count:,} triangles its header counts")


def _unreadable(spec: ObjectSpec, exc: Exception) -> SceneError:
    reason = next((line.strip() for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
    return SceneError(f"object {spec.id!r}: cannot read mesh {spec.value} ({reason})")


def _check_mesh(mesh: object, where: str) -> None:
    """Refuse what trimesh loads without a word but cannot be processed or measured.

    A face index past the vertices is an IndexError deep in processing; a negative one wraps around in numpy's
    indexing and builds bogus triangles; a NaN vertex poisons every estimate.

    Raises:
        SceneError: no triangles, non-integer or out-of-range face indices, or non-finite vertices; the message
            starts with ``where``.
    """
    faces = np.asarray(getattr(mesh, "faces", ()))
    if len(faces) == 0:
        raise SceneError(f"{where} holds no triangles")
    vertices = np.asarray(mesh.vertices)  # type: ignore[attr-defined]
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise SceneError(f"{where} has faces that are not triangles of vertex indices ({faces.dtype}, {faces.shape})")
    outside = int(((faces < 0) | (faces >= len(vertices))).any(axis=1).sum())
    if outside:
        raise SceneError(f"{where} has {outside} face(s) with vertex indices outside 0..{len(vertices) - 1}")
    bad = int((~np.isfinite(vertices).all(axis=1)).sum())
    if bad:
        raise SceneError(f"{where} has {bad} vertices with NaN or inf coordinates")


def estimate_object(spec: ObjectSpec) -> tuple[PhysicalEstimate, float]:
    """Estimate one scene object from its cloud (sampled from its mesh when it has one).

    Returns the estimate and the object's friction.

    Raises:
        SceneError: anything estimation rejects (unreadable cloud, too few points, no enclosed volume),
            with the object's id in the message.
    """
    from scenes.sampling import sample_surface

    try:
        density, mat = resolve_density(spec.material, spec.density)
        mesh = source_mesh(spec)
        viewpoint = None
        if mesh is None:
            cloud, viewpoint = scene_cloud(spec)
        else:
            if spec.source == "mesh":
                _check_size(spec, mesh.extents)
            # Seeded by the id, so the same scene builds the same twin.
            cloud = sample_surface(mesh, spec.points, seed=zlib.crc32(spec.id.encode()))
        result = estimate(cloud, density, material=None if mat is None else mat.name, viewpoint=viewpoint)
        if spec.source == "cloud":
            _check_size(spec, result.obb.extents)  # the points' box once strays are dropped
    except SceneError:
        raise
    except TwinError as exc:
        raise SceneError(f"object {spec.id!r}: {exc}") from exc
    return result, DEFAULT_FRICTION if mat is None else mat.friction


def _check_size(spec: ObjectSpec, extents: np.ndarray) -> None:
    """Refuse a mesh or cloud object whose size (``extents``, metres, in the scene's units) says its file is in other
    units: a cup drawn in mm read as metres is 90 m across and 90,000 t, and failed on where the end effector
    starts; a part in metres read as mm failed in MuJoCo's inertia check."""
    if units_warning(extents) is None:  # the range ``twin estimate`` warns outside of
        return
    largest = float(np.max(extents))
    low, high = tol.PLAUSIBLE_EXTENT_M
    if largest > high:
        hint = 'if the file is in mm or cm, set units = "mm" or "cm" on the object'
    else:
        hint = 'if the file is in metres, set units = "m" on the object' if spec.units != "m" else \
            "if the file is in metres, the object is smaller than a scene can hold"
    raise SceneError(f"object {spec.id!r} ({spec.source} {Path(str(spec.value)).name}) is {_length(largest)} across "
                     f"read in units = {spec.units!r}; a scene's objects are {_length(low)} to {_length(high)}: {hint}")


def _length(metres: float) -> str:
    return f"{metres:.3g} m" if metres >= 1 else f"{1000 * metres:.3g} mm"


def frame_rotation(spec: ObjectSpec) -> np.ndarray:
    """(3, 3) rotation of a cloud's frame in the world (the scene's ``quat`` or ``rotation``); identity when
    the scene gives none (the cloud's axes are the world's)."""
    return np.eye(3) if spec.frame_rotation is None else np.asarray(spec.frame_rotation, dtype=np.float64)


def scene_cloud(spec: ObjectSpec) -> tuple[PointCloud, np.ndarray | None]:
    """A cloud object's points in metres, turned into world axes by its frame's rotation (not moved:
    :func:`placement` puts it in place), with what orients its normals.

    Viewpoints are the scene's ``viewpoints`` (file frame and units), else the file's own (a PCD
    ``VIEWPOINT``, an NPZ ``sensor_origins``). One viewpoint is returned for ``estimate(viewpoint=...)``,
    as ``twin estimate --viewpoint`` passes it. Several: each point is oriented towards the nearest one (the
    sensor most likely to have seen it; a list of origins says nothing of which point each saw) and the
    cloud comes back with those normals. Normals the file carries are kept either way (``estimate`` uses them).

    Returns:
        The cloud ((n, 3) metres, world axes, origin the cloud file's) and one viewpoint ((3,) metres, same
        frame) or None.

    Raises:
        SceneError: the file cannot be read (with the object's id).
    """
    scale = unit_scale(spec.units)
    try:
        cloud = load_cloud(spec.value, scale=scale)  # type: ignore[arg-type]
    except TwinError as exc:
        raise SceneError(f"object {spec.id!r}: {exc}") from exc
    rotation = frame_rotation(spec)
    # Rotating moves the file's own sensor origins with the points (PointCloud.transformed).
    cloud = cloud.transformed(rotation, np.zeros(3))
    if spec.viewpoints:
        origins = np.asarray(spec.viewpoints, dtype=np.float64) * scale @ rotation.T
    elif cloud.sensor_origins is not None:
        single = is_single_origin(cloud.sensor_origins)
        origins = cloud.sensor_origins[:1] if single else cloud.sensor_origins
        if not single:  # one origin per point: the file says which sensor saw each
            return _with_normals(cloud, origins), None
    else:
        return cloud, None
    if len(origins) == 1:
        return cloud, origins[0]
    nearest = cKDTree(origins).query(cloud.points)[1]
    return _with_normals(cloud, origins[nearest]), None


def _with_normals(cloud: PointCloud, origins: np.ndarray) -> PointCloud:
    """``cloud`` with normals each flipped towards its point's sensor origin ((n, 3) metres), unless it has some."""
    if cloud.normals is not None:
        return cloud
    return replace(cloud, normals=oriented_normals(cloud.points, origins))


def reference_estimate(spec: ObjectSpec) -> tuple[PhysicalEstimate, float]:
    """The truth for a mesh, primitive or paper object: the exact record of its true mesh, no cloud.

    A twin built from these is the reference the estimated twin is measured against.

    Raises:
        SceneError: a cloud object (its truth is unknown) or a mesh that encloses no volume.
    """
    mesh = source_mesh(spec)
    if mesh is None:
        raise SceneError(f"object {spec.id!r}: a cloud has no true mesh to build a reference from")
    try:
        density, mat = resolve_density(spec.material, spec.density)
        result = from_mesh(mesh.vertices, mesh.faces, density, material=None if mat is None else mat.name)
    except TwinError as exc:
        raise SceneError(f"object {spec.id!r}: {exc}") from exc
    return result, DEFAULT_FRICTION if mat is None else mat.friction


def prepare_objects(
    specs: list[ObjectSpec] | tuple[ObjectSpec, ...], *, table_top: float | None, coacd: CoacdSettings = DEFAULT_SETTINGS,
    cache_dir: Path | None = None, progress: bool = True,
    estimates: list[tuple[PhysicalEstimate, float]] | None = None,
) -> list[TwinObject]:
    """Estimate, decimate and decompose every object; CoACD runs in parallel over the cache misses.

    ``estimates`` (from :func:`estimate_object`, one per spec) skips the estimation step.
    """
    if estimates is None:
        estimates = [estimate_object(s) for s in specs]
    visuals = [visual_mesh(est) for est, _ in estimates]
    shapes = collision_shapes(visuals, coacd, cache_dir=cache_dir, progress=progress)
    out = []
    for s, (est, friction), visual, (hulls, cached, primitive) in zip(specs, estimates, visuals, shapes, strict=True):
        obj = TwinObject(id=s.id, estimate=est, friction=friction, visual=visual, hulls=hulls,
                         position=np.zeros(3), quat=np.array([1.0, 0, 0, 0]), hull_cached=cached,
                         primitive=primitive)
        position = placement(s, lowest_point(obj), table_top, center_of_mass=est.mass.center_of_mass)
        out.append(replace(obj, position=position))
    return out


def placement(spec: ObjectSpec, lowest: float, table_top: float | None, *,
              center_of_mass: np.ndarray | None = None) -> np.ndarray:
    """World position of the centre of mass: [x, y] rests the object on the table (or floor).

    For a posed cloud (``spec.posed``) ``position`` is its frame's origin, and ``center_of_mass`` ((3,)
    metres, the estimate's: the cloud's frame in world axes) is added to it: [x, y, z] puts the cloud
    exactly where its pose says; [x, y] keeps x and y so and rests it on the table.

    ``lowest``: the lowest z, metres, of what collides (:func:`twin.objects.lowest_point` of the object
    at the origin): its primitive where one stands in for the hulls, else the hulls; not the visual mesh.
    A hull reaching below the visual mesh would start inside the table and be kicked out; a box resting
    on its hulls' fringe would start a few millimetres above the table and drop.
    """
    offset = np.zeros(3)
    if spec.posed:
        if center_of_mass is None:
            raise ValueError(f"object {spec.id!r}: a posed cloud is placed by its centre of mass; none given")
        offset = np.asarray(center_of_mass, dtype=np.float64)
    if len(spec.position) == 3:
        placed = np.asarray(spec.position, dtype=np.float64) + offset
    else:
        base = table_top if table_top is not None else 0.0
        placed = np.array([spec.position[0] + offset[0], spec.position[1] + offset[1], base - lowest + PLACEMENT_GAP])
    if spec.posed and float(np.abs(placed).max()) > MAX_COORDINATE:
        # The scene file's position is bounded, but a posed cloud adds its own coordinates to it: a cloud 8.7 km
        # out built a body at (5000, 5000, 5001) m, whose poses the wire then refused.
        raise SceneError(f"object {spec.id!r}: its cloud's own coordinates place it at "
                         f"{np.array2string(placed, precision=4)} m, beyond the {MAX_COORDINATE:g} m a scene holds "
                         f"(with quat or rotation, position is the cloud frame's origin: is it in the same units?)")
    return placed


def _primitive(p: dict) -> trimesh.Trimesh:
    kind, size = p["type"], p["size"]
    if kind == "box":
        return trimesh.creation.box(extents=size)
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=size[0], height=size[1], sections=64)
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=3, radius=size[0])
    if kind == "capsule":
        return trimesh.creation.capsule(height=size[1], radius=size[0], count=[32, 32])
    return trimesh.creation.torus(major_radius=size[0], minor_radius=size[1], major_sections=64, minor_sections=32)
