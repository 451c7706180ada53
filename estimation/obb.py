"""Oriented bounding box from the moment-of-inertia frame, as PCL's ``MomentOfInertiaEstimation`` does.

The paper's upper bound on volume: axes are the eigenvectors of the points' covariance, extents the
spread of the points along them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class OrientedBox:
    """A box in the cloud's frame.

    Attributes:
        center: (3,) metres.
        extents: (3,) full side lengths, metres, along ``rotation``'s columns (ordered by decreasing
            variance of the points, not by length).
        rotation: (3, 3) columns are the box axes in the cloud frame (a proper rotation, det = +1).
    """

    center: np.ndarray
    extents: np.ndarray
    rotation: np.ndarray

    @property
    def volume(self) -> float:
        return float(np.prod(self.extents))


def oriented_box(points: np.ndarray) -> OrientedBox:
    """OBB of ``points`` ((n, 3) float64, metres) from the covariance eigenvectors."""
    mean = points.mean(axis=0)
    centred = points - mean
    # eigh returns ascending eigenvalues; reverse so the first axis carries the largest spread.
    _, vectors = np.linalg.eigh(centred.T @ centred)
    axes = vectors[:, ::-1].copy()
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    local = centred @ axes
    low, high = local.min(axis=0), local.max(axis=0)
    center = mean + axes @ ((low + high) / 2)
    return OrientedBox(center=center, extents=high - low, rotation=axes)
