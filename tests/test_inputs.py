"""Bad input gets a clear error naming the problem; good files of every format read the same."""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pytest
import trimesh

from estimation import (
    CloudError,
    CloudFileError,
    MaterialError,
    PointCloud,
    estimate,
    load_cloud,
    make_cloud,
    save_cloud,
)
from estimation.materials import MAX_DENSITY, MIN_DENSITY, material, materials
from estimation.units import UnitsError, unit_scale
from scenes.sampling import sample_surface


@pytest.fixture(scope="module")
def box_cloud():
    return sample_surface(trimesh.creation.box(extents=(0.2, 0.1, 0.05)), 5_000, seed=1)


def test_empty_cloud():
    with pytest.raises(CloudError, match="empty"):
        make_cloud(np.zeros((0, 3)))


def test_wrong_shape():
    with pytest.raises(CloudError, match=r"expected shape \(n, 3\)"):
        make_cloud(np.zeros((10, 2)))
    # A complex array lost its imaginary part with only numpy's warning.
    with pytest.raises(CloudError, match="expected real coordinates, got a complex128 array"):
        make_cloud(np.zeros((10, 3)) + 1j)


def test_nan_rows_are_dropped_and_reported(box_cloud, caplog):
    pts = box_cloud.points.copy()
    pts[:7, 1] = np.nan
    pts[7, 0] = np.inf
    with caplog.at_level(logging.WARNING):
        cloud = make_cloud(pts)
    assert cloud.dropped_nonfinite == 8 and len(cloud) == len(pts) - 8
    assert "dropped 8" in caplog.text
    result = estimate(cloud, 1000.0)
    assert any("dropped 8" in w for w in result.warnings)


def _with_nan(points):
    out = points.copy()
    out[3, 2] = np.nan
    return out


# Ways a PointCloud built by hand (not by make_cloud) goes wrong: its fields from good points p and unit
# normals n, and what the error must say.
BY_HAND = {
    "nan point": (lambda p, n: dict(points=_with_nan(p)), r"points: 1 of \d+ rows hold NaN or inf"),
    "2 columns": (lambda p, n: dict(points=p[:, :2]), r"points: expected shape \(n, 3\)"),
    "strings": (lambda p, n: dict(points=[["a", "b", "c"]] * len(p)), "points: expected a numeric"),
    "short normals": (lambda p, n: dict(points=p, normals=n[:10]), r"normals: expected shape \(\d+, 3\)"),
    "nan normals": (lambda p, n: dict(points=p, normals=np.full_like(n, np.nan)), "normals: .* NaN or inf"),
    "zero normals": (lambda p, n: dict(points=p, normals=np.zeros_like(n)), "normals: expected unit vectors"),
    "long normals": (lambda p, n: dict(points=p, normals=n * 2), "normals: expected unit vectors"),
    "short colours": (lambda p, n: dict(points=p, colors=np.zeros((5, 3))), "colors: expected shape"),
    "0-255 colours": (lambda p, n: dict(points=p, colors=np.full(p.shape, 200.0)), r"colors: expected values in \[0, 1\]"),
    "short origins": (lambda p, n: dict(points=p, sensor_origins=p[:-1]), "sensor_origins: expected shape"),
    "nan origin": (lambda p, n: dict(points=p, sensor_origins=np.broadcast_to([np.nan, 0, 0], p.shape)),
                   "sensor_origins: .* NaN or inf"),
    "dropped": (lambda p, n: dict(points=p, dropped_nonfinite=-1), "dropped_nonfinite: expected a count"),
}


@pytest.mark.parametrize("case", list(BY_HAND))
def test_a_cloud_built_by_hand_is_checked_like_one_from_make_cloud(case):
    good = sample_surface(trimesh.creation.box(extents=(0.2, 0.1, 0.05)), 1_000, seed=1, with_normals=True)
    fields, said = BY_HAND[case]
    with pytest.raises(CloudError, match=said):
        PointCloud(**fields(good.points, good.normals))


def test_a_cloud_built_by_hand_with_huge_finite_points_is_refused_by_range(box_cloud):
    cloud = PointCloud(np.vstack([box_cloud.points, [[1e308, 1e308, 0]]]))  # its sum overflows: checked row by row
    with pytest.raises(CloudError, match="beyond the 10000 m"):
        estimate(cloud, 1000.0)


def test_a_cloud_built_by_hand_from_lists_is_the_cloud_make_cloud_builds(box_cloud):
    by_hand = PointCloud(box_cloud.points.tolist())
    assert by_hand.points.dtype == np.float64 and by_hand.points.shape == box_cloud.points.shape
    assert estimate(by_hand, 1000.0).volume == estimate(make_cloud(box_cloud.points), 1000.0).volume


def test_all_nan():
    with pytest.raises(CloudError, match="NaN or inf"):
        make_cloud(np.full((50, 3), np.nan))


def test_too_few_points(box_cloud):
    with pytest.raises(CloudError, match="too few points: 40"):
        estimate(make_cloud(box_cloud.points[:40]), 1000.0)


def test_too_few_after_dropping_nan(box_cloud):
    pts = box_cloud.points[:150].copy()
    pts[:100] = np.nan
    with pytest.raises(CloudError, match="too few points: 50"):
        estimate(make_cloud(pts), 1000.0)


def test_planar_cloud():
    xy = np.random.default_rng(0).uniform(size=(1000, 2))
    with pytest.raises(CloudError, match="flat"):
        estimate(make_cloud(np.c_[xy, np.zeros(1000)]), 1000.0)


