"""Numerical tolerances and resolution defaults for estimation, each with the reason for its value.

Everything geometric is relative to the object's own size, so the same settings work for a 1 cm die and
a 1 m crate.
"""

from __future__ import annotations

#: Fewer points than this cannot fix a closed surface of any interest (a cube needs ~8 per face to
#: estimate normals with 10 neighbours); the CLI contract says "~100". Distinct positions are counted: a
#: repeated row (a quantised sensor, rounded coordinates, copies of one scan) adds no surface.
MIN_POINTS = 100

#: Largest coordinate, metres, an estimate accepts. 10 km is beyond any object placed in a workspace
#: (PLAUSIBLE_EXTENT_M warns from 5 m) and keeps float64 resolution near 1e-12 m; far beyond it squared
#: distances overflow (a cloud at 1e50 m failed inside the SVD) or the file's units are simply wrong.
MAX_COORDINATE_M = 1e4

#: Smallest object extent, metres, an estimate accepts: 1 um, a thousandth of the smallest extent
#: PLAUSIBLE_EXTENT_M lets pass without a warning and below any depth sensor's resolution. Much smaller
#: clouds (1e-200 m) underflow the volumes (extent cubed) and spacings to zero.
MIN_EXTENT_M = 1e-6

#: A quaternion's norm must be within this of 1 (files carry ~7 significant digits; a wrong order or a
#: missing component is off by far more). Within it, the quaternion is normalised before use.
QUAT_NORM_TOLERANCE = 1e-3

#: A normal in a PointCloud built by hand must have a length within this of 1: float32 files and sums of
#: rounded components stay far inside it, an unnormalised or zero normal is far outside.
UNIT_NORMAL_TOLERANCE = 1e-3

#: A cloud whose smallest principal extent is below this fraction of its largest is flat (a sheet) or
#: line-like: it encloses no volume. 1e-3 is a 1 mm thick sheet at 1 m, far below any real object.
FLATNESS_RATIO = 1e-3

#: A point farther from a cloud's median than this many times the radius holding 99 % of its points is a
#: stray (a reflection, a point on the far wall), not the object: a flat or line-like verdict that such
#: points alone cause says so (``cloud.check_estimable``). 10x is far past any object's own tail.
OUTLIER_REACH = 10.0

#: 'auto': most fine nodes its narrow band may hold (tens of bytes each). The bench shapes need under 2 M at
#: 200k points (a thin torus 1.3 M); a 10 cm sphere with one stray point 1 km off asked for 4e11 (3.2 TiB).
MAX_BAND_NODES = 30_000_000

#: When the band is refused, its message blames clustered points (copies of one scan, points repeated with
#: a little jitter) if their spacing is this many times below extent / sqrt(n), the spacing of n points
#: spread over a surface of that extent. A sphere's spacing is about 1.8 times that, a 1 m wire 1 mm thick
#: 0.06 times; 20 copies of a 10 cm ball 1e-6 m apart, 0.003 times (the message named several objects).
CLUSTERED_SPACING = 100.0

#: Grid cells along the object's longest OBB side for the 'obb' downsampling and the 'surface'
#: method's grid. 'auto' takes its fine cell from the point spacing instead (``FINE_CELL_SPACINGS``).
GRID_RESOLUTION = 128

#: The ``resolution`` an estimate accepts: fewer than 8 cells across cannot hold an object's shape (1 cell
#: lost two thirds of a box without a word); past 1024 a dense grid outgrows memory (1024^3 cells).
MIN_RESOLUTION, MAX_RESOLUTION = 8, 1024

#: 'auto': fine cell as a multiple of the point spacing (square root of the surface area per point).
#: One spacing is the finest the points support: with about one point per cell every node near the
#: surface is within a cell of a point, and a wall two spacings thick has nodes inside it.
FINE_CELL_SPACINGS = 1.0

