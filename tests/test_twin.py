"""The twin: scene files, real CoACD, real MjSpec models, live edits, the CLI."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from cli.main import main
from estimation.errors import SettingsError
from scenes.build import build_scene, write_scene
from scenes.scenefile import SceneError, load_scene, parse_scene
from twin.decompose import CoacdSettings, decompose
from twin.model import COLLIDES, EE_BODY, add_object
from twin.sim import Twin, run_paced
from twin.trajectory import push_trajectory

SMALL = Path(__file__).parent / "data" / "small.toml"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "coacd"))


@pytest.fixture(scope="module")
def small_scene() -> Path:
    return SMALL


@pytest.fixture(scope="module")
def built(small_scene, tmp_path_factory):
    return build_scene(load_scene(small_scene), cache_dir=tmp_path_factory.getbasetemp() / "coacd", progress=False)


def test_model_has_explicit_estimated_inertia(built):
    import mujoco

    model = built.model
    for obj in built.objects:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, obj.id)
        assert model.body_mass[bid] == pytest.approx(obj.estimate.mass.mass, rel=1e-9)
        # MuJoCo stores the diagonalised inertia; its moments are the estimate's principal moments.
        np.testing.assert_allclose(np.sort(model.body_inertia[bid]), obj.estimate.mass.principal_moments, rtol=1e-6)
    crate = built.objects[0]
    assert crate.estimate.mass.mass == pytest.approx(0.12 * 0.08 * 0.06 * 510, rel=0.01)


def test_visual_geoms_do_not_collide(built):
    import mujoco

    model = built.spec.compile()  # as built: a Twin stepping built.model switches its contact bits (twin.tabletop)
    for g in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
        if name.endswith("/visual"):
            assert model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0
        if "/hull" in name:  # a hull collides unless a primitive collides for its object (twin.model)
            primitive = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name.split("/")[0] + "/primitive") >= 0
            assert model.geom_contype[g] == (0 if primitive else COLLIDES)
        if name.endswith("/primitive"):
            assert model.geom_contype[g] == COLLIDES


def test_objects_rest_on_the_table(built):
    with Twin(built.spec, built.model) as twin:
        start = {o.id: twin.pose(o.id)[0] for o in built.objects}
        twin.step(1000)
        for o in built.objects:
            moved = np.linalg.norm(twin.pose(o.id)[0] - start[o.id])
            # Placed 1 mm above the table: they settle, they do not fall through or wander.
            assert moved < 0.005, o.id


def test_end_effector_push_moves_object_and_reads_force(built):
    with Twin(built.spec, built.model) as twin:
        start = twin.data.mocap_pos[0].copy()
        twin.step(200)
        before = twin.pose("crate")[0]
        push = push_trajectory(start, start + np.array([0.45, 0, -0.03]), 1.0)  # at the crate's mid-height
        assert np.array_equal(twin.end_effector_force(), np.zeros(3))  # free space: nothing to render
        forces = []
        for _ in range(1000):
            twin.set_end_effector(push(twin.time - 0.2))
            twin.step()
            forces.append(twin.end_effector_force())
        assert twin.pose("crate")[0][0] - before[0] > 0.05
        # Pushing along +x, the crate pushes back along -x.
        strongest = max(forces, key=np.linalg.norm)
        assert np.linalg.norm(strongest) > 0.1 and strongest[0] < -0.9 * np.linalg.norm(strongest)


def test_live_add_and_remove_keep_state(built):
    from scenes.scenefile import ObjectSpec
    from scenes.sources import prepare_objects

    with Twin(built.spec.copy(), None) as twin:
        twin.step(300)
        crate_before = twin.pose("crate")
        extra = prepare_objects([ObjectSpec(id="ball", source="primitive", value={"type": "sphere", "size": (0.03,)},
                                            density=500, position=(-0.2, 0.15), points=5000)],
                                table_top=0.5, progress=False)[0]
        twin.add(extra)
        assert "ball" in twin.object_ids()
        # recompile carries qpos over; the crate moves by no more than solver noise (~1e-8 m).
        np.testing.assert_allclose(twin.pose("crate")[0], crate_before[0], atol=1e-6)
        twin.step(10)
        twin.remove("ball")
        assert "ball" not in twin.object_ids()
        with pytest.raises(KeyError, match="no object 'ball'"):
            twin.pose("ball")


def test_write_scene_round_trip(built, tmp_path):
    import mujoco

    path = write_scene(built.spec, tmp_path / "out")
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nbody == built.model.nbody and model.ngeom == built.model.ngeom
    # to_xml writes ~6 significant digits.
    np.testing.assert_allclose(model.body_mass, built.model.body_mass, rtol=1e-5)
    np.testing.assert_allclose(model.body_inertia, built.model.body_inertia, rtol=1e-4)
    assert any((tmp_path / "out" / "assets").glob("*.stl"))


def test_coacd_cache_and_determinism(tmp_path):
    mesh = trimesh.creation.annulus(r_min=0.03, r_max=0.05, height=0.04, sections=32)
    settings = CoacdSettings(max_convex_hull=6)
    first, cached = decompose(mesh.vertices, mesh.faces, settings, cache_dir=tmp_path)
    assert not cached and len(first) > 1  # a ring is not convex
    again, cached = decompose(mesh.vertices, mesh.faces, settings, cache_dir=tmp_path)
    assert cached and len(again) == len(first)
    other, _ = decompose(mesh.vertices, mesh.faces, settings, cache_dir=tmp_path / "fresh")
    for (a, _), (b, _) in zip(first, other, strict=True):  # seeded: same hulls without the cache
        np.testing.assert_allclose(a, b)


def test_degenerate_mesh_falls_back_to_hull(tmp_path, caplog):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.1
    no_faces = np.zeros((0, 3), np.int64)  # CoACD gives no parts for it
    with caplog.at_level("WARNING", logger="twin.decompose"):
        hulls, _ = decompose(v, no_faces, CoacdSettings(), cache_dir=tmp_path)
    assert "using the convex hull" in caplog.text
    # The fallback is exactly one hull: the convex hull of the input, here the tetrahedron itself.
    assert len(hulls) == 1
    hv, hf = hulls[0]
    assert sorted(map(tuple, hv)) == sorted(map(tuple, v))
    assert trimesh.Trimesh(hv, hf).volume == pytest.approx(0.1**3 / 6, rel=1e-9)


def test_open_mesh_gives_closed_hulls_inside_its_hull(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.1
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    hulls, _ = decompose(v, f[:2], CoacdSettings(), cache_dir=tmp_path)  # an open, two-face "mesh"
    # CoACD (with manifold preprocessing) thickens it; each part is a closed convex solid within ~1 mm of
    # the input's hull (the preprocessing's voxel size at resolution 50 on a 0.1 m mesh is ~2 mm).
    assert hulls
    for hv, hf in hulls:
        part = trimesh.Trimesh(hv, hf)
        assert part.is_watertight and part.volume > 0
        assert (hv.min(axis=0) > -0.002).all() and (hv.max(axis=0) < 0.1 + 0.002).all()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,1,1]}\ncolour="red"', "unknown key 'colour'"),
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,1,1]}\nmaterail="steel"', "did you mean 'material'"),
        ('name="x"\n[[objects]]\nid="a"\nmesh="missing.stl"', "does not exist"),
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,1,1]}\ndensity=-3', "must be positive"),
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,0,1]}', "must be 0.001 to 100 m, got 0.0"),
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,1,1]}\nmaterial="unobtainium"', "unknown material"),
        ('name="x"\n[[objects]]\nid="a"\nprimitive={type="box",size=[1,1,1]}\n[[objects]]\nid="a"\npaper="cone"', "duplicate"),
        ('name="x"\n[[objects]]\nid="a"', "exactly one source"),
        ('[[objects]]\nid="a"\npaper="cone"', "missing 'name'"),
        ('name="x"\n[[objects]]\nid="a"\npaper="sphere"', "unknown paper object"),
    ],
)
def test_scene_errors_name_the_problem(tmp_path, text, message):
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=message):
        load_scene(path)


def test_estimation_error_names_object(tmp_path):
    from scenes.sources import estimate_object

    np.save(tmp_path / "tiny.npy", np.random.default_rng(0).uniform(size=(40, 3)))
    scene = parse_scene({"name": "x", "objects": [{"id": "pebble", "cloud": "tiny.npy"}]}, base=tmp_path)
    with pytest.raises(SceneError, match=r"object 'pebble': too few points: 40"):
        estimate_object(scene.objects[0])


def test_scene_error_names_object():
    with pytest.raises(SceneError, match="object 'mug'"):
        parse_scene({"name": "x", "objects": [{"id": "mug", "paper": "mug", "density": 0}]})


def test_cli_build_and_run(small_scene, tmp_path, capsys):
    out = tmp_path / "built"
    assert main(["build", str(small_scene), "--out", str(out)]) == 0
    assert (out / "scene.xml").is_file()
    assert main(["build", str(small_scene), "--out", str(out)]) == 0  # its own earlier output is replaced
    capsys.readouterr()
    # ... but not a file put in it since: it went with the folder, silently.
    (out / "assets" / "mynotes.txt").write_text("mine")
    assert main(["build", str(small_scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds assets/mynotes.txt, which no build wrote" in err, err
    assert (out / "assets" / "mynotes.txt").read_text() == "mine" and (out / "scene.xml").is_file()
    (out / "assets" / "mynotes.txt").unlink()
    # Nor an edit to a file it wrote (`twin run DIR` runs the folder "edits included"), nor a folder made in it.
    with (out / "scene.xml").open("a") as f:
        f.write("<!-- mine -->\n")
    (out / "mine").mkdir()
    assert main(["build", str(small_scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds the folder mine, which no build made" in err, err
    (out / "mine").rmdir()
    assert main(["build", str(small_scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "scene.xml was edited since the build wrote it" in err, err
    assert (out / "scene.xml").read_text().endswith("<!-- mine -->\n")
    (out / "scene.xml").write_text((out / "scene.xml").read_text().removesuffix("<!-- mine -->\n"))
    assert main(["build", str(small_scene), "--out", str(out)]) == 0
    capsys.readouterr()
    # The folder as a plain mkdir makes it (mkdtemp's 0700 kept other users out).
    umask = os.umask(0)
    os.umask(umask)
    assert (out.stat().st_mode & 0o777) == 0o777 & ~umask
    assert main(["run", str(out), "--duration", "0.2", "--no-realtime", "--json"]) == 0
    record = json.loads(capsys.readouterr().out, parse_constant=_no_constants)  # strict JSON: no NaN
    assert record["steps"] == 200 and record["objects"] == 2 and record["step_p99_ms"] > 0


def _no_constants(name: str) -> None:
    raise AssertionError(f"{name} in JSON output")


def test_cli_build_bad_scene_leaves_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('name="x"\n[[objects]]\nid="a"\nmesh="nope.stl"\n')
    out = tmp_path / "out"
    assert main(["build", str(bad), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".twin-build-*"))


def test_cli_build_never_replaces_what_it_did_not_write(small_scene, tmp_path, monkeypatch, capsys):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "keep.txt").write_text("precious")
    assert main(["build", str(small_scene), "--out", str(mine)]) == 2
    assert "not written by 'twin build'" in capsys.readouterr().err
    assert (mine / "keep.txt").read_text() == "precious"
    home = tmp_path / "project"
    home.mkdir()
    scene = home / "scene.toml"
    scene.write_text(small_scene.read_text())
    monkeypatch.chdir(home)
    for out in (".", str(tmp_path)):  # the current folder, and a parent of it
        assert main(["build", "scene.toml", "--out", out]) == 2
        assert "current folder" in capsys.readouterr().err
    monkeypatch.chdir(mine)
    assert main(["build", str(scene), "--out", str(home)]) == 2  # the folder holding the scene
    assert "holds" in capsys.readouterr().err
    assert scene.read_text() == small_scene.read_text() and (mine / "keep.txt").is_file()


@pytest.mark.parametrize("marker", ["", "written by 'twin build'\n"])
def test_cli_build_does_not_replace_a_folder_whose_marker_lists_no_files(small_scene, tmp_path, capsys, marker):
    """An emptied marker, or one from before the lists: such a folder was taken to hold only what a build's layout
    holds, and a user's objects/my_extra.xml and assets/textures/wood.png went with the next build (exit 0)."""
    out = tmp_path / "built"
    assert main(["build", str(small_scene), "--out", str(out), "--cache-dir", str(tmp_path / "c")]) == 0
    (out / ".tactile-twin-build").write_text(marker)
    (out / "objects" / "my_extra.xml").write_text("mine")
    (out / "assets" / "textures").mkdir()
    (out / "assets" / "textures" / "wood.png").write_text("mine too")
    capsys.readouterr()
    assert main(["build", str(small_scene), "--out", str(out), "--cache-dir", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "its .tactile-twin-build lists no files" in err, err
    assert (out / "objects" / "my_extra.xml").read_text() == "mine"
    assert (out / "assets" / "textures" / "wood.png").read_text() == "mine too"


def test_cli_build_refuses_a_symlinked_out(small_scene, tmp_path, capsys):
    # Replacing a link to an earlier build would fail half way (rmtree refuses links) or follow it.
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / ".tactile-twin-build").write_text("written by 'twin build'\n")
    (tmp_path / "link").symlink_to(earlier)
    assert main(["build", str(small_scene), "--out", str(tmp_path / "link"), "--cache-dir", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "link: is a symbolic link" in err, err
    assert (tmp_path / "link").is_symlink() and (earlier / ".tactile-twin-build").is_file()


def test_cli_file_names_too_long_are_one_line_errors(small_scene, tmp_path, capsys):
    long = tmp_path / ("a" * 300)
    for argv in (["estimate", f"{long}.xyz"], ["estimate", f"{long}.png", "--intrinsics", "50", "50", "10", "10"],
                 ["build", f"{long}.toml", "--out", str(tmp_path / "o")],
                 ["build", str(small_scene), "--out", str(long)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{long}" in err and "File name too long" in err, (argv, err)


def test_cli_viewer_without_display(small_scene, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["run", str(small_scene), "--viewer", "--duration", "0.1"]) == 2
    assert "needs a display" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["run", str(SMALL), "--rate", "1e9"], r"--rate must be > 0 and <= 100000, got 1e\+09"),
        (["run", str(SMALL), "--rate", "nan"], r"--rate must be a finite number, got nan"),
        (["run", str(SMALL), "--rate", "0"], r"--rate must be > 0 and <= 100000, got 0"),
        (["run", str(SMALL), "--rate=-inf"], r"--rate must be a finite number, got -inf"),
        (["run", str(SMALL), "--duration", "nan"], r"--duration must be a finite number, got nan"),
        (["run", str(SMALL), "--duration", "inf"], r"--duration must be a finite number, got inf"),
        (["run", str(SMALL), "--duration", "-0.5"], r"--duration must be > 0, got -0.5"),
        (["run", str(SMALL), "--threshold", "nan"], r"--threshold must be a finite number"),
        (["demo", "--duration", "nan"], r"--duration must be a finite number, got nan"),
        (["remote", str(SMALL), "--duration", "-1"], r"--duration must be > 0, got -1"),
        (["remote", str(SMALL), "--deadband-mm", "nan"], r"--deadband-mm must be a finite number"),
        (["remote", str(SMALL), "--points", "0"], r"--points must be from 100 to 10000000, got 0"),
        (["remote", str(SMALL), "--points", "2000000000"], r"--points must be from 100 to 10000000, got 2000000000"),
        (["run", str(SMALL), "--threshold", "2"], r"--threshold must be > 0 and <= 1, got 2"),
        (["build", str(SMALL), "--out", "o", "--threshold", "1.5"], r"--threshold must be > 0 and <= 1, got 1.5"),
        (["run", str(SMALL), "--max-hulls", "-5"], r"--max-hulls must be -1 \(no cap\) or >= 1, got -5"),
        (["local", "--duration", "0"], r"--duration must be > 0, got 0"),
        (["local", "--stale-after", "inf"], r"--stale-after must be a finite number, got inf"),
        (["estimate", str(SMALL), "--density", "nan"], r"--density must be a finite number, got nan"),
        (["estimate", str(SMALL), "--density", "1e-300"], r"--density must be >= 0.1 and <= 100000, got 1e-300"),
        (["estimate", str(SMALL), "--density", "1e300"], r"--density must be >= 0.1 and <= 100000, got 1e\+300"),
        (["estimate", str(SMALL), "--viewpoint", "0", "nan", "0"], r"--viewpoint must be three finite numbers"),
        (["run", str(SMALL), "--rerun-rate", "0"], r"--rerun-rate must be > 0, got 0"),
        (["run", str(SMALL), "--rerun", "save", "/proc/twin.rrd"], r"--rerun save: cannot write in /proc"),
        (["run", str(SMALL), "--rerun", "save", "/no/such/dir/twin.rrd"],
         r"--rerun save: folder /no/such/dir does not exist"),
    ],
)
def test_cli_refuses_bad_numbers_and_paths_with_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"twin {argv[0]}: error: ")
    assert re.search(message, err), err


def test_running_out_of_memory_is_one_line_and_exit_2(capsys, monkeypatch):
    # numpy raises MemoryError as it allocates (an 84 kB PNG once asked for 3.4 GB): a line, not a trace.
    import estimation

    def too_big(*_args, **_kwargs):  # type: ignore[no-untyped-def]
        raise MemoryError("Unable to allocate 894. GiB for an array with shape (40000000000, 3)")

    monkeypatch.setattr(estimation, "load_cloud", too_big)
    assert main(["estimate", str(SMALL)]) == 2
    err = capsys.readouterr().err
    assert err == "twin estimate: error: out of memory: the input is too large for this machine's memory\n"


def test_cli_errors_and_warnings_of_a_failed_command_are_one_line(tmp_path, capsys):
    import cli.main as cli_main

    built = tmp_path / "built"
    built.mkdir()
    (built / "scene.xml").write_text('<mujoco><include file="missing.xml"/></mujoco>')  # MuJoCo: several lines
    assert main(["run", str(built), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "MuJoCo cannot load it" in err, err

    assert cli_main.one_line("a bad input\n  Element name 'x'\n\n") == "a bad input; Element name 'x'"


def test_a_built_folder_whose_scene_xml_is_no_file_is_named_so(tmp_path, capsys):
    """A scene.xml linked to /dev/zero (or a folder) was "no scene.xml (build it with 'twin build')"."""
    for name, make in (("device", lambda p: p.symlink_to("/dev/zero")), ("folder", lambda p: p.mkdir())):
        built = tmp_path / name
        built.mkdir()
        make(built / "scene.xml")
        assert main(["run", str(built), "--duration", "0.1"]) == 2
        assert capsys.readouterr().err == (f"twin run: error: {built / 'scene.xml'}: not a regular file (a folder, "
                                           "device or pipe); 'twin build' writes a file there\n")
    (tmp_path / "empty").mkdir()
    assert main(["run", str(tmp_path / "empty")]) == 2
    assert "empty: no scene.xml (build it with 'twin build')" in capsys.readouterr().err


def test_cli_rerun_save_to_an_unwritable_place_fails_before_any_work(small_scene, tmp_path, capsys):
    out = tmp_path / "built"
    folder = tmp_path / "a-folder.rrd"
    folder.mkdir()
    for target in ("/proc/twin.rrd", str(folder)):
        assert main(["build", str(small_scene), "--out", str(out), "--cache-dir", str(tmp_path / "coacd"),
                     "--rerun", "save", target]) == 2
        assert "--rerun save" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "coacd").exists()  # nothing built, nothing cached
    assert list(folder.iterdir()) == []  # the write probe cleans up after itself


def test_cli_json_is_strict():
    from cli.main import to_json

    text = to_json({"a": float("nan"), "b": [float("inf"), 1.5, -float("inf")], "c": np.float64("nan"),
                    "d": np.int64(3), "e": (np.float32(0.5),)})
    assert json.loads(text) == {"a": None, "b": [None, 1.5, None], "c": None, "d": 3, "e": [0.5]}
    assert "NaN" not in text and "Infinity" not in text


def test_paced_loop_statistics(built):
    with Twin(built.spec, built.model) as twin:
        stats = run_paced(twin, 0.05, 1000.0, realtime=True)
        simulated = twin.time
    # Counts and orderings only: how long the wall clock took depends on the machine's load, not the loop.
    assert stats.steps == 50 and 0 < stats.p50 <= stats.p99 <= stats.max
    assert simulated == pytest.approx(0.05) and 0 <= stats.missed <= stats.steps


def test_cli_estimate_subprocess(tmp_path):
    from estimation import save_cloud
    from scenes.sampling import sample_surface

    cloud = sample_surface(trimesh.creation.box(extents=(0.1, 0.06, 0.04)), 20_000, seed=1)
    save_cloud(cloud, tmp_path / "box.ply")
    twin = Path(sys.executable).with_name("twin")
    res = subprocess.run([str(twin), "estimate", str(tmp_path / "box.ply"), "--material", "steel", "--json"],
                         capture_output=True, text=True, check=False)
    assert res.returncode == 0, res.stderr
    record = json.loads(res.stdout)
    assert record["mass_kg"] == pytest.approx(0.1 * 0.06 * 0.04 * 7850, rel=0.01)
    for key in ("volume_m3", "density_kg_m3", "center_of_mass_m", "inertia_kg_m2", "obb", "method",
                "points_in", "points_used", "watertight", "seconds"):
        assert key in record
    low, high = record["volume_bounds_m3"]
    assert low <= record["volume_m3"] <= high
    res = subprocess.run([str(twin), "estimate", str(tmp_path / "missing.ply")], capture_output=True, text=True,
                         check=False)
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0 and "no such file" in res.stderr


def test_build_says_each_objects_estimation_warnings(tmp_path, capsys):
    # A 1 mm disc from 2,000 points: the estimate's volume is several times the disc's, and it says so.
    scene = tmp_path / "thin.toml"
    scene.write_text('name = "thin"\n[table]\nsize = [1.0, 0.6, 0.04]\nheight = 0.5\n[[objects]]\nid = "disc"\n'
                     'primitive = { type = "cylinder", size = [0.05, 0.001] }\ndensity = 700\n'
                     'position = [0.0, 0.0]\npoints = 2000\n')
    assert main(["build", str(scene), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().err  # warnings go to stderr, the table to stdout
    saved = json.loads((tmp_path / "out" / "estimates.json").read_text())["objects"][0]["warnings"]
    assert saved  # the case this is about
    shown = [line.removeprefix("warning: disc: ") for line in out.splitlines() if line.startswith("warning: ")]
    assert shown == saved  # each warning whole, one line each, with its object
    assert main(["build", str(scene), "--out", str(tmp_path / "out"), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)  # the JSON carries them, and nothing else is on stdout
    assert record["objects"][0]["warnings"] == saved


def test_build_warns_up_front_of_a_slow_coacd_threshold_and_reports_each_object(tmp_path, capsys):
    from twin.decompose import FAST_THRESHOLD

    # The small scene's box and can are near-convex: no CoACD runs, so a low threshold costs this test nothing.
    slow = FAST_THRESHOLD / 2
    assert main(["build", str(SMALL), "--out", str(tmp_path / "slow"), "--threshold", f"{slow:g}"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (f"twin build: warning: --threshold {slow:g} is below {FAST_THRESHOLD:g}, where CoACD slows sharply "
                      f"(a 2,300-face torus: 2 s at 0.02, 40 s at 0.01); each concave object may take minutes")
    assert err[1] == "building 'small': 2 objects"
    # A line per object as it is built, whole (not wrapped at 80 columns, as a pipe had it).
    assert sorted(line.split(":")[0] for line in err[2:4]) == ["[1/2] crate", "[2/2] can"]
    assert all(re.search(r"hull\(s\) in [\d.]+ s \((collides as a \w+, no CoACD|near-convex, no CoACD|cached|CoACD)\)$", line) for line in err[2:4])
    assert main(["build", str(SMALL), "--out", str(tmp_path / "fast"), "--threshold", f"{FAST_THRESHOLD:g}"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_live_edit_that_does_not_compile_is_rolled_back_and_the_twin_runs_on(built):
    from dataclasses import replace

    crate = built.objects[0]
    flat = np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.01, 0.01, 0]])  # a hull with no volume
    bad = replace(crate, id="bad", hulls=((flat, np.array([[0, 1, 2], [1, 3, 2]])),),
                  position=crate.position + np.array([0.0, 0.0, 0.3]))
    good = replace(crate, id="good", position=crate.position + np.array([0.0, 0.0, 0.3]))
    failures: list[Exception] = []
    with Twin(built.spec.copy(), background=False) as twin:
        model_before = twin.model
        twin.step(10)
        twin.edit_async(lambda spec: add_object(spec, bad), failed=failures.append)
        assert twin.poll() == 0 and twin.failed_edits == 1 and len(failures) == 1
        assert twin.model is model_before and sorted(twin.object_ids()) == ["can", "crate"]
        twin.step(10)  # still steps
        twin.edit_async(lambda spec: add_object(spec, good))
        assert twin.poll() == 1
        assert sorted(twin.object_ids()) == ["can", "crate", "good"]  # the failed edit left no trace
        with pytest.raises(ValueError):
            twin.add(bad)  # synchronous edits raise, and also leave the twin as it was
        assert sorted(twin.object_ids()) == ["can", "crate", "good"]
        twin.step(10)


def test_cli_run_script_takes_the_csv_its_help_describes(built, small_scene, tmp_path, capsys):
    script = tmp_path / "push.csv"
    script.write_text("t,x,y,z\n0.0,-0.3,0.0,0.53\n0.2,-0.1,0.0,0.53\n")
    out = tmp_path / "built"
    assert main(["build", str(small_scene), "--out", str(out)]) == 0
    assert main(["run", str(out), "--duration", "0.3", "--no-realtime", "--json", "--script", str(script)]) == 0
    capsys.readouterr()
    script.write_text("t,x,y,z\n0.0,-0.3,0.0,0.53\n0.0,-0.1,0.0,0.53\n")
    assert main(["run", str(out), "--duration", "0.3", "--no-realtime", "--script", str(script)]) == 2
    assert "increas" in capsys.readouterr().err


def test_a_non_finite_object_is_put_back_and_the_rest_of_the_twin_runs_on(built, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the current folder
    with Twin(built.spec.copy(), background=False) as twin:
        twin.set_velocity("can", np.array([0.0, 0.3, 0.0]), np.zeros(3))
        twin.step(50)
        crate_before, can_before = twin.pose("crate"), twin.pose("can")
        adr, _ = twin._dof("crate")
        twin.data.qvel[adr] = np.nan  # what a corrupt write or a solver blow-up leaves behind
        twin.step()
        assert twin.recovered == 1
        assert np.allclose(twin.pose("crate")[0], crate_before[0], atol=1e-4)  # back where it was good, one step on
        assert np.isfinite(twin.data.qpos).all() and twin.time > 0.05  # no whole-model reset to t = 0
        assert twin.pose("can")[0][1] > can_before[0][1]  # the other object kept moving
        twin.step(10)
        assert np.isfinite(twin.data.qpos).all()
        with pytest.raises(ValueError, match="finite"):
            twin.set_pose("crate", np.array([np.nan, 0, 0]), np.array([1.0, 0, 0, 0]))
        with pytest.raises(ValueError, match="non-zero quaternion"):
            twin.set_pose("crate", np.zeros(3), np.zeros(4))
        with pytest.raises(ValueError, match="finite"):
            twin.set_end_effector(np.array([0.0, np.inf, 0.0]))


def test_a_huge_state_is_put_back_and_a_strict_twin_says_it_diverged(built, tmp_path, monkeypatch):
    from twin.sim import DivergedError

    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the current folder
    for strict in (False, True):
        with Twin(built.spec.copy(), background=False, strict=strict) as twin:
            twin.step()
            start = twin.pose("crate")[0]
            adr, _ = twin._dof("crate")
            twin.data.qvel[adr + 2] = -1e27  # what gravity of -1e30 m/s^2 left after one step: finite, not a state
            if strict:
                with pytest.raises(DivergedError, match=r"^the simulation diverged at t=0\.001 s \(a NaN, infinite "
                                                        r"or huge state in crate\)"):
                    twin.step()
            else:
                twin.step()
                assert twin.recovered == 1
            assert np.allclose(twin.pose("crate")[0], start, atol=1e-4)  # put back either way


def test_the_state_check_bounds_every_entry_exactly():
    """The 1 kHz check's sum of squares is a shortcut only: many entries each within MAX_STATE are a good state,
    one past it, a NaN or an infinity a bad one."""
    from twin.sim import MAX_STATE, _good

    many = np.full(150, MAX_STATE)  # a sum of squares 150 times the bound's square, every entry within it
    assert _good(many, np.zeros(3)) and _good(np.zeros(0))
    for bad in (np.nextafter(MAX_STATE, np.inf), -2 * MAX_STATE, np.nan, np.inf, -np.inf):
        v = np.zeros(126)
        v[77] = bad
        assert not _good(np.zeros(7), v)
        assert not _good(v)


def test_every_accessor_names_an_unknown_object_and_refuses_an_id_that_is_no_string(built):
    from estimation.errors import TwinError, UnknownObjectError

    with Twin(built.spec.copy(), background=False) as twin:
        accessors = (twin.pose, twin.velocity, twin.joint, lambda i: twin.set_pose(i, np.zeros(3), np.ones(4)),
                     lambda i: twin.set_velocity(i, np.zeros(3), np.zeros(3)))
        for call in accessors:
            # A bare KeyError (printed in quotes by the CLI), and None was "no object None", not a TypeError.
            with pytest.raises(UnknownObjectError, match=r"^no object 'cann' in the model; did you mean 'can'\?$"):
                call("cann")
            with pytest.raises(TypeError, match=r"^an object id is a string, got NoneType$"):
                call(None)
        with pytest.raises(UnknownObjectError) as caught:
            twin.pose("nope")
        assert str(caught.value) == "no object 'nope' in the model; its objects: crate, can"
        assert isinstance(caught.value, KeyError) and isinstance(caught.value, TwinError)
        with pytest.raises(UnknownObjectError, match=r"^no object 'nope' in the model; its objects: crate, can$"):
            twin.remove("nope")
        assert not twin.has("nope") and twin.has("can")
        for body in (EE_BODY, "world"):  # bodies of the scene, not objects: removing the end effector was allowed
            with pytest.raises(UnknownObjectError, match=rf"^no object '{body}' in the model"):
                twin.remove(body)
        assert twin.model.body(EE_BODY).id > 0
        with pytest.raises(TypeError, match="an object id is a string, got list"):
            twin.has(["can"])


def test_a_jump_of_the_target_is_followed_at_the_speed_limit(built):
    """A script jumping the target 0.6 m in a microsecond pulled the sphere through the scene at ~30 m/s (its soft
    weld closes a gap in ~20 ms) and flung the crate 0.29 m. The target now moves at EE_MAX_SPEED at most."""
    from twin.sim import EE_MAX_SPEED

    with Twin(built.spec.copy(), background=False) as twin:
        ee = twin.model.body(EE_BODY).id
        start = twin.data.mocap_pos[0].copy()
        goal = start + np.array([0.0, 0.0, 0.3])  # straight up: free space
        twin.set_end_effector(goal)
        assert np.allclose(twin.end_effector_goal, goal) and not np.allclose(twin.data.mocap_pos[0], goal)
        speeds, dt = [], twin.model.opt.timestep
        for _ in range(400):
            before = twin.data.mocap_pos[0].copy()
            twin.step()
            speeds.append(np.linalg.norm(twin.data.mocap_pos[0] - before) / dt)
            speeds.append(float(np.linalg.norm(twin.data.cvel[ee][3:])))
        assert max(speeds) <= EE_MAX_SPEED * 1.3  # the sphere lags the target a little and catches up
        assert np.allclose(twin.data.mocap_pos[0], goal) and np.array_equal(twin.end_effector_goal, twin.data.mocap_pos[0])
        # steps of several at once move it as far as one at a time would
        twin.set_end_effector(start)
        twin.step(10)
        assert np.linalg.norm(twin.data.mocap_pos[0] - goal) == pytest.approx(10 * EE_MAX_SPEED * dt)
        # a target within a step's reach is taken at once, as before
        here = twin.data.mocap_pos[0].copy()
        twin.set_end_effector(here + 0.001)
        assert np.allclose(twin.data.mocap_pos[0], here + 0.001) and np.allclose(twin.end_effector_goal, here + 0.001)
        # A speed that would freeze the target, drive it away or leave it NaN for good is refused when set.
        for bad in (float("nan"), 0.0, -2.0, "2", True):
            with pytest.raises(SettingsError, match="ee_max_speed must be a number of m/s above 0"):
                twin.ee_max_speed = bad
        assert twin.ee_max_speed == EE_MAX_SPEED
        # A target written non-finite (a direct write) is put right by the next set_end_effector, not kept NaN.
        twin.set_end_effector(here + 0.2)
        twin.data.mocap_pos[0] = np.nan
        twin.set_end_effector(here)
        assert np.array_equal(twin.data.mocap_pos[0], here)
        twin.set_end_effector(here + 0.2)
        twin.data.mocap_pos[0] = np.nan
        twin.step()  # or by the next step: towards its goal
        assert np.allclose(twin.data.mocap_pos[0], here + 0.2) and np.isfinite(twin.data.qpos).all()
        twin.ee_max_speed = 10**400  # past the float range: no limit
        assert twin.ee_max_speed == float("inf")


def test_setters_and_step_refuse_absurd_values_and_leave_the_state_alone(built):
    from sync.messages import MAX_ANGULAR_SPEED, MAX_COORDINATE, MAX_SPEED

    with Twin(built.spec.copy(), background=False) as twin:
        twin.step(10)
        qpos, qvel, mocap, t = twin.data.qpos.copy(), twin.data.qvel.copy(), twin.data.mocap_pos.copy(), twin.time
        refused = [
            (lambda: twin.set_velocity("can", np.array([1e300, 0, 0]), np.zeros(3)),
             rf"'can': linear velocity must be at most {MAX_SPEED:g} m/s in magnitude"),
            (lambda: twin.set_velocity("can", np.zeros(3), np.array([0, 0, 2 * MAX_ANGULAR_SPEED])),
             rf"'can': angular velocity must be at most {MAX_ANGULAR_SPEED:g} rad/s"),
            (lambda: twin.set_velocity("can", np.array([0, np.nan, 0]), np.zeros(3)), "3 finite numbers"),
            (lambda: twin.set_velocity("can", np.zeros(2), np.zeros(3)), "linear velocity must be 3 finite numbers"),
            (lambda: twin.set_pose("can", np.array([2 * MAX_COORDINATE, 0, 0]), np.array([1.0, 0, 0, 0])),
             rf"'can': position must be at most {MAX_COORDINATE:g} m in each axis"),
            (lambda: twin.set_pose("can", np.zeros(3), np.array([np.inf, 0, 0, 0])), "non-zero quaternion"),
            (lambda: twin.set_pose("can", np.zeros(3), np.array([1.0, 0, 0])), "non-zero quaternion"),
            (lambda: twin.set_end_effector(np.array([0.0, 0.0, 1e300])), "end-effector target must be at most"),
            (lambda: twin.step(-1), r"n must be a whole number from 0 to 2147483647, got -1"),
            (lambda: twin.step(2.5), r"n must be a whole number from 0 to 2147483647, got 2\.5"),
            (lambda: twin.step(True), r"n must be a whole number from 0 to 2147483647, got True"),
            # MuJoCo's C int: a multi-line pybind error.
            (lambda: twin.step(2**31), r"n must be a whole number from 0 to 2147483647, got 2147483648"),
        ]
        for call, message in refused:  # each a TwinError too (docs/api.md), and a ValueError
            with pytest.raises(SettingsError, match=message):
                call()
        with pytest.raises(TypeError, match=r"Twin\.add takes a TwinObject"):
            twin.add(None)  # type: ignore[arg-type]  # an AttributeError
        with pytest.raises(TypeError, match=r"Twin\.remove takes an object id \(str\)"):
            twin.remove(None)  # type: ignore[arg-type]  # a multi-line pybind error
        for setter, args in ((twin.set_velocity, (np.zeros(3), np.zeros(3))), (twin.set_pose, (np.zeros(3), np.ones(4)))):
            with pytest.raises(KeyError, match="no object 'mug'"):
                setter("mug", *args)
        assert twin.time == t and twin.recovered == 0  # nothing was written, nothing stepped
        assert np.array_equal(twin.data.qpos, qpos) and np.array_equal(twin.data.qvel, qvel)
        assert np.array_equal(twin.data.mocap_pos, mocap)
        # What stays allowed: up to the limits, a quaternion of any finite scale (normalised), no steps at all.
        twin.set_velocity("can", np.array([0.0, MAX_SPEED, 0.0]), np.array([MAX_ANGULAR_SPEED, 0.0, 0.0]))
        twin.set_velocity("can", np.zeros(3), np.zeros(3))
        position = twin.pose("can")[0]
        for scale in (1e-200, 2.0, 1e300):  # their norms underflow and overflow unless scaled first
            twin.set_pose("can", position, scale * np.array([1.0, 0, 0, 1.0]))
            assert np.allclose(twin.pose("can")[1], [0.5**0.5, 0, 0, 0.5**0.5])
        twin.set_pose("can", position, np.array([1.0, 0, 0, 0]))
        assert np.allclose(twin.pose("can")[0], position)
        twin.step(0)
        twin.step(np.int64(2))
        assert twin.time == pytest.approx(t + 2 * twin.model.opt.timestep)


def test_the_twin_estimates_a_cloud_with_the_normals_that_came_with_it(tmp_path):
    # A noisy ball: its normals as sent (one byte per axis) give the estimate a side the points alone do not.
    from estimation import estimate, make_cloud
    from sync.messages import cloud_message, decode, encode, unpack_normals, unpack_points
    from twin.runtime import build_from_cloud

    rng = np.random.default_rng(4)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = 0.04 * directions + rng.normal(0.0, 0.001, directions.shape) + [0.0, 0.0, 0.6]
    data = encode(cloud_message("ball", points, stamp_ns=0, epoch=0, seq=1, material=None, density=1000.0,
                                frame_position=np.array([0.0, 0.0, 0.6]), frame_quat=np.array([1.0, 0, 0, 0]),
                                normals=directions))
    obj, _ = build_from_cloud(data, CoacdSettings(max_convex_hull=4), tmp_path)
    msg = decode(data)
    sent = unpack_points(msg)
    with_normals = estimate(make_cloud(sent, unpack_normals(msg)), 1000.0).volume
    points_only = estimate(make_cloud(sent), 1000.0).volume
    assert with_normals != points_only
    assert obj.estimate.volume == with_normals


def test_warnings_wait_for_success_and_only_the_first_few_are_kept(monkeypatch, capsys, caplog):
    """A failed command's stderr is its one error line; one that succeeds shows the warnings it raised
    afterwards, at most MAX_HELD_WARNINGS of them and a count of the rest."""
    import warnings

    import cli.main as cli
    from estimation.errors import TwinError

    def noisy(fail: bool):  # type: ignore[no-untyped-def]
        def handler(args) -> int:  # type: ignore[no-untyped-def]
            for k in range(cli.MAX_HELD_WARNINGS + 5):
                warnings.warn(f"overflow {k}", RuntimeWarning, stacklevel=1)
            if fail:
                raise TwinError("bad input\nsecond line")
            return 0
        return handler

    monkeypatch.setattr(cli, "_cmd_materials", noisy(True))
    assert main(["materials"]) == 2
    err = capsys.readouterr().err
    assert err == "twin materials: error: bad input; second line\n", err
    monkeypatch.setattr(cli, "_cmd_materials", noisy(False))
    caplog.clear()
    assert main(["materials"]) == 0
    shown = [r.getMessage() for r in caplog.records]  # the log's records (pytest holds the handlers)
    assert sum(m.startswith("RuntimeWarning: overflow") for m in shown) == cli.MAX_HELD_WARNINGS, shown
    assert "5 more warnings" in shown, shown


def test_a_closed_twin_refuses_to_step_or_change_and_closing_again_does_nothing(built):
    """After close, step() stepped on and edit_async() started a compile thread nothing shut down."""
    import threading

    from twin.sim import TwinClosedError

    def compile_threads() -> list[str]:
        return [t.name for t in threading.enumerate() if t.name.startswith("twin-compile")]

    twin = Twin(built.spec.copy())  # background: edits compile in a thread
    twin.edit_async(lambda spec: None).result()
    assert compile_threads()
    twin.step(5)
    twin.close()
    assert not compile_threads() and twin.closed
    t, qpos = twin.time, twin.data.qpos.copy()
    refused = [twin.step, lambda: twin.step(10), lambda: twin.edit(lambda spec: None),
               lambda: twin.edit_async(lambda spec: None), lambda: twin.remove("crate"),
               lambda: twin.set_end_effector(np.zeros(3)), lambda: twin.set_pose("crate", np.zeros(3), np.ones(4)),
               lambda: twin.set_velocity("crate", np.zeros(3), np.zeros(3)), twin.__enter__]
    for call in refused:
        with pytest.raises(TwinClosedError, match=r"^twin is closed$"):
            call()
    assert not compile_threads() and twin.edits_pending == 0
    assert twin.time == t and np.array_equal(twin.data.qpos, qpos)
    twin.close()  # idempotent
    assert np.isfinite(twin.pose("crate")[0]).all()  # reading still works


def test_the_twin_names_a_wrong_constructor_argument_in_one_line(built):
    """Twin(None) was an AttributeError ('compile'), Twin(spec, "model") a multi-line pybind TypeError."""
    for args, message in (((None,), r"^Twin: spec must be a mujoco\.MjSpec, got NoneType$"),
                          (("scene.xml",), r"^Twin: spec must be a mujoco\.MjSpec, got str$"),
                          ((built.spec, "model"), r"^Twin: model must be a mujoco\.MjModel or None, got str$")):
        with pytest.raises(TypeError, match=message):
            Twin(*args)


@pytest.mark.parametrize("rate", [1000.0, 500.0, 1000 / 3, 333.333, 0.5])
def test_a_paced_run_simulates_its_duration_and_keeps_to_its_clock(built, rate):
    from sync.clock import SimClock

    # Paced against a simulated clock, so the pacing is checked without timing anything: each iteration's
    # deadline is 1/rate of clock time after the last, and it must cover 1/rate of simulated time.
    clock = SimClock()
    duration = 4.0 if rate < 1 else 0.3
    with Twin(built.spec, built.model) as twin:
        stats = run_paced(twin, duration, rate, clock=clock)
        assert twin.time == pytest.approx(duration, abs=1e-9)
    assert stats.steps == round(duration * rate) and clock.now() == pytest.approx(duration, abs=1e-9)


@pytest.mark.parametrize(("rate", "message"), [
    (700.0, r"^rate 700 Hz is not a whole number of 1 ms physics steps per iteration: use 1000 Hz divided by a "
            r"whole number \(1000, 500, 333.333, 250, ...\); the nearest are 1000 and 500 Hz$"),
    (3000.0, r"^rate 3000 Hz is faster than the physics: .* 1000 Hz at most; the rates that work are"),
    (100000.0, r"^rate 100000 Hz is faster than the physics"),
    (0, r"^rate must be a finite number of Hz above 0, got 0$"),
    (-1, r"^rate must be a finite number of Hz above 0, got -1$"),
    (float("nan"), r"^rate must be a finite number of Hz above 0, got nan$"),
    (float("inf"), r"^rate must be a finite number of Hz above 0, got inf$"),
    ("1000", r"^rate must be a number of Hz, got '1000'$"),
    (1e-320, r"^rate .* Hz is too slow for any loop"),
    (10**400, r"^rate must be a finite number of Hz above 0, got an integer of 1329 bits$"),  # was OverflowError
])
def test_rates_that_are_not_whole_physics_steps_are_refused(built, rate, message):
    from estimation.errors import TwinError
    from twin.loop import LoopError

    with Twin(built.spec, built.model) as twin, pytest.raises(LoopError, match=message) as err:
        run_paced(twin, 1.0, rate, realtime=False)
    assert isinstance(err.value, TwinError) and isinstance(err.value, ValueError) and twin.time == 0


@pytest.mark.parametrize(("duration", "message"), [
    ("1", r"^duration must be a number of seconds, got '1'$"),
    (True, r"^duration must be a number of seconds, got True$"),
    (-1.0, r"^duration must be a finite number of seconds, at least 0, got -1$"),
    (float("nan"), r"^duration must be a finite number of seconds, at least 0, got nan$"),
    (float("inf"), r"^duration must be a finite number of seconds, at least 0, got inf$"),
    (10**400, r"^duration must be a finite number of seconds, at least 0, got an integer of 1329 bits$"),
    (0.0004, r"^duration 0.0004 s is shorter than one iteration at 1000 Hz \(0.001 s each\): nothing would run$"),
])
def test_bad_durations_are_refused(built, duration, message):
    from twin.loop import LoopError

    with Twin(built.spec, built.model) as twin, pytest.raises(LoopError, match=message):
        run_paced(twin, duration, 1000.0, realtime=False)


def test_a_trajectory_returning_none_sets_no_new_target(built):
    with Twin(built.spec, built.model) as twin:
        start = twin.data.mocap_pos[0].copy()
        run_paced(twin, 0.05, 1000.0, trajectory=lambda t: None, realtime=False)  # was "must be 3 finite numbers"
        assert np.array_equal(twin.data.mocap_pos[0], start) and twin.time == pytest.approx(0.05)


def test_cli_run_simulates_duration_seconds_at_any_rate_it_takes(capsys):
    for rate in ("500", "1000"):
        assert main(["run", str(SMALL), "--duration", "1", "--rate", rate, "--no-realtime", "--json"]) == 0
        record = json.loads(capsys.readouterr().out)
        assert record["sim_time_s"] == pytest.approx(1.0) and record["steps"] == int(rate)
    for rate in ("700", "3000"):  # 0.7 s and 3 s simulated before, 3x the wall clock in real time at 3000
        assert main(["run", str(SMALL), "--duration", "1", "--rate", rate, "--no-realtime"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "1000 Hz divided by a whole number (1000, 500, 333.333, 250, ...)" in err, err


def test_a_rerun_recording_inside_the_build_folder_is_refused_before_the_work(small_scene, tmp_path, capsys):
    """It was written into the folder, and the next build refused the folder for it."""
    out = tmp_path / "built"
    out.mkdir()
    assert main(["build", str(small_scene), "--out", str(out), "--rerun", "save", str(out / "view.rrd")]) == 2
    err = capsys.readouterr().err
    assert "inside --out" in err and "which the build replaces whole" in err and err.count("\n") == 1, err
    assert not any(out.iterdir())
