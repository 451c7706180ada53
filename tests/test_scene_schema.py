"""docs/scene.schema.json is what the loader's types generate, and every shipped scene and example passes both."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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
        {"name": "x", "objects": [{"id": "mug\n", "paper": "mug"}]},  # made a body of its own, "mug\n"
        {"name": "x\n"},
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


# --- fuzz: the schema and the loader agree; the new keys raise nothing but SceneError -------------------

def _mostly(good: st.SearchStrategy, bad: st.SearchStrategy, odds: int = 4) -> st.SearchStrategy:
    """``odds`` times in ``odds + 1`` a plausible value (so documents get past the first checks), else a bad one."""
    return st.sampled_from([True] * odds + [False]).flatmap(lambda ok: good if ok else bad)


_bad_num = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.booleans(), st.text(max_size=2))
_num = _mostly(st.one_of(st.floats(-2, 2), st.integers(-2, 2)), _bad_num, odds=20)
_vec3 = _mostly(st.lists(_num, min_size=3, max_size=3), st.lists(_num, min_size=0, max_size=4))
_unit = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: sum(x * x for x in q) > 0.1).map(
    lambda q: [x / sum(y * y for y in q) ** 0.5 for x in q])
_turn = st.sampled_from([[[0, -1, 0], [1, 0, 0], [0, 0, 1]], [[1, 0, 0], [0, 0, -1], [0, 1, 0]]])
_orientation = st.one_of(
    st.just({}),
    st.fixed_dictionaries({"quat": _mostly(_unit, st.lists(_num, min_size=3, max_size=5))}),
    st.fixed_dictionaries({"rotation": _mostly(_turn, st.lists(_vec3, min_size=2, max_size=4))}),
    st.fixed_dictionaries({"quat": _unit, "rotation": _turn}),
)
_pose = st.fixed_dictionaries(
    {"id": _mostly(st.just("scan"), st.just("bad id")), "cloud": _mostly(st.just("c.ply"), st.just("missing.ply"))},
    optional={
        "viewpoints": _mostly(st.lists(_vec3, min_size=1, max_size=3), st.lists(_vec3, max_size=0)),
        "position": _mostly(st.lists(_num, min_size=2, max_size=3), _vec3),
        "rotation_deg": _mostly(st.just([0, 0, 0]), _vec3),
        "units": st.sampled_from(["m", "mm", "km"]),
    },
).flatmap(lambda o: _orientation.map(lambda r: {**o, **r}))
_docs = st.fixed_dictionaries(
    {"name": _mostly(st.just("s"), st.just("")), "objects": st.lists(_pose, max_size=1)},
    optional={"workspace": _mostly(
        st.fixed_dictionaries({"min": st.lists(st.floats(-2, 0), min_size=3, max_size=3),
                               "max": st.lists(st.floats(0, 2), min_size=3, max_size=3)}),
        st.fixed_dictionaries({"min": _vec3, "max": _vec3}, optional={"x": _num}))},
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(doc=_docs)
def test_the_loader_accepts_only_what_the_schema_accepts(doc, tmp_path):
    (tmp_path / "c.ply").write_text("")
    try:
        scene = parse_scene(doc, base=tmp_path)
    except SceneError as exc:
        assert "\n" not in str(exc)
        return
    assert VALIDATOR.is_valid(doc)
    for obj in scene.objects:
        if obj.frame_rotation is not None:
            m = np.asarray(obj.frame_rotation)
            np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-9)
        assert np.isfinite(np.asarray(obj.viewpoints, dtype=float)).all()
    if scene.workspace is not None:
        assert all(a < b for a, b in zip(*scene.workspace, strict=True))
