"""Holding still what the remote says is still: the contact graph and the pin, on the real small scene."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from scenes.build import build_scene
from scenes.scenefile import load_scene
from twin.contacts import contact_component
from twin.hold import Hold, HoldSettings
from twin.model import EE_BODY
from twin.sim import Twin
from twin.trajectory import push_trajectory

SMALL = Path(__file__).parent / "data" / "small.toml"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    return build_scene(load_scene(SMALL), cache_dir=tmp_path_factory.getbasetemp() / "coacd", progress=False)


def _body(twin: Twin, name: str) -> int:
    return mujoco.mj_name2id(twin.model, mujoco.mjtObj.mjOBJ_BODY, name)


def _component(twin: Twin, seeds: list[int]) -> list[int]:
    return np.flatnonzero(contact_component(twin.model, twin.data, np.array(seeds, dtype=int))).tolist()


def _qpos(model, object_id: str) -> slice:
    adr = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{object_id}/free")]
    return slice(adr, adr + 3)


def _rest(twin: Twin, steps: int = 400) -> None:
    twin.step(steps)
    assert np.abs(twin.data.qvel).max() < 0.01


def _can_in_front_of_the_crate(twin: Twin) -> None:
    crate = twin.pose("crate")[0]
    can, can_quat = twin.pose("can")
    twin.set_pose("can", np.array([crate[0] + 0.06 + 0.03 + 0.002, crate[1], can[2]]), can_quat)
    _rest(twin)


def test_contact_component_follows_touching_bodies_but_not_through_the_table(built):
    with Twin(built.spec, built.model) as twin:
        _rest(twin)
        crate, can, ee = _body(twin, "crate"), _body(twin, "can"), _body(twin, EE_BODY)
        # Both rest on the table, apart: the table (world body) links nothing.
        assert _component(twin, [crate]) == [crate]
        assert _component(twin, [ee]) == [ee]
        assert _component(twin, []) == []
        # The can stood on the crate: one touches the other.
        top = twin.pose("crate")[0][2] + 0.03 + 0.05 + 0.001
        twin.set_pose("can", np.array([*twin.pose("crate")[0][:2], top]), np.array([1.0, 0, 0, 0]))
        twin.step(100)  # landed, not yet asleep (a sleeping body has no contacts, and needs no hold)
        assert twin.pose("can")[0][2] > top - 0.005
        assert _component(twin, [can]) == sorted([crate, can])
        assert _component(twin, [ee]) == [ee]


def _kick(built, settings: HoldSettings) -> tuple[float, Hold]:
    """Kick the resting crate in the twin only; return how far it ends from where C still has it."""
    with Twin(built.spec, built.model) as twin:
        _rest(twin)
        hold = Hold(settings)
        pos, quat = twin.pose("crate")
        hold.target("crate", pos, quat, np.zeros(3), np.zeros(3), now=twin.time)
        twin.set_velocity("crate", np.array([0.6, 0.0, 0.0]), np.array([0.0, 0.0, 3.0]))
        for _ in range(500):
            hold.apply(twin)
            twin.step()
        return float(np.linalg.norm(twin.pose("crate")[0] - pos)), hold


def test_an_object_straying_on_its_own_is_pinned_back_to_the_remote_pose(built):
    free, _ = _kick(built, HoldSettings(enabled=False))
    held, hold = _kick(built, HoldSettings())
    assert free > 0.02  # it slid away and stays there
    assert held < 0.001 and hold.pins == 1 and hold.pinned == {"crate"}


def _push(built, settings: HoldSettings, seconds: float) -> tuple[np.ndarray, Hold, float]:
    """Push the crate into the can while C (silent) still has both where they were.

    Returns qpos at every step, the hold, and the twin time the end effector last touched anything.
    """
    with Twin(built.spec, built.model) as twin:
        _rest(twin)
        _can_in_front_of_the_crate(twin)
        hold = Hold(settings)
        for object_id in ("crate", "can"):
            hold.target(object_id, *twin.pose(object_id), np.zeros(3), np.zeros(3), now=twin.time)
        start = twin.data.mocap_pos[0].copy()
        push = push_trajectory(start, start + np.array([0.35, 0.0, -0.03]), 0.8)
        back = start + np.array([0.35, 0.0, 0.1])
        t0, last_touch, qpos = twin.time, -1.0, []
        for _ in range(round(seconds / twin.model.opt.timestep)):
            t = twin.time - t0
            twin.set_end_effector(push(t) if t < 0.8 else back)  # push, then lift off
            hold.apply(twin)
            twin.step()
            qpos.append(twin.data.qpos.copy())
            if np.linalg.norm(twin.end_effector_force()) > 0:
                last_touch = twin.time
        return np.array(qpos), hold, last_touch - t0


def test_the_operator_pushing_through_a_chain_of_objects_is_never_held(built):
    # Long enough for both to stop rocking (how long depends on their estimated hulls: 1.0-1.6 s after
    # the push), then ``after``, then the pull back.
    free, _, touched_until = _push(built, HoldSettings(enabled=False), 3.0)
    held, hold, _ = _push(built, HoldSettings(), 3.0)
    dt = built.model.opt.timestep
    crate, can = _qpos(built.model, "crate"), _qpos(built.model, "can")
    assert free[-1][crate][0] - free[0][crate][0] > 0.05  # the crate moved
    assert free[-1][can][0] - free[0][can][0] > 0.05  # and pushed the can, which the end effector never touched
    # While the operator disturbs them, and for `after` seconds since, the twin's physics alone moves both.
    undisturbed = round((touched_until + HoldSettings().after) / dt) - 2
    np.testing.assert_array_equal(held[:undisturbed], free[:undisturbed])
    # Then C's silence counts: it still has them where they were, so the twin pins them back.
    assert hold.pinned == {"crate", "can"}
    for q in (crate, can):
        assert np.linalg.norm(held[-1][q] - held[0][q]) < 0.002


def test_nlerp_of_a_stack_is_the_nlerp_of_each_row_the_short_way():
    from twin.poses import angle_deg, nlerp

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(5, 4)), rng.normal(size=(5, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    stack = nlerp(a, b, 0.3)
    for k in range(5):
        np.testing.assert_allclose(stack[k], nlerp(a[k], b[k], 0.3), atol=1e-12)
        np.testing.assert_allclose(nlerp(a[k], -b[k], 1.0), nlerp(a[k], b[k], 1.0), atol=1e-12)  # -q is q
        assert angle_deg(nlerp(a[k], b[k], 0.5), b[k]) <= angle_deg(a[k], b[k]) / 2 + 1e-6


@pytest.mark.parametrize(("field", "value", "message"), [
    # A NaN threshold compares false: the hold pinned nothing, without a word.
    ("distance", float("nan"), r"^HoldSettings\.distance must be a finite number, got nan$"),
    ("distance", -0.001, r"^HoldSettings\.distance must be >= 0, got -0\.001$"),
    ("angle_deg", 200.0, r"^HoldSettings\.angle_deg must be >= 0 and <= 180, got 200$"),
    ("after", float("inf"), r"^HoldSettings\.after must be a finite number, got inf$"),
    ("rest_speed", -1, r"^HoldSettings\.rest_speed must be >= 0, got -1$"),
    ("rest_spin", "0.1", r"^HoldSettings\.rest_spin must be a number, got str '0\.1'$"),
    ("quiet", None, r"^HoldSettings\.quiet must be a number, got NoneType None$"),
    # 0 looked at every step but never pulled a pinned object back; -1 the same.
    ("check_every", 0, r"^HoldSettings\.check_every must be > 0 and <= 1, got 0$"),
    ("check_every", -1, r"^HoldSettings\.check_every must be > 0 and <= 1, got -1$"),
    ("check_every", 5.0, r"^HoldSettings\.check_every must be > 0 and <= 1, got 5$"),
    ("enabled", "no", r"^HoldSettings\.enabled must be True or False, got str 'no'$"),
    # Past the float range: float() of it raised OverflowError, not this.
    ("distance", 10**400, r"^HoldSettings\.distance must be >= 0, got an integer of 1329 bits$"),
])
def test_hold_settings_refuse_what_the_hold_cannot_mean(field, value, message):
    from twin.settings import SettingsError

    with pytest.raises(SettingsError, match=message):
        HoldSettings(**{field: value})


def test_hold_settings_at_their_limits_still_hold(built):
    # 0 thresholds and the longest look are values the hold can use: an object straying at all is pinned.
    settings = HoldSettings(distance=0.0, angle_deg=180.0, after=0.0, rest_speed=0.0, rest_spin=0.0, quiet=0.0,
                            check_every=1.0)
    with Twin(built.spec, built.model) as twin:
        hold = Hold(settings)
        pos, quat = twin.pose("crate")
        hold.target("crate", pos + np.array([0.0, 0.0, 0.01]), quat, np.zeros(3), np.zeros(3), twin.time)
        assert hold.apply(twin) == ["crate"]
