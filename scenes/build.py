"""Building a scene into a MuJoCo model, and writing it out.

A build folder holds ``scene.xml`` (the whole scene), ``assets/*.stl`` (its meshes), ``objects/<id>.xml``
(each object alone, to ``<include>`` or attach into another MJCF model), and ``estimates.json`` (every
object's estimate and the transform from its cloud's or mesh's frame to its body frame).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from scenes.placement import check_placement
from scenes.scenefile import ObjectSpec, SceneSpec, check_in_workspace
from scenes.sources import estimate_object, prepare_objects
from sync.replacing import file_sha256, listed_files, marker_text
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings, ProgressBar, concavity, skips_coacd
from twin.model import DEFAULT_PHYSICS, PhysicsSettings, add_object
from twin.objects import TwinObject
from twin.poses import matrix_quat


class BuildError(TwinError, RuntimeError):
    """MuJoCo refused the model (the message names the object), or the output folder is not ours to write."""


#: A file every build output folder holds: only a folder with it may be replaced by a new build.
MARKER = ".tactile-twin-build"


@dataclass(frozen=True)
class BuiltScene:
    """A compiled scene: the spec (for live edits), the model, and the objects that went into it.

    Attributes:
        seconds: the whole build, wall time.
        estimate_seconds: object id -> seconds its estimate took (sampling included).
        decompose_seconds: visual meshes and convex decomposition, summed over objects (which run in
            parallel: more than the wall time they took), cache reads included.
        reports: object id -> how it was built (:class:`ObjectReport`).
        compile_seconds: adding every object to the spec and compiling it, wall time.
        workers: processes the objects were built in (1: this one).
    """

    scene: SceneSpec
    spec: object
    model: object
    objects: tuple[TwinObject, ...]
    seconds: float
    estimate_seconds: dict[str, float] = field(default_factory=dict)
    decompose_seconds: float = 0.0
    reports: dict[str, ObjectReport] = field(default_factory=dict)
    compile_seconds: float = 0.0
    workers: int = 1


@dataclass(frozen=True)
class ObjectReport:
    """How one object was built, measured in the process that built it.

    Attributes:
        source_seconds: wall seconds to make its cloud: sample its true mesh, or read its cloud file.
        estimate_seconds: wall seconds of the estimator itself (``PhysicalEstimate.timings``).
        hull_seconds: wall seconds of its visual mesh and convex parts (decimation, cache, CoACD).
        cpu_seconds: CPU seconds of all three, in the process that built it.
        concavity: :func:`twin.decompose.concavity` of its visual mesh.
        skipped_coacd: CoACD did not run on it: it collides as a primitive (:func:`twin.objects.collision_shapes`)
            or, near-convex (:func:`twin.decompose.skips_coacd`), as its convex hull. False for hulls read
            from the cache.
    """

    source_seconds: float
    estimate_seconds: float
    hull_seconds: float
    cpu_seconds: float
    concavity: float
    skipped_coacd: bool


#: ``on_object(index, total, obj, report)``: called by :func:`build_scene` as each object is built, in the
#: order they finish (``index``: its place in the scene, from 0), so a command can show progress (the
#: library itself prints nothing).
OnObject = Callable[[int, int, TwinObject, ObjectReport], None]


def table_top(scene: SceneSpec) -> float | None:
    return None if scene.table is None else scene.table.height


def table_size(scene: SceneSpec) -> tuple[float, float, float] | None:
    return None if scene.table is None else scene.table.size


def build_scene(scene: SceneSpec, *, coacd: CoacdSettings = DEFAULT_SETTINGS, cache_dir: Path | None = None,
                progress: bool = True, physics: PhysicsSettings = DEFAULT_PHYSICS,
                on_object: OnObject | None = None, workers: int | None = None) -> BuiltScene:
    """Estimate every object, decompose it, and compile the whole scene.

    Objects are built independently (:func:`build_object`), in ``workers`` processes (default: one per
    core, at most one per object, as many as the memory holds: :func:`default_workers`; 1 builds them here);
    the result does not depend on how many.

    ``progress``: a progress bar over the objects on stderr, unless ``on_object`` (see :data:`OnObject`)
    reports them instead.

    Raises:
        SceneError: bad objects, or objects placed inside each other, the table, the floor or the end
            effector (:func:`scenes.placement.check_placement`). BuildError: MuJoCo rejected the model, or a
            worker process died.
    """
    t0 = time.perf_counter()
    most = max((o.points for o in scene.objects), default=0)
    workers = default_workers(len(scene.objects), most) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    built = _build_objects(scene, coacd=coacd, cache_dir=cache_dir, workers=workers, on_object=on_object,
                           progress=progress)
    objects = tuple(obj for obj, _ in built)
    if scene.workspace is not None:
        _check_posed_inside(scene, objects)
    reports = {obj.id: report for obj, report in built}
    t = time.perf_counter()
    spec = scene.empty_spec(physics)
    for obj in objects:
        add_object(spec, obj)
    model = compile_spec(spec)
    check_placement(scene.name, model, {obj.id for obj in objects},
                    scanned={o.id for o in scene.objects if o.source == "cloud" and len(o.position) == 3})
    compile_s = time.perf_counter() - t
    return BuiltScene(scene, spec, model, objects, time.perf_counter() - t0,
                      {i: r.source_seconds + r.estimate_seconds for i, r in reports.items()},
                      sum(r.hull_seconds for r in reports.values()), reports, compile_s, workers)


def _check_posed_inside(scene: SceneSpec, objects: tuple[TwinObject, ...]) -> None:
    """Each posed cloud where it landed, against the declared workspace. Its ``position`` is its frame's origin and
    its own coordinates add to it, so the scene file's check of ``position`` alone (``scenefile``) cannot see
    where that is."""
    posed = {o.id for o in scene.objects if o.posed}
    for obj in objects:
        if obj.id in posed:
            check_in_workspace(obj.id, obj.position, scene.workspace,  # type: ignore[arg-type]
                               what=f"its cloud's own coordinates place it at "
                                    f"{np.array2string(obj.position, precision=4)} m, which")


#: Memory a build worker takes per point of its object's sampled cloud (sampling, estimate, reconstruction): a
#: primitive of 10,000,000 points (``scenes.scenefile.MAX_POINTS``) took about 1.9 GB a worker, 3.9 GB in all on
#: this 2-core machine (a review, /usr/bin/time), and one worker a core would take cores x that.
BYTES_PER_POINT = 200


def default_workers(objects: int, points: int = 0) -> int:
    """Processes to build ``objects`` objects in: one per core this process may run on, at most one each, and no
    more than the memory available holds at :data:`BYTES_PER_POINT` for the largest object's ``points``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    workers = max(1, min(objects, cores))
    free = available_memory()
    if points > 0 and free is not None:
        workers = max(1, min(workers, free // (points * BYTES_PER_POINT)))
    return workers


def available_memory() -> int | None:
    """Bytes of memory available to start new work without swapping (Linux's MemAvailable); None where unknown."""
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024  # kB
    except (OSError, ValueError, IndexError):
        pass
    return None


def build_object(spec: ObjectSpec, *, table_top: float | None, coacd: CoacdSettings = DEFAULT_SETTINGS,
                 cache_dir: Path | None = None,
                 table_size: tuple[float, float, float] | None = None) -> tuple[TwinObject, ObjectReport]:
    """One object of a scene, ready for the model, and how it was built: its estimate
    (:func:`scenes.sources.estimate_object`), then its visual mesh, hulls and placement
    (:func:`scenes.sources.prepare_objects`). What runs in each build worker.

    Raises:
        SceneError: the object cannot be estimated, or rests on neither the table nor the floor
            (:func:`scenes.sources.placement`).
    """
    cpu0, t0 = time.process_time(), time.perf_counter()
    est, friction = estimate_object(spec)
    t1 = time.perf_counter()
    (obj,) = prepare_objects([spec], table_top=table_top, coacd=coacd, cache_dir=cache_dir, progress=False,
                             estimates=[(est, friction)], table_size=table_size)
    t2 = time.perf_counter()
    # Measured again here (a hull of the ~3000-face visual mesh: milliseconds) so the report says whether
    # CoACD was skipped by the very rule twin.decompose applied, even though prepare_objects returns hulls only.
    excess = concavity(*obj.visual)
    report = ObjectReport(source_seconds=max(0.0, t1 - t0 - est.timings.total), estimate_seconds=est.timings.total,
                          hull_seconds=t2 - t1, cpu_seconds=time.process_time() - cpu0, concavity=excess,
                          skipped_coacd=not obj.hull_cached and (obj.primitive is not None
                                                                 or skips_coacd(excess, coacd)))
    return obj, report


def _build_objects(scene: SceneSpec, *, coacd: CoacdSettings, cache_dir: Path | None, workers: int,
                   on_object: OnObject | None, progress: bool) -> list[tuple[TwinObject, ObjectReport]]:
    """:func:`build_object` for every object, in scene order whatever order they finish in."""
    specs, top, size = scene.objects, table_top(scene), table_size(scene)
    results: list[tuple[TwinObject, ObjectReport] | None] = [None] * len(specs)
    bar = ProgressBar(progress and on_object is None, len(specs), "objects")

    def finished(i: int, result: tuple[TwinObject, ObjectReport]) -> None:
        results[i] = result
        bar.advance()
        if on_object is not None:
            on_object(i, len(specs), *result)

    try:
        if workers == 1 or len(specs) < 2:
            for i, s in enumerate(specs):
                finished(i, build_object(s, table_top=top, coacd=coacd, cache_dir=cache_dir, table_size=size))
        else:
            _build_in_pool(specs, top, coacd, cache_dir, workers, finished, table_size=size)
    finally:
        bar.close()
    return [r for r in results if r is not None]


#: Primitive kinds that are convex: their objects skip CoACD (:func:`twin.decompose.skips_coacd`).
CONVEX_PRIMITIVES = frozenset({"box", "cylinder", "sphere", "capsule"})


def start_order(specs: tuple[ObjectSpec, ...]) -> list[int]:
    """Indices of ``specs`` in the order a build pool starts them: objects that may go to CoACD (clouds,
    meshes, paper objects, a torus: seconds each) before convex primitives (a fraction of a second), each
    group in scene order. Longest first: started last, one long CoACD run kept one core busy for 12 s
    while the other sat idle (mixed100, cold, ``bench/build.py``)."""
    def convex(s: ObjectSpec) -> bool:
        return s.source == "primitive" and isinstance(s.value, dict) and s.value.get("type") in CONVEX_PRIMITIVES

    return sorted(range(len(specs)), key=lambda i: convex(specs[i]))


def _build_in_pool(specs: tuple[ObjectSpec, ...], top: float | None, coacd: CoacdSettings, cache_dir: Path | None,
                   workers: int, finished: Callable[[int, tuple[TwinObject, ObjectReport]], None], *,
                   table_size: tuple[float, float, float] | None = None) -> None:
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from twin.workers import background_worker

    # spawn: CoACD and MuJoCo hold threads, forking them is not safe. background_worker: niced, and the
    # workers die with this process.
    pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=background_worker)
    try:
        pending = {pool.submit(build_object, specs[i], table_top=top, coacd=coacd, cache_dir=cache_dir,
                               table_size=table_size): i
                   for i in start_order(specs)}
        while pending:
            ready, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in ready:
                finished(pending.pop(future), future.result())
    except BrokenProcessPool as exc:
        raise BuildError(f"a build worker process died ({exc}); nothing was written") from exc
    finally:
        # On an error, objects not started are dropped; the (at most `workers`) running ones finish first.
        pool.shutdown(wait=True, cancel_futures=True)


def compile_spec(spec):  # type: ignore[no-untyped-def]
    try:
        return spec.compile()
    except ValueError as exc:
        # MuJoCo's message spans lines ("Error: ...\nElement name 'a', id 3"); the CLI prints one.
        raise BuildError(f"MuJoCo could not compile the model: {' '.join(str(exc).split())}") from exc


def check_output(out: Path, *, keep: tuple[Path, ...] = ()) -> None:
    """Refuse an output folder a build must not replace.

    A build replaces ``out`` whole, so ``out`` must be new, empty, or written by an earlier build (it holds
    :data:`MARKER`) and nothing since (every file is one the marker lists); and never the current folder, one
    of its parents, or a folder holding any of ``keep`` (the scene file and its sources).

    Raises:
        BuildError: naming the folder and why (a symbolic link is refused: replacing it would follow it to
            the folder it names, or fail half way).
    """
    try:
        _check_output(Path(out), keep)
    except OSError as exc:  # a name too long, a permission denied on the way
        raise BuildError(f"cannot use --out {out}: {exc.strerror or exc}") from None


def _check_output(out: Path, keep: tuple[Path, ...]) -> None:
    if out.is_symlink():
        raise BuildError(f"{out}: is a symbolic link; give --out a real folder (a build replaces it whole)")
    out = out.resolve()
    cwd = Path.cwd().resolve()
    if out == cwd or out in cwd.parents:
        raise BuildError(f"{out}: refusing to build into the current folder or one of its parents; "
                         f"give --out a new folder")
    for path in keep:
        if out in Path(path).resolve().parents:
            raise BuildError(f"{out}: holds {path}; give --out a new folder")
    if out.exists():
        if not out.is_dir():
            raise BuildError(f"{out}: exists and is not a folder")
        if any(out.iterdir()) and not (out / MARKER).is_file():
            raise BuildError(f"{out}: not empty and not written by 'twin build'; give --out a new or empty folder")
        if (out / MARKER).is_file():
            ours = _built_files(out)
            folders = {"assets", OBJECTS} | {p for name in ours for p in map(str, Path(name).parents) if p != "."}
            for path in sorted(out.rglob("*")):
                name = path.relative_to(out).as_posix()
                if (path.is_file() or path.is_symlink()) and name not in ours:
                    # A build replaces the folder whole: what the user put in it since would go with it.
                    raise BuildError(f"{out}: holds {name}, which no build wrote; move it out or give --out a new "
                                     f"folder")
                if path.is_dir() and not path.is_symlink() and name not in folders:
                    raise BuildError(f"{out}: holds the folder {name}, which no build made; move it out or give "
                                     f"--out a new folder")
                digest = ours.get(name)
                if digest is not None and path.is_file() and file_sha256(path) != digest:
                    # docs/cli.md: `twin run DIR` runs a built folder as it now is, edits included.
                    raise BuildError(f"{out}: {name} was edited since the build wrote it; move the folder aside or "
                                     f"give --out a new folder")


def _built_files(out: Path) -> dict[str, str | None]:
    """The files (relative, POSIX) the build that wrote ``out`` listed in its marker, the marker included, each
    with the sha256 it was written with (None where the marker gives none: builds before session 38).

    Raises:
        BuildError: a marker that lists no files (a build before 2026-12-04, or a marker emptied or cut short):
            what was written there is not known. Such folders were taken to hold only what their layout says
            a build writes (scene.xml, estimates.json, assets/, objects/), and a hostile-input review showed what
            that costs: a user's objects/my_extra.xml and assets/textures/wood.png went with the next build.
    """
    listed = listed_files((out / MARKER).read_text(errors="replace"))
    if listed is None:
        raise BuildError(f"{out}: its {MARKER} lists no files (an older build's, or emptied), so what else the "
                         f"folder holds is not known; move it aside or give --out a new folder")
    return {MARKER: None, **listed}


def write_scene(spec, out: Path, *, keep: tuple[Path, ...] = (), built: BuiltScene | None = None) -> Path:  # type: ignore[no-untyped-def]
    """Write ``out/scene.xml`` and ``out/assets/*.stl``; nothing half-written is left on failure.

    The in-memory spec carries mesh data inline; the written copy references STL files instead, so the
    scene opens in MuJoCo's own viewer and the XML stays readable. ``out`` is checked with
    :func:`check_output` first (``keep``: files the build must not delete).

    With ``built`` (the :class:`BuiltScene` ``spec`` came from), also ``out/estimates.json``
    (:func:`estimates_record`) and ``out/objects/<id>.xml`` for each object (:func:`object_xml`).

    Raises:
        BuildError: ``out`` is not ours to replace.
    """
    import trimesh

    out = Path(out)
    check_output(out, keep=keep)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=".twin-build-", dir=out.parent))
    except OSError as exc:  # a file where a folder should be, a read-only place
        raise BuildError(f"cannot write --out {out}: {exc.strerror or exc}") from None
    try:
        (staging / "assets").mkdir()
        copy = spec.copy()
        copy.meshdir = "assets"
        copy.modelfiledir = str(staging)  # to_xml resolves mesh files relative to this
        for mesh in copy.meshes:
            v = np.asarray(mesh.uservert, dtype=np.float64).reshape(-1, 3)
            f = np.asarray(mesh.userface, dtype=np.int64).reshape(-1, 3)
            filename = mesh_filename(mesh.name)
            trimesh.Trimesh(v, f, process=False).export(staging / "assets" / filename)
            mesh.file = filename
            mesh.uservert = []
            mesh.userface = []
        (staging / "scene.xml").write_text(copy.to_xml())
        if built is not None:
            (staging / OBJECTS).mkdir()
            for obj in built.objects:
                (staging / OBJECTS / f"{obj.id}.xml").write_text(object_xml(obj, staging / OBJECTS))
            record = estimates_record(built)
            (staging / ESTIMATES).write_text(json.dumps(record, indent=1, allow_nan=False) + "\n")
        written = {p.relative_to(staging).as_posix(): file_sha256(p) for p in staging.rglob("*") if p.is_file()}
        (staging / MARKER).write_text(marker_text("written by 'twin build'; the next build into this folder replaces "
                                                  "it, unless it holds files not listed here, or listed files changed "
                                                  "since (their sha256 follows each)", written))
        import mujoco

        mujoco.MjModel.from_xml_path(str(staging / "scene.xml"))  # what we write must load
        if built is not None:
            for obj in built.objects:  # and each object on its own
                mujoco.MjModel.from_xml_path(str(staging / OBJECTS / f"{obj.id}.xml"))
        if out.exists():
            check_output(out, keep=keep)  # still ours: nothing else was put there while we built
            shutil.rmtree(out)
        umask = os.umask(0)
        os.umask(umask)
        staging.chmod(0o777 & ~umask)  # mkdtemp's 0700 kept every other user out of a build folder
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out / "scene.xml"


