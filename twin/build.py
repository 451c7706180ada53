"""Building a scene into a MuJoCo model, and writing it as scene.xml plus mesh assets."""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.errors import TwinError
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings
from twin.model import DEFAULT_PHYSICS, PhysicsSettings, add_object, new_spec
from twin.objects import TwinObject, prepare_objects
from twin.scenefile import SceneSpec


class BuildError(TwinError, RuntimeError):
    """MuJoCo refused the model; the message names the object (from the element's info)."""


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
    spec = new_spec(scene, physics)
    for obj in objects:
        add_object(spec, obj)
    model = compile_spec(spec)
    return BuiltScene(scene, spec, model, tuple(objects), time.perf_counter() - t0)


def compile_spec(spec):  # type: ignore[no-untyped-def]
    try:
        return spec.compile()
    except ValueError as exc:
        raise BuildError(f"MuJoCo could not compile the model: {exc}") from exc


def write_scene(spec, out: Path) -> Path:  # type: ignore[no-untyped-def]
    """Write ``out/scene.xml`` and ``out/assets/*.stl``; nothing half-written is left on failure.

    The in-memory spec carries mesh data inline; the written copy references STL files instead, so the
    scene opens in MuJoCo's own viewer and the XML stays readable.
    """
    import trimesh

    out = Path(out)
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
        import mujoco

        mujoco.MjModel.from_xml_path(str(staging / "scene.xml"))  # what we write must load
        if out.exists():
            shutil.rmtree(out)
        staging.rename(out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out / "scene.xml"