#: 'auto': fine cell at least this many noise standard deviations (``spacing.surface_noise``). Node
#: values average the plane distances of a cell's few points; with cells much finer than the noise
#: their scatter crosses zero and becomes bubbles and ripples of surface. Coarser cells cost walls:
#: at 3 sigma a 4 mm mug wall under 0.5 mm noise held both faces in many cells (+4 % volume), at 2
#: sigma -0.3 %, while thick shapes moved by under 0.2 %.
FINE_CELL_NOISE = 2.0

#: 'auto': most points (so about most surface cells: the cell is their spacing) the reconstruction
#: works from; denser clouds keep one measured point per voxel (``downsample.voxel_subsample``). Time
#: grows linearly with it, accuracy does not need more for the targets (0.25 % median, 1 % worst with
#: given normals): on the 44 shapes of ``bench/shapes.py`` at 100k points, with given normals, keeping
#: ~20k / 30k / 40k / all points gave volume median 0.021 / 0.018 / 0.012 / 0.014 %, worst 0.30 / 0.11 /
#: 0.09 / 0.06 %, centre of mass worst 0.20 / 0.13 / 0.14 / 0.06 mm, inertia worst 0.74 / 0.32 / 0.31 /
#: 0.24 % (``.venv/bin/python bench/shapes.py --no-baseline`` with this changed). 30k keeps a million
#: points within ~0.4 s of CPU. What it costs: walls thinner than two or three spacings of this many
#: points (a 1.6 mm wall on ~0.03 m^2 of surface) are resolved only when the first pass reports cells
#: holding both faces of a wall (``estimate._estimate_auto`` then refines, up to ``REFINE_POINTS``, and past
#: it where walls stay merged: ``FULL_POINTS``).
POINT_BUDGET = 30_000

#: 'auto' runs a second, finer pass when the first one's volume bounds (surface it did not measure,
#: cells holding both faces of a wall) exceed this fraction of the volume and points were left out.
#: On bench/shapes.py at 30k points the bound tracked the error: every shape off by more than 0.1 %
#: had a bound over 0.19 %, smooth shapes had ~0 (thin walls and sharp low-poly shapes carry it).
REFINE_DOUBT = 0.001

#: The second pass takes at least this many times the first pass's points (cells half as wide): the
#: bounds' hole term does not shrink with the square of the cell, and a pass barely finer than the
#: first (the paper cone's 0.111 % asked for 1.2x) bought nothing but its time.
REFINE_MIN_FACTOR = 4.0

#: Most points of the second pass: the old fixed budget, at which the benchmark's worst shape was
#: 0.06 % off with given normals (~1.5 s of CPU for its reconstruction).
REFINE_POINTS = 120_000

#: Most points the passes after the refining one take while it still leaves more than ``VOLUME_DOUBT_FRACTION``
#: of the volume in doubt (``estimate._with_more_points``): the size of the speed target's cloud.
FULL_POINTS = 1_000_000

#: ... and they run only where the last pass left unmeasured at most this share of what the pass before it left
#: unmeasured (or still merges walls): finer cells measured more of the surface there, so the points hold what
#: the cap thinned away. Measured, the second pass's unmeasured share over the first's: a star prism 0.55-0.63 and
#: an I-beam 0.24-0.65 (both shrank again on all the points), a scan of three faces of a box 1.00 (the rest unseen).
MEASURED_GAIN = 0.8

#: Occupied voxels per point budget: a random plane through a cube of side v cuts ~(2/3) v^2 of it
#: (Cauchy: volume over mean width 3/2 v), so a surface of area A touches ~1.5 A / v^2 voxels; the voxel
#: is widened by sqrt(1.5) to keep POINT_BUDGET, not 1.5 x POINT_BUDGET, points.
VOXELS_PER_AREA = 1.5

#: Most points the views of one object keep when fused (``views.estimate_views``), thinned one per voxel: the
#: estimate's own speed target is a 1M-point cloud, and it thins to ``REFINE_POINTS`` (at most ``FULL_POINTS``
#: where walls stay merged) anyway.
VIEW_POINTS = 1_000_000

