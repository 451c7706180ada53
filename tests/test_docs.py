"""docs/api.md's examples run as written, and docs/scenes.md agrees with the scene loader."""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from scenes.scenefile import _OBJECT_KEYS, _TOP_KEYS, PRIMITIVES, SOURCES, SceneError, parse_scene
from twin.model import EndEffectorSpec, TableSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
API, SCENES = ROOT / "docs" / "api.md", ROOT / "docs" / "scenes.md"


def _blocks(path: Path, language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", path.read_text(), flags=re.S | re.M)


API_BLOCKS = _blocks(API, "python")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A folder with tests/data/small.toml, where every example runs (they share its files and a CoACD cache)."""
    folder = tmp_path_factory.mktemp("docs")
    (folder / "tests" / "data").mkdir(parents=True)
    shutil.copy(ROOT / "tests" / "data" / "small.toml", folder / "tests" / "data" / "small.toml")
    return folder


def test_the_api_page_has_examples():
    assert len(API_BLOCKS) >= 8


@pytest.mark.parametrize("index", range(len(API_BLOCKS)))
def test_api_example_runs(index, workdir, tmp_path_factory):
    # A subprocess: a fresh interpreter, as a user's script would be (python -c, so spawned workers do not
    # re-run it), in a folder of its own; one CoACD cache for all of them keeps the builds after the first fast.
    cache = tmp_path_factory.getbasetemp() / "docs-coacd"
    env = {**os.environ, "TWIN_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", API_BLOCKS[index]], cwd=workdir, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, f"example {index} failed:\n{API_BLOCKS[index]}\n{done.stderr[-3000:]}"


# -- docs/scenes.md --------------------------------------------------------------------------------------

SCENE_BLOCKS = _blocks(SCENES, "toml")


def test_every_key_the_loader_accepts_is_on_the_page():
    text = SCENES.read_text()
    keys = {*_TOP_KEYS, *_OBJECT_KEYS, *SOURCES, *PRIMITIVES,
            *(f.name for f in dataclasses.fields(TableSpec)), *(f.name for f in dataclasses.fields(EndEffectorSpec))}
    missing = sorted(k for k in keys if f"`{k}`" not in text)
    assert not missing, f"docs/scenes.md does not mention {missing}"


def test_the_page_has_an_example_per_source():
    for source in SOURCES:
        assert any(re.search(rf"^{source}\s*=", block, flags=re.M) for block in SCENE_BLOCKS), source


@pytest.mark.parametrize("index", range(len(SCENE_BLOCKS)))
def test_scene_example_parses(index, tmp_path):
    # The files the examples name, so the loader's "does not exist" check passes.
    for name in ("meshes/mug.stl", "scans/mug.ply"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("")
    scene = parse_scene(tomllib.loads(SCENE_BLOCKS[index]), base=tmp_path)
    assert scene.name


def test_the_documented_table_and_end_effector_keys_are_the_loaders():
    # The keys the page lists for [table] and [end_effector] parse; a key the loader does not know is refused.
    doc = {"name": "x", "table": {f.name: getattr(TableSpec(), f.name) for f in dataclasses.fields(TableSpec)},
           "end_effector": {f.name: getattr(EndEffectorSpec(), f.name) for f in dataclasses.fields(EndEffectorSpec)}}
    doc["table"]["size"] = list(doc["table"]["size"])
    doc["end_effector"]["position"] = list(doc["end_effector"]["position"])
    parse_scene(doc)
    with pytest.raises(SceneError, match=r"table: unknown key 'colour'"):
        parse_scene({"name": "x", "table": {"colour": "red"}})
