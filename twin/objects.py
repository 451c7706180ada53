"""What the twin needs of one object: its estimate, a visual mesh and convex hulls, and where it is.

:class:`TwinObject` is the record every part of the twin reads; :func:`object_at_estimate` makes one from
an estimate (decimating the reconstruction and decomposing it with CoACD). :func:`fit_primitive` says
when an object is so nearly a box, capsule or sphere that MuJoCo's own primitive can collide in its place
(much cheaper than meshes, and a ball rolls instead of resting on a facet).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation import PhysicalEstimate
from estimation.contracts import check_number, shown
from estimation.errors import SettingsError
from twin.decompose import DEFAULT_SETTINGS, CoacdSettings, Hull, decompose_many

log = logging.getLogger(__name__)

#: Faces kept in the visual mesh: enough to look right, light enough for a viewer and for CoACD.
VISUAL_FACES = 3000

#: Most faces a mesh may have: MuJoCo's STL reader refuses more ("number of faces should be between 1 and
#: 200000"), and a built folder's meshes are STL files.
MAX_MESH_FACES = 200_000

#: A decimation that moved the volume is tried again with this many times the faces (:func:`decimate`).
RETRY_FACTOR = 8

#: fast-simplification's aggressiveness (0-10): 3 keeps the volume within 0.05 % on our test objects
#: where its default 7 lost up to 2.5 % on thin rings.
DECIMATION_AGGRESSION = 3.0

#: An object that collides as one convex part collides as the hull of a subset of its surface's hull vertices
#: (:func:`estimation.hull.simplified_hull`) that leaves none of them more than this far outside, metres: about
#: as far as MuJoCo's soft contacts let an object sink into what it rests on at rest (0.1-0.16 mm, the median
#: of the random tabletops' objects). MuJoCo's own 64-vertex cap had rested a 9 cm blob 2.2 mm into the table
#: (an ellipsoid 2.7 mm, a capsule 1.0 mm), on the remote's simulated scene and in the twin alike.
HULL_TOLERANCE = 2e-4

#: ...with at most this many vertices (then some lie farther out: a 9 cm blob takes all 1024, bench/hull_sink.py).
#: CoACD's parts have at most ``CoacdSettings.max_ch_vertex``.
MAX_HULL_VERTICES = 1024

#: Friction for objects given by density only.
DEFAULT_FRICTION = 0.5

#: An object collides as one primitive when its volume over the fitted primitive's (the fill) is within
#: [this, 1 / this]. Measured (``bench/replay.py --fills``) on clutter20 and the paper scene, from 30k- and
#: 100k-point estimates and from the true meshes: every box, cylinder, capsule and sphere there fills
#: 0.96-1.0 of its primitive; the nearest other shape, the paper's chunk (a box with a corner cut off),
#: 0.86-0.92; tori, the mug, the cone, the stack and the bridge under 0.7.
PRIMITIVE_MIN_FILL = 0.94

#: Primitive kinds fitted, in MuJoCo's geom type names. Not "cylinder": MuJoCo collides
#: cylinders with boxes through its general convex routine, no cheaper than a hull (clutter20 awake: 6.5k
#: steps/s without cylinders, 6.3k with), and a cylinder lying on its side crept on its line contact (the
#: battery rolled 11 mm, 38 degrees, in 2 s at rest) where its prism hull rests on a facet.
PRIMITIVE_KINDS = ("box", "capsule", "sphere")

#: Metres: thinner capsules keep their hulls. MuJoCo's capsule-box contact loses its way once the capsule's
#: axis is inside the box, and the soft default contacts let an impact go deeper than a thin capsule's
#: radius: a 7 mm rod (a random tabletop's, toppling where it was placed) went through the 4 cm table top.
#: Dropped onto that table in 12 orientations from 0, 1, 3, 10 and 30 cm, capsules 8 cm long sank through it
#: all 12 times at 5 mm radius from any height, at 10 mm in 6 of 12 from 10 cm, at 15 mm in 4 of 12 from
#: 30 cm, at 20 mm never; convex-mesh capsules of 5-30 mm never did (``bench/capsule_drop.py``).
MIN_CAPSULE_RADIUS = 0.02

#: Fraction of the surface's vertices a fitted capsule may leave outside on each side. Dual contouring
#: leaves a few vertices at creases and corners up to 5 mm proud of the true surface (0.1-1 % of a
#: decimated 30k-point box's vertices); a primitive sized to contain them all was up to 20 % too large.
PRIMITIVE_TRIM = 0.01

#: Boxes and spheres are fitted to the median of the surface, not to its outer quantiles: a camera-built
#: surface is rough by the sensor's noise, and a box reaching its 1 % quantiles held a Kinect-scanned
#: 120 x 80 x 60 mm crate as 123 x 85 x 62 mm (looked at by hand; fill 0.88: refused, so it collided as
#: CoACD hulls and turned when pushed). The median says where the surface is, not how rough it is; whether it is the primitive's
#: shape is then :data:`PRIMITIVE_MAX_MISFIT`'s question. Samples are spread uniformly over the area (seeded:
#: the same mesh gives the same fit).
FIT_SAMPLES = 20_000

#: A surface sample nearest a box face counts as on it when its normal is within this angle of the face's:
#: wide enough for the tilted facets of a rough surface (on tests/test_primitives.py's 0.5 mm-rough box, 65 %
#: of the area is more than 30 degrees off and 12 % more than 45), narrow enough to leave out most of a
#: rounded edge's.
FACE_CONE_DEG = 60.0

#: The most of its volume, as area times the distance between surface and primitive summed over patches,
#: a median-fitted box or sphere may get wrong in and out together (the fill only sees the net). Each box
#: face is cut into 3 x 3 patches and a sphere into 24; a patch's distance is its median (noise averages
#: out, shape does not). Measured: camera-built boxes and spheres 0.005-0.028 at sigma 1 mm and 0.019-0.050
#: with the Kinect model where accepted (``bench/camera_fidelity.py``'s "collides as"; the Kinect dice is
#: refused); cylinders, jars and bottles as boxes 0.12-0.13 at fills of 0.91-0.92, the
#: paper's cone 0.28-0.31 at 0.94-0.95 (``bench/replay.py --fills``). tests/test_primitives.py refuses an
#: octagonal prism and an ellipsoid with axes 1 : 1 : 0.9, whose fills alone would pass. The same tolerance
#: as the fill's: the primitive is within 6 % of the object, net and gross.
PRIMITIVE_MAX_MISFIT = 1.0 - PRIMITIVE_MIN_FILL

#: A round primitive whose centre (sphere) or axis (cylinder, capsule) misses the centre of mass by less
#: than this fraction of its radius is moved onto it. Off by 0.1 mm (fitting noise: the estimated centre
#: of mass is good to 0.01 mm, the fitted centre to about 0.1 mm at 30k points), a resting orange rolled
#: 50 mm in 2 s like an unbalanced wheel; a mesh hull rests on a facet instead and never showed it.
ROUND_SNAP = 0.02

#: The misfit a round primitive's centre off by d alone makes, per d / radius: the volume between a sphere
#: and itself moved by d is d times the integral of |cos| over its surface, 2 pi r^2 d, over 4/3 pi r^3
#: (a cylinder's side: 4 / pi, less). Within the fit's own misfit the centre of mass cannot be told from
#: the fitted centre either: a noisier cloud (the Kinect model's tennis ball, misfit 0.047, its centre 0.78
#: mm = 2.4 % of the radius off) is snapped as far as its misfit allows, not rolled 16.5 mm.
MISFIT_PER_OFFSET = 1.5


@dataclass(frozen=True)
class Primitive:
    """A MuJoCo primitive geom that contains one convex hull and nearly equals it.

    Attributes:
        kind: "box", "cylinder", "capsule" or "sphere" (MuJoCo's geom type names).
        size: MuJoCo's geom size, metres: box half-extents; cylinder and capsule (radius, half-length of
            the axis or of the segment between the caps, 0); sphere (radius, 0, 0). Axis along local z.
        position: (3,) centre in the body frame (relative to the centre of mass), metres.
        quat: (4,) orientation in the body frame, w x y z (MuJoCo order).
        fill: the surface's volume over the primitive's.
        misfit: the volume between surface and primitive, in and out, over the surface's volume
            (:data:`PRIMITIVE_MAX_MISFIT`); 0 for a capsule (sized to contain the surface, not to its median).
    """

    kind: str
    size: tuple[float, float, float]
    position: np.ndarray
    quat: np.ndarray
    fill: float
    misfit: float = 0.0


@dataclass(frozen=True)
class TwinObject:
    """One object ready for the model. Geometry is relative to the centre of mass (the body frame).

    Attributes:
        id: unique name in the scene.
        estimate: the physical estimate (mass, inertia in the body frame's axes), with what the estimator
            warned of and the volume interval the cloud leaves open (``warnings``, ``volume_bounds_m3``): the
            record the twin keeps of the object and reports (:meth:`twin.runtime.Local.twin_object`, which
            keeps it without the full reconstruction and points: ``visual`` is what the twin draws).
        friction: sliding friction coefficient.
        visual: decimated reconstruction, vertices (v, 3) metres relative to the centre of mass.
        hulls: convex parts for collision, same frame; under a ``primitive``, the visual mesh's convex hull
            alone (CoACD is not run for what does not collide: :func:`collision_shapes`).
        position: (3,) world position of the centre of mass, metres.
        quat: (4,) body orientation, w x y z (MuJoCo order).
        hull_cached: the hulls came from the CoACD cache.
        primitive: what collides in place of the hulls (:func:`collision_primitive`), or None: the hulls.
            Fitted where the object is made, with its hulls (in a build or estimation worker), not where
            it is added to a model.
    """

    id: str
    estimate: PhysicalEstimate
    friction: float
    visual: Hull
    hulls: tuple[Hull, ...]
    position: np.ndarray
    quat: np.ndarray
    hull_cached: bool = False
    primitive: Primitive | None = None

    def __post_init__(self) -> None:
        """Refuse a friction MuJoCo would take and then run wrongly: NaN made the object's state non-finite
        at its first contact, -1 compiled and slid.

        Raises:
            SettingsError: ``friction`` not a finite number at least 0.
        """
        check_friction(self.friction, self.id)


def check_friction(friction: object, object_id: object) -> None:
    """Refuse a sliding friction coefficient that is not a finite number at least 0 (0: frictionless).

    Raises:
        SettingsError: naming the object and the value.
    """
    check_number(friction, f"friction of object {shown(object_id)}", error=SettingsError)


def fit_primitive(mesh: Hull, *, min_fill: float = PRIMITIVE_MIN_FILL,
                  max_misfit: float = PRIMITIVE_MAX_MISFIT) -> Primitive | None:
    """The primitive of :data:`PRIMITIVE_KINDS` whose volume is closest to what ``mesh`` encloses among
    those within ``max_misfit`` of its shape, or None when that volume ratio (the fill) is outside
    ``[min_fill, 1 / min_fill]``.

    Two frames are tried: the mesh's principal axes of inertia (exact for a box or cylinder, whatever
    spikes its surface has) and its smallest oriented bounding box (trimesh, from its convex hull's faces:
    a cube's principal axes are arbitrary, its faces are not). A box's faces and a sphere's radius then sit
    at the surface's median (:data:`FIT_SAMPLES`), the box turned onto planes fitted to its faces; capsules
    try each axis, sized by area-weighted trimmed quantiles of the vertices (:data:`PRIMITIVE_TRIM`).

    Args:
        mesh: vertices (v, 3) float64 metres, body frame; faces (f, 3) int, a closed outward surface.
    """
    import trimesh

    from estimation.inertia import mass_properties, signed_volumes, triangle_areas
    from twin.poses import matrix_quat

    vertices, faces = mesh
    tri = vertices[faces]
    volume = float(signed_volumes(tri).sum())
    if volume <= 0:
        return None
    surface = trimesh.Trimesh(vertices, faces, process=False)
    points, index = trimesh.sample.sample_surface(surface, FIT_SAMPLES, seed=0)
    samples = (points, surface.face_normals[index], float(surface.area) / FIT_SAMPLES)
    # Each vertex stands for a third of the area of the faces around it.
    weight = np.bincount(faces.ravel(), weights=np.repeat(triangle_areas(tri) / 3, 3), minlength=len(vertices))
    to_origin, _ = trimesh.bounds.oriented_bounds(vertices)
    obb = (to_origin[:3, :3].T, -to_origin[:3, :3].T @ to_origin[:3, 3])  # (axes as columns, centre)
    principal = (mass_properties(vertices, faces, 1.0).principal_axes, np.zeros(3))
    fits = [c for axes, origin in (obb, principal)
            for c in _box_and_sphere(*samples, volume, axes, origin) + _capsules(vertices, weight, volume, axes, origin)
            if c[1] in PRIMITIVE_KINDS and c[5] <= max_misfit]
    if not fits:
        return None
    # Best: the primitive whose volume is closest to the surface's, on a log scale.
    fill, kind, size, frame, position, misfit = min(fits, key=lambda c: abs(np.log(c[0])))
    if not min_fill <= fill <= 1 / min_fill:
        return None
    return Primitive(kind=kind, size=size, position=_on_centre(kind, position, frame[:, 2], size[0], misfit),
                     quat=matrix_quat(frame), fill=fill, misfit=misfit)


#: (fill, kind, size, frame (3, 3) columns in the body frame, centre (3,), misfit): one fitted primitive.
_Fit = tuple[float, str, tuple[float, float, float], np.ndarray, np.ndarray, float]


def _proper(axes: np.ndarray) -> np.ndarray:
    """``axes`` (columns) as a proper rotation, for the quaternion."""
    return axes * np.array([1.0, 1.0, np.sign(np.linalg.det(axes))])


def _box_and_sphere(points: np.ndarray, normals: np.ndarray, area: float, volume: float, axes: np.ndarray,
                    origin: np.ndarray) -> list[_Fit]:
    """A box and a sphere at the median of the surface samples (``points``, ``normals`` (n, 3), each
    standing for ``area`` m^2), with their misfits (:data:`PRIMITIVE_MAX_MISFIT`).

    From the samples' bounding box in ``axes``, three times over: each sample belongs to the box face it is
    nearest to (:func:`_nearest_faces`), each face moves to its samples' median, and between rounds the axes
    turn onto planes fitted to opposite faces (:func:`_face_normals`). The sphere shares the box's centre.
    """
    rot = _proper(axes)
    local = (points - origin) @ rot
    lo, hi = local.min(axis=0), local.max(axis=0)
    for rounds_left in (2, 1, 0):
        centre, half = (lo + hi) / 2, (hi - lo) / 2
        face, outward = _nearest_faces(local - centre, normals @ rot, half)
        if len(np.unique((2 * face + outward)[face >= 0])) < 6:
            return []  # a face with no surface: not a box, and no centre for a sphere
        for k in range(3):
            lo[k] = np.median(local[(face == k) & ~outward, k])
            hi[k] = np.median(local[(face == k) & outward, k])
        if rounds_left:
            turn = _proper(_face_normals(points, face, outward, rot))
            # The box turns about its centre: its bounds are re-read in the new axes.
            middle = origin + rot @ ((lo + hi) / 2)
            rot, local = turn, (points - origin) @ turn
            lo, hi = (middle - origin) @ rot - (hi - lo) / 2, (middle - origin) @ rot + (hi - lo) / 2
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    if not (half > 0).all():
        return []
    local = local - centre
    face, outward = _nearest_faces(local, normals @ rot, half)
    least = max(20, len(points) // 500)  # samples a patch needs to count
    box = 0.0
    for k in range(3):
        u, v = (k + 1) % 3, (k + 2) % 3
        for side in (False, True):
            on = (face == k) & (outward == side)
            patch = _thirds(local[on, u], half[u]) * 3 + _thirds(local[on, v], half[v])
            box += _patch_misfit(np.abs(local[on, k]) - half[k], patch, least)
    distance = np.linalg.norm(local, axis=1)
    r = float(np.median(distance))
    # 24 patches: which axis the direction is nearest to, on which side, and the other two signs.
    near = np.argmax(np.abs(local), axis=1)
    signs = (local > 0).astype(int)
    patch = near * 8 + np.take_along_axis(signs, np.stack([near, (near + 1) % 3, (near + 2) % 3], 1), 1) @ [4, 2, 1]
    sphere = _patch_misfit(distance - r, patch, least)
    position = origin + rot @ centre
    return [(volume / float(np.prod(2 * half)), "box", (float(half[0]), float(half[1]), float(half[2])), rot,
             position, box * area / volume),
            (volume / (4 / 3 * np.pi * r**3), "sphere", (r, 0.0, 0.0), rot, position, sphere * area / volume)]


def _face_normals(points: np.ndarray, face: np.ndarray, outward: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """The nearest rotation to the normals of planes fitted to each pair of opposite faces' samples (their
    least-variance direction, each face about its own mean), columns ordered and signed as ``rot``'s.
    Planes through the points, not mean facet normals: leaving out an edge's tilted facets biases the
    latter by a degree or two on a rough surface; the points' spread across the plane is unbiased."""
    axes = np.empty((3, 3))
    for k in range(3):
        scatter = np.zeros((3, 3))
        for side in (False, True):
            on = points[(face == k) & (outward == side)]
            on = on - on.mean(axis=0)
            scatter += on.T @ on
        normal = np.linalg.eigh(scatter)[1][:, 0]
        axes[:, k] = normal if normal @ rot[:, k] > 0 else -normal
    u, _, vt = np.linalg.svd(axes)
    return u @ vt


