"""What the build writes (estimates.json, objects/<id>.xml), what commands print and where, and material aliases."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from cli.demo import object_records
from cli.main import main
from estimation import MaterialError, estimate, from_mesh, make_cloud, material, save_cloud
from estimation.materials import aliases, materials
from scenes.build import BuiltScene, build_scene, estimates_record, write_scene
from scenes.scenefile import load_scene, parse_scene
from scenes.sources import source_mesh
from twin.objects import TwinObject, body_vertices
from twin.runtime import LocalReport

ROOT = Path(__file__).resolve().parent.parent
SMALL = ROOT / "tests" / "data" / "small.toml"


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("coacd")


@pytest.fixture(scope="module")
def built(cache):
    return build_scene(load_scene(SMALL), cache_dir=cache, progress=False)


@pytest.fixture(scope="module")
def out(built, tmp_path_factory):
    folder = tmp_path_factory.mktemp("build") / "small"
    write_scene(built.spec, folder, built=built)
    return folder


def _no_constants(name: str) -> None:
    raise AssertionError(f"{name} in JSON output")


# -- build outputs ------------------------------------------------------------------------------------------

def test_build_writes_objects_and_estimates(out, built):
    assert sorted(p.name for p in (out / "objects").iterdir()) == ["can.xml", "crate.xml"]
    assert (out / ".tactile-twin-build").is_file()
    record = json.loads((out / "estimates.json").read_text(), parse_constant=_no_constants)
    assert record["format"] == "tactile-twin estimates" and record["version"] == 1 and record["scene"] == "small"
    objects = {o["id"]: o for o in record["objects"]}
    assert list(objects) == ["crate", "can"]
    model = built.model
    for obj in built.objects:
        o = objects[obj.id]
        assert o["mass_kg"] == pytest.approx(model.body(obj.id).mass[0], rel=1e-12)
        assert o["mass_kg"] == pytest.approx(o["volume_m3"] * o["density_kg_m3"], rel=1e-12)
        assert o["hull_count"] == len(obj.hulls) >= 1
        assert np.allclose(o["source_to_body"]["translation_m"], -obj.estimate.mass.center_of_mass)
        assert o["source_to_body"]["quat_wxyz"] == [1.0, 0.0, 0.0, 0.0]
        assert np.allclose(o["body_pose_world"]["position_m"], obj.position)
        assert o["mjcf"] == f"objects/{obj.id}.xml"
        inertia = np.asarray(o["inertia_kg_m2"])
        assert inertia.shape == (3, 3) and np.allclose(inertia, inertia.T)
        for key in ("center_of_mass_m", "method", "points_in", "points_used", "warnings", "watertight"):
            assert key in o
    assert (objects["crate"]["density_source"], objects["crate"]["material"]) == ("material", "wood_pine")
    assert (objects["can"]["density_source"], objects["can"]["density_kg_m3"]) == ("given", 700.0)
    assert objects["crate"]["source"] == {"kind": "primitive", "value": {"type": "box", "size": [0.12, 0.08, 0.06]},
                                          "units": "m", "rotation_deg": [0.0, 0.0, 0.0], "points": 20000}


def test_an_object_file_is_included_into_another_model(out, built, tmp_path):
    # A user's own world, in a folder of its own, includes the crate; MuJoCo finds its meshes.
    world = tmp_path / "robot" / "world.xml"
    world.parent.mkdir()
    world.write_text(f'<mujoco><worldbody><geom type="plane" size="1 1 0.1"/></worldbody>'
                     f'<include file="{out / "objects" / "crate.xml"}"/></mujoco>')
    model = mujoco.MjModel.from_xml_path(str(world))
    crate = next(o for o in built.objects if o.id == "crate")
    assert model.body("crate").mass[0] == pytest.approx(crate.estimate.mass.mass, rel=1e-5)  # 6 digits in MJCF
    assert model.nmesh == 1 + len(crate.hulls)
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "crate/free") >= 0
    # no <option> or <compiler> of ours: the host's settings stand
    text = (out / "objects" / "crate.xml").read_text()
    assert "<option" not in text and "<compiler" not in text and "sleep" not in text


def test_an_object_file_attaches_with_a_prefix(out, tmp_path):
    world = tmp_path / "world.xml"
    world.write_text(f'<mujoco><asset><model name="c" file="{out / "objects" / "can.xml"}"/></asset>'
                     f'<worldbody><attach model="c" body="can" prefix="left-"/>'
                     f'<attach model="c" body="can" prefix="right-"/></worldbody></mujoco>')
    model = mujoco.MjModel.from_xml_path(str(world))
    left, right = model.body("left-can").mass[0], model.body("right-can").mass[0]
    assert left == right > 0


def test_source_to_body_maps_a_rotated_mesh_onto_the_body(tmp_path):
    # A box turned 90 deg about z: its own (unrotated) vertices, mapped by source_to_body, are the body's mesh.
    scene = parse_scene({"name": "r", "objects": [{"id": "b", "primitive": {"type": "box", "size": [0.2, 0.1, 0.05]},
                                                   "rotation_deg": [90, 0, 0], "density": 500}]})
    spec = scene.objects[0]
    mesh = source_mesh(spec)
    est = from_mesh(mesh.vertices, mesh.faces, 500.0)
    visual = (body_vertices(est), est.faces)
    obj = TwinObject(id="b", estimate=est, friction=0.5, visual=visual, hulls=(visual,),
                     position=np.array([0, 0, 0.03]), quat=np.array([1.0, 0, 0, 0]))
    record = estimates_record(BuiltScene(scene, None, None, (obj,), 0.0))["objects"][0]
    transform = record["source_to_body"]
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(transform["quat_wxyz"]))
    own = trimesh.creation.box(extents=[0.2, 0.1, 0.05]).vertices
    mapped = own @ rotation.reshape(3, 3).T + transform["translation_m"]
    assert np.allclose(sorted(map(tuple, np.round(mapped, 9))), sorted(map(tuple, np.round(visual[0], 9))))
    assert np.allclose(transform["quat_wxyz"], [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])


# -- command output: results on stdout, progress on stderr, --json exactly one object ------------------------

def test_build_progress_on_stderr_result_on_stdout(cache, tmp_path, capsys):
    assert main(["build", str(SMALL), "--out", str(tmp_path / "a"), "--cache-dir", str(cache)]) == 0
    captured = capsys.readouterr()
    assert "[1/2] crate: estimated in" in captured.err and "[2/2] can: estimated in" in captured.err
    assert "convex decomposition" in captured.err
    assert "estimated in" not in captured.out and "crate" in captured.out and "wrote" in captured.out
    assert main(["build", str(SMALL), "--out", str(tmp_path / "b"), "--cache-dir", str(cache), "--json"]) == 0
    captured = capsys.readouterr()
    record = json.loads(captured.out, parse_constant=_no_constants)  # the whole of stdout is one object
    assert [o["id"] for o in record["objects"]] == ["crate", "can"]
    assert Path(record["estimates_json"]).is_file() and all(Path(o["mjcf"]).is_file() for o in record["objects"])


def test_run_json_has_per_object_poses(out, capsys):
    assert main(["run", str(out), "--duration", "0.3", "--no-realtime", "--json"]) == 0
    record = json.loads(capsys.readouterr().out, parse_constant=_no_constants)
    assert record["objects"] == 2 and record["steps"] == 300  # the older fields stay
    per = {o["id"]: o for o in record["per_object"]}
    assert set(per) == {"crate", "can"}
    for o in per.values():
        assert len(o["position_m"]) == 3 and np.linalg.norm(o["quat_wxyz"]) == pytest.approx(1.0)
        assert o["displacement_m"] >= 0 and 0 <= o["rotation_deg"] <= 180
    assert per["can"]["displacement_m"] < 0.01  # the push goes along x at y = 0: the can, at y = 0.1, stays


def test_demo_records_compare_estimated_and_true_mass():
    report = LocalReport(touchable_after={"mug": (1.5, 1.2)}, divergence={"mug": [0.001, 0.004, 0.002]})
    pose = (np.array([0.1, 0.2, 0.8]), np.array([1.0, 0, 0, 0]))
    (record,) = object_records(report, {"mug": 0.33}, {"mug": pose}, {"mug": 0.002}, {"mug": 0.30})
    assert record["id"] == "mug" and record["add_latency_s"] == 1.2 and record["add_latency_from_publish_s"] == 1.5
    assert record["divergence_max_m"] == 0.004 and record["twin_minus_remote_m"] == 0.002
    assert record["mass_error_pct"] == pytest.approx(10.0) and record["true_mass_kg"] == 0.30
    (unknown,) = object_records(LocalReport(), {"mug": 0.33}, {"mug": pose}, {})
    assert "true_mass_kg" not in unknown and unknown["add_latency_s"] is None and unknown["divergence_max_m"] is None
    assert unknown["warnings"] is None and unknown["volume_bounds_m3"] is None  # no estimate given: not known
    # SI base units only, and each key says which (the estimate's warnings are text)
    assert all(k in ("id", "warnings") or k.endswith(("_m", "_kg", "_s", "_pct", "_wxyz", "_m3")) for k in record)


def test_demo_and_local_records_carry_each_estimates_warnings_and_volume_interval():
    from cli.main import to_json

    box = trimesh.creation.box((0.12, 0.08, 0.06))
    points, index = trimesh.sample.sample_surface(box, 20000, seed=1)
    one_side = estimate(make_cloud(points[box.face_normals[index] @ [1.0, 0.5, 0.8] > 0]), 500.0)  # one sheet
    whole = estimate(make_cloud(points), 500.0)
    pose = (np.array([0.1, 0.2, 0.8]), np.array([1.0, 0, 0, 0]))
    records = object_records(LocalReport(), {"box": 0.05, "whole": 0.29}, {"box": pose, "whole": pose}, {},
                             estimates={"box": one_side, "whole": whole})
    box_record, whole_record = json.loads(to_json(records), parse_constant=_no_constants)
    assert box_record["warnings"] == list(one_side.warnings) and any("one sheet" in w for w in box_record["warnings"])
    assert box_record["volume_bounds_m3"] == [0.0, None]  # unbounded above: null, as `twin estimate --json` says it
    assert box_record["estimated_volume_m3"] == one_side.volume
    assert whole_record["warnings"] == [] and whole_record["volume_bounds_m3"] == list(whole.volume_bounds_m3)


# -- materials -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "expected"), [
    ("PLA", "pla_plastic"), ("ABS", "abs_plastic"), ("aluminum", "aluminium"), ("Aluminium", "aluminium"),
    ("steel", "steel"), ("stainless", "stainless_steel"), ("AISI 316", "stainless_steel"), ("HDPE", "polyethylene_hd"),
    ("plexiglass", "acrylic"), ("Teflon", "ptfe"),
])
def test_material_aliases(name, expected):
    assert material(name).name == expected


def test_every_alias_names_a_material():
    table = materials()
    assert aliases() and all(target in table for target in aliases().values())
    assert not set(aliases()) & set(table)  # an alias never hides a table name


def test_did_you_mean_considers_aliases():
    with pytest.raises(MaterialError, match=r"unknown material 'alumnum'; did you mean aluminum \(= aluminium\)"):
        material("alumnum")
    with pytest.raises(MaterialError, match=r"did you mean stainless \(= stainless_steel\)"):
        material("stainles")


def test_cli_material_alias(tmp_path, capsys):
    points = trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(5000, return_index=False)
    np.save(tmp_path / "box.npy", points)
    assert main(["estimate", str(tmp_path / "box.npy"), "--material", "PLA", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["material"] == "pla_plastic" and record["density_kg_m3"] == materials()["pla_plastic"].density
    assert main(["estimate", str(tmp_path / "box.npy"), "--material", "alumnum"]) == 2
    assert "did you mean aluminum (= aluminium)" in capsys.readouterr().err
    assert main(["materials"]) == 0
    listing = capsys.readouterr().out
    assert "pla_plastic" in listing and "also: pla" in listing and "aluminum" in listing


def test_mesh_out_never_overwrites_an_input(tmp_path, capsys):
    import os

    cloud = tmp_path / "in.ply"
    cloud.write_bytes(b"")
    save_cloud(make_cloud(trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False)), cloud)
    before = cloud.read_bytes()
    (tmp_path / "link.ply").symlink_to(cloud)
    os.link(cloud, tmp_path / "hard.ply")
    for out in (cloud, tmp_path / "link.ply", tmp_path / "hard.ply", tmp_path / "sub" / ".." / "in.ply"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is the input" in err and "would destroy the input" in err, err
        assert cloud.read_bytes() == before


def test_a_mesh_write_that_fails_leaves_the_old_file_whole(tmp_path, capsys):
    cloud = tmp_path / "box.npy"
    np.save(cloud, trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False))
    old = tmp_path / "old.xyz"  # trimesh writes no mesh as .xyz: it used to truncate the file, then fail
    old.write_text("precious\n")
    assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(old)]) == 2
    assert "--mesh-out " + str(old) + ": unknown format '.xyz'; use one of .obj, .ply, .stl" in capsys.readouterr().err
    assert old.read_text() == "precious\n" and sorted(p.name for p in tmp_path.iterdir()) == ["box.npy", "old.xyz"]
    assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(tmp_path / "m.stl")]) == 0
    assert len(trimesh.load_mesh(tmp_path / "m.stl").faces) > 0


def test_mesh_out_is_checked_before_the_work(tmp_path, capsys):
    """A FIFO at --mesh-out was replaced by the mesh (deleting what the command did not write); a folder, a
    missing folder or a format trimesh cannot write failed only after the estimate, with trimesh's
    "('%s exporter not available!', '')"."""
    import os

    cloud = tmp_path / "box.npy"
    np.save(cloud, trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False))
    os.mkfifo(tmp_path / "pipe.stl")
    (tmp_path / "folder.stl").mkdir()
    for out, why in ((tmp_path / "pipe.stl", "exists and is not a regular file; refusing to replace it"),
                     (tmp_path / "folder.stl", "exists and is not a regular file"),
                     (tmp_path / "no" / "m.stl", f"the folder {tmp_path / 'no'} does not exist"),
                     (tmp_path / "m", "unknown format (no suffix); use one of .obj, .ply, .stl")):
        assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--mesh-out {out}: {why}" in err, err
    assert (tmp_path / "pipe.stl").is_fifo() and (tmp_path / "folder.stl").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.npy", "folder.stl", "pipe.stl"]


def test_scene_material_alias():
    scene = parse_scene({"name": "x", "objects": [{"id": "a", "paper": "box", "material": "PLA"}]})
    assert material(scene.objects[0].material).name == "pla_plastic"
    assert estimate(make_cloud(trimesh.creation.box(extents=[0.1] * 3).sample(2000, return_index=False)),
                    material("aluminum").density).mass.density == 2700


# -- public surface --------------------------------------------------------------------------------------------

def test_packages_re_export_lazily():
    code = ("import sys, twin, sync, scenes, cli\n"
            "heavy = ('mujoco', 'zenoh', 'open3d', 'rerun', 'trimesh')\n"
            "assert not [m for m in heavy if m in sys.modules], [m for m in heavy if m in sys.modules]\n"
            "for p in (twin, sync, scenes, cli):\n"
            "    assert p.__all__ == sorted(p.__all__)\n"
            "    for n in p.__all__: getattr(p, n)\n"
            "    assert set(p.__all__) <= set(dir(p))\n"
            "assert not [m for m in ('zenoh', 'open3d', 'rerun') if m in sys.modules]\n"
            "import cli.main as m\n"
            "assert callable(m.main) and m.__name__ == 'cli.main'\n"
            "from twin import Twin; from twin.sim import Twin as T; assert Twin is T\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_unknown_public_name():
    import twin

    with pytest.raises(AttributeError, match="module 'twin' has no attribute 'Twinn'"):
        twin.Twinn  # noqa: B018


def test_a_large_cloud_shows_its_stages_on_stderr_and_a_small_one_nothing(tmp_path, capsys):
    from estimation.tolerances import POINT_BUDGET

    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    rng = np.random.default_rng(2)
    for name, n in (("small", POINT_BUDGET // 3), ("large", 2 * POINT_BUDGET)):
        np.save(tmp_path / f"{name}.npy", trimesh.sample.sample_surface(box, n, seed=rng)[0])
    assert main(["estimate", str(tmp_path / "small.npy"), "--json"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["estimate", str(tmp_path / "large.npy"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["volume_m3"] > 0  # stdout stays one JSON object
    lines = err.splitlines()
    assert lines[0].endswith(f"measuring the noise of {2 * POINT_BUDGET:,} points"), lines
    assert any(f"reconstructing from up to {POINT_BUDGET:,} points" in line for line in lines), lines
    # The same lines from the API, for any caller that shows progress.
    seen: list[str] = []
    estimate(make_cloud(np.load(tmp_path / "large.npy")), 1000.0, progress=seen.append)
    assert [line.split(" ")[0] for line in seen[:2]] == ["measuring", "reconstructing"]


@pytest.mark.parametrize("command", [["build", str(SMALL)], ["experiment", str(SMALL), "--delays", "0"]])
def test_an_out_folder_that_cannot_be_made_is_one_line_before_the_work(tmp_path, capsys, command):
    blocker = tmp_path / "a_file"
    blocker.write_text("mine\n")
    assert main([*command, "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert f"{blocker} is not a folder" in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert blocker.read_text() == "mine\n"


def test_what_the_readers_only_logged_is_in_the_json_warnings(tmp_path, capsys):
    # Given normals with a NaN row are all ignored, and a PCD whose WIDTH x HEIGHT is not its POINTS is read by
    # POINTS: both were said on stderr only, so a script reading the JSON never knew.
    from cli.main import main

    rng = np.random.default_rng(0)
    ball = rng.normal(size=(3000, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True)
    normals = ball.copy()
    normals[5] = np.nan
    header = ["ply", "format ascii 1.0", "element vertex 3000", *(f"property float {c}" for c in
                                                                   ("x", "y", "z", "nx", "ny", "nz")), "end_header"]
    rows = [" ".join(f"{x:g}" for x in np.r_[p * 0.05, q]) for p, q in zip(ball, normals, strict=True)]
    (tmp_path / "ball.ply").write_text("\n".join(header + rows) + "\n")
    pcd = ["VERSION .7", "FIELDS x y z", "SIZE 4 4 4", "TYPE F F F", "COUNT 1 1 1", "WIDTH 10", "HEIGHT 1",
           "VIEWPOINT 0 0 0 1 0 0 0", "POINTS 3000", "DATA ascii", *(" ".join(f"{x:g}" for x in p * 0.05) for p in ball)]
    (tmp_path / "ball.pcd").write_text("\n".join(pcd) + "\n")
    for name, said in (("ball.ply", "ignoring all given normals"), ("ball.pcd", "WIDTH x HEIGHT is 10 x 1")):
        assert main(["estimate", str(tmp_path / name), "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert sum(said in w for w in out["warnings"]) == 1, out["warnings"]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
@pytest.mark.parametrize("command", [["materials"], ["schema", "scene"]])
def test_output_that_cannot_be_written_is_one_line_and_a_closed_pipe_is_quiet(command):
    """A full disk is said in one line, exit 2 (it was 1); a reader that stopped reading is not an error to print."""
    twin = [sys.executable, "-m", "cli.main", *command]
    with open("/dev/full", "w") as full:
        done = subprocess.run(twin, stdout=full, stderr=subprocess.PIPE, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 2
    assert done.stderr == f"twin {command[0]}: error: no space left writing the output\n"
    gone = subprocess.Popen(twin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT)
    gone.stdout.close()  # type: ignore[union-attr]  # the reader left before the first line (| head -0)
    assert gone.wait(timeout=60) == 1 and gone.stderr.read() == b""  # type: ignore[union-attr]
    gone.stderr.close()  # type: ignore[union-attr]


@pytest.mark.parametrize(("code", "said"), [(errno.ENOSPC, "no space left writing"),
                                            (errno.EDQUOT, "disk quota exceeded writing")])
def test_an_output_file_on_a_full_disk_is_named_in_one_line(tmp_path, capsys, monkeypatch, code, said):
    """A --mesh-out on a full disk exited 1 with "cannot write the output: No space left on device", naming no
    file; the file it would replace is left as it was, and no temporary file behind."""
    cloud = tmp_path / "box.npy"
    np.save(cloud, trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False))
    mesh = tmp_path / "m.stl"
    mesh.touch()

    def full(*_: object, **__: object) -> None:
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(trimesh.Trimesh, "export", full)
    assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(mesh)]) == 2
    assert capsys.readouterr().err == f"twin estimate: error: {said} {mesh}\n"
    assert mesh.read_bytes() == b"" and sorted(p.name for p in tmp_path.iterdir()) == ["box.npy", "m.stl"]


def test_mesh_out_replaces_only_a_mesh_it_wrote(tmp_path, capsys):
    """``--mesh-out thesis.stl`` replaced any existing file; ``--record`` and ``--rerun save`` refuse a file that
    is not of their own kind, and so does --mesh-out now: a mesh it wrote (or an empty file) is replaced."""
    cloud = tmp_path / "box.npy"
    np.save(cloud, trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False))
    thesis = tmp_path / "thesis.stl"
    thesis.write_text("chapter 1\n")
    cad = tmp_path / "part.stl"  # a real binary STL from another tool: its header names the tool
    cad.write_bytes(b"exported by a CAD tool".ljust(80, b" ") + (0).to_bytes(4, "little"))
    mine = tmp_path / "mine.ply"
    save_cloud(make_cloud(np.load(cloud)), mine)  # a PLY, but a cloud the user saved, not our mesh
    # A part the user saved with trimesh: it carries trimesh's marks, which were taken for ours (replaced, exit 0).
    parts = [tmp_path / f"part{suffix}" for suffix in (".stl", ".ply", ".obj")]
    for part in parts:
        trimesh.creation.annulus(r_min=0.02, r_max=0.04, height=0.01).export(part)
    for path in (thesis, cad, mine, *parts):
        before = path.read_bytes()
        assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"--mesh-out {path}: exists and is not a mesh this command wrote; refusing to replace it" in err
        assert err.count("\n") == 1 and path.read_bytes() == before, err
    for suffix in (".stl", ".ply", ".obj"):  # written, then replaced by the next run
        out = tmp_path / f"m{suffix}"
        for _ in range(2):
            assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(out)]) == 0, capsys.readouterr()
            assert len(trimesh.load_mesh(out).faces) > 0
    empty = tmp_path / "empty.obj"
    empty.touch()
    assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(empty)]) == 0
    assert len(trimesh.load_mesh(empty).faces) > 0
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_mesh_out_does_not_replace_a_file_without_faces(tmp_path, capsys, suffix):
    """A point cloud trimesh wrote carries the same comment line as --mesh-out's meshes: a user's scan.ply was
    replaced by the mesh. A mesh has faces: a PLY header's face count above 0, an OBJ ending in faces, an STL's
    triangle count above 0."""
    cloud = tmp_path / "box.npy"
    np.save(cloud, trimesh.creation.box(extents=[0.1, 0.06, 0.04]).sample(2000, return_index=False))
    scan = tmp_path / f"scan{suffix}"
    if suffix == ".stl":
        scan.write_bytes(bytes(84))  # a zeroed header, no triangles
    else:
        trimesh.PointCloud(np.random.default_rng(0).random((300, 3)) * 0.1).export(scan)
    before = scan.read_bytes()
    assert main(["estimate", str(cloud), "--method", "hull", "--mesh-out", str(scan)]) == 2
    assert capsys.readouterr().err == (f"twin estimate: error: --mesh-out {scan}: exists and is not a mesh this "
                                       "command wrote; refusing to replace it\n")
    assert scan.read_bytes() == before


def _own_file(path: Path) -> None:
    """A file of ``path``'s output kind, as its writer makes it: a recording, a rerun file, a mesh."""
    if path.suffix == ".mcap":
        from sync.clock import SimClock
        from sync.recording import Recorder

        with Recorder(path, clock=SimClock()) as r:
            r.target(0.0, np.zeros(3))
    elif path.suffix == ".rrd":
        import rerun as rr

        from twin.rerunlog import APP_ID

        stream = rr.RecordingStream(APP_ID)
        stream.save(str(path))
        stream.log("p", rr.Points3D([[0.0, 0.0, 0.0]]))
        stream.disconnect()
    else:
        from cli.outputs import mark_mesh

        path.write_bytes(mark_mesh(path.suffix, trimesh.creation.box().export(file_type="stl")))


