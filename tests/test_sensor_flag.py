"""`--sensor surface|cameras` on `twin demo` and `twin remote`: the sensor the flag gives the remote (real
ray-cast depth cameras) builds every object in a headless twin; the loopback demo does too (slow: the
cameras' scans block the remote's loop for seconds, about 7 minutes on the shared two cores)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cli.main import main

SMALL = Path(__file__).parent / "data" / "small.toml"


@pytest.mark.slow
def test_the_camera_sensor_of_the_flag_builds_every_object_headless(tmp_path):
    from cli.demo import remote_sensor
    from estimation import estimate, make_cloud
    from scenes.headless import Headless
    from scenes.scenefile import load_scene
    from scenes.sensing import CameraSensor
    from sync.messages import decode, unpack_completed, unpack_normals, unpack_points

    scene = load_scene(SMALL)
    sensor = remote_sensor("cameras", scene)
    assert isinstance(sensor, CameraSensor) and remote_sensor("surface", scene) is None
    with Headless(scene, sensor=sensor, cache_dir=tmp_path) as session:
        session.run(0.05)
        assert set(session.local.objects) == {"crate", "can"}
        assert sensor.feed.stats.scans >= 1 and sensor.feed.stats.unseen == 0
        for object_id in ("crate", "can"):  # built from the cameras' clouds, not the true meshes
            est = session.local.twin.model.body(object_id).mass[0]
            true = session.remote.twin.model.body(object_id).mass[0]
            # Not the true mesh's mass, which a build from it gives to rounding (1e-3 was asked before session 44's
            # flat tops put the crate within 0.014 % of it).
            assert 0.5 < est / true < 2.0 and est != pytest.approx(true, rel=1e-6)
            # The cameras' normals (turned towards each point's camera) went with the cloud.
            sent = decode(session.remote._replies[session.remote.keys.object(object_id, "cloud")])  # type: ignore[attr-defined]
            normals = unpack_normals(sent)
            assert normals is not None and normals.shape == (sent.count, 3)
            # And which points the remote's completion added (the base, what no camera saw): the twin's volume
            # interval rests on the rest, and holds the true volume.
            completed = unpack_completed(sent)
            assert completed is not None and 0 < completed.mean() < 0.6
            low, high = session.local.twin_object(object_id).estimate.volume_bounds_m3
            true_volume = session.remote.true_surface(object_id).volume
            assert low < true_volume < high, (object_id, low, true_volume, high)
            plain = estimate(make_cloud(unpack_points(sent), normals), 1000.0)  # the completed counted as measured
            assert plain.volume_bounds_m3 is not None
            assert low < plain.volume_bounds_m3[0] and high > plain.volume_bounds_m3[1]


@pytest.mark.slow
def test_demo_with_cameras_builds_every_object_in_the_twin(capsys):
    assert main(["demo", "--scene", str(SMALL), "--sensor", "cameras", "--duration", "0.3", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    objects = {o["id"]: o for o in record["per_object"]}
    assert set(objects) == {"crate", "can"}
    for o in objects.values():
        # A camera estimate, not the truth: the mass is there and within a factor of two of the true one.
        assert 0.5 < o["estimated_mass_kg"] / o["true_mass_kg"] < 2.0, o


@pytest.mark.parametrize("command", [["demo"], ["remote", str(SMALL)]])
def test_an_unknown_sensor_is_refused_and_surface_is_the_default(capsys, command):
    from cli.main import _parser

    assert _parser().parse_args([*command]).sensor == "surface"
    with pytest.raises(SystemExit) as exc:
        main([*command, "--sensor", "lidar"])
    assert exc.value.code == 2
    assert "invalid choice: 'lidar'" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_says_which_objects_the_cameras_never_saw(capsys):
    # A 5 mm bead no default camera resolves: the remote publishes nothing of it (it crashed on an empty cloud
    # before), and the demo's summary says so (unseen_clouds, the camera feed's counters) rather than leave
    # the reader to notice one object short in per_object.
    bead = Path(__file__).parent / "data" / "bead.toml"
    assert main(["demo", "--scene", str(bead), "--sensor", "cameras", "--duration", "0.3", "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert [o["id"] for o in record["per_object"]] == ["crate"]
    assert record["unseen_clouds"] == 1
    assert record["sensor_stats"]["scans"] >= 1 and record["sensor_stats"]["unseen"] >= 1


@pytest.mark.slow
def test_cameras_keep_every_object_of_the_paper_table_at_rest(tmp_path):
    # The demo's scene, nothing moving: its large objects sit closer than two clustering cells of the 3 m
    # cameras, so segments merge, and which objects one segment holds changes from scan to scan with the noise.
    # Associated by the nearest segment centroid, the chunk and the mug were lost from t = 1.65 s on (11 lost
    # tracks, 2 scans without them); by the overlap of their models, each is tracked at every scan, in place.
    import numpy as np

    from cli.demo import default_scene
    from scenes.headless import sensor_for
    from scenes.remote import Remote
    from scenes.scenefile import load_scene
    from sync.clock import SimClock
    from sync.inprocess import InProcessBus

    scene = load_scene(default_scene())
    sensor = sensor_for("cameras", scene)
    clock = SimClock()
    remote = Remote(scene, InProcessBus(clock).transport("remote"), clock=clock, sensor=sensor,
                    cache_dir=tmp_path)  # no twin: the sensor is the case
    try:
        ids = sorted(remote.twin.object_ids())
        first = {i: sensor.track(remote, i) for i in ids}
        for _ in range(round(2.7 / remote.twin.model.opt.timestep)):
            remote.step()
            clock.advance(remote.twin.model.opt.timestep)
        stats = sensor.feed.stats
        assert stats.scans >= 4 and stats.merged >= 1  # the case: merged segments
        assert stats.lost_tracks == 0 and stats.unseen == 0, stats
        for i in ids:
            now = sensor.track(remote, i)
            assert now.seen and now.time > 2.0, (i, now)
            assert np.linalg.norm(now.position - first[i].position) < 0.01, i  # at rest: within 1 cm
    finally:
        remote.close()