def _nearest_faces(local: np.ndarray, normals: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For points (n, 3) in a box's frame about its centre with half-extents ``half`` (3,) and their unit
    normals (n, 3) in the same frame: the axis (n,) of the face each is nearest to, -1 where the normal is
    more than :data:`FACE_CONE_DEG` off that face's (an edge's rounding, not the face), and whether that is
    the face on the axis's positive side (n,) bool."""
    face = np.argmin(np.abs(np.abs(local) - half), axis=1)
    outward = np.take_along_axis(local, face[:, None], 1)[:, 0] > 0
    along = np.take_along_axis(normals, face[:, None], 1)[:, 0] * np.where(outward, 1.0, -1.0)
    return np.where(along > np.cos(np.radians(FACE_CONE_DEG)), face, -1), outward


def _thirds(x: np.ndarray, half: float) -> np.ndarray:
    """0, 1 or 2: which third of [-half, half] each of ``x`` lies in (clipped)."""
    return np.clip(((x / half + 1) * 1.5).astype(int), 0, 2)


def _patch_misfit(distance: np.ndarray, patch: np.ndarray, least: int) -> float:
    """Sum over patches of (samples in it) x |median ``distance`` in it|, metres x samples; patches of fewer
    than ``least`` samples left out (a corner's sliver says nothing)."""
    total = 0.0
    for p in np.unique(patch):
        d = distance[patch == p]
        if len(d) >= least:
            total += len(d) * abs(float(np.median(d)))
    return total


