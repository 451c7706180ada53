"""Damaged mesh sources and edited build folders: one line on stderr and exit 2, never a traceback or a hang."""

from __future__ import annotations

import base64
import json
import os
import re

import numpy as np
import pytest
import trimesh

from cli.main import main
from scenes.scenefile import MESH_SUFFIXES, SceneError, parse_scene
from scenes.sources import source_mesh

BOX = trimesh.creation.box(extents=(0.1, 0.1, 0.1))


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "coacd"))


def _ply(faces: np.ndarray) -> str:
    """An ascii PLY of the box's vertices with ``faces`` as written, whatever they index."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(BOX.vertices)}", "property float x",
             "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(f"{c:g}" for c in v) for v in BOX.vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


def _gltf(faces: np.ndarray, *, stride: int | None = None) -> str:
    """A glTF of the box with ``faces`` in its index buffer (uint32) and, if given, the vertices' byteStride."""
    positions = BOX.vertices.astype(np.float32).tobytes()
    indices = np.asarray(faces, dtype=np.uint32).tobytes()
    view = {"buffer": 0, "byteOffset": 0, "byteLength": len(positions)}
    if stride is not None:
        view["byteStride"] = stride
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(positions) + len(indices),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(positions + indices).decode()}],
        "bufferViews": [view, {"buffer": 0, "byteOffset": len(positions), "byteLength": len(indices)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(BOX.vertices), "type": "VEC3",
                       "min": BOX.vertices.min(axis=0).tolist(), "max": BOX.vertices.max(axis=0).tolist()},
                      {"bufferView": 1, "componentType": 5125, "count": int(np.size(faces)), "type": "SCALAR"}],
    }
    return json.dumps(doc)


def _scene(tmp_path, mesh_name: str, content: str | bytes):
    mesh = tmp_path / mesh_name
    mesh.write_bytes(content if isinstance(content, bytes) else content.encode())
    scene = tmp_path / "scene.toml"
    scene.write_text(f'name = "s"\n[[objects]]\nid = "m"\nmesh = "{mesh_name}"\npoints = 2000\n')
    return scene


def _build_fails(scene, tmp_path, capsys) -> str:
    out = tmp_path / "out"
    assert main(["build", str(scene), "--out", str(out)]) == 2
    # The build's progress line ("building 's': 1 objects") comes first; the error is the one line after it.
    err = capsys.readouterr().err.splitlines()[-1]
    assert err.startswith("twin build: error: object 'm'"), err
    assert not out.exists()
    return err


def _faces(last: list[int]) -> np.ndarray:
    return np.vstack([BOX.faces[:-1], last])


@pytest.mark.parametrize("last", [[0, 1, 1_000_000], [0, 1, -1]])
def test_ply_face_index_outside_the_vertices_is_refused(tmp_path, capsys, last):
    # Past the end was an IndexError in processing; a negative index wrapped and built bogus triangles.
    err = _build_fails(_scene(tmp_path, "box.ply", _ply(_faces(last))), tmp_path, capsys)
    assert "box.ply has 1 face(s) with vertex indices outside 0..7" in err, err


@pytest.mark.parametrize("face", ["0 2 3", "1/1 0/2 3/3", "1//1 2//2 -0//3"])
def test_obj_face_index_zero_is_refused_naming_the_line(tmp_path, capsys, face):
    # OBJ counts from 1; trimesh read 0 as -1, the last vertex, and built a wrong triangle without a word.
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in BOX.vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in BOX.faces[:-1]] + [f"f {face}"]
    err = _build_fails(_scene(tmp_path, "box.obj", "\n".join(lines) + "\n"), tmp_path, capsys)
    assert f"box.obj line {len(lines)}: a face with vertex index 0 (OBJ counts vertices from 1)" in err, err