def test_a_flat_verdict_gives_the_extents_that_made_it():
    # A needle 1 m long and 1.5 x 0.5 mm across is a strip by the flatness ratios: the extents say so.
    box = np.random.default_rng(0).uniform(size=(5000, 3)) * [1.0, 0.0015, 0.0005]
    with pytest.raises(CloudError, match=r"flat \(planar\), it encloses no volume \(1 x 0\.0015\d* x 0\.000[45]\d* m along "
                                         r"its principal axes\)$"):
        estimate(make_cloud(box), 1000.0)


def test_line_cloud():
    t = np.linspace(0, 1, 500)
    with pytest.raises(CloudError, match="line-like"):
        estimate(make_cloud(np.c_[t, 2 * t, -t]), 1000.0)


@pytest.mark.parametrize("far", [
    # One stray point asked for a 3.2 TiB grid (MemoryError); five made the cloud "line-like" with no word on why.
    [[1000.0, 0, 0]],
    [[1000.0 + i / 4, 0, 0] for i in range(5)],
])
def test_a_few_far_points_are_dropped_as_strays_and_said(far):
    ball = estimate(make_cloud(_sphere(2000)), 1000.0)
    est = estimate(make_cloud(np.r_[_sphere(2000), far]), 1000.0)
    assert est.mass.volume == pytest.approx(ball.mass.volume, rel=1e-3)
    assert any(w.startswith(f"dropped {len(far)} stray point(s) in {len(far)} cluster(s)") for w in est.warnings)


@pytest.mark.parametrize(("far", "verdict"), [
    ([[1000.0, 0, 0]], r"the points span 1e\+03 m at a 0.0\d+ m spacing: \S+ grid nodes, more than the 3e\+07 "
                       r"an estimate holds; "),
    ([[1000.0 + i / 4, 0, 0] for i in range(5)], r"degenerate cloud: line-like, it encloses no volume \(1e\+03 x \S+ x \S+ m along its principal axes\); but that is "),
])
def test_far_points_kept_on_request_are_named_when_they_make_the_cloud_unusable(far, verdict):
    with pytest.raises(CloudError, match=verdict + rf"{len(far)} far point\(s\), up to 1e\+03 m from the rest, which "
                                                   r"lies within 0.0\d+ m: remove them$"):
        estimate(make_cloud(np.r_[_sphere(2000), far]), 1000.0, keep_strays=True)


def test_points_beyond_range_are_named():
    with pytest.raises(CloudError, match=r"coordinates reach 1e\+200 m from the origin, beyond the 10000 m an estimate "
                                         r"accepts; that is 1 far point\(s\), up to 1e\+200 m from the rest, which "
                                         r"lies within 0.0\d+ m: remove them$"):
        estimate(make_cloud(np.r_[_sphere(2000), [[1e200, 0, 0]]]), 1000.0)
    t = np.linspace(0, 1, 500)  # a real line stays a plain line
    with pytest.raises(CloudError, match=r"line-like, it encloses no volume \(2\.45 x \S+ x \S+ m along its principal axes\)$"):
        estimate(make_cloud(np.c_[t, 2 * t, -t]), 1000.0)


def test_identical_points():
    with pytest.raises(CloudError, match="identical"):
        estimate(make_cloud(np.ones((500, 3))), 1000.0)


def _sphere(n: int, radius: float = 0.05) -> np.ndarray:
    v = np.random.default_rng(3).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def test_repeated_rows_count_once():
    # 20 distinct positions written five times each are 100 rows, but not 100 points.
    with pytest.raises(CloudError, match="too few distinct points: 20 distinct positions among 100"):
        estimate(make_cloud(np.repeat(_sphere(20), 5, axis=0)), 1000.0)


@pytest.mark.parametrize("method", ["auto", "obb", "hull", "surface"])
def test_repeated_positions_are_estimated(tmp_path, method):
    # Every position repeated 20 times (more than the spacing's 8 neighbours) used to read a point spacing
    # of 0 and divide by it; rounded coordinates (a quantised sensor) repeat positions the same way.
    path = tmp_path / "dup.xyz"
    np.savetxt(path, np.repeat(_sphere(400), 20, axis=0))
    once = estimate(make_cloud(_sphere(400)), 1000.0, method=method)
    repeated = estimate(load_cloud(path), 1000.0, method=method)
    # The copies add no surface: the same answer, not one near it (auto fitted normals to patches of
    # copies and came out 1 % and then 5 % off).
    assert repeated.volume == pytest.approx(once.volume, rel=0.005)
    rounded = tmp_path / "rounded.xyz"
    np.savetxt(rounded, np.round(_sphere(3000), 2))
    assert estimate(load_cloud(rounded), 1000.0, method=method).volume > 0


@pytest.mark.parametrize(("copies", "jitter"), [(20, 1e-12), (20, 1e-6), (20, 1e-9)])
def test_copies_of_a_scan_a_hair_apart_are_refused_and_said(copies, jitter):
    # Each point written 20 times, a hair apart: past the distinct-points check, with a spacing of the jitter.
    # It overflowed the voxel grid's int64 cell count (1e-12: "negative dimensions"), or split patches
    # evenly between copies and eigh raised on the NaNs (1e-6, 1e-9); the refusal named several objects.
    rng = np.random.default_rng(5)
    points = np.repeat(_sphere(2000), copies, axis=0)
    with pytest.raises(CloudError, match=r"the points come in clusters \S+ times tighter than .* copies of one scan\? "
                                         r"merge them\)$"):
        estimate(make_cloud(points + rng.normal(0.0, jitter, points.shape)), 1000.0)