def _capsules(vertices: np.ndarray, weight: np.ndarray, volume: float, axes: np.ndarray,
              origin: np.ndarray) -> list[_Fit]:
    """A capsule along each axis of ``axes`` (columns) about ``origin``, sized by area-weighted trimmed
    quantiles of the vertices (misfit 0: a capsule contains the surface, and its fill decides)."""
    rot = _proper(axes)
    local = (vertices - origin) @ rot
    lo = np.array([_quantile(local[:, k], weight, PRIMITIVE_TRIM) for k in range(3)])
    hi = np.array([_quantile(local[:, k], weight, 1 - PRIMITIVE_TRIM) for k in range(3)])
    centre = (lo + hi) / 2
    local = local - centre
    fits: list[_Fit] = []
    for axis in range(3):
        # The axis onto the geom's z, keeping a proper rotation (a cyclic permutation of the box axes).
        perm = np.eye(3)[:, [(axis + 1) % 3, (axis + 2) % 3, axis]]
        radial = np.hypot(local[:, (axis + 1) % 3], local[:, (axis + 2) % 3])
        r = _quantile(radial, weight, 1 - PRIMITIVE_TRIM)
        # The shortest segment whose caps of radius r reach the (trimmed) farthest points.
        reach = np.abs(local[:, axis]) - np.sqrt(np.maximum(r**2 - radial**2, 0.0))
        segment = _quantile(reach, weight, 1 - PRIMITIVE_TRIM)
        if segment > 0 and r >= MIN_CAPSULE_RADIUS:  # no segment: a sphere (MuJoCo refuses a capsule of zero length)
            fits.append((volume / (np.pi * r**2 * 2 * segment + 4 / 3 * np.pi * r**3), "capsule", (r, segment, 0.0),
                         rot @ perm, origin + rot @ centre, 0.0))
    return fits