#: Where :func:`write_scene` puts each object's MJCF, and every object's estimate.
OBJECTS, ESTIMATES = "objects", "estimates.json"

#: ``estimates.json``'s format; bump it when a field changes meaning or goes away (adding one does not).
ESTIMATES_VERSION = 1


def object_xml(obj: TwinObject, folder: Path) -> str:
    """One object as MJCF to ``<include>`` (or ``<attach>``) into another model: ``<asset>`` and
    ``<worldbody>`` only, no ``<compiler>`` or ``<option>`` to override the host model's.

    The body (named as the object, with a free joint ``<id>/free``, explicit inertia at its origin,
    the visual mesh and the collision hulls) sits where the build placed it. Mesh files are
    ``../assets/*.stl``: MuJoCo resolves them against the folder of this file (``folder``, which must be
    ``<build>/objects``), wherever the including model is.
    """
    import xml.etree.ElementTree as ET

    import mujoco

    spec = mujoco.MjSpec()
    spec.modelname = obj.id
    add_object(spec, obj)
    spec.modelfiledir = str(folder)
    for mesh in spec.meshes:
        mesh.file = f"../assets/{mesh_filename(mesh.name)}"
        mesh.uservert = []
        mesh.userface = []
    root = ET.fromstring(spec.to_xml())
    for child in list(root):
        if child.tag not in ("asset", "worldbody"):
            root.remove(child)
    ET.indent(root, space="  ")
    comment = (f"<!-- object {obj.id!r}, written by 'twin build': include it in a model "
               f"(<include file=\"objects/{obj.id}.xml\"/>) or attach it; its estimate is in ../{ESTIMATES} -->\n")
    return comment + ET.tostring(root, encoding="unicode") + "\n"


