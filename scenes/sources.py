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
from collections.abc import Sequence
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
from estimation.units import implausible_size, unit_scale
from scenes.scenefile import ObjectSpec, SceneError
from sync.messages import MAX_COORDINATE
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.objects import (
    DEFAULT_FRICTION,
    TwinObject,
    body_vertices,
    collision_shapes,
    lowest_point,
    visual_mesh,
)

log = logging.getLogger(__name__)

#: Gap left between a resting object and the table when it is placed, metres.
PLACEMENT_GAP = 0.001


def source_mesh(spec: ObjectSpec) -> trimesh.Trimesh | None:
    """The true mesh of a mesh/primitive/paper object, rotated as the scene says (metres); None for clouds.

    Closed (a mesh file's small slips repaired: :func:`_closed`), and the union of its closed parts where they
    overlap (:func:`_union_of_parts`): the surface of the solid that is the object's truth.

    Raises:
        SceneError: a mesh file that cannot be read, is not a closed surface or has no triangle with any area (with
            the object's id and the file).
    """
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
        mesh = _closed(mesh, spec)
    mesh = _union_of_parts(mesh, spec)
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


def _closed(mesh: trimesh.Trimesh, spec: ObjectSpec) -> trimesh.Trimesh:
    """``mesh`` (metres) as a closed surface: as it is, or repaired by what does not change the solid it bounds
    (vertices merged across texture seams, duplicate and zero-area faces dropped, each part's faces turned the way
    most of them face, holes of three or four edges filled).

    An open surface bounds no solid. Its truth was the signed sum over its faces (as if its rim were joined to the
    origin) and its samples one sheet: an open cup's truth weighed 1.0 kg and its twin 0.1 kg, with only a log line.

    Raises:
        SceneError: the surface is still open after the repair (with the object's id, the file and its open edges),
            or none of its triangles has any area (:func:`_check_area`).
    """
    if mesh.is_watertight and mesh.is_winding_consistent:
        _check_area(mesh, spec)
        return mesh
    repaired = mesh.copy()
    repaired.merge_vertices(merge_tex=True, merge_norm=True)  # an OBJ's texture seams split its vertices
    repaired.update_faces(repaired.unique_faces() & repaired.nondegenerate_faces())
    _fix_winding(repaired)
    trimesh.repair.fill_holes(repaired)  # a triangle's or a quad's hole only: a larger one is no slip
    opened = _open_edges(repaired)
    if opened == 0:
        _check_area(repaired, spec)  # before the warning: a repair that left nothing repaired nothing
        if len(repaired.vertices) != len(mesh.vertices) or not np.array_equal(repaired.faces, mesh.faces):
            log.warning("object %r: mesh %s was not closed; repaired (vertices merged, duplicate or zero-area "
                        "faces dropped, winding made consistent, small holes filled)", spec.id, spec.value)
        return repaired
    raise SceneError(f"object {spec.id!r}: mesh {spec.value} is not a closed surface: {opened} open edge(s) after "
                     f"merging vertices, fixing the winding and filling small holes; its volume, so its mass, is "
                     f"undefined: close it in a mesh editor (fill its holes; give an open shell a wall thickness)")


def _check_area(mesh: trimesh.Trimesh, spec: ObjectSpec) -> None:
    """Refuse a closed mesh (metres) none of whose triangles has any area: it bounds no solid.

    Vertices that merge into one (a mesh nanometres across, or every corner at the same point) leave no face at
    all, which failed deep in the search for its parts; faces along one line are closed but have no normal, and
    failed on the samples' zero normals. trimesh's own test of a degenerate face, the one the repair drops by.

    Raises:
        SceneError: no face with both sides of its bounding rectangle above ``trimesh.tol.merge`` (with the object's
            id and the file).
    """
    if len(mesh.faces) and mesh.nondegenerate_faces().any():
        return
    raise SceneError(f"object {spec.id!r}: mesh {spec.value} has no triangle left with any area once its vertices "
                     f"are merged (its corners all on one point or one line, or its units far too small): it encloses "
                     f"no volume")