def _on_centre(kind: str, position: np.ndarray, axis: np.ndarray, radius: float, misfit: float) -> np.ndarray:
    """A sphere's centre, or a cylinder's or capsule's axis, moved onto the centre of mass (the body
    origin) when it is off by less than :data:`ROUND_SNAP` of the radius, or than the offset the fit's own
    ``misfit`` allows (:data:`MISFIT_PER_OFFSET`); other positions as they are."""
    if kind == "sphere":
        off = position
    elif kind in ("cylinder", "capsule"):
        off = position - float(position @ axis) * axis
    else:
        return position
    limit = max(ROUND_SNAP, misfit / MISFIT_PER_OFFSET) * radius
    return position - off if float(np.linalg.norm(off)) < limit else position


def _quantile(values: np.ndarray, weight: np.ndarray, q: float) -> float:
    """The ``q`` quantile of ``values`` (n,) where each counts ``weight`` (n,) times (the lower value)."""
    order = np.argsort(values)
    cumulative = np.cumsum(weight[order])
    return float(values[order][min(int(np.searchsorted(cumulative, q * cumulative[-1])), len(values) - 1)])


def collision_primitive(obj: TwinObject, *, min_fill: float = PRIMITIVE_MIN_FILL,
                        max_misfit: float = PRIMITIVE_MAX_MISFIT) -> Primitive | None:
    """The primitive that may collide for the whole object (instead of its hulls), or None: what
    :attr:`TwinObject.primitive` holds for objects made by :func:`object_at_estimate` and the scene builder.

    Decided on the visual mesh (the decimated reconstruction) and its own volume: a mug or a torus fills
    its bounding cylinder far too little, whatever CoACD made of it; a box CoACD split in two is still one
    box.
    """
    return fit_primitive(obj.visual, min_fill=min_fill, max_misfit=max_misfit)


