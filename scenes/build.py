"""Building a scene into a MuJoCo model, and writing it as scene.xml plus mesh assets."""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from scenes.scenefile import SceneSpec
from scenes.sources import prepare_objects
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.model import DEFAULT_PHYSICS, PhysicsSettings, add_object
from twin.objects import TwinObject


class BuildError(TwinError, RuntimeError):
    """MuJoCo refused the model (the message names the object), or the output folder is not ours to write."""


#: A file every build output folder holds: only a folder with it may be replaced by a new build.
MARKER = ".tactile-twin-build"


@dataclass(frozen=True)
class BuiltScene:
    """A compiled scene: the spec (for live edits), the model, and the objects that went into it."""

    scene: SceneSpec
    spec: object
    model: object
    objects: tuple[TwinObject, ...]
    seconds: float


def table_top(scene: SceneSpec) -> float | None:
    return None if scene.table is None else scene.table.height


def build_scene(scene: SceneSpec, *, coacd: CoacdSettings = DEFAULT_SETTINGS, cache_dir: Path | None = None,
                progress: bool = True, physics: PhysicsSettings = DEFAULT_PHYSICS) -> BuiltScene:
    """Estimate every object, decompose it, and compile the whole scene.

    Raises:
        SceneError: bad objects. BuildError: MuJoCo rejected the model.
    """
    t0 = time.perf_counter()
    objects = prepare_objects(scene.objects, table_top=table_top(scene), coacd=coacd, cache_dir=cache_dir,
                              progress=progress)
    spec = scene.empty_spec(physics)
    for obj in objects:
        add_object(spec, obj)
    model = compile_spec(spec)
    return BuiltScene(scene, spec, model, tuple(objects), time.perf_counter() - t0)


def compile_spec(spec):  # type: ignore[no-untyped-def]
    try:
        return spec.compile()
    except ValueError as exc:
        raise BuildError(f"MuJoCo could not compile the model: {exc}") from exc


def check_output(out: Path, *, keep: tuple[Path, ...] = ()) -> None:
    """Refuse an output folder a build must not replace.

    A build replaces ``out`` whole, so ``out`` must be new, empty, or written by an earlier build (it holds
    :data:`MARKER`); and never the current folder, one of its parents, or a folder holding any of ``keep``
    (the scene file and its sources).

    Raises:
        BuildError: naming the folder and why.
    """
    out = Path(out).resolve()
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


def write_scene(spec, out: Path, *, keep: tuple[Path, ...] = ()) -> Path:  # type: ignore[no-untyped-def]
    """Write ``out/scene.xml`` and ``out/assets/*.stl``; nothing half-written is left on failure.

    The in-memory spec carries mesh data inline; the written copy references STL files instead, so the
    scene opens in MuJoCo's own viewer and the XML stays readable. ``out`` is checked with
    :func:`check_output` first (``keep``: files the build must not delete).

    Raises:
        BuildError: ``out`` is not ours to replace.
    """
    import trimesh

    out = Path(out)
    check_output(out, keep=keep)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".twin-build-", dir=out.parent))
    try:
        (staging / "assets").mkdir()
        copy = spec.copy()
        copy.meshdir = "assets"
        copy.modelfiledir = str(staging)  # to_xml resolves mesh files relative to this
        for mesh in copy.meshes:
            v = np.asarray(mesh.uservert, dtype=np.float64).reshape(-1, 3)
            f = np.asarray(mesh.userface, dtype=np.int64).reshape(-1, 3)
            filename = mesh.name.replace("/", "__") + ".stl"
            trimesh.Trimesh(v, f, process=False).export(staging / "assets" / filename)
            mesh.file = filename
            mesh.uservert = []
            mesh.userface = []
        (staging / "scene.xml").write_text(copy.to_xml())
        (staging / MARKER).write_text("written by 'twin build'; the next build into this folder replaces it\n")
        import mujoco

        mujoco.MjModel.from_xml_path(str(staging / "scene.xml"))  # what we write must load
        if out.exists():
            check_output(out, keep=keep)  # still ours: nothing else was put there while we built
            shutil.rmtree(out)
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out / "scene.xml"