def test_a_few_copies_one_picometre_apart_are_refused_at_once():
    # 150 points, 20 copies each, 1e-12 m apart: the coarse grid's ratio was counted up one at a time from 2
    # towards 7e8 (hours). Bisected, the refusal is immediate.
    rng = np.random.default_rng(6)
    points = np.repeat(_sphere(150), 20, axis=0)
    with pytest.raises(CloudError, match="times tighter"):
        estimate(make_cloud(points + rng.normal(0.0, 1e-12, points.shape)), 1000.0)


def test_the_coarse_ratio_is_the_least_whose_grid_holds_the_nodes():
    # Bisection instead of counting up: the same ratio as counting, over boxes from flat to long.
    import importlib

    from estimation import tolerances as tol
    from estimation.grid import PAD_CELLS

    coarse_ratio = importlib.import_module("estimation.estimate")._coarse_ratio

    def counted(extents, h):  # the loop it replaced
        longest = max(2, int(np.ceil(float(extents.max()) / (h * tol.COARSE_RESOLUTION))))
        ratio = max(2, -(-longest // tol.COARSE_REFINE))
        while ratio < longest and np.prod(np.ceil(extents / (ratio * h)) + 2 * PAD_CELLS + 1) > tol.COARSE_RESOLUTION**3:
            ratio += 1
        return ratio

    rng = np.random.default_rng(7)
    for _ in range(2000):
        extents, h = np.exp(rng.uniform(np.log(1e-3), np.log(2.0), 3)), float(np.exp(rng.uniform(np.log(1e-5), np.log(1e-2))))
        assert coarse_ratio(extents, h, refine=True) == counted(extents, h)


def test_with_normals_a_long_thin_object_keeps_its_band_blocks_small():
    """Given normals, the coarse grid keeps the longest side's cells (it closes holes at that scale) until each
    band block would hold more than ``COARSE_REFINE`` cubed nodes: a 300 mm wire 2 mm thick at 0.135 mm cells
    took ratio 18, 11.8M band nodes for 346k measured, 25 s and 2.8 GB (3.7 s and 0.55 GB now)."""
    import importlib

    from estimation import tolerances as tol

    coarse_ratio = importlib.import_module("estimation.estimate")._coarse_ratio
    wire = np.array([0.3, 0.002, 0.002])
    assert coarse_ratio(wire, 1.35e-4, refine=False) <= tol.COARSE_REFINE
    assert coarse_ratio(wire, 1.35e-4, refine=False) == coarse_ratio(wire, 1.35e-4, refine=True)
    ball = np.array([0.1, 0.1, 0.1])
    assert coarse_ratio(ball, 1e-4, refine=False) == 8  # ceil(0.1 / (1e-4 * 128)): compact, unchanged


def test_a_cloud_in_layers_fits_its_normals_without_nans():
    # x and y in metres, z cut to whole units: neighbourhoods split evenly between two layers kept no point
    # of their own sheet (a median between them), and the refit's eigh raised on NaNs.
    v = np.random.default_rng(0).normal(size=(2000, 3))
    points = 0.05 * v / np.linalg.norm(v, axis=1, keepdims=True)
    points[:, 2] = np.trunc(points[:, 2] * 1000)
    assert estimate(make_cloud(points), 1000.0).volume > 0


@pytest.mark.parametrize("method", ["auto", "obb"])
@pytest.mark.parametrize(("scale", "match"), [(1e50, r"reach \S+e\+49 m .* beyond the 10000 m"),
                                              (1e6, "beyond the 10000 m"),
                                              (1e-200, r"e-200 m across, below the 1e-06 m"),
                                              (1e-7, "below the 1e-06 m")])
def test_out_of_range_scale(scale, match, method):
    with pytest.raises(CloudError, match=match):
        estimate(make_cloud(_sphere(500, 1.0) * scale), 1000.0, method=method)


@pytest.mark.parametrize("method", ["auto", "obb", "hull"])
@pytest.mark.parametrize("radius", [2e-6, 2e3])
def test_scales_within_range_are_estimated(radius, method):
    unit = estimate(make_cloud(_sphere(2000, 1.0)), 1000.0, method=method).volume
    assert estimate(make_cloud(_sphere(2000, radius)), 1000.0, method=method).volume / radius**3 == \
        pytest.approx(unit, rel=1e-3)


@pytest.mark.parametrize("density", [0.0, -5.0, float("nan"), float("inf")])
def test_bad_density(box_cloud, density):
    with pytest.raises(MaterialError, match="density must be a positive"):
        estimate(box_cloud, density)


@pytest.mark.parametrize(("density", "said"), [
    # eigh failed on the inertia 1e306 made; 1e-300 gave an all-zero inertia; 1e300 a 2e296 kg box
    (1e306, "from 0.1 to 100000"), (1e-300, "from 0.1 to 100000"), (1e300, "from 0.1 to 100000"),
    ("1000", "density must be a number of kg/m^3, got '1000'"), (None, "must be a number"), (True, "must be a number"),
])
def test_a_density_no_object_has_is_refused(box_cloud, density, said):
    with pytest.raises(MaterialError, match=re.escape(said)):
        estimate(box_cloud, density)  # type: ignore[arg-type]


@pytest.mark.parametrize(("density", "shown"), [
    # ":g" printed these as "got 100000" and "got 0.1", the limits themselves: the reason was rounded away.
    (100000.0001, "got 100000.0001"), (0.09999999, "got 0.09999999"), (100000.5, "got 100000.5"),
    (2e5, "got 200000"), (1e-300, "got 1e-300"),  # as :g wrote them where its six digits tell them apart
])
def test_a_refused_density_shows_the_digits_that_refuse_it(box_cloud, density, shown):
    with pytest.raises(MaterialError, match=re.escape(f"from 0.1 to 100000 (aerogel to past osmium), {shown}") + "$"):
        estimate(box_cloud, density)


@pytest.mark.parametrize(("argv", "said"), [
    (["estimate", "c.ply", "--density", "100000.0001"], "--density must be >= 0.1 and <= 100000, got 100000.0001"),
    (["estimate", "c.ply", "--density", "0.0999999999"], "--density must be >= 0.1 and <= 100000, got 0.0999999999"),
    (["run", "s.toml", "--threshold", "1.0000001"], "--threshold must be > 0 and <= 1, got 1.0000001"),
    (["experiment", "s.toml", "--out", "o", "--loss", "100.00001"], "measure nothing), got 100.00001"),
    (["replay", "r.mcap", "--loss", "100"], "--loss must be below 100"),  # as twin experiment: one check
    # Refused only with --delay/--jitter/--loss given, as "seed must be ...", naming no option; else ignored.
    (["replay", "r.mcap", "--seed", str(10**23)], f"--seed must be a whole number from 0 to {2**64 - 1}, got {10**23}"),
    # In the ms it takes: the link model's message said "in [0, 3600], got 1000000.0", its seconds, no unit.
    (["experiment", "s.toml", "--out", "o", "--delays", "0,3600000.001"],
     "--delays: a delay must be at most 3.6e+06 ms (an hour), got 3600000.001 ms"),
    (["experiment", "s.toml", "--out", "o", "--delays", "5", "--jitter", "1e9"],
     "--jitter must be at most 3.6e+06 ms (an hour), got 1e+09 ms"),
    # Less than a physics step replayed nothing and reported "89x real time".
    (["replay", "r.mcap", "--duration", "0.0004"], "--duration must be >= 0.001, got 0.0004"),
])
def test_the_cli_shows_a_refused_number_with_the_digits_that_refuse_it(capsys, argv, said):
    from cli.main import main

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1, err


@pytest.mark.parametrize(("value", "limits", "digits", "shown"), [
    (100000.0001, (0.1, 1e5), 6, "100000.0001"), (1e300, (0.1, 1e5), 6, "1e+300"), (0.0, (0.0,), 6, "0"),
    (1.0010001, (0.999, 1.001), 1, "1.0010001"),  # "1" lies inside the range, "1.001" on its limit
    (100000.6, (1e5,), 3, "100001"), (float("nan"), (1.0,), 6, "nan"), (-1e-20, (0.0,), 6, "-1e-20"),
    (319.5, (0.0, 40.0), 6, "319.5"), (12345.678, (1e4,), 3, "1.23e+04"),  # as :g and :.3g wrote them
])
def test_a_refused_number_is_shown_on_its_own_side_of_each_limit(value, limits, digits, shown):
    from estimation.errors import refused_number

    assert refused_number(value, *limits, digits=digits) == shown


def test_a_quaternion_just_off_unit_norm_shows_why_it_is_refused():
    from estimation.contracts import unit_quaternion

    with pytest.raises(CloudError, match=re.escape("must have norm 1 (within 0.001), got 1.0010001")):
        unit_quaternion([1.0010001, 0.0, 0.0, 0.0])


def test_coordinates_just_past_the_range_show_why_they_are_refused():
    with pytest.raises(CloudError, match=re.escape("coordinates reach 10000.0001 m from the origin, beyond the 10000 m")):
        estimate(make_cloud(np.r_[_sphere(2000) + 9999.5, [[10000.0001, 0, 0]]]), 1000.0, keep_strays=True)


@pytest.mark.parametrize("scale", [float("nan"), float("inf"), 0.0, -1.0, None, "0.001"])
def test_a_scale_that_is_not_a_positive_number_is_refused(scale):
    # NaN made every point NaN past the finiteness check (then scipy's "data must be finite"); -1 mirrored it.
    with pytest.raises(CloudError, match="scale must be a positive number of metres per unit"):
        make_cloud(_sphere(200), scale=scale)  # type: ignore[arg-type]


@pytest.mark.parametrize("resolution", [0, 1, -5, 7, 1025, 64.0, float("nan"), True, "64"])
@pytest.mark.parametrize("method", ["obb", "surface"])
def test_a_resolution_that_cannot_hold_a_shape_is_refused(box_cloud, method, resolution):
    with pytest.raises(ValueError, match=r"resolution must be a whole number of cells from 8 to 1024"):
        estimate(box_cloud, 1000.0, method=method, resolution=resolution)


def test_a_viewpoint_that_is_not_a_point_is_refused(box_cloud):
    with pytest.raises(CloudError, match=r"viewpoint: expected shape \(n, 3\)"):
        estimate(box_cloud, 1000.0, viewpoint=[0.0, 1.0])


def test_unknown_method(box_cloud):
    # docs/api.md: every error raised on bad input derives from TwinError (these were plain ValueErrors).
    from estimation.errors import SettingsError, TwinError
    from sync.messages import MessageError, decode

    with pytest.raises(SettingsError, match="unknown method 'poisson'"):
        estimate(box_cloud, 1000.0, method="poisson")
    with pytest.raises(SettingsError, match="resolution must be a whole number"):
        estimate(box_cloud, 1000.0, resolution=0)
    with pytest.raises(MessageError) as err:
        decode(b"not a message")
    assert isinstance(err.value, TwinError) and isinstance(err.value, ValueError)


def test_unknown_material_suggests():
    with pytest.raises(MaterialError, match="did you mean wood_oak"):
        material("wood_oka")


@pytest.mark.parametrize("name", [123, None, b"steel", ["steel"]])
def test_a_material_that_is_not_a_name_is_refused(name):
    with pytest.raises(MaterialError, match=r"^a material is named by a string \(see 'twin materials'\), got "):
        material(name)


def test_material_table_has_sources():
    table = materials()
    assert len(table) >= 20
    for m in table.values():
        assert m.density > 0 and m.friction > 0 and len(m.source) > 10
        assert MIN_DENSITY * 100 < m.density < MAX_DENSITY / 5, m.name  # well inside what the wire takes
    assert material("Wood-Oak").name == "wood_oak"


def test_unit_scale():
    assert unit_scale("mm") == 0.001
    with pytest.raises(UnitsError, match="unknown units 'inch'"):
        unit_scale("inch")


def test_wrong_units_warns(box_cloud):
    result = estimate(make_cloud(box_cloud.points, scale=1000.0), 1.0)  # a 200 m box
    assert any("--units mm" in w for w in result.warnings)


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".xyz", ".npy", ".npz"])
@pytest.mark.parametrize("with_normals", [True, False])
def test_round_trip_formats(tmp_path, box_cloud, suffix, with_normals):
    if suffix == ".xyz" and with_normals:
        suffix = ".xyzn"
    cloud = box_cloud if with_normals else box_cloud.without_normals()
    path = tmp_path / f"c{suffix}"
    save_cloud(cloud, path)
    back = load_cloud(path)
    np.testing.assert_allclose(back.points, cloud.points, rtol=1e-6, atol=1e-6)
    assert (back.normals is not None) == with_normals