#: 'auto': coarse cells along the longest side for the flood fill that decides inside and outside away
#: from the points (and closes holes); an elongated or flat object gets as many finer cells as the same
#: number of nodes (this cubed) holds. A 600 mm pipe with 3 mm walls got 128 cells of 5.5 mm along its
#: length, too coarse to see which side of a wall is its inside, and came out solid without normals
#: (+137 %); within the same nodes its cells are 2.8 mm (-0.2 %). The fine band lives inside its shell.
COARSE_RESOLUTION = 128

#: ...at most this many times finer than the longest side's cells (reached by an object 8^1.5, about 23, times
#: longer than wide): a kept point 1 km from a 10 cm ball made the extents 1 km by 10 cm, and the node budget gave
#: cells of 8 cm, the ball in one of them (2.5 times its volume); the longest side's rule refuses it.
COARSE_REFINE = 8

#: When the points are sparser than the grid (median spacing after downsampling over one cell; a dense
#: cloud sits at ~0.9), the cell grows to this many spacings: finer, cells hold no points and the shell
#: used for inside/outside has gaps.
MIN_CELL_SPACINGS = 1.1

#: Voxel size for downsampling, as a fraction of the reconstruction cell. One point per surface cell is
#: enough for the distance field (bench: < 0.07 % volume error on every paper object) and 4x cheaper
#: than half a cell.
DOWNSAMPLE_CELL_FRACTION = 1.0

#: Neighbours for normal estimation (PCA of the local covariance). 16 averages sensor noise well while
#: staying inside one face near edges at the downsampled spacing.
NORMAL_NEIGHBOURS = 16

#: At most this many neighbours when noise widens the normal fit (``estimate`` scales
#: ``NORMAL_NEIGHBOURS`` by the cell's area in point spacings): enough for 0.5 mm noise at 100k points
#: on a 10 cm object, and bounded in time.
MAX_NORMAL_NEIGHBOURS = 96

#: Extents outside this range (metres) probably mean the file is not in the units the caller said.
PLAUSIBLE_EXTENT_M = (0.002, 5.0)

#: A part of the volume the cloud cannot pin down (see ``PhysicalEstimate.volume_bounds_m3``) above
#: this fraction of the volume earns a warning: below it, it is within the method's own accuracy.
VOLUME_DOUBT_FRACTION = 0.005

#: How far, in noise variances times the mean curvature, noise can move a curved surface's reconstruction
#: (``PhysicalEstimate.volume_bounds_m3`` widens by this times sigma^2 times the integral of the mean curvature).
#: Isotropic noise sigma on a surface of mean curvature H moves the points' mean outward by sigma^2 H (their
#: tangential scatter lifts them off the curve) and the peak of their density inward by 2 sigma^2 H (the same
#: points spread over more area outside than inside); a reconstruction lands between. ``bench/noise_curvature.py``
#: (70 shapes at sigma 0.5 and 1 mm): the truth inside the interval for 68 and 64 of 70 with it, 43 and 37
#: without; the error was at most two thirds of the widening wherever the noise is under an eighth of the radius
#: of curvature (past a fifth, as on a 5 mm ball at 1 mm, the noise reads low and the widening falls short).
NOISE_CURVATURE_BIAS = 2.0

#: What a patch of surface no point measured may hide, as a share of its half width (twice its area over its
#: perimeter: a disc's radius, a strip's width): ``volume_bounds_m3`` widens by its area times this times that
#: half width, where that passes the closing shell's half width. A dome or a dent as deep as the patch is wide:
#: a hemisphere's volume over its base is 2/3 r. A wide hole's depth is not in the points: a mug whose inner floor
#: no point reached came out -12 %, the truth outside an interval of the shell's half width (the flood fill
#: took the base below the hole for outside).
HOLE_DEPTH_SHARE = 2.0 / 3.0

#: Facets on a curved surface: ``volume_bounds_m3`` widens by this times the slivers added back between the
#: facets and the surface (``curvature.bulge_volumes``, unsigned: a second-order model, its residual is of its
#: own size) and by this times the slivers left out where the surface turns faster than the cells resolve
#: (``curvature.unresolved_volumes``), which also count towards a refining pass. ``bench/curved_intervals.py``
#: measures it against 0 (the interval before session 41, of zero width on clean smooth clouds).
CHORDAL_DOUBT = 1.0