def lowest_point(obj: TwinObject) -> float:
    """The lowest world z, metres, of what collides for ``obj`` at its pose: its primitive where one
    collides in place of the hulls (:attr:`TwinObject.primitive`), else the hulls. The reconstruction's own
    fringe below a flat face (a few cells) does not collide under a primitive, so it does not count."""
    from twin.poses import rotation

    primitive = obj.primitive
    body = rotation(np.asarray(obj.quat, float))
    if primitive is None:
        return float(obj.position[2] + min(float((v @ body.T)[:, 2].min()) for v, _ in obj.hulls))
    frame = body @ rotation(np.asarray(primitive.quat, float))
    centre = float(obj.position[2] + (body @ primitive.position)[2])
    down = np.abs(frame[2])  # |z| of the primitive's local axes in the world
    a, b = primitive.size[0], primitive.size[1]
    if primitive.kind == "box":
        reach = float(down @ np.asarray(primitive.size))
    elif primitive.kind == "sphere":
        reach = a
    elif primitive.kind == "capsule":
        reach = down[2] * b + a
    else:  # cylinder: the rim's lowest point
        reach = down[2] * b + a * float(np.sqrt(max(0.0, 1.0 - down[2] ** 2)))
    return centre - reach


def decimate(vertices: np.ndarray, faces: np.ndarray, target: int = VISUAL_FACES) -> Hull:
    """Quadric decimation to about ``target`` faces (no-op when already smaller).

    The mesh is scaled to unit size first: the simplifier's error thresholds are absolute, and at the
    size of a cereal box in metres every collapse looked free (it cut 10-14 % off boxes' volume).
    A result that still moves the volume by more than 1 % is refused and the full mesh kept, unless it has more
    faces than MuJoCo's mesh files take (:data:`MAX_MESH_FACES`): then it is tried again with :data:`RETRY_FACTOR`
    times the faces, and the finest try is kept even if none holds the volume (the visual and CoACD's input; the
    mass properties are the estimate's).
    """
    if len(faces) <= target:
        return vertices, faces
    import fast_simplification

    from estimation.inertia import signed_volumes

    scale = float(np.ptp(vertices, axis=0).max())
    before = signed_volumes(vertices[faces]).sum()
    goal = target
    while True:
        v, f = fast_simplification.simplify(vertices / scale, faces.astype(np.int32), target_count=goal,
                                            agg=DECIMATION_AGGRESSION)
        v, f = np.asarray(v, np.float64) * scale, np.asarray(f, np.int64)
        change = signed_volumes(v[f]).sum() / before - 1
        if abs(change) <= 0.01:
            return v, f
        if len(faces) <= MAX_MESH_FACES:
            log.warning("decimation changed the volume by %.1f %%; keeping the full mesh", 100 * change)
            return vertices, faces
        if goal * RETRY_FACTOR > MAX_MESH_FACES:
            log.warning("decimation changed the volume by %.1f %%; kept all the same: the full mesh's %d faces are "
                        "more than MuJoCo's mesh files take (%d)", 100 * change, len(faces), MAX_MESH_FACES)
            return v, f
        goal *= RETRY_FACTOR


