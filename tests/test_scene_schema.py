"""docs/scene.schema.json is what the loader's types generate, and every shipped scene and example passes both."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import jsonschema
import pytest

from cli.main import main
from scenes.scenefile import SceneError, load_scene, parse_scene, scene_schema, scene_schema_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "docs" / "scene.schema.json"
EXAMPLES = re.findall(r"^```toml\n(.*?)^```", (ROOT / "docs" / "scenes.md").read_text(), flags=re.S | re.M)
FILES = sorted((ROOT / "scenes" / "data").glob("*.toml")) + sorted((ROOT / "tests" / "data").glob("*.toml"))
VALIDATOR = jsonschema.Draft202012Validator(scene_schema())


def test_the_shipped_schema_is_what_the_code_generates():
    assert SHIPPED.read_text() == scene_schema_text(), "regenerate: twin schema scene > docs/scene.schema.json"
    jsonschema.Draft202012Validator.check_schema(json.loads(SHIPPED.read_text()))


def test_twin_schema_scene_prints_it(capsys):
    assert main(["schema", "scene"]) == 0
    assert capsys.readouterr().out == SHIPPED.read_text()


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_every_shipped_scene_passes_the_schema_and_loads(path):
    assert FILES
    VALIDATOR.validate(tomllib.loads(path.read_text()))
    load_scene(path)


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_every_example_on_the_page_passes_the_schema_and_loads(index, tmp_path):
    doc = tomllib.loads(EXAMPLES[index])
    VALIDATOR.validate(doc)
    for key in ("mesh", "cloud"):  # the files the examples name, so the loader's "does not exist" passes
        for obj in doc.get("objects", []):
            if key in obj:
                (tmp_path / obj[key]).parent.mkdir(parents=True, exist_ok=True)
                (tmp_path / obj[key]).write_text("")
    assert parse_scene(doc, base=tmp_path).name


@pytest.mark.parametrize(
    "doc",
    [
        {"name": "x", "tabel": {}},
        {"name": "x", "table": {"height": True}},
        {"name": "x", "table": {"size": [1, 1]}},
        {"name": "x", "table": {"height": 0}},
        {"name": "x", "workspace": {"min": [0, 0, 0]}},
        {"name": "x", "objects": [{"id": "bad id", "paper": "mug"}]},
        {"name": "x", "objects": [{"id": "a", "paper": "teapot"}]},
        {"name": "x", "objects": [{"id": "a", "paper": "mug", "units": "km"}]},
        {"name": "x", "objects": [{"id": "a", "paper": "mug", "points": 5}]},
        {"name": "x", "objects": [{"id": "a", "primitive": {"type": "box", "size": [1, 1]}}]},
        {"name": "x", "objects": [{"id": "a", "primitive": {"type": "cone", "size": [1, 1]}}]},
        {"name": "x", "objects": [{"id": "a", "cloud": "c.ply", "quat": [1, 0, 0]}]},
    ],
)
def test_what_the_schema_refuses_the_loader_refuses(doc, tmp_path):
    (tmp_path / "c.ply").write_text("")
    assert not VALIDATOR.is_valid(doc)
    with pytest.raises(SceneError):
        parse_scene(doc, base=tmp_path)