def test_text_file_in_millimetres(tmp_path, box_cloud):
    path = tmp_path / "c.txt"
    np.savetxt(path, np.c_[box_cloud.points * 1000, box_cloud.normals])
    back = load_cloud(path, scale=0.001)
    np.testing.assert_allclose(back.points, box_cloud.points, atol=1e-9)
    assert back.normals is not None


def test_text_file_with_colours(tmp_path, box_cloud):
    path = tmp_path / "c.csv"
    colours = np.full((len(box_cloud), 3), 200.0)
    np.savetxt(path, np.c_[box_cloud.points, colours], delimiter=",")
    back = load_cloud(path)
    assert back.normals is None and back.colors is not None
    np.testing.assert_allclose(back.colors, 200 / 255)


def test_missing_file(tmp_path):
    with pytest.raises(CloudFileError, match="no such file"):
        load_cloud(tmp_path / "nope.ply")


def test_unknown_format(tmp_path):
    (tmp_path / "c.obj").write_text("v 0 0 0\n")
    with pytest.raises(CloudFileError, match=r"unknown cloud format '\.obj'"):
        load_cloud(tmp_path / "c.obj")


@pytest.mark.parametrize("suffix", [".ply", ".pcd", ".npy", ".txt"])
def test_garbage_file(tmp_path, suffix):
    path = tmp_path / f"c{suffix}"
    path.write_bytes(b"\x00\x01garbage that is no cloud\xff" * 3)
    with pytest.raises(CloudFileError):
        load_cloud(path)