#: A closed piece of the estimated surface with less than this share of the largest piece's area is a speck
#: of noise (a bubble inside, a blob outside), not a part: the visual mesh and CoACD leave it out (the mass
#: properties keep it). A Kinect-noise scan of an apple came out as 18 pieces, the largest 90 % of the
#: area and the next 4 %, and CoACD crashed (SIGSEGV) on the whole; on its largest piece it did not.
SPECK_AREA_FRACTION = 0.1


def body_vertices(est: PhysicalEstimate) -> np.ndarray:
    """The estimate's full reconstruction's vertices (v, 3) in the body frame: metres from its centre of mass."""
    return est.vertices - est.mass.center_of_mass


def visual_mesh(est: PhysicalEstimate) -> Hull:
    """The estimate's surface as the twin shows and decomposes it: object frame (origin at the centre of
    mass), decimated (:func:`decimate`), specks of noise left out (``SPECK_AREA_FRACTION``). The specks are
    found after decimation: on the ~3000 faces, not the reconstruction's 50-80k (10-50 ms against 120-150
    ms, in every build and estimation worker)."""
    return without_specks(*decimate(body_vertices(est), est.faces))


def without_specks(vertices: np.ndarray, faces: np.ndarray) -> Hull:
    """The mesh's connected pieces of at least ``SPECK_AREA_FRACTION`` of the largest one's area.

    A mesh in one piece comes back as it was given (the same arrays: CoACD's cache keys do not change).
    """
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    pieces = mesh.split(only_watertight=False)
    if len(pieces) <= 1:
        return vertices, faces
    areas = np.array([p.area for p in pieces])
    kept = [p for p, a in zip(pieces, areas, strict=True) if a >= SPECK_AREA_FRACTION * areas.max()]
    log.info("left %d specks of noise out of the visual mesh (%.1f %% of its area)", len(pieces) - len(kept),
             100 * (1 - sum(p.area for p in kept) / areas.sum()))
    merged = trimesh.util.concatenate(kept)
    return np.asarray(merged.vertices, np.float64), np.asarray(merged.faces, np.int64)


