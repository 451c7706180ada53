"""Sheets: points that lie in two sheets about one reconstructed surface, not one.

A wall thinner than a few noise sigmas has its two faces' points merge into one noisy sheet: the noise
measured over it is the wall's width plus the noise, the flood fill sees one surface, and a hollow ball
2 mm thick at sigma 0.5 mm came out solid, +552 %, with no warning. What the points still show is the shape of
their spread across the surface: one noisy face spreads as the noise does (Gaussian: kurtosis 3, or more with
outliers), two faces a wall apart as two such bumps side by side (flatter: kurtosis down to 1). So the signed
distances of the points to the surface say when the surface may have merged a wall, and how thick it may be.

The same flat spread comes from noise that is itself flat (depth quantised in steps wider than the noise) and
from views out of register (two copies of one face): in each, the cloud does not pin the surface to a layer
that thin either, so the warning is the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Points whose distance to the surface is measured: the kurtosis of that many draws is within about 0.06 of
#: the population's for a Gaussian (its standard error is sqrt(24 / n)).
SAMPLE = 8000

#: Below this kurtosis the spread is two sheets, not one. Over 63 solids whose cell the noise set (bench/shapes.py's
#: seeds 0 and 1, bench/thin_parts.py, bench/hollows.py, hollow balls with 3-4 mm walls; sigma 0.5 to 2 mm) one
#: face measured 2.89 to 3.23; hollow balls whose walls the noise merged (1.5-2.5 mm at sigma 0.5 mm) 1.64-2.17,
#: and 14 generated cups, trays, tubes, bowls and plates of 1.4-2.8 mm that came out +66 to +251 %, 1.73-2.44.
#: Six more thin ones (+7 to +112 %) measured 2.82-3.47: their surface follows one face, and the spread cannot tell.
TWO_SHEETS_KURTOSIS = 2.6


@dataclass(frozen=True)
class Spread:
    """How the points spread about the surface.

    Attributes:
        kurtosis: of their signed distances to it (3 for one Gaussian sheet, lower for two).
        spread: metres, the distances' standard deviation.
        separation: metres, the distance between two equal Gaussian sheets of that spread and kurtosis
            (0 when the kurtosis is 3 or more): the wall the surface may have merged.
    """

    kurtosis: float
    spread: float
    separation: float

    @property
    def two_sheets(self) -> bool:
        return self.kurtosis < TWO_SHEETS_KURTOSIS


def spread_about(points: np.ndarray, vertices: np.ndarray, normals: np.ndarray) -> Spread:
    """The spread of ``points`` about a surface given by its ``vertices`` and their outward unit ``normals``.

    Each point's distance is along the normal of its nearest vertex: on a surface contoured at a cell no
    coarser than the points' noise, that vertex is within a cell and its plane is the surface's to first order.

    Args:
        points: (n, 3) metres. vertices: (v, 3) metres, the same frame. normals: (v, 3) unit, outward.
    """
    from scipy.spatial import cKDTree

    sample = points[:: max(1, len(points) // SAMPLE)]
    nearest = cKDTree(vertices).query(sample)[1]
    distance = np.einsum("ij,ij->i", sample - vertices[nearest], normals[nearest])
    centred = distance - distance.mean()
    variance = float(np.mean(centred**2))
    if variance <= 0:
        return Spread(kurtosis=3.0, spread=0.0, separation=0.0)
    kurtosis = float(np.mean(centred**4)) / variance**2
    # Two Gaussians of sigma s at -a and +a: variance a^2 + s^2, fourth moment a^4 + 6 a^2 s^2 + 3 s^4, so
    # a^4 = (3 - kurtosis) variance^2 / 2.
    half = (max(0.0, 3.0 - kurtosis) / 2) ** 0.25 * variance**0.5
    return Spread(kurtosis=kurtosis, spread=variance**0.5, separation=2 * half)