def _open_edges(mesh: trimesh.Trimesh) -> int:
    """How many of ``mesh``'s edges its faces do not close: crossed more times one way than the other (a rim, a
    hole's edge, or a face wound against its neighbour's).

    Not trimesh's ``is_watertight``, which wants every edge on exactly two faces: a closed surface may meet itself
    along an edge (two boxes sharing one; ``twin estimate --mesh-out``'s surfaces, where parts meet), and its
    signed volume is still the solid's.
    """
    edges = np.asarray(mesh.edges)
    edges = edges[edges[:, 0] != edges[:, 1]]  # a zero-area face's loop bounds nothing
    ways, pairs = np.where(edges[:, 0] < edges[:, 1], 1, -1), np.sort(edges, axis=1)
    _, which = np.unique(pairs, axis=0, return_inverse=True)
    return int(np.count_nonzero(np.bincount(which.ravel(), weights=ways)))


def _fix_winding(mesh: trimesh.Trimesh) -> None:
    """Turn ``mesh``'s faces (in place) so neighbours agree, each connected part the way most of its faces faced.

    trimesh keeps each part's first face as it is: a box whose one flipped face came first came out inside out,
    a hollow part's cavity came out as a second solid."""
    before = np.array(mesh.faces)
    trimesh.repair.fix_winding(mesh)
    flipped = (np.asarray(mesh.faces) != before).any(axis=1)
    if not flipped.any():
        return
    faces = np.array(mesh.faces)
    for part in trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(faces))):
        if flipped[part].mean() > 0.5:
            faces[part] = faces[part][:, ::-1]
    mesh.faces = faces


def _union_of_parts(mesh: trimesh.Trimesh, spec: ObjectSpec) -> trimesh.Trimesh:
    """``mesh`` (closed, metres) as the union of its closed parts where they overlap (a CAD assembly in one file).

    The union is the solid the truth is (:func:`estimation.from_mesh` takes it), and so the surface the sensors
    sample: the parts' faces buried inside each other were sampled as if they were surface (two crossed boxes'
    twin came out 3.7 % light, warned of as a surface with holes). One part, parts apart or a union manifold3d
    cannot form: the mesh as it is (``from_mesh`` warns of the last).
    """
    from estimation.meshparts import overlap_union

    union = overlap_union(np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64))
    if union is None or union.vertices is None or union.faces is None:
        return mesh
    log.info("object %r: %d of its %d closed parts overlap: it is their union (%.3g m^3 counted twice by its faces)",
             spec.id, union.overlapping, union.parts, union.shared)
    return trimesh.Trimesh(union.vertices, union.faces)


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
    side = implausible_size(extents)  # the range ``twin estimate`` warns outside of
    if side == 0:
        return
    largest = float(np.max(extents))
    low, high = tol.PLAUSIBLE_EXTENT_M
    if side > 0:
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
    estimates: list[tuple[PhysicalEstimate, float]] | None = None, table_size: Sequence[float] | None = None,
) -> list[TwinObject]:
    """Estimate, decimate and decompose every object; CoACD runs in parallel over the cache misses.

    ``estimates`` (from :func:`estimate_object`, one per spec) skips the estimation step. ``table_top`` and
    ``table_size``: the table's (:class:`twin.model.TableSpec` ``height`` and ``size``), where [x, y] objects rest
    (:func:`placement`).

    Raises:
        SceneError: as :func:`placement`.
    """
    if estimates is None:
        estimates = [estimate_object(s) for s in specs]
    visuals = [visual_mesh(est) for est, _ in estimates]
    shapes = collision_shapes(visuals, coacd, cache_dir=cache_dir, progress=progress,
                              surfaces=[body_vertices(est) for est, _ in estimates])
    out = []
    for s, (est, friction), visual, (hulls, cached, primitive) in zip(specs, estimates, visuals, shapes, strict=True):
        obj = TwinObject(id=s.id, estimate=est, friction=friction, visual=visual, hulls=hulls,
                         position=np.zeros(3), quat=np.array([1.0, 0, 0, 0]), hull_cached=cached,
                         primitive=primitive)
        position = placement(s, lowest_point(obj), table_top, center_of_mass=est.mass.center_of_mass,
                             table_size=table_size, footprint=object_footprint(obj))
        out.append(replace(obj, position=position))
    return out


