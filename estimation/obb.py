"""Oriented bounding box from the moment-of-inertia frame, as PCL's ``MomentOfInertiaEstimation`` does.

The paper's upper bound on volume: axes are the eigenvectors of the points' covariance, extents the
spread of the points along them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.contracts import as_points
from estimation.errors import CloudError


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

    def to_local(self, vectors: np.ndarray, *, direction: bool = False) -> np.ndarray:
        """Points (or, with ``direction``, vectors) (n, 3) from the cloud frame into the box frame.

        ``(p - center) @ rotation``, written as an einsum: a BLAS product of an (n, 3) by a (3, 3) array
        spins up OpenBLAS's threads and cost ~6x the CPU time of this on a million points.
        """
        shifted = vectors if direction else vectors - self.center
        return np.einsum("ni,ij->nj", shifted, self.rotation)

    def to_cloud(self, vectors: np.ndarray, *, direction: bool = False) -> np.ndarray:
        """The inverse of :meth:`to_local`: points (or vectors) (n, 3) from the box frame to the cloud's."""
        turned = np.einsum("nj,ij->ni", vectors, self.rotation)
        return turned if direction else turned + self.center


def column_bounds(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column minimum and maximum of ``values`` ((n, d)).

    Column by column because numpy's ``min(axis=0)`` of an (n, 3) array is ~10x slower (26 ms against
    2 ms of CPU on a million points, where every pass counts).
    """
    return (np.array([values[:, i].min() for i in range(values.shape[1])]),
            np.array([values[:, i].max() for i in range(values.shape[1])]))


def column_mean(values: np.ndarray) -> np.ndarray:
    """Per-column mean of ``values`` ((n, d)); column by column for the reason in :func:`column_bounds`."""
    return np.array([values[:, i].mean() for i in range(values.shape[1])])


#: Points sampled (strided) to pick the axes' signs: the third moment of 20k points has the sign of the
#: full cloud's on any shape asymmetric enough for the sign to matter.
SKEW_SAMPLE = 20_000


def oriented_box(points: np.ndarray) -> OrientedBox:
    """OBB of ``points`` ((n, 3) float64, metres, at least one, finite) from the covariance eigenvectors.

    Raises:
        CloudError: as :func:`oriented_box_local`.
    """
    return oriented_box_local(points)[0]


def oriented_box_local(points: np.ndarray) -> tuple[OrientedBox, np.ndarray]:
    """:func:`oriented_box`, and ``points`` in the box frame ((n, 3) metres, origin at the box centre).

    The box frame is where 'auto' works; on a million points each pass over them costs ~10-25 ms of
    CPU, so the projection that finds the extents is handed on instead of being done twice.

    Raises:
        CloudError: ``points`` not a numeric (n, 3) array, empty, or holding NaN or inf (the eigenvectors
            of a NaN covariance did not converge).
    """
    # ~0.5 ms on a million points (a finite sum), against ~50 ms for the box.
    points = as_points(points, "points", min_rows=1)
    mean = column_mean(points)
    centred = points - mean
    # eigh returns ascending eigenvalues; reverse so the first axis carries the largest spread.
    with np.errstate(over="ignore", invalid="ignore"):
        scatter = centred.T @ centred
    if not np.isfinite(scatter).all():  # coordinates past 1e150: numpy's "Eigenvalues did not converge"
        raise CloudError(f"points: coordinates too large to measure (up to {float(np.abs(points).max()):.3g}); "
                         "are they in metres?")
    _, vectors = np.linalg.eigh(scatter)
    axes = vectors[:, ::-1].copy()
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    local = np.einsum("ni,ij->nj", centred, axes)  # not BLAS: see OrientedBox.to_local
    # Eigenvector signs are arbitrary, and a flipped axis mirrors every grid built in this frame (a rigid
    # motion of one bracket scan changed 'auto''s volume by 0.7 %): each of the first two axes points to
    # the side where the points' third moment (on a strided sample: cheap, and the same points whatever
    # the motion) is positive; the third keeps the frame right-handed. A shape symmetric along an axis
    # leaves that sign to the noise, as before.
    sample = local[:: max(1, len(local) // SKEW_SAMPLE), :2]
    sign = np.where(np.einsum("ni->i", sample**3) < 0, -1.0, 1.0)
    flip = np.array([sign[0], sign[1], sign[0] * sign[1]])
    if (flip < 0).any():
        axes *= flip
        local *= flip
    low, high = column_bounds(local)
    middle = (low + high) / 2
    local -= middle
    return OrientedBox(center=mean + axes @ middle, extents=high - low, rotation=axes), local
