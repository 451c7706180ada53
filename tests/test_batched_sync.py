"""The remote's per-step deadband check, done over all objects at once, against the per-object code it
replaced (issue 14: per-object Python, not MuJoCo, limited headless replay), on the real small scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes.headless import Headless
from scenes.scenefile import load_scene
from scenes.sensing import Observation, SurfaceSensor, Track
from twin.trajectory import push_trajectory

SMALL = Path(__file__).parent / "data" / "small.toml"


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


class _TrackOnly:
    """A sensor with only the two methods of the original seam (no batched ``poses``)."""

    def __init__(self) -> None:
        self.inner = SurfaceSensor()
        self.tracks = 0

    def observe(self, truth, object_id: str, points: int, *, shot: int) -> Observation:  # type: ignore[no-untyped-def]
        return self.inner.observe(truth, object_id, points, shot=shot)

    def track(self, truth, object_id: str) -> Track:  # type: ignore[no-untyped-def]
        self.tracks += 1
        return self.inner.track(truth, object_id)


def _pushed_session(cache: Path, sensor) -> tuple[dict[str, bytes], dict[str, bytes], int]:  # type: ignore[no-untyped-def]
    with Headless(load_scene(SMALL), cache_dir=cache, sensor=sensor) as session:
        start = session.local.twin.data.mocap_pos[0].copy()
        session.run(1.5, trajectory=push_trajectory(start, start + np.array([0.6, 0.0, -0.03]), 1.0))
        twin = {i: np.concatenate(p).tobytes() for i, p in session.poses().items()}
        return twin, dict(session.remote._replies), session.remote.pose_updates


def test_a_sensor_without_batched_poses_publishes_the_same_messages(cache):
    """The remote checks the deadband from ``poses`` when the sensor has it, else from full tracks: the same
    poses go out either way, and the old seam is still asked for one track per object per step."""
    legacy = _TrackOnly()
    fast = _pushed_session(cache, None)
    slow = _pushed_session(cache, legacy)
    assert fast[2] == slow[2] > 10  # the push moved things: poses were published
    assert fast[1] == slow[1]  # the last message on every key, byte for byte (stamps are simulated)
    assert fast[0] == slow[0]
    assert legacy.tracks >= 2 * 1500  # two objects, every step


def test_surface_sensor_poses_are_its_tracks(cache):
    with Headless(load_scene(SMALL), cache_dir=cache) as session:
        session.run(0.2)
        remote, sensor = session.remote, SurfaceSensor()
        ids = ["crate", "can"]
        pos, quat = sensor.poses(remote, ids)
        for k, object_id in enumerate(ids):
            track = sensor.track(remote, object_id)
            assert pos[k].tobytes() == track.position.tobytes() and quat[k].tobytes() == track.quat.tobytes()
        # As the twin's own accessors say it (a KeyError too): sensor.track(remote, "mug") raises the same.
        from estimation.errors import UnknownObjectError

        for ask in (lambda: sensor.poses(remote, ["crate", "mug"]), lambda: sensor.track(remote, "mug")):
            with pytest.raises(UnknownObjectError, match=r"^no object 'mug' in the model; its objects: crate, can$"):
                ask()