#: The noise's reach on a curved surface (above) earns a warning past this fraction of the volume: the error
#: was up to two thirds of the reach on the shapes measured, so past it the error may pass 1 %, the accuracy the
#: issue asks of noisy clouds at the median. (At ``VOLUME_DOUBT_FRACTION`` it warned for most shapes at 0.5 mm
#: noise, a 14 cm torus off by 0.01 % among them: sharp edges count in the curvature integral, and move less.)
NOISE_CURVATURE_WARN = 0.02

#: Noise below this share of the cell moves the surface by under a 200th of a cell wherever the grid resolves
#: the curvature (radius a cell or more): the curvature integral (a sort of every edge) is not worth its time.
NOISE_CURVATURE_MIN_CELLS = 0.05

#: A cloud whose coarse flood fill enclosed nothing and whose surface is more than this share unmeasured
#: is open (holes wider than the widest closing radius), not thin-walled: its volume interval reaches up to
#: the points' convex hull. A clean thin-walled cloud leaves almost nothing unmeasured (bench/shapes.py's
#: noisy mugs 1.2-1.3 %); clutter20's cereal box, its 28 x 19 cm back unseen, 44 %.
LEAK_UNMEASURED_SHARE = 0.1

#: The share of the surface's area whose spacing (``spacing.sparse_spacing``) says where a cloud is sampled
#: most sparsely: a tenth, so a few stray sparse patches do not set it, and a side seen from afar does.
SPARSE_AREA_SHARE = 0.1

#: A cloud is spaced unevenly when its sparsest parts' spacing is this many times the cell it was estimated
#: at: an evenly sampled one reads 1.3 times its typical spacing (44 shapes of ``scenes.shapes``: 1.30-1.31),
#: one sampled three times less densely on one half 2.1, ten times 3.7 (``estimate._at_sparse_spacing``).
UNEVEN_SPACING = 2.0

#: A cloud is sampled along lines (``spacing.line_gap``) where, past its noise, the median patch of 8 nearest points
#: spreads less than this share as much across as along (second over first principal variance). Measured (by
#: hand, 5,000 patches each): evenly sampled spheres and wires 0.44-0.58 clean and at sigma 0.5-1 mm, regular
#: grids 0.6-1.0, a box's faces on a 1 x 4 mm grid (a depth camera at a grazing angle) 0.33 with 0.1 mm of noise;
#: slices of a sphere, box and torus 2-4 mm apart, 0.1-0.3 mm along, 0.000-0.001 clean, 0.07-0.15 with 0.2 mm noise.
LINE_FLATNESS = 0.2

#: A cloud sampled along lines (``spacing.line_gap``) whose first pass left much of its surface unmeasured is estimated
#: again from one point per voxel of its lines' gap when that gap is this many cells or more (``estimate._along_lines``),
#: and the stray filter joins islands across the gap when it is this many spacings (``strays.islands``). Measured on an
#: outside probe's slices: lines 1.1-1.6 cells apart close today (a ball sliced every 2 mm with points 0.5
#: or 1 mm along, 2-3 % unmeasured), a box sliced every 1 mm (0.2 mm along) with its gap 1.34 first-pass cells did
#: not (16 % unmeasured, interval 0..inf m^3; -0.05 % and +-0.2 % once thinned to the gap).
LINE_GAP_CELLS = 1.25

#: Closed parts of one mesh overlap when the sum over its faces exceeds their union's volume by more than this
#: fraction of it (``estimation.meshparts``); a cavity lies in a part when their intersection is its volume to
#: within it. Parts whose bounding boxes overlap while they do not (a rod through a ring, a ball in a cavity)
#: differ by rounding, 1e-16 of the volume; an overlap worth a word, by many orders more.
MESH_OVERLAP_SHARE = 1e-9
