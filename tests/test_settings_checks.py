"""Settings records and model inputs refuse bad values where they are made, with one line naming the field.

Each case here was accepted before (a NaN, a negative time, a string, another scene's model) and failed
later and elsewhere: a ZeroDivisionError in ``run_paced``, a multi-line MuJoCo compile error, an IndexError,
a non-finite simulation or a twin with no objects. Valid values, the defaults included, build as before.
"""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest
import trimesh

from estimation import from_mesh
from estimation.errors import MaterialError, SettingsError, TwinError
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings, CoacdSettingsError, cache_key
from twin.model import DEFAULT_PHYSICS, EndEffectorSpec, PhysicsSettings, TableSpec, add_object, new_spec
from twin.objects import object_at_estimate
from twin.sim import ModelMismatchError, Twin

NAN, INF = float("nan"), float("inf")


def _one_line(exc: pytest.ExceptionInfo, *names: str) -> None:
    """The error is one line and names each of ``names``."""
    text = str(exc.value)
    assert "\n" not in text, text
    for name in names:
        assert name in text, text


# -- PhysicsSettings ------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("field", "value"), [
    ("timestep", 0.0),        # compiled, then run_paced raised ZeroDivisionError
    ("timestep", -0.001),     # compiled, then a loop of "-1000 Hz"
    ("timestep", NAN),
    ("timestep", INF),
    ("timestep", "x"),        # a multi-line pybind TypeError in new_spec
    ("timestep", None),
    ("timestep", True),
    ("sleep", 1),
    ("sleep", "no"),
    ("elliptic", None),
    ("multiccd", NAN),
    ("table_plane", "yes"),
    ("iterations", 0),
    ("iterations", -5),       # compiled and ran
    ("iterations", 2.5),
    ("iterations", True),
    ("iterations", 2**31),    # past MuJoCo's C int: a pybind TypeError in new_spec
])
def test_physics_settings_refuse_what_they_cannot_mean(field, value):
    with pytest.raises(SettingsError) as exc:
        PhysicsSettings(**{field: value})
    _one_line(exc, f"PhysicsSettings.{field}")
    assert isinstance(exc.value, TwinError) and isinstance(exc.value, ValueError)


def test_physics_settings_valid_values_build_the_same_model():
    assert PhysicsSettings() == DEFAULT_PHYSICS
    physics = PhysicsSettings(timestep=0.002, sleep=False, elliptic=False, multiccd=False, iterations=7)
    model = new_spec("x", physics=physics).compile()
    assert model.opt.timestep == 0.002 and model.opt.iterations == 7
    assert model.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    default = new_spec("x").compile()
    assert default.opt.timestep == 0.001 and default.opt.iterations == 100


# -- CoacdSettings --------------------------------------------------------------------------------------------

_COACD_INTS = ("max_convex_hull", "preprocess_resolution", "resolution", "mcts_nodes", "mcts_iterations",
               "mcts_max_depth", "max_ch_vertex", "seed")


@pytest.mark.parametrize(("field", "value"), [
    *((name, NAN) for name in _COACD_INTS),       # NaN was accepted in every count
    *((name, "8") for name in _COACD_INTS),       # a raw TypeError ('<' not supported)
    *((name, None) for name in _COACD_INTS),
    *((name, 8.0) for name in _COACD_INTS),       # a float count
    *((name, True) for name in _COACD_INTS),
    *((name, 2**32 + 16) for name in _COACD_INTS),  # ctypes wrapped it (to 16) without a word
    ("seed", -1),                                 # ctypes made it 4294967295
    ("threshold", "0.1"),                         # a raw TypeError (must be real number)
    ("threshold", None),
    ("threshold", True),                          # was threshold 1
    ("threshold", 10**400),                       # an OverflowError in math.isfinite
    ("convex_tolerance", "x"),
    ("convex_tolerance", None),
    ("merge", NAN),
    ("merge", "yes"),
    ("decimate", None),
    ("decimate", 1),
    ("preprocess_mode", None),
])
def test_coacd_settings_check_every_field(field, value):
    with pytest.raises(CoacdSettingsError) as exc:
        CoacdSettings(**{field: value})
    _one_line(exc, field)
    assert isinstance(exc.value, TwinError) and isinstance(exc.value, ValueError)


def test_coacd_settings_numpy_numbers_make_the_same_cache_key():
    """A numpy count or float is taken as the Python number (the cache key's JSON could not write an int64)."""
    v, f = trimesh.creation.box().vertices, trimesh.creation.box().faces
    plain = CoacdSettings(resolution=500, threshold=0.5)
    numpy = CoacdSettings(resolution=np.int64(500), threshold=np.float32(0.5))
    assert type(numpy.resolution) is int and type(numpy.threshold) is float
    assert cache_key(v, f, numpy) == cache_key(v, f, plain)


def test_coacd_default_settings_are_unchanged():
    assert CoacdSettings() == DEFAULT_SETTINGS
    assert replace(DEFAULT_SETTINGS, max_convex_hull=-1, seed=2**32 - 1).seed == 2**32 - 1


# -- TableSpec and EndEffectorSpec ----------------------------------------------------------------------------

