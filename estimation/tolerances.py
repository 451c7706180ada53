"""Numerical tolerances and resolution defaults for estimation, each with the reason for its value.

Everything geometric is relative to the object's own size, so the same settings work for a 1 cm die and
a 1 m crate.
"""

from __future__ import annotations

#: Fewer points than this cannot fix a closed surface of any interest (a cube needs ~8 per face to
#: estimate normals with 10 neighbours); the CLI contract says "~100".
MIN_POINTS = 100

#: A cloud whose smallest principal extent is below this fraction of its largest is flat (a sheet) or
#: line-like: it encloses no volume. 1e-3 is a 1 mm thick sheet at 1 m, far below any real object.
FLATNESS_RATIO = 1e-3

#: Grid cells along the object's longest OBB side for the implicit reconstruction. 128 puts the
#: marching-cubes chord error below 0.05 % of volume on the paper's curved shapes (bench/paper_table.py)
#: while keeping a 1M-point estimate under a second on two cores.
GRID_RESOLUTION = 128

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

#: Extents outside this range (metres) probably mean the file is not in the units the caller said.
PLAUSIBLE_EXTENT_M = (0.002, 5.0)
