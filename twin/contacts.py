"""Which bodies touch which: the contact graph of a running model."""

from __future__ import annotations

import numpy as np


def contact_component(model, data, seeds: np.ndarray, geom_root: np.ndarray | None = None) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Bodies connected to any of ``seeds`` (root body ids) through the current contacts, seeds included.

    Returns a (nbody,) bool mask over root body ids. The world body (id 0: the table, the floor) is not a
    link, or everything resting on the table would be connected to everything else. A sleeping body has
    no contacts with other sleeping bodies (MuJoCo skips them), so a resting pile links nothing until
    something awake touches it. ``geom_root``: :func:`geom_roots` of the model, when called every step.
    """
    mask = np.zeros(model.nbody, dtype=bool)
    mask[seeds] = True
    n = data.ncon
    if n == 0 or len(seeds) == 0:
        return mask
    roots = (geom_roots(model) if geom_root is None else geom_root)[data.contact.geom[:n]]  # (n, 2)
    roots = roots[(roots != 0).all(axis=1)]
    while True:  # one contact hop per pass: a chain of k bodies takes k passes
        reached = roots[mask[roots].any(axis=1)].ravel()
        if mask[reached].all():
            return mask
        mask[reached] = True


def geom_roots(model) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The root body of every geom: (ngeom,) int."""
    return model.body_rootid[model.geom_bodyid]