def mesh_filename(mesh_name: str) -> str:
    """The STL file name of a spec mesh (``crate/hull0`` -> ``crate__hull0.stl``), the same in scene.xml."""
    return mesh_name.replace("/", "__") + ".stl"


def estimates_record(built: BuiltScene) -> dict:
    """The ``estimates.json`` record: per object, the estimate and where its body frame is.

    Units are SI and named in the keys. Frames: the *source frame* is the cloud file's or the mesh's
    own (converted to metres; a primitive's or paper object's is centred on it), before the scene's
    ``rotation_deg``; the *body frame* has its origin at the estimated centre of mass, and
    ``p_body = R p_source + t`` with ``R`` the rotation of ``source_to_body.quat_wxyz`` and ``t`` its
    ``translation_m``. ``center_of_mass_m`` is in the source frame rotated by ``R``; ``inertia_kg_m2`` is
    about the centre of mass in body axes (what the MJCF's ``fullinertia`` holds). ``body_pose_world`` is
    where the build placed the body.
    """
    specs = {o.id: o for o in built.scene.objects}
    return {
        "format": "tactile-twin estimates",
        "version": ESTIMATES_VERSION,
        "scene": built.scene.name,
        "frames": ("p_body = rotate(source_to_body.quat_wxyz, p_source) + source_to_body.translation_m; "
                   "quaternions w x y z (MuJoCo's order); inertia about the centre of mass, body axes"),
        "objects": [_object_record(obj, specs[obj.id], built.estimate_seconds.get(obj.id)) for obj in built.objects],
    }


