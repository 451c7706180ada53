"""The per-step sync work done over all objects at once, against the per-object code it replaced.

The remote's deadband check and the twin's pose corrections run as one pass over every object's arrays
(issue 14: per-object Python, not MuJoCo, limited headless replay). Each fast path is compared here with a
slow reference, one object at a time, on the real small scene, bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenes.headless import Headless
from scenes.scenefile import load_scene
from scenes.sensing import Observation, SurfaceSensor, Track
from sync.messages import VERSION, Pose
from twin.poses import angle_deg, blend, quat_conj, quat_mul, rotation
from twin.runtime import Local, _on_twin_body
from twin.trajectory import push_trajectory

SMALL = Path(__file__).parent / "data" / "small.toml"


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.getbasetemp() / "coacd"


def _reference_correct(local: Local, object_id: str) -> None:
    """The per-object correction as it was before it was batched (twin/runtime.py at d9c79b9)."""
    target = local._targets[object_id]
    want_p, want_q = _on_twin_body(target, local._offsets[object_id])
    pos, quat = local.twin.pose(object_id)
    dist = float(np.linalg.norm(want_p - pos))
    angle = angle_deg(quat, want_q)
    s = local.settings
    if dist > s.snap_distance or angle > s.snap_angle_deg:
        alpha = 1.0
    else:
        alpha = 1.0 - float(np.exp(-local.twin.model.opt.timestep / s.correction_tau))
    new_p, new_q = blend(pos, quat, want_p, want_q, alpha)
    local.twin.set_pose(object_id, new_p, new_q, forward=False)
    lin, ang = local.twin.velocity(object_id)
    local.twin.set_velocity(object_id, lin + alpha * (np.asarray(target.linvel) - lin),
                            ang + alpha * (np.asarray(target.angvel) - ang))
    if alpha == 1.0:
        local.report.snaps += 1
    if alpha == 1.0 or (dist < 2e-4 and angle < 0.1):
        del local._targets[object_id]


def _target(local: Local, object_id: str, shift: float, turn_deg: float, seq: int) -> Pose:
    """A pose message that maps onto the twin's body ``shift`` metres and ``turn_deg`` degrees (about z) from
    where the twin has the object now."""
    pos, quat = local.twin.pose(object_id)
    half = np.radians(turn_deg) / 2
    want_q = quat_mul(np.array([np.cos(half), 0.0, 0.0, np.sin(half)]), quat)
    want_p = pos + np.array([shift, -shift / 2, 0.0])
    offset_p, offset_q = local._offsets[object_id]
    q = quat_mul(want_q, quat_conj(offset_q))  # _on_twin_body inverted
    p = want_p - rotation(q) @ offset_p
    latest = local._latest[object_id]
    return Pose(v=VERSION, stamp_ns=0, object_id=object_id, epoch=latest.epoch, seq=seq, sim_time=0.0,
                position=tuple(p.tolist()), quat=tuple((q / np.linalg.norm(q)).tolist()), linvel=(0.05, -0.02, 0.01),
                angvel=(0.3, 0.1, -0.2))


@pytest.mark.parametrize(("shift", "turn_deg"), [(0.004, 2.0), (0.08, 0.0), (0.0, 30.0), (1e-5, 0.01)],
                         ids=["blend", "snap-far", "snap-turned", "reached"])
def test_batched_corrections_equal_the_per_object_ones_bit_for_bit(cache, shift, turn_deg):
    with Headless(load_scene(SMALL), cache_dir=cache) as session:
        start = session.local.twin.data.mocap_pos[0].copy()
        session.run(0.3, trajectory=push_trajectory(start, start + np.array([0.3, 0.0, -0.03]), 1.0))
        local, data = session.local, session.local.twin.data
        ids = sorted(local.objects)
        assert ids == ["can", "crate"]
        local._targets = {i: _target(local, i, shift * (k + 1), turn_deg, 10**6 + k) for k, i in enumerate(ids)}
        saved = data.qpos.copy(), data.qvel.copy(), dict(local._targets), local.report.snaps

        def results() -> tuple[bytes, bytes, list[str], int]:
            return data.qpos.tobytes(), data.qvel.tobytes(), sorted(local._targets), local.report.snaps

        def restore() -> None:
            data.qpos[:], data.qvel[:] = saved[0], saved[1]
            local._targets, local.report.snaps = dict(saved[2]), saved[3]

        # One correction of each object, then the step's two corrections of one whose pose just arrived.
        for arrived in ([], ["crate"], ["can", "crate"]):
            restore()
            for object_id in arrived:  # on arrival
                _reference_correct(local, object_id)
            for object_id in list(local._targets):  # every target, as each step does
                _reference_correct(local, object_id)
            slow = results()
            restore()
            local._correct_all(arrived + [i for i in ids if i not in arrived], twice=set(arrived))
            fast = results()
            assert fast[2:] == slow[2:], arrived
            if _sums_as_one_vector():
                assert fast[:2] == slow[:2], arrived
            else:  # another BLAS: the last bit of a 3- or 4-term sum may differ (deterministically)
                for a, b in zip(fast[:2], slow[:2], strict=True):
                    np.testing.assert_array_max_ulp(np.frombuffer(a), np.frombuffer(b), maxulp=4)
        if turn_deg >= local.settings.snap_angle_deg or shift > local.settings.snap_distance:
            assert slow[2] == [] and slow[3] == saved[3] + 2  # both snapped and dropped
        elif shift < 1e-4:
            assert slow[2] == []  # reached: dropped without a snap
        else:
            assert slow[2] == ids and slow[3] == saved[3]


def _sums_as_one_vector() -> bool:
    """Whether batched ``np.matmul`` sums each row as ``np.dot`` and ``@`` sum one vector (this machine's
    OpenBLAS does): the batched paths are then bit for bit the per-object ones."""
    rng = np.random.default_rng(0)
    a, b, m = rng.normal(size=(200, 4)), rng.normal(size=(200, 4)), rng.normal(size=(200, 3, 3))
    rows = np.matmul(a[:, None, :], b[:, :, None])[:, 0, 0]
    mv = np.matmul(m, a[:, :3, None])[:, :, 0]
    return (rows == np.array([np.dot(x, y) for x, y in zip(a, b, strict=True)])).all() and \
        (mv == np.array([x @ y for x, y in zip(m, a[:, :3], strict=True)])).all()


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
        with pytest.raises(KeyError, match="no object 'mug' in the model"):
            sensor.poses(remote, ["crate", "mug"])