def object_footprint(obj: TwinObject) -> np.ndarray:
    """(2, 2) low and high x, y, metres, world axes, of what collides for ``obj`` at its orientation (its hulls;
    under a primitive, the visual mesh's convex hull), relative to its centre of mass."""
    from twin.poses import rotation

    xy = (np.vstack([np.asarray(v) for v, _ in obj.hulls]) @ rotation(np.asarray(obj.quat, dtype=np.float64)).T)[:, :2]
    return np.array([xy.min(axis=0), xy.max(axis=0)])


def placement(spec: ObjectSpec, lowest: float, table_top: float | None, *,
              center_of_mass: np.ndarray | None = None, table_size: Sequence[float] | None = None,
              footprint: np.ndarray | None = None) -> np.ndarray:
    """World position of the centre of mass: [x, y] rests the object on the table (or floor).

    With ``table_size`` (the table's full x, y (, z) extents, metres; it is centred on the world's origin) and
    the object's ``footprint`` (:func:`object_footprint`), [x, y] rests it on the table where its centre of mass
    is over the table top, and on the floor (z = 0) where its footprint is clear of the table's edges; without
    them, on the table wherever x and y are (a box placed 1.4 m beyond a 1.2 m table's edge started in mid-air,
    at the table top's height, and fell to the floor).

    For a posed cloud (``spec.posed``) ``position`` is its frame's origin, and ``center_of_mass`` ((3,)
    metres, the estimate's: the cloud's frame in world axes) is added to it: [x, y, z] puts the cloud
    exactly where its pose says; [x, y] keeps x and y so and rests it on the table.

    ``lowest``: the lowest z, metres, of what collides (:func:`twin.objects.lowest_point` of the object
    at the origin): its primitive where one stands in for the hulls, else the hulls; not the visual mesh.
    A hull reaching below the visual mesh would start inside the table and be kicked out; a box resting
    on its hulls' fringe would start a few millimetres above the table and drop.

    Raises:
        SceneError: a posed cloud placed beyond the coordinates a scene holds; an [x, y] object whose centre of
            mass is beyond the table's edge while its footprint reaches over the table (it would tip off the edge,
            or start inside the table on the floor).
    """
    offset = np.zeros(3)
    if spec.posed:
        if center_of_mass is None:
            raise ValueError(f"object {spec.id!r}: a posed cloud is placed by its centre of mass; none given")
        offset = np.asarray(center_of_mass, dtype=np.float64)
    if len(spec.position) == 3:
        placed = np.asarray(spec.position, dtype=np.float64) + offset
    else:
        xy = np.array([spec.position[0] + offset[0], spec.position[1] + offset[1]])
        base = 0.0 if table_top is None else table_top
        if table_top is not None and table_size is not None and footprint is not None:
            base = _support(spec, xy, table_top, table_size, footprint)
        placed = np.array([xy[0], xy[1], base - lowest + PLACEMENT_GAP])
    if spec.posed and float(np.abs(placed).max()) > MAX_COORDINATE:
        # The scene file's position is bounded, but a posed cloud adds its own coordinates to it: a cloud 8.7 km
        # out built a body at (5000, 5000, 5001) m, whose poses the wire then refused.
        raise SceneError(f"object {spec.id!r}: its cloud's own coordinates place it at "
                         f"{np.array2string(placed, precision=4)} m, beyond the {MAX_COORDINATE:g} m a scene holds "
                         f"(with quat or rotation, position is the cloud frame's origin: is it in the same units?)")
    return placed


def _support(spec: ObjectSpec, xy: np.ndarray, table_top: float, table_size: Sequence[float],
             footprint: np.ndarray) -> float:
    """Height, metres, of what an object placed by [x, y] rests on: the table top where its centre of mass
    (``xy``, (2,) metres, world) is over the table (an overhang then holds), the floor where its ``footprint``
    ((2, 2) low and high x, y relative to ``xy``) is clear of the table's edges (the floor, a MuJoCo plane, is
    z = 0 everywhere).

    Raises:
        SceneError: the centre of mass off the table and the footprint over it.
    """
    half = np.asarray(table_size[:2], dtype=np.float64) / 2
    if (np.abs(xy) <= half).all():
        return table_top
    low, high = xy + footprint[0], xy + footprint[1]
    if (high <= -half).any() or (low >= half).any():
        return 0.0
    raise SceneError(f"object {spec.id!r}: position {list(spec.position)} puts its centre of mass "
                     f"({xy[0]:.3g}, {xy[1]:.3g}) beyond the table's edge (the table spans x "
                     f"{-half[0]:.3g}..{half[0]:.3g}, y {-half[1]:.3g}..{half[1]:.3g} m) while its footprint "
                     f"(x {low[0]:.3g}..{high[0]:.3g}, y {low[1]:.3g}..{high[1]:.3g} m) reaches over it: it would "
                     f"tip off the edge; put its centre of mass over the table, or its footprint clear of the table "
                     f"to rest it on the floor")


