"""What the twin needs of one object: its estimate, a visual mesh and convex hulls, and where it is.

:class:`TwinObject` is the record every part of the twin reads; :func:`object_at_estimate` makes one from
an estimate (decimating the reconstruction and decomposing it with CoACD).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation import PhysicalEstimate
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings, Hull, decompose

log = logging.getLogger(__name__)

#: Faces kept in the visual mesh: enough to look right, light enough for a viewer and for CoACD.
VISUAL_FACES = 3000

#: fast-simplification's aggressiveness (0-10): 3 keeps the volume within 0.05 % on our test objects
#: where its default 7 lost up to 2.5 % on thin rings.
DECIMATION_AGGRESSION = 3.0

#: Friction for objects given by density only.
DEFAULT_FRICTION = 0.5


@dataclass(frozen=True)
class TwinObject:
    """One object ready for the model. Geometry is relative to the centre of mass (the body frame).

    Attributes:
        id: unique name in the scene.
        estimate: the physical estimate (mass, inertia in the body frame's axes).
        friction: sliding friction coefficient.
        visual: decimated reconstruction, vertices (v, 3) metres relative to the centre of mass.
        hulls: convex parts for collision, same frame.
        position: (3,) world position of the centre of mass, metres.
        quat: (4,) body orientation, w x y z (MuJoCo order).
        hull_cached: the hulls came from the CoACD cache.
    """

    id: str
    estimate: PhysicalEstimate
    friction: float
    visual: Hull
    hulls: tuple[Hull, ...]
    position: np.ndarray
    quat: np.ndarray
    hull_cached: bool = False


def decimate(vertices: np.ndarray, faces: np.ndarray, target: int = VISUAL_FACES) -> Hull:
    """Quadric decimation to about ``target`` faces (no-op when already smaller).

    The mesh is scaled to unit size first: the simplifier's error thresholds are absolute, and at the
    size of a cereal box in metres every collapse looked free (it cut 10-14 % off boxes' volume).
    A result that still moves the volume by more than 1 % is refused and the full mesh kept.
    """
    if len(faces) <= target:
        return vertices, faces
    import fast_simplification

    from estimation.inertia import signed_volumes

    scale = float(np.ptp(vertices, axis=0).max())
    v, f = fast_simplification.simplify(vertices / scale, faces.astype(np.int32), target_count=target,
                                        agg=DECIMATION_AGGRESSION)
    v, f = np.asarray(v, np.float64) * scale, np.asarray(f, np.int64)
    before, after = signed_volumes(vertices[faces]).sum(), signed_volumes(v[f]).sum()
    if abs(after / before - 1) > 0.01:
        log.warning("decimation changed the volume by %.1f %%; keeping the full mesh", 100 * (after / before - 1))
        return vertices, faces
    return v, f


def object_at_estimate(object_id: str, est: PhysicalEstimate, friction: float, *,
                       coacd: CoacdSettings = DEFAULT_SETTINGS, cache_dir: Path | None = None) -> TwinObject:
    """A twin object where its cloud was: body at the estimated centre of mass, world axes.

    What the synchronised twin builds from a remote cloud (no placement: the cloud says where it is).
    """
    visual = decimate(est.vertices - est.mass.center_of_mass, est.faces)
    hulls, cached = decompose(*visual, coacd, cache_dir=cache_dir)
    return TwinObject(id=object_id, estimate=est, friction=friction, visual=visual, hulls=tuple(hulls),
                      position=est.mass.center_of_mass.copy(), quat=np.array([1.0, 0, 0, 0]), hull_cached=cached)
