"""`[end_effector] push` aims `twin demo`'s push: a scene whose objects do not lie along +x from the end
effector is pushed where its file says, not swept past (the demo pushed 2.2 m along +x whatever the scene)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cli.main import main
from scenes.scenefile import DEMO_PUSH, SceneError, parse_scene

SCENE = """name = "aimed"
[table]
size = [1.0, 0.6, 0.04]
height = 0.5
[end_effector]
radius = 0.02
position = [0.0, -0.25, 0.53]
{push}
[[objects]]
id = "crate"
primitive = {{ type = "box", size = [0.12, 0.08, 0.06] }}
material = "wood_pine"
position = [0.0, 0.0]
points = 20000
"""


def _scene(push: list[float] | None) -> dict:
    import tomllib

    return tomllib.loads(SCENE.format(push="" if push is None else f"push = {push}"))


def test_a_scene_aims_the_push_and_the_default_is_unchanged():
    assert parse_scene(_scene([0.0, 0.4, 0.0])).push == (0.0, 0.4, 0.0)
    assert parse_scene(_scene(None)).push == DEMO_PUSH == (2.2, 0.0, -0.12)
    assert parse_scene({"name": "bare"}).push == DEMO_PUSH


@pytest.mark.parametrize(("push", "message"), [
    ([0.0, 3.0, 0.0], r"end_effector\.push \[0\.0, 3\.0, 0\.0\] ends at \[0\.0, 2\.75, 0\.53\], which lies outside "
                      r"the operator's reach"),
    ([0.0, 0.0, -0.6], r"end_effector\.push .* lies outside the operator's reach"),  # into the floor
    ([0.0, float("nan"), 0.0], r"end_effector\.push"),
    ([0.0, 0.1], r"end_effector\.push: expected"),
])
def test_a_push_out_of_reach_or_malformed_is_refused(push, message):
    doc = _scene(None)
    doc["end_effector"]["push"] = push
    with pytest.raises(SceneError, match=message):
        parse_scene(doc)


@pytest.mark.slow
@pytest.mark.parametrize("push", [[0.0, 0.4, 0.0], None])
def test_the_demo_pushes_where_the_scene_aims(push, tmp_path, capsys):
    path = tmp_path / "aimed.toml"
    path.write_text(SCENE.format(push="" if push is None else f"push = {push}"))
    assert main(["demo", "--scene", str(path), "--duration", "1.0", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    crate = next(o for o in record["per_object"] if o["id"] == "crate")
    moved = float(np.hypot(*crate["position_m"][:2]))
    if push is None:  # the default push sweeps along +x at y = -0.25, past the crate
        assert moved < 0.002, crate
    else:  # aimed along +y, through it
        assert crate["position_m"][1] > 0.02, crate