#: Facets of the round primitives: 64 sections round a cylinder, 32 by 32 on a capsule, 64 by 32 on a torus, a
#: 1280-face icosphere (subdivisions 3), as before. Few enough for the samples and the estimate downstream; their
#: volume is made the analytic one by :func:`_analytic_volume`, not by more faces (inscribed, a sphere needs
#: 20,000 faces to come within 0.1 %, a torus 33,000).
_SECTIONS = 64
_SPHERE_SUBDIVISIONS = 3


def _primitive(p: dict) -> trimesh.Trimesh:
    """A primitive's closed mesh (metres, centred on the origin, axis z) enclosing its analytic volume.

    Built with its smallest size 1 and scaled after: trimesh merges vertices within absolute tolerances, which at
    millimetres joined a capsule's rings (radius and length 1 mm: 1 mm tall instead of 3, 57 % of its volume
    lost; not closed for every radius under 4 mm).
    """
    kind = p["type"]
    size = np.asarray(p["size"], dtype=np.float64)
    unit = float(size.min())
    a, b = (*(size / unit).tolist(), 0.0)[:2]
    if kind == "box":
        mesh = trimesh.creation.box(extents=size / unit)
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=a, height=b, sections=_SECTIONS)
    elif kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=_SPHERE_SUBDIVISIONS, radius=a)
    elif kind == "capsule":
        mesh = trimesh.creation.capsule(height=b, radius=a, count=[_SECTIONS // 2, _SECTIONS // 2])
    else:
        mesh = trimesh.creation.torus(major_radius=a, minor_radius=b, major_sections=_SECTIONS,
                                      minor_sections=_SECTIONS // 2)
    mesh = _analytic_volume(mesh, kind, a, b)
    mesh.apply_scale(unit)
    return mesh


def _analytic_volume(mesh: trimesh.Trimesh, kind: str, a: float, b: float) -> trimesh.Trimesh:
    """``mesh`` of a round primitive (sizes ``a``, ``b`` as :func:`_primitive` builds it) with its vertices moved
    out across its axis until it encloses the shape's analytic volume; a box as it is.

    Facets through points of the true surface lie inside it: a 64-gon has 0.16 % less area than its circle, an
    icosphere of 1280 faces 0.86 % less volume than its sphere, so a ``sphere`` weighed 0.86 % light (its inertia
    1.4 %). Scaled across the axis, the facets straddle the true surface and the volume, with the mass, is the
    shape's: a polygon's area and a revolved polygon's volume scale exactly with the square of the scale, so the
    sphere's and cylinder's inertia come out exact too, the capsule's and torus's within 0.15 %.
    """
    if kind == "box":
        return mesh
    vertices = np.array(mesh.vertices)
    if kind == "sphere":
        vertices *= (4 / 3 * np.pi * a**3 / mesh.volume) ** (1 / 3)
    elif kind in ("cylinder", "capsule"):
        volume = np.pi * a**2 * b + (4 / 3 * np.pi * a**3 if kind == "capsule" else 0.0)
        vertices[:, :2] *= np.sqrt(volume / mesh.volume)
    else:  # torus: its tube's cross-section about the circle of radius a
        k = np.sqrt(2 * np.pi**2 * a * b**2 / mesh.volume)
        rho = np.linalg.norm(vertices[:, :2], axis=1)
        # A vertex on the axis (minor radius = major: a horn torus) stays there.
        vertices[:, :2] *= np.divide(a + k * (rho - a), rho, out=np.ones_like(rho), where=rho > 0)[:, None]
        vertices[:, 2] *= k
    return trimesh.Trimesh(vertices, mesh.faces, process=False)