def object_at_estimate(object_id: str, est: PhysicalEstimate, friction: float, *,
                       coacd: CoacdSettings = DEFAULT_SETTINGS, cache_dir: Path | None = None) -> TwinObject:
    """A twin object where its cloud was: body at the estimated centre of mass, world axes.

    What the synchronised twin builds from a remote cloud (no placement: the cloud says where it is).

    Raises:
        SettingsError: ``friction`` not a finite number at least 0 (checked before the mesh work).
    """
    check_friction(friction, object_id)
    visual = visual_mesh(est)
    ((hulls, cached, primitive),) = collision_shapes([visual], coacd, cache_dir=cache_dir, progress=False,
                                                     surfaces=[body_vertices(est)])
    return TwinObject(id=object_id, estimate=est, friction=friction, visual=visual, hulls=hulls,
                      position=est.mass.center_of_mass.copy(), quat=np.array([1.0, 0, 0, 0]), hull_cached=cached,
                      primitive=primitive)


def collision_shapes(visuals: list[Hull], coacd: CoacdSettings = DEFAULT_SETTINGS, *, cache_dir: Path | None = None,
                     progress: bool = True, surfaces: list[np.ndarray] | None = None
                     ) -> list[tuple[tuple[Hull, ...], bool, Primitive | None]]:
    """What collides for each visual mesh (body frame): (hulls, from CoACD's cache, primitive or None).

    A mesh that fits a primitive (:func:`fit_primitive`) collides as it, and its hulls are only its convex
    hull, for viewers: CoACD is not run for parts that would not collide (2-5 s each for a camera-scanned
    box, whose noise makes it read as concave). The others go to CoACD (:func:`twin.decompose.decompose_many`,
    cache misses in parallel).

    ``surfaces``: each visual's full-resolution vertices (same frame), when known. A mesh that collides as one
    convex part then collides as their convex hull, not the decimated mesh's: decimation moves a flat base's
    edge, and a camera-built pill bottle lying on its side rested turned 3.3 degrees on the decimated mesh's
    hull, 0.9 on the full one's (bench/camera_fidelity.py). That hull is thinned to the vertices that keep it
    within :data:`HULL_TOLERANCE` of the whole (:func:`estimation.hull.simplified_hull`).
    """
    from estimation.hull import convex_hull, simplified_hull

    primitives = [fit_primitive(v) for v in visuals]
    rest = [i for i, p in enumerate(primitives) if p is None]
    decomposed = dict(zip(rest, decompose_many([visuals[i] for i in rest], coacd, cache_dir=cache_dir,
                                               progress=progress), strict=True))
    if surfaces is not None:
        for i, (hulls, cached) in decomposed.items():
            if len(hulls) == 1 and len(surfaces[i]) >= 4:
                decomposed[i] = ([simplified_hull(np.asarray(surfaces[i], np.float64), HULL_TOLERANCE,
                                                  MAX_HULL_VERTICES)], cached)
    return [(tuple(decomposed[i][0]), decomposed[i][1], None) if p is None
            else ((convex_hull(visuals[i][0]),), False, p) for i, p in enumerate(primitives)]
