"""A narrow band of fine grid nodes around a cloud, indexed through a coarse dense grid.

The fine grid (spacing ``h``, from the point spacing) is never allocated densely. Only fine nodes whose
nearest coarse node (spacing ``B h``) lies in the coarse occupancy shell are stored: ``B**3`` of them
per shell node, in one flat array. A fine node's storage slot is found in O(1) through the coarse node's
slot number, so nothing is sorted or hashed. Memory and time grow with the surface area over ``h**2``
(the band is a few cells thick), not with the volume over ``h**3``. Fine nodes outside the band take
inside/outside from the coarse flood fill, which is what makes every level set closed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.grid import Grid, Occupancy


@dataclass(frozen=True)
class Band:
    """Fine nodes ``origin + h * i`` near the surface, ``i`` (3,) int, stored by coarse block.

    Attributes:
        coarse: the coarse grid (spacing ``ratio * h``) whose flood fill decides far nodes.
        occ: its occupancy (shell, outside).
        ratio: fine cells per coarse cell, B >= 2.
        slot: int32 array of ``coarse.shape``: block number of each shell coarse node, -1 elsewhere.
        blocks: (m, 3) int64 coarse indices of the shell nodes, in slot order.
        block_step: (m, 6) int64, the slot of each block's face neighbour (+x, -x, +y, -y, +z, -z),
            -1 where that coarse node is not in the shell.
        block_step_inside: (m, 6) bool, the coarse flood fill's inside for those neighbours.
    """

    coarse: Grid
    occ: Occupancy
    ratio: int
    slot: np.ndarray
    blocks: np.ndarray
    block_step: np.ndarray
    block_step_inside: np.ndarray

    def step(self, flat: np.ndarray, axis: int, direction: int) -> tuple[np.ndarray, np.ndarray]:
        """Face neighbours of band nodes ``flat`` along ``axis`` (+1 or -1 ``direction``).

        Returns:
            their band positions (-1 where outside the band), and for those outside the band whether
            the coarse flood fill puts them inside. Arithmetic within a block, one table look-up across.
        """
        b = self.ratio
        stride = b ** (2 - axis)
        block, local = np.divmod(flat, b**3)
        coord = (local // stride) % b
        crossing = coord == (b - 1 if direction > 0 else 0)
        column = 2 * axis + (0 if direction > 0 else 1)
        out = flat + direction * stride
        nbr_block = self.block_step[block[crossing], column]
        wrapped = local[crossing] - direction * (b - 1) * stride
        out[crossing] = np.where(nbr_block >= 0, nbr_block * b**3 + wrapped, -1)
        inside = np.zeros(len(flat), dtype=bool)
        inside[crossing] = self.block_step_inside[block[crossing], column]
        return out, inside

    @property
    def h(self) -> float:
        """Fine node spacing, metres."""
        return self.coarse.cell / self.ratio

    @property
    def origin(self) -> np.ndarray:
        return self.coarse.origin

    @property
    def size(self) -> int:
        """Number of band nodes."""
        return len(self.blocks) * self.ratio**3

    @property
    def dims(self) -> np.ndarray:
        """Fine index range along each axis (exclusive): fine indices stay in ``[0, dims)``."""
        return np.asarray(self.coarse.shape) * self.ratio

    def locate(self, index: np.ndarray) -> np.ndarray:
        """Band position (flat int64) of fine nodes ``index`` ((n, 3) int), -1 where not in the band."""
        b = self.ratio
        coarse = (index + b // 2) // b
        local = index + b // 2 - b * coarse
        inside = ((coarse >= 0) & (coarse < np.asarray(self.coarse.shape))).all(axis=1)
        coarse = np.where(inside[:, None], coarse, 0)
        block = self.slot[coarse[:, 0], coarse[:, 1], coarse[:, 2]].astype(np.int64)
        flat = block * b**3 + (local[:, 0] * b + local[:, 1]) * b + local[:, 2]
        return np.where(inside & (block >= 0), flat, -1)

    def far_inside(self, index: np.ndarray) -> np.ndarray:
        """For fine nodes outside the band: True where the coarse flood fill says inside."""
        b = self.ratio
        coarse = np.clip((index + b // 2) // b, 0, np.asarray(self.coarse.shape) - 1)
        return ~self.occ.outside[coarse[:, 0], coarse[:, 1], coarse[:, 2]]

    def index_of(self, flat: np.ndarray) -> np.ndarray:
        """Fine indices (n, 3) int64 of band positions ``flat``."""
        b = self.ratio
        block, local = np.divmod(flat, b**3)
        lx, rest = np.divmod(local, b * b)
        ly, lz = np.divmod(rest, b)
        return self.blocks[block] * b + np.stack([lx, ly, lz], axis=1) - b // 2

    def position(self, index: np.ndarray) -> np.ndarray:
        """Positions (n, 3) metres of fine indices (n, 3)."""
        return self.origin + index * self.h


def narrow_band(coarse: Grid, occ: Occupancy, ratio: int) -> Band:
    """The band of fine nodes (``ratio`` per coarse cell, >= 2) inside the coarse shell ``occ.shell``."""
    if ratio < 2:
        raise ValueError(f"ratio: expected >= 2 (a point's neighbour nodes must stay in the band), got {ratio}")
    blocks = np.argwhere(occ.shell).astype(np.int64)
    slot = np.full(coarse.shape, -1, dtype=np.int32)
    slot[blocks[:, 0], blocks[:, 1], blocks[:, 2]] = np.arange(len(blocks), dtype=np.int32)
    step = np.empty((len(blocks), 6), dtype=np.int64)
    step_inside = np.empty((len(blocks), 6), dtype=bool)
    for column, offset in enumerate(np.array([(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)])):
        # The shell stays PAD_CELLS - closing >= 2 nodes off the border, so neighbours are in range.
        nbr = blocks + offset
        step[:, column] = slot[nbr[:, 0], nbr[:, 1], nbr[:, 2]]
        step_inside[:, column] = ~occ.outside[nbr[:, 0], nbr[:, 1], nbr[:, 2]]
    return Band(coarse=coarse, occ=occ, ratio=ratio, slot=slot, blocks=blocks, block_step=step,
                block_step_inside=step_inside)
