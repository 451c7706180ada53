"""The estimation pipeline: one object's cloud in, one :class:`PhysicalEstimate` out.

Stages (each timed): downsample in the cloud's principal frame, normals (given, or estimated and
oriented outward), reconstruction by the chosen method, mass properties. 'auto' takes its cell from the
point spacing of at most ``tolerances.POINT_BUDGET`` of the cloud's points and its noise
(``estimation.spacing``), refines once where its own volume bounds say the cells were too coarse
(``tolerances.REFINE_DOUBT``), works on a narrow band of that grid
(``estimation.sparsegrid``), signs it by IMLS near the points and a coarse flood fill beyond
(``estimation.implicit``, ``estimation.grid``) and dual-contours it with vertices on the points' own
planes (``estimation.dualcontour``), so creases stay sharp and thin walls keep their thickness.
"""

from __future__ import annotations

import logging
import numbers
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from estimation import tolerances as tol
from estimation.cloud import (
    PointCloud,
    check_count_and_range,
    check_estimable,
    check_is_cloud,
    check_range,
    check_sensor_origin,
    distinct_rows,
    nonfinite_note,
)
from estimation.contracts import as_points
from estimation.downsample import thin_to_budget, voxel_downsample
from estimation.errors import CloudError, ReconstructionError, SettingsError, refused_number
from estimation.inertia import MassProperties, mass_properties, triangle_areas
from estimation.materials import check_density
from estimation.obb import OrientedBox, oriented_box, oriented_box_local
from estimation.units import units_warning

if TYPE_CHECKING:
    from estimation.dualcontour import DualSurface

log = logging.getLogger(__name__)

METHODS = ("auto", "obb", "hull", "surface")

#: The noise set the cell when the cell is within this factor of ``tol.FINE_CELL_NOISE`` noise sigmas (the cell is
#: the larger of that and the spacing's): then each face is a layer several points deep, and the shape of its
#: spread can be read (``_merged_sheets``).
NOISE_SET_CELL = 1.01

#: Below this share of the surface faced by its points (``estimation.coverage``, within two cells and 60 degrees)
#: and below ``ON_FACE_SHARE`` of it with a point within ``ON_FACE_SIGMAS`` noise sigmas (or half a cell) of its
#: plane, the points are one sheet (``_one_sheet``). Faced: whole objects measured 0.986 and up (bench/shapes.py's
#: 44 shapes, clean, noisy and with normals, but for the thin family's noisy walls), but bench/thin_parts.py's
#: noisy heatsinks (3.4-3.9 mm fins) 0.81 and 0.84, where orienting the normals failed in places; single views
#: of a box, a ball and a can 0.48-0.75 (one camera or two, 90 degrees apart; clean and sigma 1 mm), and the noisy
#: 1.6-2.8 mm walls that came out +80 to +250 % 0.59-0.79 (two brackets, +5 and +19 %, 0.93). On the faces'
#: planes: the heatsinks 0.995, the solids tried 0.998 and up; the views 0.49-0.91, the merged walls 0.65-0.89.
FACED_SHARE = 0.9
ON_FACE_SHARE = 0.97
ON_FACE_SIGMAS = 2.5

#: Faces whose coverage is measured: a stride over at most about this many (the share is an area average).
FACED_SAMPLE = 5_000


@dataclass(frozen=True)
class Timings:
    """Seconds spent in each stage (``read`` is filled by whoever read the file)."""

    read: float = 0.0
    downsample: float = 0.0
    normals: float = 0.0
    reconstruct: float = 0.0
    mass_properties: float = 0.0

    @property
    def total(self) -> float:
        return self.read + self.downsample + self.normals + self.reconstruct + self.mass_properties


@dataclass(frozen=True)
class PhysicalEstimate:
    """Everything estimated about one object, in the cloud's frame and SI units.

    This is the record that flows from estimation to the twin and over the network.

    Attributes:
        method: the reconstruction method used.
        mass: volume, mass, centre of mass, inertia about it (see :class:`MassProperties`).
        obb: the moment-of-inertia oriented bounding box of the points.
        vertices: (v, 3) float64 metres, the reconstructed surface.
        faces: (f, 3) int64, outward winding.
        watertight: the surface is closed and consistently oriented (so the solid is well defined).
        points_in: points read (after dropping non-finite rows).
        points_used: points after downsampling.
        cell: reconstruction grid spacing, metres (0 where no grid was used).
        timings: seconds per stage.
        material: the material name, if the density came from the table.
        warnings: things the user should know (suspicious units, dropped rows, an open surface).
        points: (points_used, 3) float32, metres, cloud frame: the downsampled points the surface was
            built from (None for 'obb', 'hull' and 'mesh'). For display and debugging.
        normals: (points_used, 3) float32, unit, cloud frame: their outward normals (given or estimated).
        volume_bounds_m3: (low, high) m^3, the volumes the cloud cannot tell apart from the estimate
            ('auto' only, else None): surface the points did not measure (holes closed by the shell)
            could lie anywhere across the shell (a wide patch as deep as it is wide: ``tol.HOLE_DEPTH_SHARE``),
            coordinates rounded to a lattice by half its step (``estimation.lattice``), walls thinner than a
            cell anywhere from nothing to a cell thick, noise on a curved surface moves it by up to twice sigma^2 times the
            mean curvature (``tol.NOISE_CURVATURE_BIAS``), the slivers added back between the facets and the
            curved surface (``curvature.bulge_volumes``) are known to their own size, and a surface curving
            faster than the cells resolve by what the facets cut off it (``curvature.unresolved_volumes``).
    """

    method: str
    mass: MassProperties
    obb: OrientedBox
    vertices: np.ndarray
    faces: np.ndarray
    watertight: bool
    points_in: int
    points_used: int
    cell: float
    timings: Timings
    material: str | None = None
    warnings: tuple[str, ...] = field(default=())
    points: np.ndarray | None = field(default=None, repr=False)
    normals: np.ndarray | None = field(default=None, repr=False)
    volume_bounds_m3: tuple[float, float] | None = None

    @property
    def volume(self) -> float:
        return self.mass.volume