@pytest.mark.parametrize(("kwargs", "name"), [
    ({"size": (-1, 1, 0.04)}, "TableSpec.size[0]"),     # a multi-line MuJoCo compile error
    ({"size": (1, NAN, 0.04)}, "TableSpec.size[1]"),
    ({"size": (1, 1, 0)}, "TableSpec.size[2]"),
    ({"size": (1, 1, 1e300)}, "TableSpec.size[2]"),
    ({"size": (1, 1)}, "TableSpec.size"),               # an IndexError in new_spec
    ({"size": "abc"}, "TableSpec.size"),
    ({"size": None}, "TableSpec.size"),
    ({"size": (1, "a", 1)}, "TableSpec.size[1]"),
    ({"height": NAN}, "TableSpec.height"),
    ({"height": -0.75}, "TableSpec.height"),
    ({"height": "high"}, "TableSpec.height"),
    ({"material": None}, "TableSpec.material"),
])
def test_table_spec_refuses_what_mujoco_cannot_build(kwargs, name):
    with pytest.raises(SettingsError) as exc:
        TableSpec(**kwargs)
    _one_line(exc, name)


def test_table_spec_refuses_an_unknown_material_where_it_is_made():
    with pytest.raises(MaterialError, match=r"^TableSpec.material: unknown material 'unobtainium'") as exc:
        TableSpec(material="unobtainium")
    _one_line(exc)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"position": (NAN, 0, 0.9)}, "EndEffectorSpec.position[0]"),  # compiled and stepped NaN
    ({"position": (0, 0, INF)}, "EndEffectorSpec.position[2]"),
    ({"position": (0, 2e3, 0.9)}, "EndEffectorSpec.position[1]"),
    ({"position": (0, 0)}, "EndEffectorSpec.position"),
    ({"position": np.zeros((3, 1))}, "EndEffectorSpec.position"),
    ({"position": np.array(0.9)}, "EndEffectorSpec.position"),
    ({"position": b"abc"}, "EndEffectorSpec.position"),
    ({"radius": 0}, "EndEffectorSpec.radius"),                      # a multi-line MuJoCo compile error
    ({"radius": -1}, "EndEffectorSpec.radius"),
    ({"radius": NAN}, "EndEffectorSpec.radius"),
    ({"radius": 1e300}, "EndEffectorSpec.radius"),                  # stepped to a non-finite state
    ({"radius": "big"}, "EndEffectorSpec.radius"),
])
def test_end_effector_spec_refuses_what_mujoco_cannot_run(kwargs, name):
    with pytest.raises(SettingsError) as exc:
        EndEffectorSpec(**kwargs)
    _one_line(exc, name)


def test_valid_table_and_end_effector_build_as_given():
    model = new_spec("x", table=TableSpec(size=[1.0, 0.5, 0.02], height=0.7, material="PLA"),
                     end_effector=EndEffectorSpec(radius=0.03, position=np.array([0.1, 0.2, 0.9]))).compile()
    table = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "table")
    np.testing.assert_array_equal(model.geom_size[table], [0.5, 0.25, 0.01])
    np.testing.assert_array_equal(model.body("ee").pos, [0.1, 0.2, 0.9])
    assert TableSpec() == TableSpec(size=(1.2, 0.8, 0.04), height=0.75, material="wood_oak")
    assert EndEffectorSpec() == EndEffectorSpec(radius=0.02, position=(0.0, -0.5, 0.9))


# -- friction -------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def box_estimate():
    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    return from_mesh(box.vertices + np.array([0, 0, 0.771]), box.faces, 1000)


@pytest.fixture(scope="module")
def crate(box_estimate, tmp_path_factory):
    return object_at_estimate("crate", box_estimate, 0.5, cache_dir=tmp_path_factory.mktemp("coacd"))


@pytest.mark.parametrize("friction", [NAN, -1.0, INF, "0.5", None])
def test_object_at_estimate_refuses_a_bad_friction(box_estimate, tmp_path, friction):
    """NaN made the object's state non-finite at its first contact; -1 compiled and slid."""
    with pytest.raises(SettingsError) as exc:
        object_at_estimate("crate", box_estimate, friction, cache_dir=tmp_path)
    _one_line(exc, "friction", "'crate'")
    assert isinstance(exc.value, TwinError) and isinstance(exc.value, ValueError)


@pytest.mark.parametrize("friction", [NAN, -0.1])
def test_twin_object_refuses_a_bad_friction(crate, friction):
    with pytest.raises(SettingsError) as exc:
        replace(crate, friction=friction)
    _one_line(exc, "friction", "'crate'")


def test_a_valid_friction_reaches_the_model(crate):
    assert crate.friction == 0.5
    spec = new_spec("x", table=TableSpec())
    add_object(spec, replace(crate, friction=0.0))  # frictionless is a friction
    model = spec.compile()
    assert model.geom("crate/hull0").friction[0] == 0.0


# -- Twin(spec, model) ----------------------------------------------------------------------------------------

def test_twin_refuses_a_model_not_compiled_from_its_spec(crate):
    spec = new_spec("t", table=TableSpec(), end_effector=EndEffectorSpec())
    add_object(spec, crate)
    # Another scene's model: the twin ran with no objects (object_ids() was []).
    with pytest.raises(ModelMismatchError) as exc:
        Twin(spec, new_spec("x").compile())
    _one_line(exc, "model", "spec")
    assert isinstance(exc.value, TwinError) and isinstance(exc.value, ValueError)
    # As many bodies, another name.
    other = new_spec("t", table=TableSpec(), end_effector=EndEffectorSpec())
    add_object(other, replace(crate, id="box"))
    with pytest.raises(ModelMismatchError, match=r"body 3 is 'box', its spec's 'crate'") as exc:
        Twin(spec, other.compile())
    _one_line(exc)


def test_twin_takes_the_model_compiled_from_its_spec(crate):
    spec = new_spec("t", table=TableSpec(), end_effector=EndEffectorSpec())
    add_object(spec, crate)
    model = spec.compile()
    with Twin(spec, model) as twin:
        assert twin.model is model and twin.object_ids() == ["crate"]
    with Twin(spec.copy(), model) as twin:  # a copy of the spec compiles to the same model
        assert twin.object_ids() == ["crate"]
