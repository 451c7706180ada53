"""Space carving: what the depth cameras prove empty, and the solid that is left around one object.

A depth pixel says more than where its surface point is: everything on its ray in front of that point is
empty. An object's unseen faces (the side no camera faced, the part hidden behind a neighbour) lie
somewhere in the space no ray passed through; carving every camera's free space out of a voxel grid
around the object leaves a solid that holds the object (an upper bound, the "visual hull" with depth).
Where rays pass close to the object (its silhouettes from several cameras, the table seen around it)
that solid is tight; where no ray gets near (under a ball, inside a ring's hole) it is loose. So the
solid's surface is used only where the object has nothing better: no observed point and no mirror image
(``estimation.completion``).

Conventions as in ``estimation.fusion``: pinhole cameras, OpenCV axes, depth along the camera's z,
NaN where there was no return; world frame, metres.

Noise: a voxel is free only when it lies in front of the measured depth by more than
``FREE_SIGMAS`` of that pixel's axial noise plus ``FREE_CELLS`` of a voxel (the voxel's centre is a
proxy for its whole extent). Edge pixels (flying pixels, ``fusion.edge_mask``) carve up to their nearest
neighbour's depth: left out, each silhouette casts a pixel-wide wedge nobody carves, and two views of an
L-bracket kept its concave corner (+11 % with exact depth). Pixels on the support plane carve down to the
fitted plane itself (it is known far better than one pixel's noise), which is what lets the table seen
around an object carve the space beside the object's base.

What a camera did not see is never free for it: space outside its frame, beyond its range, behind a pixel
without return. Nor is its frame's border an outline of the object: an object cut by a frame may run on out
of view (:func:`frame_cut`). The solid stands on what was seen; where no view looked past a cut
(:func:`open_past_frame`), nothing bounds the object there, and completion says so
(``completion.Completion.open_past_frame``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimation.contracts import as_points
from estimation.fusion import Intrinsics, depth_to_points, edge_mask
from estimation.segmentation import Plane

#: A voxel is free when it lies this many axial noise sigmas in front of the measured depth (one camera,
#: one pixel: at 1.5 sigma a surface voxel is carved by noise in ~7 % of pixels, and other cameras and
#: the mirror image cover what a stray carve removes) ...
FREE_SIGMAS = 1.5

#: ... plus this many voxel sizes (the centre stands for the whole voxel, half a cell each way).
FREE_CELLS = 0.5

#: A pixel near the support plane is taken as the plane only if it is no nearer the camera than the plane
#: by more than this many of its noise sigmas.
PLANE_SIGMAS = 2.0

#: A shadow whose principal spread is under this many times its second is round (:func:`plane_frame`): a disc
#: of noisy points is within 1.02, a 6 x 4 cm box's top seen at a slant 1.3 and more.
ROUND_SHADOW = 1.1

#: Voxels along the object's longest extent: the carved solid's resolution. Relative to the object so that
#: a 2 cm die and a 30 cm box cost the same (~1e5 voxels in the footprint); the carved surface is only
#: used where nothing was observed, so its cell bounds the error of unseen faces, not of seen ones.
CELLS_PER_EXTENT = 48

#: The finest carving a caller may ask for, voxels along the longest extent (cost ~ its square: the
#: footprint's area).
MAX_CELLS_PER_EXTENT = 128

#: Unseen space between two objects goes to the one whose observed points are nearer. Against what stands on an
#: object or what it stands on (other points higher than its ``100 - SPLIT_PERCENTILE`` percentile height, or lower
#: than its ``SPLIT_PERCENTILE``, less ``SPLIT_BAND_CELLS`` cells for the noise where the two meet), a height
#: difference counts this many times a distance across: at each height an object's sides are what bound it, and a
#: cube's hidden top was nearer the sides of the cube on it. Against a neighbour beside it, plainly: counted so
#: against every neighbour, two touching boxes of one height parted irregularly, the nearest sides 3 cm off
#: either way deciding by noise (tests/test_cameras.py's touching pair failed its frame check). Median / max |volume error| over
#: bench/stacks.py's stacks at 3 cameras (written; drawn at random), ``--split-weight`` 1: 2.2 / 30.2, 4.1 / 15.0 %;
#: 3: 2.3 / 31.1, 2.3 / 10.2 %; 6: 2.1 / 28.8, 1.7 / 9.7 %; 12: 1.7 / 25.5, 1.4 / 8.4 %, where two boxes side by
#: side go -2.2, -2.4, -2.4 and -4.8 %.
SPLIT_VERTICAL_WEIGHT = 6.0
SPLIT_PERCENTILE = 1.0
SPLIT_BAND_CELLS = 2

#: The region carved: the observed points' shadow on the plane, closed over gaps of up to this many point
#: spacings (dropouts, the sparse far side of a view) ...
FOOTPRINT_CLOSING_SPACINGS = 2.0

#: ... and grown by this many where a point's camera is not known (completed points: the half-turned image):
#: silhouette pixels are dropped as likely flying pixels, so every view's outline is about one spacing
#: inside the object's.
FOOTPRINT_GROW_SPACINGS = 1.0

#: Where it is known, each observed point reaches this many of its camera's pixel pitches further, on its own
#: surface (:func:`silhouette_reach`): a view's outline lies at least one pixel beyond its last kept pixel
#: (the edge pixel, dropped by ``fusion.edge_mask``, was on the object). Where in the next pixel it ends
#: depends on the edge: a crisp box edge runs on, a ball's limb or a rounded rim curves away. Counting half
#: of it as well (a crisp edge's average) put the clutter's 7 mm-tube hex nut at +4.7 % from 3 cameras
#: (+3.8 % before any reach, +3.6 % with the one pixel) and +19 % from one (bench/cameras.py, by hand).
SILHOUETTE_PIXELS = 1.0

#: A surface seen at more than ~75 degrees from its normal reaches at most 1 / this many pixel pitches per
#: pitch (depth sensors return little beyond that incidence, and a noisy normal there is no guide).
GRAZING_COSINE = 0.25

#: Samples of the points' reach (:func:`silhouette_reach`) rasterised at a time (memory: 24 bytes each).
REACH_SAMPLES = 1_000_000

#: Carved-surface points per boundary voxel face, per axis (2: four points a voxel, about the observed
#: points' density, so the reconstruction sees no hole between carved and observed surface).
SUBSAMPLE = 2

#: A point whose pixel centre lies within this many pixels of its own camera's image border (0: the outermost
#: row or column's centre) was cut by the frame (:func:`frame_cut`): the object may run on past it, out of
#: view. Not an edge: ``fusion.edge_mask`` sees no jump across the border, so the outermost row is kept, and
#: the half pixel more takes in the next row where the outermost was a dropout.
FRAME_BORDER_PIXELS = 1.5

#: The object is open past the frames (:func:`open_past_frame`) when no view had in its image the space just
#: past the border behind at least this share of the cut points. A view that does have it there misses about
#: 1 % of them (its own dropouts, 1 % of pixels at this project's sensors); five times that is the bar.
OPEN_SHARE = 0.05


#: A view given as points (:func:`depth_of_points`): its pixel pitch is the points' angular spacing, the
#: distance to the 8th nearest over sqrt(2) (a camera's grid comes back at its own pitch; scattered points
#: at about 1.3 a pixel) ...
POINT_IMAGE_NEIGHBOURS = 8

#: ... the image reaches this share of the points' extent beyond them on every side ...
POINT_IMAGE_MARGIN = 0.25

#: ... and has at most this many pixels a side (coarser pixels past it; 32 MB of depth) ...
POINT_IMAGE_MAX_PIXELS = 2048

#: ... points whose neighbours are measured for the spacing ...
POINT_IMAGE_SAMPLE = 20_000

#: ... the most points of one origin pictured (a 1920 x 1080 frame whole) ...
POINT_IMAGE_MAX_POINTS = 2_100_000

#: ... every point must lie within this angle of the image's axis (a pinhole's field of view) ...
POINT_IMAGE_MAX_ANGLE_DEG = 80.0

#: ... but for at most this share of them, left out of the picture: strays (one point 30 cm behind the sensor
#: voided its view's picture, so that no view carved and a box seen by two came out -67 %). Left out, a point
#: carves nothing; more than this many may be a view wider than a pinhole's, whose empty pixels would be read
#: as the support plane and carved down to it.
POINT_IMAGE_STRAY_SHARE = 0.001

#: ... and a cloud with more distinct sensor origins than this is not pictured (an origin per point is a
#: normal's direction, not a camera).
POINT_IMAGE_MAX_ORIGINS = 16


@dataclass(frozen=True)
class DepthView:
    """One depth image with its camera: what carving needs of a frame.

    Attributes:
        depth: (height, width) float64, metres along the camera's z, NaN where no return.
        sigma: (height, width) float64 metres (or a scalar): the axial noise of each pixel.
        intrinsics: the camera's.
        rotation: (3, 3) camera-to-world rotation; position: (3,) metres, the camera centre.
    """

    depth: np.ndarray
    sigma: np.ndarray | float
    intrinsics: Intrinsics
    rotation: np.ndarray
    position: np.ndarray


@dataclass(frozen=True)
class Carving:
    """The solid the cameras leave around one object, on a grid aligned with the support plane.

    Attributes:
        solid: (nu, nv, nk) bool: voxels no camera proved empty, in the object's footprint, owned by it.
        origin: (3,) metres, world frame: the corner of voxel (0, 0, 0) on the plane.
        axes: (3, 3) rows e1, e2, up: the grid's axes in the world (up = the plane's normal).
        cell: voxel size, metres.
    """

    solid: np.ndarray
    origin: np.ndarray
    axes: np.ndarray
    cell: float

    @property
    def volume(self) -> float:
        """m^3: every voxel nobody saw through counted as object (an upper bound, up to noise)."""
        return float(self.solid.sum()) * self.cell**3

    def centres(self, index: np.ndarray) -> np.ndarray:
        """World positions (n, 3) of voxel centres ``index`` (n, 3)."""
        return self.origin + ((np.asarray(index) + 0.5) * self.cell) @ self.axes

    def index_of(self, points: np.ndarray) -> np.ndarray:
        """Voxel indices (n, 3) int64 of world ``points`` (n, 3), metres; outside the grid as they fall."""
        return np.floor((np.asarray(points) - self.origin) @ self.axes.T / self.cell).astype(np.int64)


def depth_of_points(points: np.ndarray, origins: np.ndarray, plane: Plane) -> list[DepthView] | None:
    """The depth images a view's points imply, for a view that came as points with sensor origins only (a PCD
    with a VIEWPOINT, a cloud with an origin per point), so that it carves as depth frames do.

    A point says what its pixel says: the space on its ray in front of it is empty. Each distinct origin
    (at most ``POINT_IMAGE_MAX_ORIGINS``) gets a pinhole camera there, looking at its points' mean direction,
    its roll set by the plane's normal (a rigid motion of points, origins and plane gives the same image),
    its pixel pitch the points' own angular spacing (``POINT_IMAGE_NEIGHBOURS``: a camera's grid comes back
    at its pitch). A pixel holds its nearest point. More than ``POINT_IMAGE_MAX_POINTS`` points from one
    origin are pictured from a seeded random share of them, at the pitch that share has (a 4096 x 4096
    frame's k-d tree would take seconds and gigabytes). An empty pixel next to a
    filled one takes the nearest of its neighbours, as a real frame's edge pixels do in
    :func:`carving_views` (a depth sensor's flying pixels are dropped from its points, and left out each
    silhouette casts a wedge nobody carves: two views of an L-bracket came out +20 % instead of +6 %).

    The points are taken as cut from a frame of the scene: the rest of an empty background (what joins the
    image's border) is the support plane, cut away or beyond the cut; a ray there carves down to it. A real
    frame sees the table around the object, and without it the voxels above the footprint's rim stayed
    solid to the object's full height (the bracket with its table cut away by hand: +79 %, against +6 %
    from its frames). The price: a neighbour that hid part of the object and was cut away with the table
    is carved through. Holes enclosed by points (dropouts) stay without return: unknown, never carved.
    ``sigma`` is 0: the caller sets the views' noise.

    Args:
        points: (n, 3) float64 metres, world frame: every point of the view (the table and other objects
            carve too).
        origins: (3,) or (n, 3) metres: the sensor centre, or each point's.
        plane: the support plane (its normal fixes the images' roll; the background reaches it).

    Returns:
        The views, or None when the points cannot be pictured: more distinct origins than
        ``POINT_IMAGE_MAX_ORIGINS``, fewer than ``POINT_IMAGE_NEIGHBOURS`` + 1 points from one of them, or
        more than ``POINT_IMAGE_STRAY_SHARE`` of them further than ``POINT_IMAGE_MAX_ANGLE_DEG`` from its
        image's axis (or behind its sensor; fewer are left out).
    """
    pts = np.asarray(points, dtype=np.float64)
    org = np.broadcast_to(np.asarray(origins, dtype=np.float64), pts.shape)
    if len(org) and (org == org[0]).all():  # one sensor: sorting a million equal rows took half a second
        centres, which = org[:1], np.zeros(len(org), dtype=np.int64)
    else:
        centres, which = np.unique(org, axis=0, return_inverse=True)
    if len(centres) > POINT_IMAGE_MAX_ORIGINS:
        return None
    out = []
    for k, centre in enumerate(centres):
        view = _depth_of(pts[which.ravel() == k], centre, plane)
        if view is None:
            return None
        out.append(view)
    return out


def _depth_of(points: np.ndarray, origin: np.ndarray, plane: Plane) -> DepthView | None:
    """One origin's image for :func:`depth_of_points`."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    if len(points) > POINT_IMAGE_MAX_POINTS:
        points = points[np.random.default_rng(0).choice(len(points), POINT_IMAGE_MAX_POINTS, replace=False)]
    rel = points - origin
    if len(rel) <= POINT_IMAGE_NEIGHBOURS:
        return None
    ranges = np.linalg.norm(rel, axis=1)
    axis = (rel / np.maximum(ranges, np.finfo(float).tiny)[:, None]).mean(axis=0)
    if np.linalg.norm(axis) < 1e-9:
        return None
    z = axis / np.linalg.norm(axis)
    x = np.cross(z, plane.normal)  # OpenCV axes: x right, y down, z forward
    if np.linalg.norm(x) < 1e-6:  # looking straight down the plane's normal: any roll will do
        x = np.cross(z, np.eye(3)[np.argmin(np.abs(z))])
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z], axis=1)
    cam = rel @ rotation
    inside = cam[:, 2] > np.cos(np.radians(POINT_IMAGE_MAX_ANGLE_DEG)) * ranges
    if not inside.all():
        if (~inside).sum() > POINT_IMAGE_STRAY_SHARE * len(cam) or inside.sum() <= POINT_IMAGE_NEIGHBOURS:
            return None
        cam = cam[inside]
    uv = cam[:, :2] / cam[:, 2:3]
    # Measured at a sample of the points, among all of them (a strided subset's own neighbours are further
    # apart: whole 1280 x 720 frames were pictured at twice the camera's pitch, and a die came out +24 %).
    sample = uv[:: max(1, len(uv) // POINT_IMAGE_SAMPLE)]
    reach = cKDTree(uv).query(sample, k=POINT_IMAGE_NEIGHBOURS + 1, workers=-1)[0][:, -1]
    pitch = float(np.median(reach)) / np.sqrt(2.0)  # a square grid's 8th nearest lies at sqrt(2) pitches
    low, high = uv.min(axis=0), uv.max(axis=0)
    # Room round the points: a voxel above the footprint's rim must fall inside the image to be carved.
    low, high = low - POINT_IMAGE_MARGIN * (high - low), high + POINT_IMAGE_MARGIN * (high - low)
    pitch = max(pitch, float((high - low).max()) / POINT_IMAGE_MAX_PIXELS, np.finfo(float).eps)
    f = 1.0 / pitch
    width, height = (np.ceil((high - low) * f).astype(np.int64) + 1).tolist()
    cx, cy = -low[0] * f, -low[1] * f
    col = np.clip(np.floor(uv[:, 0] * f + cx).astype(np.int64), 0, width - 1)
    row = np.clip(np.floor(uv[:, 1] * f + cy).astype(np.int64), 0, height - 1)
    depth = np.full((height, width), np.inf)
    np.minimum.at(depth, (row, col), cam[:, 2])
    empty = ~np.isfinite(depth)
    depth[empty] = ndimage.minimum_filter(depth, size=3, mode="constant", cval=np.inf)[empty]
    intrinsics = Intrinsics(f, f, cx, cy, width, height)
    labels, _ = ndimage.label(~np.isfinite(depth))
    rim = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    background = np.isin(labels, rim[rim > 0])
    rays = intrinsics.rays()[background.ravel()]  # camera frame, z = 1: t is the depth
    along = rays @ (rotation.T @ plane.normal)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -(origin @ plane.normal + plane.offset) / along
    depth[background] = np.where(t > 0, t, np.nan)
    depth[~np.isfinite(depth)] = np.nan
    return DepthView(depth, 0.0, intrinsics, rotation, origin)


def carving_views(views: Sequence[DepthView], plane: Plane | None, plane_margin: float) -> list[DepthView]:
    """The views as carving reads them: edge pixels at their nearest neighbour's depth, support-plane pixels on
    the plane itself.

    A pixel whose point lies within ``plane_margin`` (metres) of ``plane`` takes the depth of its ray's
    intersection with the plane and zero noise. Done once per scan; every object's carving reads the result.
    """
    from scipy import ndimage

    out = []
    for view in views:
        sigma = np.broadcast_to(np.nan_to_num(np.asarray(view.sigma, dtype=np.float64), nan=0.0), view.depth.shape)
        # An edge pixel's depth may be a mix of the two sides (a flying pixel), but nothing lies nearer than
        # the nearest of its neighbours: it carves up to that.
        nearest = ndimage.minimum_filter(np.where(np.isfinite(view.depth), view.depth, np.inf), size=3)
        depth = np.where(edge_mask(view.depth, sigma), nearest, view.depth)
        depth = np.where(np.isfinite(depth), depth, np.nan)
        sigma = sigma.copy()
        if plane is not None:
            pts, idx = depth_to_points(depth, view.intrinsics, view.rotation, view.position)
            near = idx[np.abs(plane.height(pts)) <= plane_margin]
            rays = view.intrinsics.rays()[near] @ np.asarray(view.rotation, dtype=np.float64).T
            along = rays @ plane.normal
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -(np.asarray(view.position, dtype=np.float64) @ plane.normal + plane.offset) / along
            flat, noise = depth.reshape(-1), sigma.reshape(-1)
            # A pixel on an object's wall just above the plane is near it too, but nearer the camera than
            # the plane by more than its noise: it keeps its depth (replaced, the plane behind it would carve
            # into the wall).
            with np.errstate(invalid="ignore"):
                on = (np.abs(along) > 1e-9) & (flat[near] >= t - PLANE_SIGMAS * noise[near] - 1e-6)
            flat[near[on]] = t[on]
            noise[near[on]] = 0.0
        out.append(DepthView(depth, sigma, view.intrinsics, view.rotation, view.position))
    return out


def free_space(points: np.ndarray, views: Sequence[DepthView], *, slack: float = 0.0,
               blend_sigma: bool = False) -> np.ndarray:
    """(n,) bool: which ``points`` ((n, 3) metres, world) some view saw through (empty space).

    ``views`` as :func:`carving_views` returns them.
    The depth at a point's projection is interpolated bilinearly between the four nearest pixel centres
    (on a slanted surface the nearest pixel's depth is off by up to half a pixel's depth change); a
    point next to a pixel without return or off every image is not free. ``slack`` (metres) is added to
    the noise margin (see the module docstring). The margin takes the largest sigma of the four pixels, or
    with ``blend_sigma`` their sigmas blended as the depth is: beside an object the largest is its edge
    pixel's, and rays passing it to the plane (sigma 0) carried that margin, leaving the carved solid wider.
    """
    pts = as_points(points, "points")
    free = np.zeros(len(pts), dtype=bool)
    for view in views:
        depth, sigma = view.depth, np.asarray(view.sigma)
        ok, x, y, z = _pixels(pts, view)
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
        # Points off the image (not ok) read pixel 0 and are masked; an image one pixel wide (a view of one
        # repeated point, pictured by depth_of_points) has no pixel 1 for them to read.
        x1, y1 = np.minimum(x0 + 1, depth.shape[1] - 1), np.minimum(y0 + 1, depth.shape[0] - 1)
        ax, ay = x - x0, y - y0
        corners = ((y0, x0), (y0, x1), (y1, x0), (y1, x1))
        weights = ((1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay)
        d = _blend(depth, corners, weights)
        s = (_blend(sigma, corners, weights) if blend_sigma
             else np.maximum.reduce([sigma[r, c] for r, c in corners]))
        with np.errstate(invalid="ignore"):
            free |= ok & np.isfinite(d) & (z < d - FREE_SIGMAS * s - slack)
    return free


def _blend(image: np.ndarray, corners: tuple, weights: tuple) -> np.ndarray:
    """``image`` read at each of four pixel ``corners`` ((rows, cols) index arrays) and summed with ``weights``."""
    (r0, c0), (r1, c1), (r2, c2), (r3, c3) = corners
    return weights[0] * image[r0, c0] + weights[1] * image[r1, c1] + weights[2] * image[r2, c2] + weights[3] * image[r3, c3]


def frame_cut(points: np.ndarray, origins: np.ndarray, views: Sequence[DepthView]) -> tuple[np.ndarray, np.ndarray]:
    """Where the frames cut the object: the observed points on their own camera's image border
    (``FRAME_BORDER_PIXELS``), and for each, the place one pixel past that border at the point's depth.

    An object's outline in a frame is where its surface turns away or the next pixel's ray passes it by,
    except at the frame's border, which is only where the camera stopped looking: the object may run on
    past it. A point in a corner of the image is cut twice (once per side).

    Args:
        points, origins: (n, 3) float64 metres, world frame: observed points and each one's sensor origin
            (NaN rows, or an origin that is none of the ``views``' camera centres to 1 mm: not cut).
        views: the cameras' depth images.

    Returns:
        (index (m,) int64 into ``points``, past (m, 3) metres, world frame).
    """
    pts = np.asarray(points, dtype=np.float64)
    org = np.asarray(origins, dtype=np.float64)
    index, past = [np.zeros(0, dtype=np.int64)], [np.zeros((0, 3))]
    if not len(views) or not len(pts):
        return index[0], past[0]
    ok = np.isfinite(org).all(axis=1)
    centres = np.array([np.asarray(v.position, dtype=np.float64) for v in views])
    gap = np.linalg.norm(np.where(ok[:, None], org, 0.0)[:, None, :] - centres[None], axis=2)
    which = np.where(ok & (gap.min(axis=1) <= 1e-3), np.argmin(gap, axis=1), -1)
    for k, view in enumerate(views):
        mine = np.flatnonzero(which == k)
        if not len(mine):
            continue
        _, x, y, z = _pixels(pts[mine], view)
        intr = view.intrinsics
        rotation = np.asarray(view.rotation, dtype=np.float64)
        # Continuous pixel coordinates as in _pixels (centres at integers); past the border by one pixel.
        for row_edge, edge, beyond in ((False, 0, -1.0), (False, intr.width - 1, float(intr.width)),
                                       (True, 0, -1.0), (True, intr.height - 1, float(intr.height))):
            cut = (z > 0) & (np.abs((y if row_edge else x) - edge) < FRAME_BORDER_PIXELS)
            if not cut.any():
                continue
            px = x[cut] if row_edge else np.full(int(cut.sum()), beyond)
            py = np.full(int(cut.sum()), beyond) if row_edge else y[cut]
            zc = z[cut]
            cam = np.stack([(px + 0.5 - intr.cx) * zc / intr.fx, (py + 0.5 - intr.cy) * zc / intr.fy, zc], axis=1)
            index.append(mine[cut])
            past.append(cam @ rotation.T + np.asarray(view.position, dtype=np.float64))
    return np.concatenate(index), np.concatenate(past)


def framed(points: np.ndarray, views: Sequence[DepthView]) -> np.ndarray:
    """(n,) bool: which ``points`` ((n, 3) metres, world) some view had in its image, at a pixel with a return.

    Such a view looked there: it saw through the place, or saw a surface at it or in front of it (an object
    there would be in its points, and its outline in that view's). Outside every image, or on pixels
    without return (past a camera's range, a dropout), nobody looked.
    """
    pts = as_points(points, "points")
    seen = np.zeros(len(pts), dtype=bool)
    for view in views:
        k = view.intrinsics
        _, x, y, z = _pixels(pts, view)
        col, row = np.floor(x + 0.5).astype(np.int64), np.floor(y + 0.5).astype(np.int64)  # the pixel it falls in
        inside = (z > 1e-6) & (col >= 0) & (col < k.width) & (row >= 0) & (row < k.height)
        depth = view.depth[np.where(inside, row, 0), np.where(inside, col, 0)]
        seen |= inside & np.isfinite(depth)
    return seen


def open_past_frame(points: np.ndarray, origins: np.ndarray, views: Sequence[DepthView]) -> bool:
    """Whether the frames cut the object where no view looked past the cut (:func:`frame_cut`,
    :func:`framed`; at least ``OPEN_SHARE`` of the cut points): the object may run on out of every view, and
    nothing the cameras saw bounds its size. Where another view did look past the cut, its own points and
    outline bound the object there as anywhere else.

    Args:
        points, origins: (n, 3) float64 metres, world frame: observed points and their sensor origins.
        views: every camera's depth image (as :func:`carving_views` returns them).
    """
    index, past = frame_cut(points, origins, views)
    if not len(index):
        return False
    return bool((~framed(past, views)).mean() >= OPEN_SHARE)


def view_sigma(points: np.ndarray, views: Sequence[DepthView]) -> float:
    """Metres: the median depth sigma the views give at the pixels ``points`` ((n, 3) metres, world) fall
    on, over every view that has them in its image (NaN when none does)."""
    pts = as_points(points, "points")
    found = []
    for view in views:
        ok, x, y, _ = _pixels(pts, view)
        s = np.asarray(view.sigma)[np.floor(y[ok]).astype(np.int64), np.floor(x[ok]).astype(np.int64)]
        found.append(s[np.isfinite(s)])
    values = np.concatenate(found) if found else np.zeros(0)
    return float(np.median(values)) if len(values) else float("nan")


def _pixels(pts: np.ndarray, view: DepthView) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ok, x, y, z): which points are ahead of ``view`` with their 2 x 2 pixel neighbourhood in its image,
    their continuous pixel coordinates (pixel centres at integers) and their depths (metres)."""
    k = view.intrinsics
    cam = (pts - np.asarray(view.position, dtype=np.float64)) @ np.asarray(view.rotation, dtype=np.float64)
    z = cam[:, 2]
    ahead = z > 1e-6
    zs = np.where(ahead, z, 1.0)
    # The intrinsics put pixel centres at +0.5.
    x = k.fx * cam[:, 0] / zs + k.cx - 0.5
    y = k.fy * cam[:, 1] / zs + k.cy - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    ok = ahead & (x0 >= 0) & (x0 + 1 < k.width) & (y0 >= 0) & (y0 + 1 < k.height)
    return ok, x, y, z


def plane_frame(points: np.ndarray, plane: Plane, toward: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Axes that move with the object standing on ``plane``: (centre (3,), axes (3, 3) rows e1, e2, up, local
    (n, 3)): e1 the principal direction of the points' shadow on the plane, up the plane's normal; local
    holds each point's coordinates along e1 and e2 from the shadow's centre (metres) and its height above the
    plane. A grid or a size measured in world axes would change with every rotation of the scene.

    A round shadow (its two spreads within ``ROUND_SHADOW``) has no principal direction a rotation keeps; e1
    is then ``toward``'s part in the plane (the cameras' mean view direction), where it has one. Otherwise
    e1 points ``toward``'s way, or to the shadow's longer tail: the direction's sign is the SVD's choice,
    and a flipped grid cuts the object elsewhere (a can seen by one camera moved 1.4 % under rotations).
    """
    up = np.asarray(plane.normal, dtype=np.float64)
    flat = points - np.outer(points @ up, up)
    centre = flat.mean(axis=0)
    _, spread, vt = np.linalg.svd(flat - centre, full_matrices=False)
    axis = vt[0]
    level = None
    if toward is not None:
        toward = np.asarray(toward, dtype=np.float64)
        level = toward - (toward @ up) * up
    if level is not None and np.linalg.norm(level) > 1e-3:
        if spread[0] < ROUND_SHADOW * spread[1]:
            axis = level
        elif axis @ level < 0:
            axis = -axis  # the SVD's sign is arbitrary: flipped, the grid's cells fall elsewhere on the object
    elif np.sum(((flat - centre) @ axis) ** 3) < 0:
        axis = -axis
    e1 = axis - (axis @ up) * up
    e1 /= np.linalg.norm(e1)
    axes = np.stack([e1, np.cross(up, e1), up])
    local = (points - centre) @ axes.T
    local[:, 2] = plane.height(points)
    return centre, axes, local


def carve(points: np.ndarray, views: Sequence[DepthView], plane: Plane, *, others: np.ndarray | None = None,
          cell: float | None = None, origins: np.ndarray | None = None, normals: np.ndarray | None = None,
          toward: np.ndarray | None = None, blend_sigma: bool = False) -> Carving:
    """The solid around one object's observed ``points`` that no view saw through.

    It stands on the object's footprint: the points' shadow on the plane, gaps closed, and grown by how far
    the object may reach past each point unseen (:func:`silhouette_reach`; ``FOOTPRINT_GROW_SPACINGS``
    where that is not known). Only the growth away from the cameras matters: whatever the cameras saw
    through is carved anyway.

    Args:
        points: (n, 3) metres, world frame: the object's observed points (above the plane).
        views: the depth images that saw the scene (every camera, not only those that saw the object), as
            :func:`carving_views` returns them.
        plane: the support plane, normal up into the objects' side; the solid stands on it.
        origins, normals: (n, 3) each point's sensor origin (metres) and unit outward normal, world frame;
            NaN rows (or None) where not known (a completed point).
        others: (m, 3) observed points of other objects: a voxel nearer to one of them than to ``points``
            is theirs (unseen space between two objects is split between them; distances on the grid).
        cell: voxel size, metres; None: the longest extent over ``CELLS_PER_EXTENT``.
        toward: (3,) the cameras' mean view direction: the grid's axis where the shadow is round
            (:func:`plane_frame`).
        blend_sigma: the noise margin as :func:`free_space` takes it.
    """
    from scipy import ndimage

    from estimation.spacing import point_spacing

    pts = as_points(points, "points")
    up = np.asarray(plane.normal, dtype=np.float64)
    centre, axes, local = plane_frame(pts, plane, toward)
    e1 = axes[0]
    extent = float(np.ptp(local, axis=0).max())
    if cell is None:
        cell = max(extent / CELLS_PER_EXTENT, 1e-4)
    spacing = point_spacing(pts)
    closing = max(1, int(np.ceil(FOOTPRINT_CLOSING_SPACINGS * spacing / cell)))
    grow = max(1, int(np.ceil(FOOTPRINT_GROW_SPACINGS * spacing / cell)))
    reach = silhouette_reach(pts, origins, normals, views, up) if origins is not None and normals is not None else None
    known = np.zeros(len(pts), bool) if reach is None else np.isfinite(reach).all(axis=(1, 2))
    longest = float(np.linalg.norm(reach[known], axis=2).sum(axis=1).max()) if known.any() else 0.0  # type: ignore[index]
    pad = closing + max(grow, int(np.ceil(longest / cell))) + 1
    lo = np.floor(local[:, :2].min(axis=0) / cell).astype(np.int64) - pad
    hi = np.floor(local[:, :2].max(axis=0) / cell).astype(np.int64) + pad + 1
    top = int(np.ceil(local[:, 2].max() / cell)) + 1
    other = as_points(others, "others") if others is not None and len(others) else np.zeros((0, 3))
    theirs_local = (other - centre) @ axes.T
    theirs_local[:, 2] = plane.height(other)
    # Up to another object's lowest point above this one's highest: what lies between is hidden from every camera
    # (a box's upper sides under a book that overhangs it) and may be either's; the split below decides.
    inside = ((theirs_local[:, :2] >= lo * cell) & (theirs_local[:, :2] <= hi * cell)).all(axis=1)
    above = theirs_local[inside & (theirs_local[:, 2] > local[:, 2].max()), 2]
    if len(above):
        top = max(top, int(np.ceil(float(above.min()) / cell)) + 1)
    shape = (int(hi[0] - lo[0]), int(hi[1] - lo[1]), max(top, 1))
    origin = centre - plane.offset * up + (lo[0] * cell) * e1 + (lo[1] * cell) * axes[1]
    carving = Carving(np.zeros(shape, dtype=bool), origin, axes, float(cell))
    seen = np.clip(carving.index_of(pts), 0, np.array(shape) - 1)
    theirs = carving.index_of(other)
    # The footprint: the shadow of the observed points, each grown by what its camera may have missed past
    # it, gaps closed; the shadow of points whose camera is not known, gaps closed, grown by a spacing.
    shadow = np.zeros(shape[:2], dtype=bool)
    if known.any():
        _mark_reach(shadow, carving, pts[known], reach[known])  # type: ignore[index]
    rest = np.zeros(shape[:2], dtype=bool)
    rest[seen[~known, 0], seen[~known, 1]] = True
    shadow = ndimage.binary_closing(shadow | rest, iterations=closing)
    if not known.all():
        shadow |= ndimage.binary_dilation(ndimage.binary_closing(rest, iterations=closing), iterations=grow)
    # Where another object's points lie above this one's, within the convex hull of its shadow, its top is hidden,
    # not seen empty as a ring's hole is (an 8 cm cube under a 6 cm one, its shadow the ring of its sides: -49.9 %
    # at 3 cameras; at 2 they saw two of a cube's sides, no ring: -92.6 %; bench/stacks.py before session 43).
    over = theirs[((theirs[:, :2] >= 0) & (theirs[:, :2] < np.array(shape[:2]))).all(axis=1)
                  & (theirs[:, 2] > seen[:, 2].max())]
    if len(over):
        covered = np.zeros(shape[:2], dtype=bool)
        covered[over[:, 0], over[:, 1]] = True
        shadow |= _convex_cells(shadow) & ndimage.binary_closing(covered, iterations=closing)
    fi, fj = np.nonzero(shadow)
    k = np.arange(shape[2])
    index = np.stack([np.repeat(fi, shape[2]), np.repeat(fj, shape[2]), np.tile(k, len(fi))], axis=1)
    keep = ~free_space(carving.centres(index), views, slack=FREE_CELLS * cell, blend_sigma=blend_sigma)
    solid = carving.solid
    solid[index[keep, 0], index[keep, 1], index[keep, 2]] = True
    # Unseen space between two objects is split by the nearest observed point, on the grid (a distance
    # transform): other objects' points outside the grid are too far to claim a voxel of the footprint.
    theirs = theirs[((theirs >= 0) & (theirs < np.array(shape))).all(axis=1)]
    if len(theirs):
        mine_far = np.ones(shape, dtype=bool)
        mine_far[seen[:, 0], seen[:, 1], seen[:, 2]] = False
        # Points above this object's or below its lowest are of what stands on it or what it stands on: heights
        # count SPLIT_VERTICAL_WEIGHT times against those; a neighbour beside it is split with plainly.
        low, high = np.percentile(seen[:, 2], [SPLIT_PERCENTILE, 100 - SPLIT_PERCENTILE])
        stacked = (theirs[:, 2] > high - SPLIT_BAND_CELLS) | (theirs[:, 2] < low + SPLIT_BAND_CELLS)
        for group, sampling in ((theirs[~stacked], None), (theirs[stacked], (1.0, 1.0, SPLIT_VERTICAL_WEIGHT))):
            if len(group):
                their_far = np.ones(shape, dtype=bool)
                their_far[group[:, 0], group[:, 1], group[:, 2]] = False
                solid &= (ndimage.distance_transform_edt(mine_far, sampling=sampling)
                          <= ndimage.distance_transform_edt(their_far, sampling=sampling))
    # Only what hangs together with the observed points is this object.
    labels, _ = ndimage.label(solid)
    ids = np.unique(labels[seen[:, 0], seen[:, 1], seen[:, 2]])
    solid &= np.isin(labels, ids[ids > 0])
    return carving


def _convex_cells(mask: np.ndarray) -> np.ndarray:
    """The cells of a 2D grid whose centres lie in the convex hull of ``mask``'s True cells (their corners)."""
    from scipy.spatial import ConvexHull, QhullError

    i, j = np.nonzero(mask)
    corners = (np.stack([i, j], axis=1)[:, None, :] + np.array([[0, 0], [0, 1], [1, 0], [1, 1]])).reshape(-1, 2)
    try:
        hull = ConvexHull(corners)
    except (QhullError, ValueError):
        return mask.copy()
    ci, cj = np.indices(mask.shape)
    centres = np.stack([ci.ravel() + 0.5, cj.ravel() + 0.5], axis=1)
    inside = (centres @ hull.equations[:, :2].T + hull.equations[:, 2] <= 1e-9).all(axis=1)
    return inside.reshape(mask.shape) | mask


def silhouette_reach(points: np.ndarray, origins: np.ndarray, normals: np.ndarray, views: Sequence[DepthView],
                     up: np.ndarray) -> np.ndarray:
    """(n, 2, 3) metres, world frame: how far the object may reach past each point unseen, as two vectors:
    along its surface away from its camera (the ray's direction in the tangent plane) and across the ray
    (tangent too, either way), each ``SILHOUETTE_PIXELS`` of that camera's pixel pitch long on the surface.

    A pixel spans range / f across the ray, and that over the cosine of the incidence along it: a box's
    top seen from 30 degrees above the level reaches 2 pitches past its last row, away from the camera;
    its front face reaches 1.15 pitches down, not back. f is the focal length in the direction the reach
    runs in the image: fx along its rows, fy down its columns, between the two for others (square pixels:
    one f), so that each reach is ``SILHOUETTE_PIXELS`` long in the image whatever the pixels' aspect. Along the ray, no further than a level surface
    would (past a ball's limb) nor than 1 / ``GRAZING_COSINE`` pitches. NaN rows where a point has no
    origin or normal, or its origin is none of the ``views``' camera centres (to 1 mm).

    Args:
        points, origins, normals: (n, 3) float64, world frame: points and their sensor origins (metres),
            unit outward normals.
        views: the cameras (their centres and focal lengths).
        up: (3,) unit, the support plane's normal (what "level" means).
    """
    pts = np.asarray(points, dtype=np.float64)
    out = np.full((len(pts), 2, 3), np.nan)
    if not len(views) or not len(pts):
        return out
    centres = np.array([np.asarray(v.position, dtype=np.float64) for v in views])
    rotations = np.array([np.asarray(v.rotation, dtype=np.float64) for v in views])
    focal = np.array([(v.intrinsics.fx, v.intrinsics.fy) for v in views])
    org = np.asarray(origins, dtype=np.float64)
    ok = np.isfinite(org).all(axis=1) & np.isfinite(normals).all(axis=1)
    gap = np.linalg.norm(np.where(ok[:, None], org, 0.0)[:, None, :] - centres[None], axis=2)
    which = np.argmin(gap, axis=1)
    ok &= gap[np.arange(len(pts)), which] <= 1e-3
    ray = pts[ok] - org[ok]
    rng = np.linalg.norm(ray, axis=1)
    ray /= np.maximum(rng, 1e-12)[:, None]
    n = np.asarray(normals, dtype=np.float64)[ok]
    seen_by = which[ok]
    pitch = SILHOUETTE_PIXELS * rng
    cosine = np.abs(np.einsum("ij,ij->i", ray, n))
    along = ray - np.einsum("ij,ij->i", ray, n)[:, None] * n
    across = np.cross(n, ray)
    # Head on, the ray has no direction in the tangent plane: a pitch in any two tangent directions.
    tiny = np.linalg.norm(along, axis=1) < 1e-6
    helper = np.where((np.abs(n[:, :1]) < 0.9), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    along[tiny] = np.cross(n[tiny], helper[tiny])
    across[tiny] = np.cross(n[tiny], along[tiny])
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    # No further than on a level surface seen along the same ray: past a ball's or a lying can's limb the
    # incidence nears 90 degrees, but the surface curves away from the next ray instead of running on.
    level = np.abs(ray @ up)
    rot = rotations[seen_by]
    cam = np.einsum("nji,nj->ni", rot, pts[ok] - centres[seen_by])  # camera frame
    fx, fy = focal[seen_by, 0], focal[seen_by, 1]
    f_along = _focal_towards(along, cam, rot, fx, fy)
    f_across = _focal_towards(across, cam, rot, fx, fy)
    out[ok, 0] = along * (pitch / f_along / np.maximum(np.maximum(cosine, level), GRAZING_COSINE))[:, None]
    out[ok, 1] = across * (pitch / f_across)[:, None]
    return out


def _focal_towards(direction: np.ndarray, cam: np.ndarray, rotation: np.ndarray, fx: np.ndarray,
                   fy: np.ndarray) -> np.ndarray:
    """(n,) pixels per unit of angle in the image direction a step along ``direction`` takes from ``cam``:
    ``hypot(fx a, fy b) / hypot(a, b)`` for that direction (a, b) (the pinhole projection's derivative), between
    fx and fy; min(fx, fy) for a step along the ray (it moves nothing in the image).

    Args:
        direction: (n, 3) world frame, unit. cam: (n, 3) metres, each point in its camera's frame.
        rotation: (n, 3, 3) each point's camera-to-world rotation. fx, fy: (n,) that camera's, pixels.
    """
    d = np.einsum("nji,nj->ni", rotation, direction)  # camera frame
    a = d[:, 0] * cam[:, 2] - cam[:, 0] * d[:, 2]
    b = d[:, 1] * cam[:, 2] - cam[:, 1] * d[:, 2]
    size = np.hypot(a, b)
    moves = size > 0
    return np.where(moves, np.hypot(fx * a, fy * b) / np.where(moves, size, 1.0), np.minimum(fx, fy))


def _mark_reach(shadow: np.ndarray, carving: Carving, points: np.ndarray, reach: np.ndarray) -> None:
    """Mark in ``shadow`` (the grid's columns, (nu, nv) bool) each point's parallelogram on the plane, point +
    [0, 1] reach[0] +- reach[1] ((n, 3) points and (n, 2, 3) reach, metres), sampled no more than a cell apart.

    Away from the camera only: towards it, a point's neighbour was seen (or was hidden by something nearer,
    as the far rim of a ring's hole is behind the hole; grown that way, the hole would close)."""
    # In the plane, in cells: only the shadow is marked.
    flat = carving.axes[:2].T / carving.cell
    xy = (points - carving.origin) @ flat
    r = reach @ flat
    steps = [max(1, int(np.ceil(float(np.linalg.norm(r[:, k], axis=1).max())))) for k in range(2)]
    a = np.linspace(0.0, 1.0, steps[0] + 1)
    b = np.linspace(-1.0, 1.0, 2 * steps[1] + 1)
    ab = np.stack(np.meshgrid(a, b, indexing="ij"), axis=-1).reshape(-1, 2)
    chunk = max(1, REACH_SAMPLES // len(ab))  # bounded memory however fine the grid is against the pixels
    for start in range(0, len(points), chunk):
        p, q = xy[start:start + chunk], r[start:start + chunk]
        cells = np.floor(p[:, None, :] + ab[None, :, :1] * q[:, None, 0] + ab[None, :, 1:] * q[:, None, 1])
        cells = cells.reshape(-1, 2).astype(np.int64)
        inside = ((cells >= 0) & (cells < np.array(shadow.shape))).all(axis=1)
        shadow[cells[inside, 0], cells[inside, 1]] = True


def carved_surface(carving: Carving, views: Sequence[DepthView] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Points on the carved solid's surface and their outward normals, (m, 3) each, world frame.

    Normals are the gradient of the solid's occupancy smoothed over a voxel; points sit on the boundary
    voxels' outer faces less the carving margin (``FREE_CELLS``), ``SUBSAMPLE``^2 per voxel. Where one of
    ``views`` (those the solid was carved with) stopped the carving, its noise margin is taken back too
    (:func:`_noise_margin`).
    """
    from scipy import ndimage

    solid = carving.solid
    padded = np.pad(solid, 1)  # the plane under layer 0 and the footprint's edge are boundary
    boundary = solid & ~ndimage.binary_erosion(padded)[1:-1, 1:-1, 1:-1]
    index = np.argwhere(boundary)
    if len(index) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    smooth = ndimage.gaussian_filter(padded.astype(np.float64), 1.0)
    grad = np.stack(np.gradient(smooth), axis=-1)[index[:, 0] + 1, index[:, 1] + 1, index[:, 2] + 1]
    normal = -grad @ carving.axes  # grid axes to world
    length = np.linalg.norm(normal, axis=1)
    ok = length > 1e-9
    index, normal = index[ok], normal[ok] / length[ok, None]
    # The last solid voxel's outer face is up to FREE_CELLS of a cell in front of where the rays stopped:
    # the face less that margin.
    centre = carving.centres(index) + (0.5 - FREE_CELLS) * carving.cell * normal
    # Except on the plane: the solid stands on it exactly, with no carving margin.
    up = carving.axes[2]
    base = (index[:, 2] == 0) & (normal @ up < -0.5)
    centre[base] -= np.outer((centre[base] - carving.origin) @ up, up)
    back = _noise_margin(centre, normal, views, carving.cell)
    back[base] = 0.0
    centre -= back[:, None] * normal
    # Tangents from the grid's own axes, not the world's: the samples then move with the object.
    e1, e2 = carving.axes[0], carving.axes[1]
    helper = np.where(np.abs(normal @ e1)[:, None] < 0.9, e1, e2)
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    steps = (np.arange(SUBSAMPLE) + 0.5) / SUBSAMPLE - 0.5
    out = [centre + carving.cell * (a * t1 + b * t2) for a in steps for b in steps]
    return np.concatenate(out), np.tile(normal, (SUBSAMPLE * SUBSAMPLE, 1))


def _noise_margin(points: np.ndarray, normals: np.ndarray, views: Sequence[DepthView], cell: float) -> np.ndarray:
    """(n,) metres: how far in along its normal the surface a camera measured lies from each carved point.

    A camera carves up to ``FREE_SIGMAS`` of its pixel's noise in front of its depth (:func:`free_space`), so
    where its rays stopped the carving the solid's face stands that margin out (bench/camera_bias.py: at
    sigma 1 mm the carved points sat a median 0.87 mm outside the true surface before this, 0.11 mm with
    exact depth, and 0.14 mm at sigma 1 mm with no margin). A view stopped it
    at a point that lies within a ``cell`` of that view's stop along its ray (nearest pixel), facing the
    view; the margin counts along the normal by the cosine between ray and normal. Of several such views
    the least is taken: a voxel stays solid only if every view leaves it, so the view carving deepest
    bounds it. 0 where no view stopped it (a face hidden from every camera, bounded by rays that pass it).

    Args:
        points, normals: (n, 3) world frame: carved points (voxel centres less ``FREE_CELLS``, metres) and
            their unit outward normals.
        views: as :func:`carving_views` returns them. cell: the carving's voxel size, metres.
    """
    back = np.full(len(points), np.inf)
    for view in views:
        ok, x, y, z = _pixels(points, view)
        sigma = np.broadcast_to(np.asarray(view.sigma, dtype=np.float64), view.depth.shape)
        row = np.clip(np.floor(y + 0.5).astype(np.int64), 0, view.depth.shape[0] - 1)
        col = np.clip(np.floor(x + 0.5).astype(np.int64), 0, view.depth.shape[1] - 1)
        margin = FREE_SIGMAS * np.nan_to_num(sigma[row, col])
        ray = points - np.asarray(view.position, dtype=np.float64)
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
        facing = np.clip(-np.einsum("ij,ij->i", ray, normals), 0.0, 1.0)
        with np.errstate(invalid="ignore"):
            stop = ok & (np.abs(z - (view.depth[row, col] - margin - FREE_CELLS * cell)) <= cell)
        back = np.minimum(back, np.where(stop, margin * facing, np.inf))
    return np.where(np.isfinite(back), back, 0.0)