@pytest.mark.parametrize("suffix", [".mcap", ".rrd", ".stl"])
def test_recordings_rerun_files_and_meshes_replace_only_their_own_by_one_rule(tmp_path, suffix):
    """Three copies of "may this output replace what stands there" had drifted: an empty .mcap was refused where an
    empty .rrd or mesh was replaced, and a path that could not be looked at was refused only for recordings (a
    mesh or rerun file went ahead, or was a traceback). One rule now (:func:`sync.replacing.found_at`)."""
    import os

    from cli.outputs import check_mesh_file
    from estimation.errors import TwinError
    from sync.recording import check_record_destination
    from twin.rerunlog import parse_target

    check = {".mcap": check_record_destination, ".rrd": lambda p: parse_target(["save", str(p)]),
             ".stl": lambda p: check_mesh_file(p, (), "--mesh-out", suffixes=(".stl",))}[suffix]
    missing, empty, own = (tmp_path / f"{name}{suffix}" for name in ("missing", "empty", "own"))
    empty.touch()
    _own_file(own)
    for path in (missing, empty, own):
        check(path)  # replaced: nothing of a user's is lost
    notes, folder, fifo, loop = (tmp_path / f"{name}{suffix}" for name in ("notes", "folder", "fifo", "loop"))
    notes.write_text("precious\n")
    folder.mkdir()
    os.mkfifo(fifo)  # not opened: reading it would block
    loop.symlink_to(loop.name)
    for path, words in ((notes, "exists and is not"), (folder, "folder|not a regular file|exists and is not"),
                        (fifo, "not a regular file|exists and is not"), (loop, "cannot check it")):
        with pytest.raises(TwinError, match=words):
            check(path)
    assert notes.read_text() == "precious\n" and folder.is_dir() and fifo.is_fifo()


def test_a_folder_where_an_output_file_goes_is_refused_before_the_work(tmp_path, capsys):
    """A folder at results.csv in an experiment's own output folder: every session ran, then a traceback."""
    from cli.outputs import replace_file
    from estimation.errors import TwinError

    out = tmp_path / "out"
    (out / "results.csv").mkdir(parents=True)
    (out / "results.csv" / "mine.txt").write_text("mine\n")
    (out / ".twin-experiment").write_text("written by twin experiment\n")
    assert main(["experiment", str(SMALL), "--delays", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "results.csv there is a folder or a device" in err and err.count("\n") == 1, err
    # And where one appears after the checks, the write is one line too.
    with pytest.raises(TwinError, match=r"cannot write .*results\.csv: Is a directory"):
        replace_file(out / "results.csv", lambda tmp: tmp.write_text("x"))
    assert (out / "results.csv" / "mine.txt").read_text() == "mine\n"
    assert sorted(p.name for p in out.iterdir()) == [".twin-experiment", "results.csv"]  # no temporary left