def _object_record(obj: TwinObject, spec: ObjectSpec, seconds: float | None) -> dict:
    est = obj.estimate
    m = est.mass
    if spec.material is not None:
        density_source = "material"
    elif spec.density is not None:
        density_source = "given"
    else:
        density_source = "default"  # estimation.materials.DEFAULT_DENSITY: water
    # The estimate's frame is the source's after the scene's rotation (scenes.sources.source_mesh), and the
    # body's origin is the centre of mass in that frame: p_body = R p_source - com.
    rotation = _source_rotation(spec)
    return {
        "id": obj.id,
        "source": {"kind": spec.source, "value": str(spec.value) if spec.source in ("mesh", "cloud") else spec.value,
                   "units": spec.units, "rotation_deg": list(spec.rotation_deg), "points": spec.points},
        "volume_m3": m.volume,
        "density_kg_m3": m.density,
        "density_source": density_source,
        "material": est.material,
        "mass_kg": m.mass,
        "center_of_mass_m": m.center_of_mass.tolist(),
        "inertia_kg_m2": m.inertia.tolist(),
        "principal_moments_kg_m2": m.principal_moments.tolist(),
        "method": est.method,
        "points_in": est.points_in,
        "points_used": est.points_used,
        "watertight": est.watertight,
        "warnings": list(est.warnings),
        "hull_count": len(obj.hulls),
        "hulls_cached": obj.hull_cached,
        "friction": obj.friction,
        "estimate_seconds": seconds,
        "source_to_body": {"quat_wxyz": _quat_wxyz(rotation), "translation_m": (-m.center_of_mass).tolist()},
        "body_pose_world": {"position_m": obj.position.tolist(), "quat_wxyz": obj.quat.tolist()},
        "mjcf": f"{OBJECTS}/{obj.id}.xml",
    }


def _source_rotation(spec: ObjectSpec) -> np.ndarray:
    """The rotation (3, 3) the build applied to the source before sampling it: the scene's ``rotation_deg``
    for mesh-like sources (:func:`scenes.sources.source_mesh`); a cloud's frame rotation
    (:func:`scenes.sources.frame_rotation`, identity when the scene gives none)."""
    if spec.source == "cloud":
        from scenes.sources import frame_rotation

        return frame_rotation(spec)
    if not any(spec.rotation_deg):
        return np.eye(3)
    from scipy.spatial.transform import Rotation

    # rotation_deg is [about Z, about local X, about local Y], the paper's order (as in scenes.sources).
    return Rotation.from_euler("ZXY", spec.rotation_deg, degrees=True).as_matrix()


def _quat_wxyz(rotation: np.ndarray) -> list[float]:
    """A rotation matrix as a unit quaternion, w x y z (MuJoCo's order), w >= 0."""
    q = matrix_quat(rotation)
    return (q if q[0] >= 0 else -q).tolist()