def test_empty_file(tmp_path):
    path = tmp_path / "c.ply"
    path.write_bytes(b"")
    with pytest.raises(CloudFileError, match="empty"):
        load_cloud(path)


def test_npz_without_points(tmp_path):
    np.savez(tmp_path / "c.npz", xyz=np.zeros((10, 3)))
    with pytest.raises(CloudFileError, match="'points'"):
        load_cloud(tmp_path / "c.npz")


def test_text_wrong_columns(tmp_path):
    np.savetxt(tmp_path / "c.txt", np.zeros((10, 5)))
    with pytest.raises(CloudFileError, match=r"3, 4, 6 or 9 columns .* got shape \(10, 5\)"):
        load_cloud(tmp_path / "c.txt")


@pytest.mark.parametrize(("colors", "said"), [
    (np.ones((500, 2)), r"colors: expected one \(r, g, b\) per point, \(500, 3\), got shape \(500, 2\); left out"),
    (np.full((500, 3), 1e38), r"colors: values outside 0\.\.255 \(or NaN\); left out"),
    (np.full((500, 3), np.nan), r"colors: values outside 0\.\.255 \(or NaN\); left out"),
])
def test_colours_that_cannot_be_colours_are_left_out_and_said(colors, said, caplog):
    # They passed silently: a wrong shape dropped without a word, 1e38 kept as 3.9e35 "in [0, 1]".
    import re

    points = np.random.default_rng(0).normal(size=(500, 3)) * 0.05
    with caplog.at_level(logging.WARNING):
        cloud = make_cloud(points, colors=colors)
    assert cloud.colors is None
    assert any(re.search(said, r.getMessage()) for r in caplog.records), caplog.text
    assert make_cloud(points, colors=np.full((500, 3), 128)).colors.max() == pytest.approx(128 / 255)


