"""A regular grid of sample nodes around a cloud, and inside/outside by flood fill.

The flood fill is what makes the project robust where the paper failed: a voxel shell of the points is
closed, so everything reachable from the grid border without crossing it is outside. That answers
"which side is out" for every normal and every far grid node, without a viewpoint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

#: Closing radii (cells) tried in turn when the shell leaks (holes in the cloud wider than a cell).
CLOSING_RADII = (1, 2, 3, 4, 5)

#: Empty cells kept between the data and the grid border: the widest shell plus two, so the border is
#: surely outside.
PAD_CELLS = max(CLOSING_RADII) + 2

#: Growing a closed shell by one cell encloses about one more surface layer: up to ~1.7x the occupied
#: node count on slanted faces, more where the shell curves outward. A jump beyond this many occupied
#: counts means the smaller radius leaked.
LEAK_JUMP_LAYERS = 4.0

#: A shell encloses the object's inside, not crumbs, when it holds at least this share of the occupied
#: node count inside it. Crumbs (pockets the shell pinches off a thin wall or a leaking cloud) held at
#: most 0.13 of it over bench/shapes.py's shapes; a 66 mm ball whose cameras missed a 20 mm patch closes
#: at 3 coarse cells with 0.36 inside (at the old bar of 1.0 it was refused and came out hollow, -50 %).
ENCLOSED_SHARE = 0.25


@dataclass(frozen=True)
class Grid:
    """Nodes ``origin + cell * (i, j, k)`` for ``0 <= (i, j, k) < shape``.

    Attributes:
        origin: (3,) metres, position of node (0, 0, 0).
        cell: node spacing, metres.
        shape: node counts along x, y, z.
    """

    origin: np.ndarray
    cell: float
    shape: tuple[int, int, int]

    def index_of(self, points: np.ndarray) -> np.ndarray:
        """Nearest node index (n, 3) int for points (n, 3) metres."""
        return np.rint((points - self.origin) / self.cell).astype(np.int64)

    def position(self, index: np.ndarray) -> np.ndarray:
        """Node positions (n, 3) metres for indices (n, 3)."""
        return self.origin + index * self.cell

    def fractional(self, points: np.ndarray) -> np.ndarray:
        """Continuous grid coordinates (3, n) for ``ndimage.map_coordinates``."""
        return ((points - self.origin) / self.cell).T


def grid_around(points: np.ndarray, cell: float, pad: int = PAD_CELLS) -> Grid:
    """The smallest grid of spacing ``cell`` covering ``points`` with ``pad`` empty cells each side."""
    low = points.min(axis=0) - pad * cell
    span = points.max(axis=0) + pad * cell - low
    shape = tuple(int(s) for s in np.ceil(span / cell).astype(int) + 1)
    return Grid(origin=low, cell=float(cell), shape=shape)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Occupancy:
    """Which nodes are near the surface, outside, or inside.

    Attributes:
        shell: bool grid, nodes within ``closing`` cells of a point (the band where the surface lies).
        outside: bool grid, nodes connected to the border without crossing the shell.
        closing: the dilation radius, in cells, that closed the shell.
        encloses: the shell encloses the object's inside (``ENCLOSED_SHARE``); False for a solid thinner
            than the shell, and for a cloud whose holes no closing radius closed (the flood leaked in).
        unsettled: nodes of the inside, and of the shell more than a cell from any point, when no closing
            radius closed the shell for good (a wider one enclosing no more) and the widest that encloses
            anything was taken: space behind walls thinner than the shell, or behind openings it sealed,
            which may be the object's own (a hollow ball's mouth). 0 when settled.
    """

    shell: np.ndarray
    outside: np.ndarray
    closing: int
    encloses: bool = True
    unsettled: int = 0

    @property
    def inside(self) -> np.ndarray:
        return ~self.shell & ~self.outside


def occupancy(points: np.ndarray, grid: Grid, air: Callable[[Occupancy], Occupancy] | None = None) -> Occupancy:
    """Flood-fill the outside of the voxel shell of ``points`` ((n, 3) metres).

    The shell is the occupied nodes dilated by a closing radius. Holes in the cloud wider than the
    shell let the flood into the interior, leaving nothing (or crumbs) inside; once they are closed, a
    larger radius only thickens the shell by about one surface layer. So we take the smallest radius
    that encloses something (``ENCLOSED_SHARE``) and after which growing it encloses no more than that.
    A solid thinner than the shell never encloses anything: it keeps radius 1 and the band decides every
    sign.

    ``air``, where given, takes what a shell encloses and returns it with the space that is not the
    object's moved outside (``estimation.hollows``): a shell that encloses only air (a bottle's mouth
    sealed) encloses nothing.
    """
    occupied = np.zeros(grid.shape, dtype=bool)
    idx = grid.index_of(points)
    occupied[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    surface_nodes = int(occupied.sum())
    # Dilating by a ball is thresholding the distance to the nearest occupied node: one distance
    # transform serves every radius (dilating by each ball in turn took 0.5 s of a 1M-point mug).
    distance2 = np.rint(ndimage.distance_transform_edt(~occupied) ** 2)
    results = []
    for radius in CLOSING_RADII:
        shell = distance2 <= _ball_radius2(radius)
        results.append(Occupancy(shell, _outside(shell), radius))
        if len(results) >= 2:
            before, after = results[-2], results[-1]
            jump = int((~after.outside).sum()) - int((~before.outside).sum())
            if before.inside.sum() > ENCLOSED_SHARE * surface_nodes and jump <= LEAK_JUMP_LAYERS * surface_nodes:
                return _without_air(before, air, results[0], surface_nodes)
    # Nothing closed for good: a thin-walled object (or a very open one). Crumbs enclosed by a wide
    # shell are not the object's inside; keep the thinnest shell and let the band decide.
    enclosing = [r for r in results if r.inside.sum() > ENCLOSED_SHARE * surface_nodes]
    if not enclosing:
        return replace(results[0], encloses=False)
    widest = _without_air(enclosing[-1], air, results[0], surface_nodes)
    if not widest.encloses:
        return widest
    return replace(widest, unsettled=int((~widest.outside & (distance2 > _ball_radius2(1))).sum()))


def _without_air(chosen: Occupancy, air: Callable[[Occupancy], Occupancy] | None, thinnest: Occupancy,
                 surface_nodes: int) -> Occupancy:
    """``chosen`` with its air moved outside; the thinnest shell, enclosing nothing, when only crumbs are left."""
    if air is None:
        return chosen
    opened = air(chosen)
    if opened.inside.sum() > ENCLOSED_SHARE * surface_nodes:
        return opened
    # The thinnest shell's free space, outside wherever it meets the opened outside (the air behind a
    # sealed opening, or a closed shell's hollow).
    labels, _ = ndimage.label(~thinnest.shell)
    reached = np.unique(labels[opened.outside & ~thinnest.shell])
    return replace(thinnest, outside=np.isin(labels, reached[reached > 0]), encloses=False)


def _outside(shell: np.ndarray) -> np.ndarray:
    """Face-connected empty region that touches the border."""
    labels, _ = ndimage.label(~shell)
    border = np.unique(
        np.concatenate(
            [labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(), labels[:, -1].ravel(),
             labels[:, :, 0].ravel(), labels[:, :, -1].ravel()]
        )
    )
    border = border[border > 0]
    return np.isin(labels, border)


def _ball_radius2(radius: int) -> int:
    """Squared node distance (cells^2) within which a closing ball of ``radius`` cells reaches."""
    # A radius-1 ball is the full 3x3x3 cube: diagonal neighbours close diagonal gaps in the shell.
    return max(radius**2, 3)