def test_an_obj_with_indices_from_1_and_from_the_end_builds(tmp_path):
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in BOX.vertices] + ["# f 0 0 0: a comment is not a face"]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in BOX.faces[:-1]]
    lines += ["f " + " ".join(str(i - len(BOX.vertices)) for i in BOX.faces[-1])]  # -8 .. -1: from the end
    (tmp_path / "box.obj").write_text("\n".join(lines) + "\n")
    spec = parse_scene({"name": "s", "objects": [{"id": "m", "mesh": "box.obj"}]}, base=tmp_path).objects[0]
    mesh = source_mesh(spec)
    assert mesh is not None and mesh.is_watertight and abs(mesh.volume - 1e-3) < 1e-9


@pytest.mark.parametrize(("cut", "words"), [
    (lambda b: b[: len(b) // 2], "is cut short: its header counts 12 triangles (684 bytes), the file has 342 bytes"),
    (lambda b: b[:-1], "is cut short: its header counts 12 triangles (684 bytes), the file has 683 bytes"),
    (lambda b: b + b"xx", "has 2 bytes past the 12 triangles its header counts"),
    (lambda b: b[:40], "is 40 bytes: shorter than a binary STL's 84-byte header, and not a text STL"),
])
def test_a_torn_binary_stl_is_named_torn_not_empty(tmp_path, capsys, cut, words):
    # trimesh reads a binary STL whose size disagrees with its header as a text STL with no triangles.
    err = _build_fails(_scene(tmp_path, "box.stl", cut(trimesh.exchange.stl.export_stl(BOX))), tmp_path, capsys)
    assert f"box.stl {words}" in err, err


def test_a_text_stl_with_a_utf8_name_is_not_taken_for_a_torn_binary_one(tmp_path, capsys):
    # "solid Würfel" has bytes past ASCII in its first 84, which the text test wanted printable: a text STL
    # without its last line was said "cut short: its header counts 175,140,719 triangles".
    text = trimesh.exchange.stl.export_stl_ascii(BOX).replace("solid", "solid Würfel", 1)
    text = text[: text.rindex("endsolid")]
    err = _build_fails(_scene(tmp_path, "box.stl", text.encode("utf-8")), tmp_path, capsys)
    assert "box.stl holds no triangles" in err, err


@pytest.mark.parametrize("variant", ["tabs", "indented", "comments", "bom"])
def test_valid_obj_layouts_build_the_same_box(tmp_path, variant):
    # Valid OBJ that trimesh read as no triangles (tabs, indented lines) or could not read (a comment after a
    # statement, a byte-order mark).
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in BOX.vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in BOX.faces]
    if variant == "tabs":
        lines = [line.replace(" ", "\t") for line in lines]
    elif variant == "indented":
        lines = ["  " + line for line in lines]
    elif variant == "comments":
        lines = [line + "  # a note" for line in lines]
    text = ("\ufeff" if variant == "bom" else "") + "\n".join(lines) + "\n"
    (tmp_path / "box.obj").write_bytes(text.encode("utf-8"))
    spec = parse_scene({"name": "s", "objects": [{"id": "m", "mesh": "box.obj"}]}, base=tmp_path).objects[0]
    mesh = source_mesh(spec)
    assert mesh is not None and len(mesh.faces) == 12 and abs(mesh.volume - 1e-3) < 1e-9


def test_gltf_index_buffer_outside_the_vertices_is_refused(tmp_path, capsys):
    err = _build_fails(_scene(tmp_path, "box.gltf", _gltf(_faces([0, 1, 99_999]))), tmp_path, capsys)
    assert "box.gltf has 1 face(s) with vertex indices outside 0..7" in err, err


def test_whatever_the_loader_raises_is_one_line_naming_the_file(tmp_path, capsys):
    # trimesh asserts byteStride > 0: an AssertionError, which the old list of caught exceptions lacked.
    err = _build_fails(_scene(tmp_path, "box.gltf", _gltf(BOX.faces, stride=0)), tmp_path, capsys)
    assert "cannot read mesh" in err and "box.gltf" in err, err


def test_running_out_of_memory_while_loading_is_said_so_not_blamed_on_the_file(tmp_path, capsys, monkeypatch):
    # The machine's limit, not the file's damage: the CLI's out-of-memory line, not "cannot read mesh".
    def exhausted(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise MemoryError

    monkeypatch.setattr(trimesh, "load_mesh", exhausted)
    scene = _scene(tmp_path, "ok.ply", _ply(BOX.faces))
    assert main(["build", str(scene), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert "out of memory" in err and "cannot read mesh" not in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("source", "scale", "units", "message"), [
    ("mesh", 1000.0, "m", r"is 100 m across read in units = 'm'; .* set units = \"mm\" or \"cm\" on the object$"),
    ("cloud", 1000.0, "m", r"is 1\d\d m across read in units = 'm'; .* set units = \"mm\" or \"cm\" on the object$"),
    ("mesh", 0.001, "mm", r"is 0.0001 mm across read in units = 'mm'; .* set units = \"m\" on the object$"),
    ("mesh", 0.0006, "m", r"is 0.06 mm across read in units = 'm'; a scene's objects are 2 mm to 5 m"),
])
def test_a_file_in_other_units_than_the_scene_says_is_one_line_on_its_size(tmp_path, capsys, source, scale, units,
                                                                          message):
    # A 100 mm box drawn in mm and read as metres built a 1,000 t box and failed on where the end effector starts; a
    # 0.06 mm one failed in MuJoCo's inertia check. Neither said what was wrong.
    box = BOX.copy().apply_scale(scale)
    name = "box.stl" if source == "mesh" else "box.ply"
    if source == "mesh":
        box.export(tmp_path / name)
    else:
        trimesh.PointCloud(box.sample(3000, seed=0)).export(tmp_path / name)
    scene = tmp_path / "scene.toml"
    points = "points = 2000\n" if source == "mesh" else ""  # a cloud's points are its file's
    scene.write_text(f'name = "s"\n[[objects]]\nid = "m"\n{source} = "{name}"\nunits = "{units}"\n{points}')
    err = _build_fails(scene, tmp_path, capsys)
    assert re.search(rf"object 'm' \({source} {name}\) {message}", err), err


def test_a_sound_gltf_and_ply_still_read(tmp_path):
    for name, text in (("ok.gltf", _gltf(BOX.faces)), ("ok.ply", _ply(BOX.faces))):
        _scene(tmp_path, name, text)
        spec = parse_scene({"name": "s", "objects": [{"id": "m", "mesh": name}]}, base=tmp_path).objects[0]
        mesh = source_mesh(spec)
        assert mesh.is_watertight and np.isclose(mesh.volume, 1e-3), name


@pytest.mark.parametrize("suffix", [".dae", ".3mf"])
def test_formats_without_an_installed_reader_are_refused_by_suffix(tmp_path, capsys, suffix):
    # trimesh reads them only with pycollada / lxml, which the project does not install: every one crashed.
    assert suffix not in MESH_SUFFIXES
    err = _build_fails(_scene(tmp_path, f"box{suffix}", b"<COLLADA/>"), tmp_path, capsys)
    assert "is not a mesh format we read; use one of .stl, .obj, .ply, .off, .glb, .gltf" in err, err
    with pytest.raises(SceneError, match="not a mesh format"):
        parse_scene({"name": "s", "objects": [{"id": "m", "mesh": f"box{suffix}"}]}, base=tmp_path)


# -- twin run DIR ------------------------------------------------------------------------------------------


def _folder(tmp_path, xml: str):
    folder = tmp_path / "built"
    folder.mkdir()
    (folder / "scene.xml").write_text(xml)
    return folder


def _run_fails(folder, capsys) -> str:
    # What was refused here hung or took gigabytes before: a regression hangs the suite, it does not pass.
    assert main(["run", str(folder), "--duration", "0.01", "--no-realtime"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("twin run: error: "), err
    return err


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('<asset><mesh name="m" file="gone.stl"/></asset><worldbody><geom type="mesh" mesh="m"/></worldbody>',
         "Error opening file"),
        ('<worldbody><geom type="box" size="-1 1 1"/></worldbody>', "must be positive"),
    ],
)
def test_a_folder_that_does_not_compile_is_one_line(tmp_path, capsys, body, message):
    folder = _folder(tmp_path, f"<mujoco>{body}</mujoco>")
    err = _run_fails(folder, capsys)
    assert f"{folder}: MuJoCo cannot compile its scene.xml (" in err and message in err, err


def _ball(pos: str = "0 0 0.5") -> str:
    return f'<body name="ball" pos="{pos}"><joint name="ball/free" type="free"/><geom type="sphere" size="0.1"/></body>'


@pytest.mark.parametrize(
    ("xml", "message"),
    [
        # MuJoCo's own "WARNING: XML contains a 'NaN'" and a blank line came first, and went to MUJOCO_LOG.TXT.
        ('<option timestep="nan"/>', "timestep nan s is outside"),
        ('<worldbody><body><inertial pos="0 0 0" mass="nan" diaginertia="1 1 1"/><freejoint/></body></worldbody>',
         "MuJoCo cannot compile its scene.xml (mass and inertia of moving bodies must be larger than mjMINVAL; "
         "MuJoCo warned: XML contains a 'NaN'"),
        ('<worldbody><geom type="sphere" size="0.1" friction="nan"/></worldbody>',
         "scene.xml: MuJoCo warns of it: XML contains a 'NaN'"),
        # Both ran, exit 0, reporting a body 1e27 m down (or out), under MuJoCo's "unstable" warnings.
        (f'<option gravity="0 0 -1e30"/><worldbody>{_ball()}</worldbody>',
         "built: the simulation diverged at t=0.002 s (a NaN, infinite or huge state in ball)"),
        (f'<worldbody>{_ball(pos="1e30 0 0.5")}</worldbody>',
         "a body position is 1e+30 m from its parent, beyond 1000 m"),
    ],
)
def test_an_edited_folder_that_mujoco_warns_of_is_our_one_line_only(tmp_path, capfd, monkeypatch, xml, message):
    # Before the supersphere case below: once an MjSpec parse has failed on a C++ exception, MuJoCo 4.0.1 spins
    # forever on the next parse that warns of a NaN, in the same process (with or without a warning handler).
    monkeypatch.chdir(tmp_path)
    folder = _folder(tmp_path, f"<mujoco>{xml}</mujoco>")
    assert main(["run", str(folder), "--duration", "0.01", "--no-realtime"]) == 2
    out, err = capfd.readouterr()  # the file descriptors: MuJoCo's C handler wrote past sys.stderr
    assert err.count("\n") == 1 and err.startswith("twin run: error: ") and message in err and not out, err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.parametrize(
    ("body", "message"),
    [
        # 0 and NaN divided by zero in the paced loop; 1 ns asked for a million steps per iteration (a hang).
        ('<option timestep="0"/>', "timestep 0 s is outside"),
        ('<option timestep="nan"/>', "timestep nan s is outside"),
        ('<option timestep="1e-9"/>', "timestep 1e-09 s is outside"),
        ('<option timestep="-0.001"/>', "timestep -0.001 s is outside"),
        ('<worldbody><body pos="nan 0 0.5"><freejoint/><geom type="sphere" size="0.1"/></body></worldbody>',
         "a body position is not finite"),
        # MuJoCo's C++ exception reached the user as a traceback.
        ('<asset><mesh name="s" builtin="supersphere" params="100000 1 1"/></asset>', "MuJoCo cannot"),
        # Minutes in compile, or gigabytes, before: refused from the XML.
        ('<size nkey="100000000"/>', "<size nkey> asks for 100,000,000 entries"),
        ('<asset><hfield name="h" nrow="30000" ncol="30000" size="1 1 1 1"/></asset>', "<hfield nrow ncol> asks for"),
        ('<asset><texture name="t" type="2d" builtin="checker" width="20000" height="20000"/></asset>',
         "<texture width height> asks for 400,000,000"),
        ('<worldbody><flexcomp type="grid" count="300 300 300" spacing=".01 .01 .01" dim="3" name="f"/></worldbody>',
         "<flexcomp count> asks for 27,000,000"),
    ],
)
def test_an_edited_folders_impossible_settings_are_one_line(tmp_path, capsys, monkeypatch, body, message):
    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warnings about NaN to MUJOCO_LOG.TXT in the working folder
    err = _run_fails(_folder(tmp_path, f"<mujoco>{body}</mujoco>"), capsys)
    assert message in err, err


def test_nested_replicates_are_refused_before_mujoco_expands_them(tmp_path, capsys):
    # 10^6 geoms: MuJoCo held 1.6 GB and had not finished parsing in 30 s.
    geom = '<geom type="sphere" size="0.01"/>'
    nested = f'<replicate count="1000" offset="0 0 1"><replicate count="1000" offset="1 0 0">{geom}</replicate></replicate>'
    err = _run_fails(_folder(tmp_path, f"<mujoco><worldbody>{nested}</worldbody></mujoco>"), capsys)
    assert "expands to more than 134,000 XML elements" in err, err


def test_replicates_in_an_included_file_count_too(tmp_path, capsys):
    folder = _folder(tmp_path, '<mujoco><worldbody><replicate count="1000" offset="0 0 1">'
                               '<include file="row.xml"/></replicate></worldbody></mujoco>')
    (folder / "row.xml").write_text('<mujoco><replicate count="1000" offset="1 0 0">'
                                    '<geom type="sphere" size="0.01"/></replicate></mujoco>')
    assert "expands to more than" in _run_fails(folder, capsys)


def test_an_oversized_or_malformed_scene_xml_is_refused(tmp_path, capsys):
    from cli.modelsize import MAX_MODEL_XML_BYTES

    folder = _folder(tmp_path, "<mujoco><worldbody>" + " " * MAX_MODEL_XML_BYTES + "</worldbody></mujoco>")
    assert "MiB of XML" in _run_fails(folder, capsys)
    (folder / "scene.xml").write_text('<mujoco><worldbody><replicate count="1000">&bomb;</replicate></worldbody></mujoco>')
    assert "not well-formed XML" in _run_fails(folder, capsys)


def test_a_small_replicate_still_runs(tmp_path, capsys):
    folder = _folder(tmp_path, '<mujoco><worldbody><replicate count="3" offset="1 0 0">'
                               '<geom type="sphere" size="0.1"/></replicate></worldbody></mujoco>')
    assert main(["run", str(folder), "--duration", "0.01", "--no-realtime", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    # MuJoCo's default 2 ms step: one step an iteration by default, so 5 iterations make the 0.01 s asked for.
    assert out["steps"] == 5 and out["sim_time_s"] == pytest.approx(0.01) and out["rate_hz"] == pytest.approx(500)


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_an_include_that_is_not_a_regular_file_is_refused(tmp_path, capsys, special):
    # MuJoCo opens a FIFO and waits for a writer for ever.
    folder = _folder(tmp_path, "<mujoco/>")
    if special == "fifo":
        os.mkfifo(folder / "fifo")
    (folder / "scene.xml").write_text(f'<mujoco><include file="{special}"/></mujoco>')
    assert "which is not a regular file" in _run_fails(folder, capsys)


@pytest.mark.parametrize("where", ["beside", "meshdir", "/dev/zero"])
def test_a_mesh_asset_that_is_not_a_regular_file_is_refused(tmp_path, capsys, where):
    # MuJoCo's compile opens a FIFO mesh and waits on it as it does on an included one.
    folder = _folder(tmp_path, "<mujoco/>")
    assets = folder / "assets"
    assets.mkdir(exist_ok=True)
    name = where if where.startswith("/") else "m.stl"
    if not where.startswith("/"):
        os.mkfifo((assets if where == "meshdir" else folder) / name)
    compiler = '<compiler meshdir="assets"/>' if where == "meshdir" else ""
    (folder / "scene.xml").write_text(f'<mujoco>{compiler}<asset><mesh name="m" content_type="model/stl" '
                                      f'file="{name}"/></asset><worldbody><geom type="mesh" mesh="m"/></worldbody>'
                                      '</mujoco>')
    assert f"{name}, which is not a regular file" in _run_fails(folder, capsys)