def test_a_failed_estimate_prints_only_its_error_line_though_it_logged_warnings_first(tmp_path):
    import subprocess
    import sys

    # Little-endian floats under a big-endian header: some decode as NaN (dropped: a log warning), the rest as
    # ~1e38 m (the error). The warning went to stderr before the error line.
    points = np.random.default_rng(0).normal(size=(2000, 3)).astype("<f4")
    header = (b"ply\nformat binary_big_endian 1.0\nelement vertex 2000\nproperty float x\nproperty float y\n"
              b"property float z\nend_header\n")
    bad = tmp_path / "endian.ply"
    bad.write_bytes(header + points.tobytes())
    run = subprocess.run([sys.executable, "-m", "cli.main", "estimate", str(bad)], capture_output=True, text=True)
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert run.stderr.startswith("twin estimate: error: coordinates reach"), run.stderr
    # A cloud that succeeds with a log warning still shows it.
    good = tmp_path / "ball.xyz"
    ball = np.random.default_rng(1).normal(size=(3000, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True) * 10
    rows = [" ".join(f"{v:.6f}" for v in p) for p in ball] + ["nan 0 0"]
    good.write_text("\n".join(rows) + "\n")
    run = subprocess.run([sys.executable, "-m", "cli.main", "estimate", str(good)], capture_output=True, text=True)
    assert run.returncode == 0 and "dropped 1 of 3001 points" in run.stderr, run.stderr


def test_a_cloud_in_other_units_is_refused_unless_units_are_given(tmp_path, capsys):
    """A 5 cm cube written in mm, estimated without --units, came out 125 m^3 and 1.6e8 kg with exit 0 and a
    warning; `twin build` refused the same file. Without --units it is refused; --units says what is meant."""
    from cli.main import _PLAUSIBLE, main
    from estimation import tolerances as tol

    low, high = tol.PLAUSIBLE_EXTENT_M
    assert _PLAUSIBLE == f"{low * 1000:g} mm to {high:g} m"
    cube = np.asarray(sample_surface(trimesh.creation.box(extents=(0.05, 0.04, 0.03)), 5000, seed=0).points)
    for name, scale, said, advice in [
            ("mm.xyz", 1000.0, " m across, more than the 2 mm to 5 m", "give --units mm or --units cm, or --units m"),
            # a unit larger than the metre is not offered: --units mm or cm would make it smaller still
            ("km.xyz", 1e-3, " mm across, less than the 2 mm to 5 m", "give --units m to take the points as metres")]:
        path = tmp_path / name
        np.savetxt(path, cube * scale)
        before = path.read_bytes()
        assert main(["estimate", str(path), "--density", "1000"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err and advice in err, err
        assert path.read_bytes() == before
    path = tmp_path / "mm.xyz"
    assert main(["estimate", str(path), "--density", "1000", "--units", "mm", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["volume_m3"] == pytest.approx(6e-5, rel=0.01)
    assert main(["estimate", str(path), "--density", "1000", "--units", "m", "--json"]) == 0  # meant: a warning
    out = json.loads(capsys.readouterr().out)
    assert out["volume_m3"] == pytest.approx(6e4, rel=0.01) and any("m across" in w for w in out["warnings"])
    # The size is the estimate's, after stray points are dropped: one point 6 m off a cube in metres was refused
    # as "6.03 m across" by a first version that measured the raw points.
    stray = tmp_path / "stray.xyz"
    np.savetxt(stray, np.vstack([cube, [[6.0, 0.0, 0.0]]]))
    assert main(["estimate", str(stray), "--density", "1000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["volume_m3"] == pytest.approx(6e-5, rel=0.01) and any("stray" in w for w in out["warnings"])


@pytest.mark.parametrize("method", ["auto", "hull"])
def test_one_far_point_kept_with_keep_strays_is_named_not_the_units(tmp_path, capsys, method):
    """A box in metres and one point 3 m off, kept by --keep-strays: "object is 5.25 m across ... the file is
    probably in other units" blamed the units. The bulk is of a plausible size: the far point is named."""
    from cli.main import main

    cube = np.asarray(sample_surface(trimesh.creation.box(extents=(0.1, 0.06, 0.04)), 1000, seed=0).points)
    path = tmp_path / "one_far.xyz"
    np.savetxt(path, np.vstack([cube, [[3.0, 3.0, 3.0]]]))
    assert main(["estimate", str(path), "--keep-strays", "--method", method]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(r"twin estimate: error: object is 5\.\d+ m across because of 1 far point\(s\), up to 3(\.\d+)? m "
                        r"from the rest, which lies within 0\.0\d+ m: remove them, or drop --keep-strays, which keeps "
                        r"them\n", err), err


@pytest.mark.parametrize(("argv", "message"), [
    (["estimate", "c.ply", "--units", "km"], r"argument --units: invalid choice: 'km'"),
    (["estimate", "c.ply", "--density", "abc"], r"argument --density: invalid float value: 'abc'"),
    (["estimate", "c.ply", "--material", "pla", "--density", "5"], r"not allowed with argument --material"),
    (["estimate"], r"the following arguments are required: VIEW"),
    (["teleport"], r"argument command: invalid choice: 'teleport'"),
])
def test_usage_errors_are_one_line(capsys, argv, message):
    # argparse printed the whole usage (eight lines for estimate) before its error line.
    import re

    from cli.main import main

    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err) and err.rstrip().endswith("--help)"), err


def test_an_error_quoting_a_huge_value_is_cut_to_a_readable_line(tmp_path, capsys):
    # A scene whose position holds 200,000 numbers: the error quoted them all (60 MB for 12 million).
    from cli.main import MAX_ERROR_CHARS, main

    scene = tmp_path / "big.toml"
    scene.write_text('name = "big"\n[[objects]]\nid = "a"\npaper = "mug"\nposition = [' + ", ".join(["0.5"] * 200_000) + "]\n")
    assert main(["build", str(scene), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("twin build: error: ") and len(err) <= MAX_ERROR_CHARS + 40, err[:300]


def test_negative_numbers_in_exponent_notation_are_values_not_options():
    # argparse's own pattern knows -1 and -1.5 only: "-1e-3" was "unrecognized arguments: -1e-3".
    from cli.main import _parser

    args = _parser().parse_args(["estimate", "a.pcd", "--support-plane", "0", "0", "1", "-1e-3",
                                 "--viewpoint", "-1E+1", "-.5", "-2."])
    assert args.support_plane == ["0", "0", "1", "-1e-3"]
    assert list(args.viewpoint[0]) == [-10.0, -0.5, -2.0]
    assert _parser().parse_args(["replay", "r.mcap", "--delay", "-inf"]).delay_ms == float("-inf")
    assert _parser().parse_args(["estimate", "a.pcd", "--viewpoint", "-Infinity", "0", "0"]).viewpoint[0][0] == float("-inf")
    assert _parser().parse_args(["experiment", "s.toml", "--out", "o", "--delays", "-5,0"]).delays == "-5,0"
    with pytest.raises(SystemExit):  # an option is still an option
        _parser().parse_args(["estimate", "a.pcd", "--support-plane", "0", "0", "1", "-e"])


def test_from_mesh_checks_its_mesh_and_says_when_it_is_not_closed():
    # Half a box's faces gave half its volume with no word; NaN vertices a LinAlgError; faces past the vertices
    # an IndexError; float faces were truncated.
    from estimation import from_mesh

    box = trimesh.creation.box(extents=[0.1, 0.06, 0.04])
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    whole = from_mesh(v, f, 1000.0)
    assert whole.watertight and whole.warnings == () and whole.volume == pytest.approx(2.4e-4)
    half = from_mesh(v, f[:6], 1000.0)
    assert not half.watertight and any("not closed" in w for w in half.warnings)
    # Closed but inside out: turned and said (tests/test_mass_properties.py); it was "mesh encloses no volume".
    turned = from_mesh(v, f[:, ::-1], 1000.0)
    assert turned.volume == pytest.approx(2.4e-4) and any("inside out" in w for w in turned.warnings)
    for vertices, faces, said in [(np.vstack([v, [np.nan] * 3]), f, "mesh vertices: contains NaN"),
                                  (v * 1e200, f, "beyond the 10000 m"), (v, f + 100, "vertex indices must be 0 to 7"),
                                  (v, f.astype(float), "whole vertex indices"), (v[:, :2], f, "expected shape (n, 3)"),
                                  # the CloudError the docstring promised (a ReconstructionError came through)
                                  (v, f[:0], "mesh encloses no volume"),
                                  # below what a cloud may span: a 10 nm box was "not closed" (its vertices merged)
                                  (v * 1e-7, f, "m across, below the 1e-06 m an estimate resolves")]:
        with pytest.raises(CloudError, match=re.escape(said)):
            from_mesh(vertices, faces, 1000.0)


def test_the_shortest_replay_is_one_physics_step():
    from cli.main import _NUMBERS
    from twin.model import TIMESTEP

    assert _NUMBERS["replay_duration"][1:3] == (TIMESTEP, True)


def test_a_simulated_clock_and_a_reader_cap_refuse_what_they_cannot_mean(tmp_path):
    """SimClock(nan) and sleep(inf) stopped a clock for good; load_cloud(max_points='5') was a TypeError from a
    reader's comparison, and -1 was taken."""
    from estimation.cloudfile import load_cloud
    from estimation.errors import SettingsError
    from sync.clock import SimClock

    for bad in (float("nan"), float("inf"), "soon"):
        with pytest.raises(SettingsError, match="simulated clock start"):
            SimClock(bad)  # type: ignore[arg-type]
    clock = SimClock()
    for call in (clock.sleep, clock.advance, clock.advance_to):
        with pytest.raises(SettingsError, match="must be a finite number"):
            call(float("inf"))
        with pytest.raises(SettingsError, match="must be a finite number, got an integer of 1329 bits"):
            call(10**400)
    clock.sleep(0.25)
    clock.advance(0.25)
    assert clock.now() == 0.5
    for bad in ("5", -1, 0, True, 2.5):
        with pytest.raises(SettingsError, match=r"max_points must be (a whole number|>= 1)"):
            load_cloud(tmp_path / "x.ply", max_points=bad)  # type: ignore[arg-type]


def test_api_misuse_is_a_clear_error_not_a_library_internal(box_cloud):
    """check_estimable(None) was an AttributeError, estimate(progress=5) "'int' object is not callable" mid-way,
    oriented_box of 1e200 m numpy's "Eigenvalues did not converge", make_config(mode='banana') Zenoh's error
    with a Rust source path."""
    from estimation import check_estimable, oriented_box
    from sync.zenoh_transport import SessionError, make_config

    with pytest.raises(TypeError, match="check_estimable takes a PointCloud"):
        check_estimable(None)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="progress must be a callable"):
        estimate(box_cloud, 1000.0, progress=5)  # type: ignore[arg-type]
    with pytest.raises(CloudError, match="coordinates too large to measure"):
        oriented_box(np.random.default_rng(0).uniform(size=(50, 3)) * 1e200)
    with pytest.raises(SessionError, match="zenoh mode must be 'peer', 'client' or 'router', got 'banana'"):
        make_config(mode="banana")


# -- from a probe of `twin estimate` with odd files (session 39) ----------------------------------------------------


def _box_views() -> tuple[np.ndarray, list[np.ndarray]]:
    """A 10 x 6 x 4 cm box on a table, as points two sensors see (faces turned towards each), and the sensors."""
    box = trimesh.creation.box(extents=[0.10, 0.06, 0.04])
    pts, faces = trimesh.sample.sample_surface(box, 20000, seed=1)
    normals = box.face_normals[faces]
    table = np.c_[np.random.default_rng(0).random((6000, 2)) * 0.3 - 0.15, np.zeros(6000)]
    cams = [np.array([0.5, -0.3, 0.45]), np.array([-0.4, 0.4, 0.5])]
    out, on_table = [], pts + np.array([0.0, 0.0, 0.02])
    for cam in cams:
        seen = np.einsum("ij,ij->i", normals, cam - on_table) > 0
        out.append(np.r_[table, on_table[seen]])
    return out, cams


def test_a_view_of_one_repeated_point_beside_real_views_is_no_index_error():
    """carving.free_space read pixel 1 of a one-pixel image (a view of 200 copies of one point, pictured by
    depth_of_points): an IndexError and exit 1 from `twin estimate A B C --support-plane auto`."""
    from estimation.views import View, estimate_views

    views, cams = _box_views()
    junk = View(np.tile([[0.0, 0.0, 0.05]], (200, 1)), cams[0])
    result = estimate_views([View(v, c) for v, c in zip(views, cams, strict=True)] + [junk], 1000.0, support="auto")
    assert result.estimate.volume == pytest.approx(2.4e-4, rel=0.05)


def test_the_views_path_refuses_one_repeated_point_and_drops_repeats_before_searching():
    """150,000 copies of one point with a VIEWPOINT took 90 s to be refused (the single-cloud path: 1.5 s); beside a
    box's 5,000 points they took 76 s in the normals' neighbour searches."""
    from estimation.views import View, estimate_views

    origin = np.array([0.5, -0.3, 0.45])
    with pytest.raises(CloudError, match="all points are identical"):
        estimate_views([View(np.tile([[0.01, 0.02, 0.03]], (150_000, 1)), origin)], 1000.0)
    with pytest.raises(CloudError, match="below the 1e-06 m"):
        estimate_views([View(np.full((5000, 3), 0.1) + np.random.default_rng(0).normal(0, 1e-9, (5000, 3)), origin)],
                       1000.0)
    box = trimesh.creation.box(extents=[0.10, 0.06, 0.04])
    pts = trimesh.sample.sample_surface(box, 5000, seed=1)[0] + [0, 0, 0.02]
    result = estimate_views([View(np.r_[np.tile([[0.01, 0.02, 0.0]], (150_000, 1)), pts], origin)], 1000.0)
    assert result.estimate.points_in <= 5001  # the copies are one point (searched as 150,000: 76 s)
    assert result.estimate.volume == pytest.approx(2.4e-4, rel=0.05)


def test_an_unreadable_depth_image_is_a_one_line_error(tmp_path, monkeypatch):
    """A permission denied on a .png or .npy depth image was a traceback, exit 1."""
    from pathlib import Path

    from estimation.depthimage import read_depth
    from estimation.errors import CloudFileError

    np.save(tmp_path / "d.npy", np.full((24, 32), 0.8))
    (tmp_path / "d.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)
    real_open = Path.open

    def denied(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        if self.name in ("d.npy", "d.png"):
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", denied)
    monkeypatch.setattr(np, "load", lambda *a, **k: (_ for _ in ()).throw(PermissionError(13, "Permission denied")))
    for name in ("d.npy", "d.png"):
        with pytest.raises(CloudFileError, match=f"cannot read .*{name}: Permission denied"):
            read_depth(tmp_path / name)


def test_a_compressed_pcd_with_8_byte_fields_is_refused_by_name_not_read_as_zeros(tmp_path):
    """open3d reads an F 8 field of a binary_compressed PCD as 0: a valid file was 'all points are identical'."""
    import struct

    from estimation.errors import CloudFileError

    pts = np.random.default_rng(0).normal(size=(500, 3))

    def literal(b: bytes) -> bytes:  # LZF with literal runs only (valid, uncompressed)
        return b"".join(bytes([len(b[i:i + 32]) - 1]) + b[i:i + 32] for i in range(0, len(b), 32))

    for size in (8, 4):
        raw = b"".join(pts[:, i].astype(f"<f{size}").tobytes() for i in range(3))
        comp = literal(raw)
        path = tmp_path / f"f{size}.pcd"
        path.write_bytes(f"VERSION 0.7\nFIELDS x y z\nSIZE {size} {size} {size}\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 500\n"
                         f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 500\nDATA binary_compressed\n".encode()
                         + struct.pack("<II", len(comp), len(raw)) + comp)
    with pytest.raises(CloudFileError, match=r"x \(F 8\), y \(F 8\), z \(F 8\); save it as binary or ascii"):
        load_cloud(tmp_path / "f8.pcd")
    assert np.allclose(load_cloud(tmp_path / "f4.pcd").points, pts.astype(np.float32))


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_a_text_table_followed_by_a_gigabyte_hole_is_read_in_bounded_memory(tmp_path, suffix, caplog):
    """A PLY claiming 200 vertices then 1 GB of NUL bytes (8 KB on disk) took 2 GB read whole; the PCD 1 GB."""
    import tracemalloc

    pts = np.random.default_rng(0).normal(size=(200, 3))
    body = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in pts)
    head = ("ply\nformat ascii 1.0\nelement vertex 200\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n" if suffix == ".ply" else
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 200\nHEIGHT 1\nPOINTS 200\nDATA ascii\n")
    path = tmp_path / f"hole{suffix}"
    path.write_text(head + body)
    with path.open("r+b") as fh:
        fh.truncate(path.stat().st_size + 200 * 2**20)  # a 200 MB hole of NUL bytes
    tracemalloc.start()
    with caplog.at_level(logging.WARNING):
        cloud = load_cloud(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert np.allclose(cloud.points, pts, atol=1e-6)
    assert peak < 20 * 2**20, peak
    assert any("after the 200" in r.getMessage() for r in caplog.records)