def estimate(
    cloud: PointCloud,
    density: float,
    *,
    method: str = "auto",
    material: str | None = None,
    viewpoint: np.ndarray | None = None,
    resolution: int = tol.GRID_RESOLUTION,
    read_seconds: float = 0.0,
    keep_strays: bool = False,
    progress: Callable[[str], None] | None = None,
) -> PhysicalEstimate:
    """Estimate one object's geometry and mass properties from its surface cloud.

    Args:
        cloud: points (metres) on one object's surface; normals are used when present.
        density: kg/m^3, > 0.
        method: 'auto' (watertight implicit reconstruction), 'obb', 'hull' or 'surface' (the paper's).
        material: name recorded with the estimate (the density is what counts).
        viewpoint: (3,) metres; when normals must be estimated, orient them towards it instead of by
            the flood fill (for single-view scans).
        resolution: grid cells along the object's longest side for 'obb' and 'surface'. 'auto' takes
            its cell from the point spacing (``tolerances.FINE_CELL_SPACINGS``) of at most
            ``tolerances.POINT_BUDGET`` points (see ``_estimate_auto``).
        read_seconds: time spent reading the file, carried into ``timings``.
        keep_strays: keep the points ``estimation.strays`` finds apart from the object (by default they are
            dropped, with a warning saying how many).
        progress: called with a line saying what 'auto' does next (a pass and its points), for callers that
            show progress on large clouds.

    Raises:
        CloudError: too few points, a flat or line-like cloud, a viewpoint beyond
            ``tolerances.MAX_COORDINATE_M``.
        MaterialError: a non-positive or non-finite density.
        SettingsError: an unknown method, a resolution outside ``tolerances.MIN_RESOLUTION``..``MAX_RESOLUTION``
            (a :class:`TwinError` and a ``ValueError``).
        ReconstructionError: 'auto' found no closed solid.
    """
    check_is_cloud(cloud, "estimate")
    if progress is not None and not callable(progress):
        raise TypeError(f"estimate: progress must be a callable taking one line of text, or None, got "
                        f"{type(progress).__name__}")
    if method not in METHODS:
        raise SettingsError(f"unknown method {str(method)[:40]!r}; choose from {', '.join(METHODS)}")
    density = check_density(density)
    if isinstance(resolution, bool) or not isinstance(resolution, numbers.Integral) or not (
            tol.MIN_RESOLUTION <= resolution <= tol.MAX_RESOLUTION):
        # 0 divided by zero, 1 cell lost two thirds of a box without a word, NaN asked for negative dimensions.
        raise SettingsError(f"resolution must be a whole number of cells from {tol.MIN_RESOLUTION} to "
                            f"{tol.MAX_RESOLUTION}, got {str(resolution)[:40]}")
    check_count_and_range(cloud.points)
    if viewpoint is not None:
        viewpoint = as_points(np.reshape(viewpoint, (1, -1)), "viewpoint")[0]
        check_sensor_origin(viewpoint, "viewpoint")
    dropped = cloud.dropped_nonfinite
    warnings = [nonfinite_note(dropped, len(cloud) + dropped)] if dropped else []
    # Strays go before the shape checks: a stray point 1 km off made a ball look line-like.
    cloud, spacing = _drop_strays(cloud, warnings, keep_strays)
    try:
        check_estimable(cloud)
    except CloudError as exc:
        # Two balls 100 m apart are a line to the shape check: the parts are the news, not the line.
        parts = next((w for w in warnings if w.startswith("the cloud is ") and "separate parts" in w), None)
        if parts is None:
            raise
        raise CloudError(f"{exc}: {parts.split(': ')[0]} (split the cloud into its objects)") from None

    box, local = oriented_box_local(cloud.points)
    if (hint := units_warning(box.extents)) is not None:
        log.info(hint)
        warnings.append(hint)
    stages: dict[str, float] = {"read": read_seconds}

    if method == "obb":
        # As the paper's pipeline: PCL's moment-of-inertia box of the voxel-downsampled cloud (the grid
        # is the cloud's own axes, which is why the paper's OBB error depends on the rotation).
        t0 = time.perf_counter()
        voxel = float(box.extents.max()) / resolution
        points, _, _ = voxel_downsample(cloud.points, voxel)
        stages["downsample"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        vertices, faces = box_mesh(oriented_box(points))
        return _finish(method, cloud, len(points), box, vertices, faces, True, voxel, density, material,
                       warnings, stages, t0)
    if method == "hull":
        from estimation.hull import convex_hull

        t0 = time.perf_counter()
        vertices, faces = convex_hull(cloud.points)
        stages["reconstruct"] = time.perf_counter() - t0
        return _finish(method, cloud, len(cloud), box, vertices, faces, True, 0.0, density, material,
                       warnings, stages, time.perf_counter())

    if method == "auto":
        return _estimate_auto(cloud, box, local, spacing, density, material, viewpoint, warnings, stages,
                              progress or _quiet)
    return _estimate_from_surface(cloud, box, density, method, material, viewpoint, resolution, warnings, stages)


def _estimate_auto(
    cloud: PointCloud,
    box: OrientedBox,
    local: np.ndarray,
    spacing: float,
    density: float,
    material: str | None,
    viewpoint: np.ndarray | None,
    warnings: list[str],
    stages: dict[str, float],
    progress: Callable[[str], None],
) -> PhysicalEstimate:
    """'auto': narrow band at the point spacing, flood-filled sign, dual contouring on the points' planes.

    The resolution: the cell is the spacing of at most ``tol.POINT_BUDGET`` points (one measured point
    per voxel of a denser cloud), or twice the noise if coarser. That meets the accuracy targets on
    smooth and low-poly shapes, and the pass says where it does not: its ``volume_bounds_m3`` widen with
    the surface it could not measure and the cells holding both faces of a wall. When they are wider
    than ``tol.REFINE_DOUBT`` of the volume and the budget left points out, a second pass runs on
    enough points to bring them to that (the thin-wall bound shrinks about linearly with the cell, so
    the points grow with the square of the doubt), at least ``tol.REFINE_MIN_FACTOR`` times as many and
    at most ``tol.REFINE_POINTS``. Where the noise sets the cell the second pass is no finer, but it
    averages more points in each cell: skipping it there took the noisy shapes of ``bench/shapes.py`` from
    0.51 to 1.31 % at worst. Where the refined pass is still in doubt past the warning's threshold and more
    points would resolve more, further passes take them (``_with_more_points``).
    """
    from estimation.lattice import lattice_step
    from estimation.spacing import surface_noise

    # The principal frame: the grid, and so the result, does not depend on the cloud's rotation.
    t0 = time.perf_counter()
    progress(f"measuring the noise of {len(local):,} points")
    # Before thinning: see ``spacing.NOISE_SUBSET``. Where the flood fill will orient the normals, a wall's other
    # face must not be read as noise (``own_sheet``).
    noise = surface_noise(local, own_sheet=cloud.normals is None and viewpoint is None)
    stages["downsample"] = time.perf_counter() - t0
    progress(f"reconstructing from up to {min(len(local), tol.POINT_BUDGET):,} points")
    run = _auto_pass(cloud, box, local, spacing, noise, tol.POINT_BUDGET, density, viewpoint, stages)
    doubt = run.doubt
    if run.points_used < len(local) and doubt > tol.REFINE_DOUBT:
        factor = max(tol.REFINE_MIN_FACTOR, (doubt / tol.REFINE_DOUBT) ** 2)
        budget = min(tol.REFINE_POINTS, int(run.points_used * factor))
        if budget > run.points_used:
            log.info("refining: volume doubt %.2f %% at %d points, again with about %d", 100 * doubt,
                     run.points_used, budget)
            progress(f"refining with up to {min(len(local), budget):,} points (the first pass left "
                     f"{100 * doubt:.2g} % of the volume in doubt)")
            first, run = run, _auto_pass(cloud, box, local, spacing, noise, budget, density, viewpoint, stages)
            run = _with_more_points(first, run, budget, cloud, box, local, spacing, noise, density, viewpoint,
                                    stages, progress)
    run = _at_sparse_spacing(run, cloud, box, local, spacing, noise, density, viewpoint, stages, warnings, progress)

    t0 = time.perf_counter()
    props, surface, h = run.props, run.surface, run.h
    if run.note is not None:
        warnings.append(run.note)
    curved = _noise_on_curvature(surface, noise, h)
    step = lattice_step(cloud.points)
    rounded = _area(surface) * step / 2  # a face along the lattice may be off by half a step (estimation.lattice)
    # The slivers added back model the surface between the vertices to second order: what they leave is not known
    # better than their own size (smooth shapes came out 0.01-0.04 % small without them, within 0.03 % either
    # way with them, and an interval of zero width missed the truth by that much).
    doubt = run.hole + run.deep + run.thin + curved + rounded + tol.CHORDAL_DOUBT * (run.unresolved + run.chordal)
    bounds = (max(0.0, props.volume - doubt), props.volume + doubt)
    bounds = _one_sheet(run, surface, noise, bounds, warnings)  # first: when it holds, what follows is said of (0, inf)
    unmeasured = _unmeasured_share(surface)
    if run.hole + run.deep > tol.VOLUME_DOUBT_FRACTION * props.volume:
        warnings.append(f"{100 * unmeasured:.1f} % of the surface "
                        f"was not measured (holes closed by a {run.closing}-cell shell): the volume is "
                        f"only known to {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    if curved > tol.NOISE_CURVATURE_WARN * props.volume and np.isfinite(bounds[1]):
        warnings.append(f"the noise ({1000 * noise:.2g} mm) is a large share of the surface's radius of curvature: "
                        f"it may move the volume by up to {100 * curved / props.volume:.2g} %: the volume is only "
                        f"known to {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    if rounded > tol.VOLUME_DOUBT_FRACTION * props.volume and np.isfinite(bounds[1]):
        warnings.append(f"the coordinates lie on a {1000 * step:.3g} mm lattice (rounded when written): a face along "
                        f"it may be off by up to half a step, so the volume is only known to {bounds[0]:.4g}.."
                        f"{bounds[1]:.4g} m^3")
    if run.sealed > tol.VOLUME_DOUBT_FRACTION * props.volume:
        # No closing radius closed the cloud for good: the inside is what the widest shell enclosed, behind
        # walls thinner than it or openings it sealed (a hollow ball's mouth, with noise as thick as its
        # wall: +560 %). Whether that space is the object's is not in the points.
        bounds = (max(0.0, bounds[0] - run.sealed), bounds[1])
        warnings.append(f"no closing radius closed the cloud for good (walls thinner than the noise, or openings up "
                        f"to {run.closing} cells wide sealed): {run.sealed:.4g} m^3 of the volume may be open "
                        f"space; the volume is only known to {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    if not run.encloses and unmeasured > tol.LEAK_UNMEASURED_SHARE:
        # Holes wider than any closing radius: the flood fill ran inside and the surface is a shell around
        # nothing (a box whose back no camera saw). What the points would enclose if closed is unknown, up
        # to about their convex hull.
        from scipy.spatial import ConvexHull, QhullError

        try:
            hull = float(ConvexHull(run.points).volume)
        except (QhullError, ValueError):
            hull = bounds[1]
        if hull > bounds[1]:
            bounds = (bounds[0], hull)
            warnings.append(f"the cloud is open ({100 * unmeasured:.0f} % of the surface not measured, in holes "
                            f"wider than the flood fill closes): the volume may be anything up to the points' "
                            f"convex hull, {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    if noise > 0 and h <= tol.FINE_CELL_NOISE * noise * NOISE_SET_CELL:
        bounds = _merged_sheets(run, surface, bounds, warnings)
    if tol.CHORDAL_DOUBT * run.unresolved > tol.VOLUME_DOUBT_FRACTION * props.volume:
        from estimation.curvature import CREASE_ANGLE

        warnings.append(f"the surface curves faster than the {1000 * h:.2g} mm cells resolve (parts a few cells across, "
                        f"their facets turning more than {np.degrees(CREASE_ANGLE):.0f} degrees each): the volume is only "
                        f"known to {bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    if run.thin > tol.VOLUME_DOUBT_FRACTION * props.volume:
        warnings.append(f"parts thinner than the point spacing ({1000 * h:.2g} mm cells hold both faces of a "
                        f"wall in {surface.opposed_cells} places): the volume is only known to "
                        f"{bounds[0]:.4g}..{bounds[1]:.4g} m^3")
    props = _rotate_properties(props, box.rotation, box.center)
    stages["mass_properties"] += time.perf_counter() - t0
    return PhysicalEstimate(
        method="auto", mass=props, obb=box, vertices=box.to_cloud(surface.vertices), faces=surface.faces,
        watertight=True, points_in=len(cloud), points_used=run.points_used, cell=h,
        timings=Timings(**stages), material=material, warnings=tuple(warnings),
        points=box.to_cloud(run.points).astype(np.float32),
        normals=box.to_cloud(run.normals, direction=True).astype(np.float32),
        volume_bounds_m3=bounds,
    )


def _noise_on_curvature(surface: DualSurface, noise: float, h: float) -> float:
    """m^3: how far noise of sigma ``noise`` (metres) on the curved ``surface`` may move its volume either way
    (``tol.NOISE_CURVATURE_BIAS``); 0 where the noise is under ``tol.NOISE_CURVATURE_MIN_CELLS`` of the cell ``h``."""
    if noise < tol.NOISE_CURVATURE_MIN_CELLS * h:
        return 0.0
    from estimation.curvature import integrated_mean_curvature

    return tol.NOISE_CURVATURE_BIAS * noise**2 * abs(integrated_mean_curvature(surface.vertices, surface.faces))


def _merged_sheets(run: _AutoPass, surface: DualSurface, bounds: tuple[float, float],
                   warnings: list[str]) -> tuple[float, float]:
    """``bounds`` widened, and a warning, where the points lie in two sheets about the surface (``estimation.sheets``):
    the faces of a wall thinner than the noise, merged. A hollow ball merged into a solid one holds a shell the
    wall thick under its surface; a plate merged into a slab, half the slab's surface times the plate. The
    separation measured falls short of the wall by up to a tenth (a 1.8 mm plate read 1.6 mm). A shell a quarter
    of the separation thick under the whole surface lies below both: the volume may be as little as that."""
    from estimation.sheets import spread_about

    found = spread_about(run.points, surface.vertices, surface.normals)
    log.debug("sheets: kurtosis %.2f, spread %.3g m, separation %.3g m", found.kurtosis, found.spread,
              found.separation)
    if not found.two_sheets:
        return bounds
    shell = _area(surface) * found.separation / 4
    low = min(bounds[0], shell)
    warnings.append(f"the points lie in two sheets about {1000 * found.separation:.2g} mm apart across the surface "
                    f"(their spread's kurtosis {found.kurtosis:.2f}, one noisy face gives 3): a wall thinner than "
                    f"the noise may have been filled (a hollow object?), or views are out of register; the volume "
                    f"is only known to {low:.4g}..{bounds[1]:.4g} m^3")
    return (low, bounds[1])


def _one_sheet(run: _AutoPass, surface: DualSurface, noise: float, bounds: tuple[float, float],
               warnings: list[str]) -> tuple[float, float]:
    """``(0, inf)`` and a warning where the points are one sheet and the reconstruction a slab closed around it,
    its far face measured by nothing: they face too little of the surface (``FACED_SHARE``) and too little of it
    lies within their noise of them (``ON_FACE_SHARE``).

    That sheet is one side of a solid seen from one side (a single view without its sensor's origin: a box
    came out -75 %, a can -87 %, each with an interval that stopped at a third of the truth), a surface with a
    hole the flood fill did not close (a box with a face unseen: a shell round nothing), or walls thinner than
    the noise, merged (a 2 mm cup at sigma 0.5 mm +142 %). The points alone do not tell which, nor how thick
    the object is behind them. Each test alone also caught whole objects: where the normals' orientation
    failed in places (a heatsink's fins, 0.81 of its surface faced), or (by depth) nothing at all.
    """
    from estimation.coverage import coverage

    faces = surface.faces[:: max(1, len(surface.faces) // FACED_SAMPLE)]
    radius = 2 * run.h
    faced, total = coverage(surface.vertices, faces, run.points, radius=radius, normals=run.normals)
    if total <= 0 or faced >= FACED_SHARE * total:
        return bounds
    on_face, _ = coverage(surface.vertices, faces, run.points, radius=radius,
                          depth=max(ON_FACE_SIGMAS * noise, run.h / 2))
    if on_face >= ON_FACE_SHARE * total:
        return bounds
    warnings.append(f"the points face only {100 * faced / total:.0f} % of the surface built around them and lie on "
                    f"{100 * on_face / total:.0f} % of it: they are one sheet with nothing measured behind it, one "
                    f"side of a solid (a single view, its far side never seen: give each view's sensor origin and "
                    f"--support-plane), a surface with holes wider than the flood fill closes, or walls thinner than "
                    f"the noise; the volume is not known from these points")
    return (0.0, float("inf"))


@dataclass(frozen=True)
class _AutoPass:
    """One 'auto' reconstruction at one resolution, in the box frame.

    Attributes:
        points, normals: (m, 3) the points used and their outward normals. h: fine cell, metres.
        surface: the contoured surface. props: its mass properties (box frame). closing: the coarse
        shell's radius, cells. hole, thin: m^3 of volume the cloud leaves open (see ``volume_bounds_m3``).
        deep: m^3 more behind unmeasured patches wider than the shell (``tol.HOLE_DEPTH_SHARE``).
        encloses: the coarse flood fill found an inside (``grid.Occupancy.encloses``). sealed: m^3 of that
        inside when no closing radius settled it (``grid.Occupancy.unsettled``): it may be open space.
    """

    points: np.ndarray
    normals: np.ndarray
    h: float
    surface: DualSurface
    props: MassProperties
    closing: int
    hole: float
    thin: float
    deep: float = 0.0
    encloses: bool = True
    sealed: float = 0.0
    note: str | None = None  # what was done to given normals (normals.orient_given)
    unresolved: float = 0.0  # m^3: slivers of smooth surface curving faster than the cells (curvature.unresolved_volumes)
    chordal: float = 0.0  # m^3: the slivers added back, unsigned (curvature.bulge_volumes): the model's own doubt

    @property
    def points_used(self) -> int:
        return len(self.points)

    @property
    def doubt(self) -> float:
        """The share of the volume this pass could not pin down that more points would: unmeasured surface,
        cells holding both faces of a wall, curvature the cells do not resolve."""
        return (self.hole + self.thin + tol.CHORDAL_DOUBT * self.unresolved) / self.props.volume


def _auto_pass(cloud: PointCloud, box: OrientedBox, local: np.ndarray, spacing: float, noise: float,
               budget: int, density: float, viewpoint: np.ndarray | None, stages: dict[str, float], *,
               min_cell: float = 0.0) -> _AutoPass:
    """Thin ``local`` ((n, 3) metres, box frame; ``spacing`` and ``noise`` metres) to ``budget`` points
    and reconstruct, with a fine cell of at least ``min_cell`` metres; stage seconds are added to ``stages``."""
    from scipy.spatial import cKDTree

    from estimation.curvature import corrected, slivers
    from estimation.dualcontour import contour
    from estimation.grid import grid_around, occupancy
    from estimation.hollows import open_hollows
    from estimation.implicit import band_field
    from estimation.neighbours import nearest
    from estimation.normals import (
        THIN_WALL_NEIGHBOURS,
        fit_normals,
        orient_given,
        orient_outward,
        orient_to_viewpoint,
    )
    from estimation.spacing import point_spacing
    from estimation.sparsegrid import narrow_band

    def lap(stage: str, since: float) -> float:
        now = time.perf_counter()
        stages[stage] = stages.get(stage, 0.0) + now - since
        return now

    t0 = time.perf_counter()
    points, normals = local, cloud.normals
    if len(points) > budget:
        keep = thin_to_budget(points, spacing, noise, budget)
        points = points[keep]
        normals = None if normals is None else normals[keep]
        spacing = point_spacing(points)
    if normals is not None:
        normals = box.to_local(normals, direction=True)
    h = max(tol.FINE_CELL_SPACINGS * spacing, tol.FINE_CELL_NOISE * noise, min_cell)
    ratio = _coarse_ratio(box.extents, h, refine=normals is None and viewpoint is None)
    coarse = grid_around(points, ratio * h)
    t0 = lap("downsample", t0)

    tree = cKDTree(points) if normals is None else None
    # Without given normals, nothing else tells a sealed hollow's air from the inside (``estimation.hollows``);
    # a single view's rays leave through what it did not see.
    air = None if tree is None or viewpoint is not None else partial(open_hollows, points, coarse, tree=tree,
                                                                      spacing=spacing, noise=noise)
    occ = occupancy(points, coarse, air)
    tilt = None  # given normals: exact
    note = None
    if normals is not None:
        normals, note = orient_given(points, normals, coarse, occ)
    else:
        # Fit normals over about a cell of surface: where noise sets the cell, a wider patch than the
        # default neighbours span (voxel-averaging the points instead biases noisy curved surfaces
        # outward by a good fraction of sigma).
        wanted = tol.NORMAL_NEIGHBOURS * (h / spacing) ** 2
        k = int(np.clip(wanted, tol.NORMAL_NEIGHBOURS, tol.MAX_NORMAL_NEIGHBOURS))
        # One neighbour search serves the fit and both orientation tests (the thin-wall one looks
        # at THIN_WALL_NEIGHBOURS); a spread fit (``_spread_neighbours``) searches its own, so this one
        # fetches only what the orientation reads.
        spread = wanted > k and len(points) > tol.POINT_BUDGET
        fetch = THIN_WALL_NEIGHBOURS if spread else max(k, THIN_WALL_NEIGHBOURS)
        reach, neighbours = nearest(tree, points, min(fetch, len(points)))
        if (reach[:, 1] == 0).any():
            # Repeated positions (a quantised sensor, copies of one scan): a patch of copies fits no plane
            # (a 400-point ball written 20 times: 59 % of its normals more than 60 degrees off, +5 %).
            points = points[distinct_rows(points)]
            spread = spread and len(points) > tol.POINT_BUDGET
            tree = cKDTree(points)
            neighbours = nearest(tree, points, min(max(k, THIN_WALL_NEIGHBOURS), len(points)))[1]
        fit_neighbours = _spread_neighbours(points, k, wanted) if spread else neighbours
        normals, tilt = fit_normals(points, k, neighbours=fit_neighbours, noise=noise)
        if viewpoint is not None:
            normals = orient_to_viewpoint(points, normals, box.to_local(np.asarray(viewpoint, dtype=np.float64)[None])[0])
        else:
            normals = orient_outward(points, normals, coarse, occ, tree, noise, neighbours=neighbours)
    t0 = lap("normals", t0)

    nodes = int(occ.shell.sum()) * ratio**3
    if nodes > tol.MAX_BAND_NODES:
        from estimation.cloud import far_points

        far = far_points(local)
        # Points spread evenly over a surface of this size would lie about extent / sqrt(n) apart; far closer
        # neighbours than that are points in tight clusters (copies of one scan, each point repeated with
        # a little jitter), not a finer surface.
        even = float(box.extents.max()) / np.sqrt(len(points))
        hint = (f"; {far}: remove them" if far else
                f" (the points come in clusters {even / spacing:.3g} times tighter than {len(points):,} points spread "
                f"over the object would be: copies of one scan? merge them)" if spacing < even / tol.CLUSTERED_SPACING
                else " (several objects, or --method obb?)")
        raise CloudError(f"the points span {float(box.extents.max()):.3g} m at a {h:.3g} m spacing: "
                         f"{refused_number(nodes, tol.MAX_BAND_NODES, digits=3)} grid "
                         f"nodes, more than the {tol.MAX_BAND_NODES:.3g} an estimate holds{hint}")
    band = narrow_band(coarse, occ, ratio)
    values, measured = band_field(points, normals, band)
    surface = contour(points, normals, band, values, measured, noise=noise, tilt=tilt)
    t0 = lap("reconstruct", t0)

    # The facets are chords of the surface: add back the slivers they cut off curved patches (``curvature``).
    # The mesh stays flat; its own volume is short of ``props.volume`` by the slivers.
    bulge, missed = slivers(surface.vertices, surface.faces, surface.normals, surface.smooth)
    props = corrected(mass_properties(surface.vertices, surface.faces, density), surface.vertices, surface.faces, bulge)
    # What the cloud leaves open: unmeasured surface anywhere across the closing shell's half width (and
    # deeper behind a patch wider than that: ``deep``, which more points would not resolve), and cells holding
    # both faces of a wall anywhere from none to a whole cell of material (whatever the mesh put there, the
    # truth may differ by up to the cell).
    shell = (occ.closing + 0.5) * coarse.cell
    hole = surface.unmeasured_area * shell
    area, half_width = surface.unmeasured_patches.T
    deep = float(area @ np.maximum(0.0, tol.HOLE_DEPTH_SHARE * half_width - shell))
    thin = surface.opposed_cells * h**3
    sealed = occ.unsettled * coarse.cell**3
    lap("mass_properties", t0)
    return _AutoPass(points=points, normals=normals, h=h, surface=surface, props=props, closing=occ.closing,
                     hole=hole, deep=deep, thin=thin, encloses=occ.encloses, sealed=sealed, note=note,
                     unresolved=float(missed.sum()), chordal=float(np.abs(bulge).sum()))


def _with_more_points(before: _AutoPass, run: _AutoPass, budget: int, cloud: PointCloud, box: OrientedBox,
                      local: np.ndarray, spacing: float, noise: float, density: float, viewpoint: np.ndarray | None,
                      stages: dict[str, float], progress: Callable[[str], None]) -> _AutoPass:
    """``run`` (a refining pass thinned to ``budget`` points, after ``before`` on fewer), or passes on budgets
    ``tol.REFINE_MIN_FACTOR`` times larger each, up to all the points or ``tol.FULL_POINTS``, while more points
    resolve what the last pass could not (:func:`_resolves_more`) and each leaves less in doubt than the one before.

    The refining cap keeps the time down where the doubt is the width of an interval around a good answer
    (0.1-0.3 %). Past the warning's threshold it is the answer: the thinning made a wall fewer spacings thick
    than the cloud has it, and the reconstruction merged its faces (a 1 m I-beam's 4 mm web, 2.3 spacings in
    200,000 points and 1.8 in the 120,000 kept, came out +7 to +24 %, its interval unbounded; every point:
    +0.03 %). Where the doubt is surface no point measured (one side of a box), more points measure no more of
    it: a 300,000-point scan of three faces took 23 s instead of 5 for the same answer.
    """
    limit = min(len(local), tol.FULL_POINTS)
    while budget < limit and _resolves_more(before, run, noise):
        # The budget, not the points kept: thinning keeps fewer than it asks, and a pass at the limit would
        # otherwise run again on the same points.
        budget = min(limit, int(tol.REFINE_MIN_FACTOR * budget))
        log.info("refining: volume doubt %.2f %% at %d points, again with up to %d", 100 * run.doubt,
                 run.points_used, budget)
        progress(f"refining with up to {budget:,} points (the last pass left {100 * run.doubt:.2g} % of the volume "
                 f"in doubt)")
        finer = _auto_pass(cloud, box, local, spacing, noise, budget, density, viewpoint, stages)
        if finer.doubt >= run.doubt:
            break
        before, run = run, finer
    return run


def _resolves_more(before: _AutoPass, run: _AutoPass, noise: float) -> bool:
    """Whether a pass on more points than ``run`` would likely leave less of the volume in doubt: ``run`` leaves
    more than ``tol.VOLUME_DOUBT_FRACTION`` in doubt, its cell is set by the spacing (not the noise, which more
    points would not make finer), and it still merges the faces of walls (its ``thin`` share over that
    fraction) or left unmeasured at most ``tol.MEASURED_GAIN`` of the surface ``before`` (on fewer points) left
    unmeasured."""
    if run.doubt <= tol.VOLUME_DOUBT_FRACTION or run.h <= tol.FINE_CELL_NOISE * noise:
        return False
    if run.thin > tol.VOLUME_DOUBT_FRACTION * run.props.volume:
        return True
    left = _unmeasured_share(before.surface)
    return left > 0 and _unmeasured_share(run.surface) <= tol.MEASURED_GAIN * left


def _at_sparse_spacing(run: _AutoPass, cloud: PointCloud, box: OrientedBox, local: np.ndarray, spacing: float,
                       noise: float, density: float, viewpoint: np.ndarray | None, stages: dict[str, float],
                       warnings: list[str], progress: Callable[[str], None]) -> _AutoPass:
    """``run``, or a pass at the cell of the cloud's sparsest parts when ``run`` left more than
    ``tol.LEAK_UNMEASURED_SHARE`` of its surface unmeasured because the points are spaced unevenly.

    The cell follows the typical spacing; where part of the surface is sampled far more sparsely (a side
    a scanner saw from afar, views of unequal resolution), the gaps there are holes at that cell, wider than
    the flood fill closes, and the surface is a shell around nothing (a ball sampled 100 times less densely
    on one half: -95 %). The sparsest ``tol.SPARSE_AREA_SHARE`` of the area sets the cell of a second pass
    (``spacing.sparse_spacing``) when it is ``tol.UNEVEN_SPACING`` times the first pass's or more; that
    pass is taken if it leaves at most half as much unmeasured, and the warnings say so. (Its coarse grid may be
    too coarse to hold an inside, ``encloses`` false, and still close the surface: a 10 cm ball at 5 mm cells.)
    Points spaced evenly along lines far apart (a laser line scanner's slices), whose every local spacing is the
    same, are tried first (``_along_lines``).
    """
    from estimation.spacing import sparse_spacing

    unmeasured = _unmeasured_share(run.surface)
    if unmeasured <= tol.LEAK_UNMEASURED_SHARE:
        return run
    lines = _along_lines(run, unmeasured, cloud, box, local, noise, density, viewpoint, stages, warnings, progress)
    if lines is not None:
        return lines
    sparse = tol.FINE_CELL_SPACINGS * sparse_spacing(local, tol.SPARSE_AREA_SHARE)
    if sparse < tol.UNEVEN_SPACING * run.h:
        return run
    progress(f"reconstructing again at the sparsest parts' {1000 * sparse:.3g} mm spacing ({100 * unmeasured:.0f} % of "
             f"the surface was unmeasured at {1000 * run.h:.3g} mm)")
    coarse = _auto_pass(cloud, box, local, spacing, noise, tol.POINT_BUDGET, density, viewpoint, stages, min_cell=sparse)
    left = _unmeasured_share(coarse.surface)
    if left > unmeasured / 2:
        log.info("uneven spacing: a pass at %.3g mm left %.1f %% unmeasured (%.1f %% at %.3g mm); not taken",
                 1000 * coarse.h, 100 * left, 100 * unmeasured, 1000 * run.h)
        return run
    warnings.append(f"the points are spaced unevenly ({1000 * spacing:.2g} mm typically, {1000 * sparse:.2g} mm over the "
                    f"sparsest {100 * tol.SPARSE_AREA_SHARE:.0f} % of the surface): estimated at {1000 * coarse.h:.2g} mm "
                    f"cells, which the sparse parts fill ({100 * unmeasured:.0f} % of the surface was unmeasured at the "
                    f"typical spacing); finer detail where the points are dense is not resolved")
    return coarse


def _along_lines(run: _AutoPass, unmeasured: float, cloud: PointCloud, box: OrientedBox, local: np.ndarray,
                 noise: float, density: float, viewpoint: np.ndarray | None, stages: dict[str, float],
                 warnings: list[str], progress: Callable[[str], None]) -> _AutoPass | None:
    """A pass on one point per voxel of the lines' gap where the points lie along lines (``spacing.line_gap``)
    that gap ``tol.LINE_GAP_CELLS`` times ``run``'s cell or more apart, taken (with a warning) if it leaves at
    most half of ``run``'s ``unmeasured`` share (0-1) of the surface unmeasured; else None.

    A laser line scanner's slices (2-4 mm apart, 0.1-0.3 mm along each) read a spacing along the lines, and the
    cell follows it: the gaps between the lines are holes several cells wide, the flood fill runs inside, and the
    surface is a shell round nothing (an 8 cm ball sliced every 2 mm: -98 %, its interval 0..inf m^3). Thinned to
    one measured point per voxel of the gap, the lines are a cloud sampled about evenly at that spacing, its patches
    two-dimensional for the normals' fits too (the ball: -0.07 %, within its interval).
    """
    from estimation.downsample import voxel_subsample
    from estimation.spacing import line_gap, point_spacing

    gap = line_gap(local)
    if gap < tol.LINE_GAP_CELLS * run.h:
        return None
    keep = voxel_subsample(local, gap)
    if len(keep) < tol.MIN_POINTS:
        return None  # lines too far apart for the object: a hundred points hold no shape to close
    progress(f"reconstructing again from one point per {1000 * gap:.3g} mm: the points lie along lines that far apart "
             f"({100 * unmeasured:.0f} % of the surface was unmeasured at {1000 * run.h:.3g} mm)")
    thinned = _auto_pass(cloud.subset(keep), box, local[keep], point_spacing(local[keep]), noise, tol.POINT_BUDGET,
                         density, viewpoint, stages)
    left = _unmeasured_share(thinned.surface)
    if left > unmeasured / 2:
        log.info("lines: a pass on one point per %.3g mm left %.1f %% unmeasured (%.1f %% at %.3g mm); not taken",
                 1000 * gap, 100 * left, 100 * unmeasured, 1000 * run.h)
        return None
    warnings.append(f"the points lie along lines {1000 * gap:.2g} mm apart, wider than the {1000 * run.h:.2g} mm cells "
                    f"their spacing along the lines gives ({100 * unmeasured:.0f} % of the surface was unmeasured at "
                    f"those): estimated from one point per {1000 * gap:.2g} mm at {1000 * thinned.h:.2g} mm cells; "
                    f"finer detail than the lines' gap is not resolved")
    return thinned


def _coarse_ratio(extents: np.ndarray, h: float, *, refine: bool) -> int:
    """Fine cells (``h`` metres) per coarse cell around a box of ``extents`` (metres).

    ``tol.COARSE_RESOLUTION`` cells along the longest side. Where the flood fill orients the normals
    (``refine``: none given, no viewpoint), an elongated or flat box gets as many finer cells as the same
    number of nodes holds (``tol.COARSE_RESOLUTION ** 3`` with the padding), down to ``tol.COARSE_REFINE``
    times finer: a box longer than that is far points, not an object, and the band check after refuses it
    as before. With normals it only closes holes, and finer cells would close smaller ones (a partial view's):
    the ratio stays the longest side's unless that exceeds ``tol.COARSE_REFINE``.
    """
    from estimation.grid import PAD_CELLS

    longest = max(2, int(np.ceil(float(extents.max()) / (h * tol.COARSE_RESOLUTION))))
    if not refine and longest <= tol.COARSE_REFINE:
        return longest
    # Past that, even with normals: each band block is ratio^3 nodes, nearly all far from any point, and the
    # signs are spread through them layer by layer (a 300 mm wire 2 mm thick, ratio 18: 11.8M band nodes for
    # 346k measured, 25 s and 2.8 GB; 1.3 s at 100 mm).

    def too_many(ratio: int) -> bool:
        return bool(np.prod(np.ceil(extents / (ratio * h)) + 2 * PAD_CELLS + 1) > float(tol.COARSE_RESOLUTION) ** 3)

    # The least ratio from the start whose grid holds the nodes (fewer nodes as the ratio grows), found by
    # bisection: counting up one at a time ran for hours on a cloud of copies 1e-12 m apart (a spacing that
    # made ``longest`` 7e8).
    low, high = max(2, -(-longest // tol.COARSE_REFINE)), longest
    if low >= high or not too_many(low):
        return low
    while high - low > 1:  # too_many(low), not too_many(high) (or high is ``longest``)
        middle = (low + high) // 2
        low, high = (middle, high) if too_many(middle) else (low, middle)
    return high


def _quiet(_: str) -> None:
    """No progress shown."""


def _spread_neighbours(points: np.ndarray, k: int, wanted: float) -> np.ndarray:
    """(n, k) indices: each point's ``k`` nearest among a seeded random share of ``points``, ``k / wanted``
    of them but at least ``tol.POINT_BUDGET``.

    A refining pass (``_estimate_auto``) takes more points than the first, and the ``k`` nearest of a denser
    cloud span a smaller patch: on a small part sampled densely it shrank inside the noise slab and its plane
    fit followed the noise (a 3.2 mm wire ring at sigma 0.5 mm, 100k points: the 96 nearest within 0.55 mm,
    83 % of its cells taken for creases, their vertices on the tangent planes, +5.8 %). Drawn from a share,
    the ``k`` span the patch ``wanted`` neighbours would, but no wider than the first pass's on its
    ``tol.POINT_BUDGET`` points: wider patches wrap round a thin wire (a 4 mm coil's, 2.6 mm across, took it
    from -9.7 to -10.2 %). The share is drawn by index, so it does not depend on where the points are.
    """
    from scipy.spatial import cKDTree

    from estimation.neighbours import nearest

    share = max(k + 1, int(len(points) * k / wanted), tol.POINT_BUDGET)
    reference = np.sort(np.random.default_rng(0).choice(len(points), min(share, len(points)), replace=False))
    return reference[nearest(cKDTree(points[reference]), points, k)[1]]


def _drop_strays(cloud: PointCloud, warnings: list[str], keep: bool) -> tuple[PointCloud, float]:
    """The cloud without its strays (``estimation.strays``; all of it with ``keep``), and its point spacing
    (metres); what was dropped, or kept, and a cloud in several parts go into ``warnings``."""
    from estimation.spacing import point_spacing
    from estimation.strays import STRAY_CELL_SPACINGS, STRAY_SHARE, islands

    spacing = point_spacing(cloud.points)
    found = islands(cloud.points, spacing)
    gap = f"{1000 * STRAY_CELL_SPACINGS * spacing:.2g} mm"
    if found.strays:
        what = (f"{found.strays} stray point(s) in {found.stray_islands} cluster(s) more than {gap} from the rest, "
                f"each under {100 * STRAY_SHARE:g} % of the points")
        if keep:
            warnings.append(f"kept {what} (keep_strays)")
        else:
            cloud = cloud.subset(found.keep)
            warnings.append(f"dropped {what}")
            spacing = point_spacing(cloud.points)
    if found.parts > 1:
        shares = ", ".join(f"{100 * s:.0f} %" for s in found.part_shares)
        warnings.append(f"the cloud is {found.parts} separate parts ({shares} of the points) more than {gap} apart: "
                        f"estimated as one rigid object (split the cloud if they are separate objects)")
    return cloud, spacing


def _area(surface) -> float:  # type: ignore[no-untyped-def]
    return float(triangle_areas(surface.vertices[surface.faces]).sum())


def _unmeasured_share(surface) -> float:  # type: ignore[no-untyped-def]
    """The share (0-1) of ``surface``'s area no point measured (``DualSurface.unmeasured_area`` over its area)."""
    return surface.unmeasured_area / max(_area(surface), 1e-30)


def _estimate_from_surface(
    cloud: PointCloud,
    box: OrientedBox,
    density: float,
    method: str,
    material: str | None,
    viewpoint: np.ndarray | None,
    resolution: int,
    warnings: list[str],
    stages: dict[str, float],
) -> PhysicalEstimate:
    from scipy.spatial import cKDTree

    from estimation.grid import grid_around, occupancy
    from estimation.normals import estimate_normals, orient_outward, orient_to_viewpoint

    # Work in the principal frame so the grid, and so the result, does not depend on the cloud's rotation.
    t0 = time.perf_counter()
    frame = box.rotation
    local = cloud.transformed(frame.T, -box.center @ frame)
    cell = float(box.extents.max()) / resolution
    points, normals, _ = voxel_downsample(local.points, tol.DOWNSAMPLE_CELL_FRACTION * cell, local.normals)
    tree = cKDTree(points)
    # Downsampling leaves about one point per cell on a dense cloud; on a sparse one the points stay
    # farther apart, and a grid finer than that would leave the voxel shell full of holes.
    spacing = _median_spacing(points, tree)
    if spacing > cell:
        cell = tol.MIN_CELL_SPACINGS * spacing
        points, normals, _ = voxel_downsample(local.points, tol.DOWNSAMPLE_CELL_FRACTION * cell, local.normals)
        tree = cKDTree(points)
    stages["downsample"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    grid = grid_around(points, cell)
    occ = occupancy(points, grid)
    if normals is None:
        normals = estimate_normals(points)
        if viewpoint is not None:
            view_local = (np.asarray(viewpoint, dtype=np.float64) - box.center) @ frame
            normals = orient_to_viewpoint(points, normals, view_local)
        else:
            normals = orient_outward(points, normals, grid, occ, tree)
    stages["normals"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if method == "auto":
        from estimation.implicit import signed_distance, surface_from_field

        mesh = surface_from_field(signed_distance(points, normals, grid, occ, tree), grid)
        vertices, faces, watertight, apex = np.asarray(mesh.vertices), np.asarray(mesh.faces), True, None
    else:
        from estimation.surface import triangulate

        vertices, faces = triangulate(points, normals, spacing)
        if len(faces) == 0:
            raise CloudError("the surface triangulation produced no faces (cloud too sparse?)")
        watertight, apex = _is_watertight(vertices, faces), np.zeros(3)  # apex: OBB centre, local frame
        if not watertight:
            warnings.append("surface triangulation is open: its volume depends on the OBB centre")
    stages["reconstruct"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    props = mass_properties(vertices, faces, density, apex=apex)
    props = _rotate_properties(props, frame, box.center)
    vertices = vertices @ frame.T + box.center
    stages["mass_properties"] = time.perf_counter() - t0
    return PhysicalEstimate(
        method=method, mass=props, obb=box, vertices=vertices, faces=np.asarray(faces, dtype=np.int64),
        watertight=watertight, points_in=len(cloud), points_used=len(points), cell=cell,
        timings=Timings(**stages), material=material, warnings=tuple(warnings),
        points=(points @ frame.T + box.center).astype(np.float32), normals=(normals @ frame.T).astype(np.float32),
    )


def _finish(method, cloud, used, box, vertices, faces, watertight, cell, density, material, warnings,
            stages, t0) -> PhysicalEstimate:  # type: ignore[no-untyped-def]
    props = mass_properties(vertices, faces, density)
    stages["mass_properties"] = time.perf_counter() - t0
    return PhysicalEstimate(
        method=method, mass=props, obb=box, vertices=np.asarray(vertices, dtype=np.float64),
        faces=np.asarray(faces, dtype=np.int64), watertight=watertight, points_in=len(cloud),
        points_used=used, cell=cell, timings=Timings(**stages), material=material, warnings=tuple(warnings),
    )


def from_mesh(vertices: np.ndarray, faces: np.ndarray, density: float, *,
              material: str | None = None) -> PhysicalEstimate:
    """The exact record of a known closed mesh (metres, outward faces): no cloud, no reconstruction.

    For reference models (the truth a twin is compared with) and for objects whose CAD mesh is known. A mesh
    that is not closed and consistently wound is estimated all the same, ``watertight`` False and a warning
    saying its volume is not a solid's (half a box's faces gave half its volume, without a word); one whose repeated
    faces are all that keeps it from being closed (coincident copies of a shell) counts each face once, with a
    warning. A mesh whose size suggests other units is warned of as :func:`estimate` warns of a cloud. A closed mesh
    whose closed parts overlap is the union of its parts: its record's surface and mass properties are the
    union's, with a warning (the sum over the faces counted the shared space twice); nested shells, a hollow
    object's outer shell and its inward-facing inner one, are the hollow solid they bound, as before. A part
    facing inward that lies in no solid (apart from the rest, or inside a cavity) is no cavity but a part wound
    inside out: it counts turned outward, with a warning (its volume was subtracted); so does a whole mesh wound
    inside out.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int, outward winding.
        density: kg/m^3.
        material: name recorded with the estimate.

    Raises:
        CloudError: vertices not a finite (v, 3) array within ``tol.MAX_COORDINATE_M``, faces not (f, 3) whole
            vertex indices within them, no volume enclosed, or a closed, consistently wound mesh with mass
            properties no solid has (a surface that passes through itself).
        MaterialError: as :func:`estimate`.
    """
    from estimation.contracts import as_faces
    from estimation.meshparts import overlap_union, turned_outward

    check_density(density)
    vertices = as_points(vertices, "mesh vertices")
    check_range(vertices, "mesh vertices")
    faces = as_faces(faces, len(vertices), "mesh faces")
    if len(vertices):
        across = float(np.ptp(vertices, axis=0).max())
        if across < tol.MIN_EXTENT_M:  # as a cloud's (check_estimable): a 10 nm box merged to "not closed"
            raise CloudError(f"mesh is {refused_number(across, tol.MIN_EXTENT_M, digits=3)} m across, below the "
                             f"{tol.MIN_EXTENT_M:g} m an estimate resolves (wrong units?)")
    t0 = time.perf_counter()
    merged = _merged(vertices, faces)
    watertight = _is_closed(merged)
    merged_vertices, merged_faces = np.asarray(merged.vertices), np.asarray(merged.faces, dtype=np.int64)
    warnings: tuple[str, ...] = ()
    if not watertight:
        # Two coincident copies of a closed box share each edge four ways: "not closed and consistently wound",
        # though each copy is, and twice the mass. Copies of one shell are its union, as overlapping parts are.
        distinct = _distinct_faces(merged_faces)
        if len(distinct) < len(merged_faces) and _is_closed(_merged(merged_vertices, distinct)):
            warnings += (f"the mesh holds {len(merged_faces) - len(distinct)} of its {len(merged_faces)} faces more "
                         f"than once (coincident copies of a closed shell): each counted once",)
            watertight, merged_faces = True, distinct
            vertices, faces = merged_vertices, merged_faces
        else:
            warnings += ("the mesh is not closed and consistently wound: its volume is a signed sum over its faces, "
                         "not a solid's",)
    # Before the sum over the faces: an inside-out part subtracted its volume (one alone gave none at all).
    turned = turned_outward(merged_vertices, merged_faces) if watertight else None
    if turned is not None:
        merged_faces = turned.faces
        vertices, faces = merged_vertices, merged_faces
        said = "the mesh is wound inside out (its faces face inward)" if turned.whole else (
            f"{turned.parts} of the mesh's {turned.total} closed parts "
            + ("is wound inside out (its faces face inward, but it lies in no solid, so it is no cavity)"
               if turned.parts == 1 else
               "are wound inside out (their faces face inward, but they lie in no solid, so they are no cavities)")
            + (f", and {turned.cavities} outward part(s) inside wound the same way, turned as cavities"
               if turned.cavities else ""))
        warnings += (f"{said}: counted turned outward ({turned.volume:.3g} m^3)",)
    try:
        props = mass_properties(vertices, faces, density)
    except ReconstructionError:  # the CloudError this docstring promised (mass_properties' error came through)
        raise CloudError("mesh encloses no volume (open, empty or inside-out)") from None
    overlap = overlap_union(merged_vertices, merged_faces) if watertight else None
    if overlap is not None and overlap.vertices is not None and overlap.faces is not None:
        vertices, faces = overlap.vertices, overlap.faces
        props = mass_properties(vertices, faces, density)
        warnings += (f"closed parts of the mesh overlap ({overlap.overlapping} of its {overlap.parts} parts): "
                     f"{overlap.shared:.3g} m^3 the sum over its faces counted more than once; its surface and mass "
                     f"properties are their union's",)
    elif overlap is not None:
        warnings += (f"closed parts of the mesh may overlap ({overlap.overlapping} of its {overlap.parts} parts have "
                     f"overlapping bounds) but their union was not formed ({overlap.unresolved}): its volume is the "
                     f"sum over its faces, which counts any space they share more than once",)
    # A mesh not closed and consistently wound is a signed sum, said so above; a closed one is a solid's, or it
    # passes through itself.
    if watertight and (why := _not_a_solid(props, vertices)) is not None:
        raise CloudError(f"the mesh's mass properties are no solid's ({why}): does it intersect itself?")
    box = oriented_box(vertices)
    if (hint := units_warning(box.extents)) is not None:  # as estimate() says of a cloud: a box in mm read as m
        warnings = (hint, *warnings)
    return PhysicalEstimate(
        method="mesh", mass=props, obb=box, vertices=vertices, faces=faces,
        watertight=watertight, points_in=0, points_used=0, cell=0.0,
        timings=Timings(mass_properties=time.perf_counter() - t0), material=material, warnings=warnings)


def _not_a_solid(props: MassProperties, vertices: np.ndarray) -> str | None:
    """What no solid of ``vertices`` (v, 3) metres could have in ``props`` (kg m^2, metres), or None.

    A closed, consistently wound surface that passes through itself counts some space twice and some less than
    never: a box with a corner pulled through its base summed to principal moments of -0.0032, -0.0029 and
    0.0005 kg m^2 and a centre of mass outside its vertices' box. Every solid's principal moments are positive
    and each is at most the sum of the other two (a flat plate's are equal to it), and its centre of mass lies
    within its vertices' bounds; a part per million covers rounding.
    """
    moments = props.principal_moments
    slack = 1e-6 * float(np.abs(moments).max(initial=0.0))
    if moments[0] <= -slack or moments[0] + moments[1] < moments[2] - slack:
        return f"principal moments {', '.join(f'{m:.3g}' for m in moments)} kg m^2"
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    margin = 1e-6 * float(np.max(high - low))
    if ((props.center_of_mass < low - margin) | (props.center_of_mass > high + margin)).any():
        return "its centre of mass lies outside its vertices' bounds"
    return None


def box_mesh(box: OrientedBox) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and outward faces of an oriented box."""
    import trimesh

    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = box.rotation, box.center
    mesh = trimesh.creation.box(extents=box.extents, transform=transform)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _median_spacing(points: np.ndarray, tree) -> float:  # type: ignore[no-untyped-def]
    """Median nearest-neighbour distance, metres, over at most 5000 of ``points``."""
    sample = points[:: max(1, len(points) // 5000)]
    return float(np.median(tree.query(sample, k=2, workers=-1)[0][:, 1]))


def _rotate_properties(props: MassProperties, frame: np.ndarray, center: np.ndarray) -> MassProperties:
    """Mass properties computed in the principal frame, expressed back in the cloud frame."""
    inertia = frame @ props.inertia @ frame.T
    axes = frame @ props.principal_axes
    return MassProperties(
        volume=props.volume, density=props.density, mass=props.mass,
        center_of_mass=frame @ props.center_of_mass + center, inertia=(inertia + inertia.T) / 2,
        principal_moments=props.principal_moments, principal_axes=axes,
    )


def _merged(vertices: np.ndarray, faces: np.ndarray):  # type: ignore[no-untyped-def]
    """The mesh as a ``trimesh.Trimesh`` with duplicate vertices merged (a triangle soup's faces joined)."""
    import trimesh

    return trimesh.Trimesh(vertices, faces, process=True)


def _distinct_faces(faces: np.ndarray) -> np.ndarray:
    """``faces`` without the repeats of a face (the same three vertices wound the same way), in their order; a
    face and its reverse are both kept (they bound no volume together, which the closed-mesh check then says)."""
    start = np.argmin(faces, axis=1)  # each face turned to start at its smallest index keeps its winding
    canonical = np.take_along_axis(faces, (start[:, None] + np.arange(3)) % 3, axis=1)
    _, first = np.unique(canonical, axis=0, return_index=True)
    return faces[np.sort(first)]


def _is_closed(mesh) -> bool:  # type: ignore[no-untyped-def]
    """True when a merged mesh (:func:`_merged`) is closed and consistently wound."""
    return bool(mesh.is_watertight and mesh.is_winding_consistent)


def _is_watertight(vertices: np.ndarray, faces: np.ndarray) -> bool:
    return _is_closed(_merged(vertices, faces))
