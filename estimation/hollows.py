"""Hollows: space the flood fill took for inside, which rays from it show is air.

The flood fill (``estimation.grid``) calls inside whatever its closing shell encloses. When the shell seals an
opening of the object's own (a bottle's mouth, a closed tin), the air behind it is enclosed too, and
without given normals nothing else says otherwise: the bottle came out filled, +385 %. Parity says it: a
ray from inside a solid crosses its surface an odd number of times before it reaches the outside; from the
air in a hollow it crosses the wall's two faces, an even number. Rays that cross nothing left through a
sealed opening (or a hole in the scan) and say nothing. Where a wall's two faces lie closer than about 1.6
spacings plus 5 noise sigmas, and (with noise) closer than the points' density tells apart, they are one sheet
to the rays: a 2 mm ball at sigma 0.5 mm stays filled.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import ndimage

from estimation.grid import Grid, Occupancy

#: Points whose distances to their neighbours set the dense test's reach (a median over 5000 is stable to ~1 %).
DENSE_SAMPLE = 5000

#: Rays cast from each origin (a Fibonacci sphere: even, and the same for every cloud in the box frame).
RAY_DIRECTIONS = 32

#: Origins per enclosed component: the deepest node and others drawn from its deeper half.
RAY_ORIGINS = 8

#: Enclosed components smaller than this many nodes are left as they are (crumbs pinched off by the shell).
MIN_COMPONENT_NODES = 8

#: A ray sample is on a sheet when a point lies within this many spacings plus ``NEAR_SIGMAS`` noise sigmas
#: of it: a sheet sampled at random at spacing s leaves a disc of radius 1.2 s empty with probability
#: exp(-pi 1.44) ~ 1 %, so a ray crossing a sheet is on it for one run; two faces 2.4 s apart stay two runs.
NEAR_SPACINGS = 1.2
NEAR_SIGMAS = 2.5

#: A second, finer reach for the first test: walls between about 1.6 and 2.4 spacings thick, one sheet at
#: ``NEAR_SPACINGS``, are two at this (a sheet is missed where no point lies this close, exp(-pi 0.64) ~ 13 % of
#: the crossings of a randomly sampled sheet, which moves a solid's even share far less than to a majority).
#: Without it a hollow ball with 2.5 mm walls and three 8 mm holes, 20k clean points (1.34 mm apart), came out
#: filled, +432 %, its interval not holding the truth. Measured on the first passes of bench/shapes.py's seeds 0
#: and 1 (20k and 100k points, clean and at sigma 0.5 mm): solids' even share at most 0.17 (0.13 at the first
#: reach); closed and holed balls and boxes with walls of 1.9-2.4 spacings 0.54-0.96 (0.00-0.10 at the first).
FINE_NEAR_SPACINGS = 0.8

#: Where the noise sets that reach (``NEAR_SIGMAS`` sigma > ``NEAR_SPACINGS`` spacings), the two faces of a wall
#: six sigmas thick merge under it; there a sample is also on a sheet when its ``DENSE_NEIGHBOURS``-th nearest
#: point is within ``DENSE_REACH`` times the points' own median distance to theirs: the points crowd in the
#: middle of each face's noise and thin out between the faces (three sigmas from each, ~45 times fewer).
#: Measured on bench/hollows.py's first passes (a wall unresolved, so one sheet) and its noisy closed box: at a
#: reach of 1.0 one sheet split into two runs on half the rays; at 1.2-1.3 on under 5 %, while the box's faces
#: still parted (0.71-0.77 of its rays even); the 8th or 16th neighbour merged them at any reach that kept
#: one sheet whole.
DENSE_NEIGHBOURS = 4
DENSE_REACH = 1.25

#: Ray step, in reaches: a run of a sheet crossed at any angle holds at least two steps.
STEP_NEARS = 0.5

#: A component is air when more than this share of the rays that crossed a sheet crossed an even number: a
#: majority. Over the solids of bench/shapes.py and bench/thin_parts.py (no normals, clean and at sigma 0.5 mm)
#: at most 0.23 of them did; over the hollows of bench/hollows.py that it opens, at least 0.55 (the noisy
#: bottle's, by the density test) and 0.97 clean.
EVEN_SHARE = 0.5

#: ...and at least this share of all its rays crossed a sheet (most did not leave through an opening).
CROSSING_SHARE = 0.25


def open_hollows(points: np.ndarray, grid: Grid, occ: Occupancy, *, tree, spacing: float,  # type: ignore[no-untyped-def]
                 noise: float) -> Occupancy:
    """``occ`` with every enclosed component that ray parity finds to be air moved to the outside.

    Args:
        points: (n, 3) metres, the cloud (box frame). grid: the flood fill's grid. occ: its occupancy.
        tree: a ``cKDTree`` over ``points``. spacing, noise: metres, the points' spacing and sigma.
    """
    inside = occ.inside
    labels, count = ndimage.label(inside)
    if count == 0:
        return occ
    reaches = [(1, NEAR_SPACINGS * spacing + NEAR_SIGMAS * noise), (1, FINE_NEAR_SPACINGS * spacing + NEAR_SIGMAS * noise)]
    if NEAR_SIGMAS * noise > NEAR_SPACINGS * spacing:
        sample = points[:: max(1, len(points) // DENSE_SAMPLE)]
        typical = float(np.median(tree.query(sample, k=DENSE_NEIGHBOURS + 1)[0][:, -1]))
        if typical > 0:  # not most points repeated (a quantised sensor): no reach to step by
            reaches.append((DENSE_NEIGHBOURS, DENSE_REACH * typical))
    directions = _fibonacci_sphere(RAY_DIRECTIONS)
    depth = ndimage.distance_transform_edt(inside)
    rng = np.random.default_rng(0)
    air = np.zeros(count + 1, dtype=bool)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    length = float(np.linalg.norm(np.asarray(grid.shape) * grid.cell))
    tests = [(k, near, np.arange(1, int(np.ceil(length / (STEP_NEARS * near))) + 1) * STEP_NEARS * near)
             for k, near in reaches]
    # Each component's nodes, from one sort of the labels (not one pass over the grid per component).
    order = np.argsort(labels, axis=None, kind="stable")
    starts = np.searchsorted(labels.ravel()[order], np.arange(count + 2))
    for component in np.flatnonzero(sizes[1:] >= MIN_COMPONENT_NODES) + 1:
        nodes = np.column_stack(np.unravel_index(order[starts[component]:starts[component + 1]], labels.shape))
        origins = grid.position(_origins(nodes, depth[tuple(nodes.T)], rng))
        for k, near, steps in tests:
            layers = np.concatenate([_layers(o, directions, steps, grid, occ, tree, k, near) for o in origins])
            crossed = layers > 0
            even = float((layers[crossed] % 2 == 0).mean()) if crossed.any() else 0.0
            if crossed.mean() >= CROSSING_SHARE and even > EVEN_SHARE:
                air[component] = True
                break
    if not air.any():
        return occ
    return replace(occ, outside=occ.outside | air[labels])


def _origins(nodes: np.ndarray, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Up to ``RAY_ORIGINS`` node indices (k, 3): the deepest and a seeded draw from the deeper half."""
    order = np.argsort(-depth, kind="stable")
    deeper = order[: max(1, len(order) // 2)]
    extra = rng.choice(deeper[1:], min(RAY_ORIGINS - 1, len(deeper) - 1), replace=False) if len(deeper) > 1 else []
    return nodes[np.concatenate([deeper[:1], np.asarray(extra, dtype=np.int64)])]


def _layers(origin: np.ndarray, directions: np.ndarray, steps: np.ndarray, grid: Grid, occ: Occupancy,
            tree, k: int, near: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Sheets of points each ray from ``origin`` (metres) crosses before it reaches the flood-filled outside
    (or leaves the grid): runs of samples whose ``k``-th nearest point is within ``near``. (rays,) int."""
    samples = origin + directions[:, None, :] * steps[None, :, None]  # (rays, steps, 3)
    index = grid.index_of(samples.reshape(-1, 3)).reshape(len(directions), len(steps), 3)
    within = np.all((index >= 0) & (index < np.asarray(grid.shape)), axis=2)
    safe = np.clip(index, 0, np.asarray(grid.shape) - 1)
    out = occ.outside[safe[..., 0], safe[..., 1], safe[..., 2]] | ~within
    # Samples from the first outside one on are past the object.
    past = np.cumsum(out, axis=1) > 0
    in_shell = occ.shell[safe[..., 0], safe[..., 1], safe[..., 2]] & ~past
    on_sheet = np.zeros(in_shell.shape, dtype=bool)
    if in_shell.any():
        distance = tree.query(samples[in_shell], k=[k], distance_upper_bound=near, workers=-1)[0]
        on_sheet[in_shell] = np.isfinite(distance[:, 0])
    starts = on_sheet & ~np.concatenate([np.zeros((len(directions), 1), dtype=bool), on_sheet[:, :-1]], axis=1)
    return starts.sum(axis=1)


def _fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
