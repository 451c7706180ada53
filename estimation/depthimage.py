"""Depth images from files: read, check, and back-project into a view of the object.

The formats and conventions are the common ones (ROS REP 118, Open3D's ``create_from_depth_image``, the
TUM and Redwood RGB-D datasets): a 16-bit single-channel PNG in millimetres, or a ``.npy`` (h, w) array
(float in metres, integer in millimetres). Zero and NaN mean "no return" and are dropped. Intrinsics are
OpenCV's pinhole ``fx fy cx cy`` in pixels with pixel centres at integer coordinates (what Open3D's
``PinholeCameraIntrinsic``, OpenCV's calibration and ROS ``camera_info`` give); the camera's axes are
OpenCV's (x right, y down, z forward) and depth is the z coordinate. The pose is camera-to-world, the
PCD ``VIEWPOINT`` form ``tx ty tz qw qx qy qz``; its translation is the view's sensor origin.

The back-projection itself is :func:`estimation.fusion.depth_to_points` (the same as for the simulated
cameras).
"""

from __future__ import annotations

import logging
import struct
import zlib
from pathlib import Path

import numpy as np

from estimation import tolerances as tol
from estimation.cloudfile import check_input_file
from estimation.contracts import unit_quaternion
from estimation.errors import CloudError, CloudFileError, refused_number
from estimation.fusion import Intrinsics, depth_to_points
from estimation.numpycloud import REAL_KINDS, npy_header

log = logging.getLogger(__name__)

#: Suffixes read as depth images when intrinsics are given.
DEPTH_SUFFIXES = (".png", ".npy")

#: Metres per stored unit when the caller gives none: integers are millimetres (16-bit PNG, the Kinect
#: and RealSense convention), floats are metres (REP 118's 32FC1).
INTEGER_DEPTH_SCALE = 0.001
FLOAT_DEPTH_SCALE = 1.0

#: A depth scale this large (metres per unit) is almost surely Open3D's inverse convention (units per
#: metre, 1000 for millimetres): 10 m per unit fits no depth sensor.
MAX_DEPTH_SCALE = 10.0

#: Most pixels a depth image may have: 4096 x 4096, twice a 4K frame's 8.3 M (no depth camera we know of comes
#: near it). Every pixel may become a point, and a point costs some 100 bytes on its way to an estimate: at the
#: 50 M of ``cloudfile.MAX_POINTS`` an 84 kB PNG of one constant depth, 6000 x 6000, took 3.4 GB.
MAX_DEPTH_PIXELS = 4096 * 4096

#: Most pixels of one depth image made into points (``coarsened``): a 1920 x 1080 frame passes whole; a larger
#: one is read every 2nd, 3rd ... row and column.
MAX_VIEW_PIXELS = 1920 * 1080

#: Smallest depth scale, metres per unit: a micrometre, finer than any sensor stores depth (RealSense's
#: finest depth unit is 1e-5 m); far below it every depth collapses under ``tolerances.MIN_EXTENT_M``.
MIN_DEPTH_SCALE = 1e-6

#: Focal lengths, pixels, a camera can have: 1 px is a ~180 degree view across a 100-pixel image, 1e6 px a
#: 0.01 degree one, past any lens we will see; outside, rays reach 1e300 m or all pixels collapse to one.
FOCAL_RANGE_PX = (1.0, 1e6)

#: Largest fx / fy (or fy / fx) taken: how far from square a pixel may be. Depth cameras have square pixels
#: (RealSense and Kinect calibrations give fx and fy within 1 % of each other); the most anisotropic pixels
#: imaging uses are 2:1 (a 2x anamorphic lens, or 1 x 2 binning on a sensor; video's non-square pixels, ITU-R
#: BT.601's 10:11 to HDV's 4:3, are nearer 1). 4 takes both at once; past it the numbers are a typo (a digit too
#: many or too few is 10-fold), not a camera. Below it the back-projection is exact for any fx, fy.
MAX_PIXEL_ASPECT = 4.0

#: PNG colour types (the IHDR byte) by name; 0, greyscale, is the one that holds depth.
PNG_COLOUR_TYPES = {0: "greyscale", 2: "RGB", 3: "palette", 4: "greyscale with alpha", 6: "RGBA"}

#: Kept for old callers: the quaternion tolerance lives with the others in ``tolerances``.
QUAT_NORM_TOLERANCE = tol.QUAT_NORM_TOLERANCE


def read_depth(path: str | Path, *, scale: float | None = None) -> np.ndarray:
    """A depth image in metres.

    Args:
        path: a 16-bit single-channel PNG, or a ``.npy`` (h, w) numeric array.
        scale: metres per stored unit; None: ``INTEGER_DEPTH_SCALE`` for integer data, ``FLOAT_DEPTH_SCALE``
            for float data.

    Returns:
        (h, w) float64 metres, NaN where there was no return (zero, negative or non-finite).

    Raises:
        CloudFileError: missing or unreadable file, not single-channel, 8-bit PNG, not real numbers, more
            than ``MAX_DEPTH_PIXELS``.
        CloudError: a bad ``scale``, an empty image, or one with no valid depth.
    """
    path = Path(path)
    if scale is not None and not (np.isfinite(scale) and MIN_DEPTH_SCALE <= scale <= MAX_DEPTH_SCALE):
        raise CloudError(f"depth scale must be metres per unit in [{MIN_DEPTH_SCALE:g}, {MAX_DEPTH_SCALE:g}] (0.001 for millimetres; "
                         f"Open3D's depth_scale is the inverse), got "
                         f"{refused_number(scale, MIN_DEPTH_SCALE, MAX_DEPTH_SCALE)}")
    check_input_file(path)
    try:
        raw = _read_raw(path)
    except CloudFileError:
        raise  # an OSError too, with its own message: wrapped, it read "cannot read X: X: not a PNG"
    except OSError as exc:  # a permission denied was a traceback (the point cloud readers said it in a line)
        raise CloudFileError(f"cannot read {path}: {exc.strerror or exc}") from None
    if raw.size == 0:
        raise CloudError(f"{path}: the depth image is empty ({raw.shape[1] if raw.ndim == 2 else 0}x{raw.shape[0]})")
    if scale is None:
        scale = FLOAT_DEPTH_SCALE if np.issubdtype(raw.dtype, np.floating) else INTEGER_DEPTH_SCALE
    depth = raw.astype(np.float64) * scale
    with np.errstate(invalid="ignore"):
        depth[~(np.isfinite(depth) & (depth > 0))] = np.nan
    if np.isnan(depth).all():
        raise CloudError(f"{path}: no pixel holds a depth (all {raw.size} are zero, negative or NaN)")
    return depth


def _check_pixels(path: Path, width: int, height: int) -> None:
    if width * height > MAX_DEPTH_PIXELS:
        raise CloudFileError(f"{path}: a {width}x{height} depth image is more than the {MAX_DEPTH_PIXELS:,} pixels "
                             f"one view may hold")


def _read_raw(path: Path) -> np.ndarray:
    """The image's stored values, by its suffix (see :func:`read_depth`)."""
    suffix = path.suffix.lower()
    if suffix == ".png":
        return _read_png(path)
    if suffix != ".npy":
        raise CloudFileError(f"{path}: depth images are read from .png or .npy, not {suffix or 'no suffix'}")
    # Shape, type and size from the header, before any data is read.
    shape, dtype = npy_header(path)
    if len(shape) != 2 or dtype.kind not in REAL_KINDS or dtype.fields is not None:
        raise CloudFileError(f"{path}: a depth image must be a numeric (h, w) array of real numbers, got {dtype} "
                             f"{shape}")
    _check_pixels(path, shape[1], shape[0])
    try:
        return np.load(path, allow_pickle=False)
    except ValueError as exc:
        raise CloudFileError(f"{path}: not a readable .npy array ({exc})") from None


def _read_png(path: Path) -> np.ndarray:
    import warnings

    from PIL import Image, UnidentifiedImageError

    # The size, from the PNG header (signature, then the IHDR chunk's big-endian width and height), is held
    # to our own cap before PIL opens it: PIL warns past 89 M pixels and raises its own error past 179 M.
    with path.open("rb") as fh:
        head = fh.read(26)
    if len(head) < 26 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        # PIL would open a TIFF or BMP under a .png name too, past the size check (a 192 KB TIFF of 8000 x 8000
        # pixels took 6.8 GB).
        raise CloudFileError(f"{path}: not a PNG (no PNG signature and header)")
    _check_pixels(path, int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big"))
    # Bit depth and colour type from the header: PIL reads a 16-bit RGB PNG as 8-bit RGB, so its mode cannot
    # say which of the two is wrong.
    bits, colour = head[24], head[25]
    if colour != 0:
        kind = PNG_COLOUR_TYPES.get(colour, f"colour type {colour}")
        article = "an" if bits == 8 else "a"
        raise CloudFileError(f"{path}: {article} {bits}-bit {kind} PNG; a depth image is a 16-bit single-channel "
                             f"(greyscale) PNG in millimetres")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # under our cap: wanted
            with Image.open(path, formats=["PNG"]) as image:
                mode = image.mode
                raw = np.asarray(image)
    except (OSError, UnidentifiedImageError, Image.DecompressionBombError,
            # PIL's PNG reader raises these too on corrupt chunks (a truncated pHYs, a broken CRC, a text
            # chunk past its cap), not only OSError.
            ValueError, SyntaxError, EOFError, struct.error, zlib.error) as exc:
        raise CloudFileError(f"{path}: not a readable PNG ({exc})") from None
    if mode in ("L", "P", "1") or raw.dtype == np.uint8:
        article = "an" if bits == 8 else "a"
        raise CloudFileError(f"{path}: {article} {bits}-bit PNG cannot hold depth; expected a 16-bit single-channel "
                             f"PNG (millimetres)")
    if raw.ndim != 2:
        raise CloudFileError(f"{path}: expected a single-channel depth PNG, got mode {mode} with shape {raw.shape}")
    return raw


def intrinsics(fx: float, fy: float, cx: float, cy: float, *, width: int, height: int) -> Intrinsics:
    """Intrinsics in OpenCV's convention (pixel centres at integers) checked against the image size.

    Raises:
        CloudError: non-finite focal lengths, ones outside ``FOCAL_RANGE_PX`` or more than ``MAX_PIXEL_ASPECT``
            times each other, a principal point outside the image.
    """
    values = (fx, fy, cx, cy)
    if not all(np.isfinite(v) for v in values):
        raise CloudError(f"intrinsics must be finite, got fx fy cx cy = {' '.join(f'{v:g}' for v in values)}")
    low, high = FOCAL_RANGE_PX
    if not (low <= fx <= high and low <= fy <= high):
        raise CloudError(f"focal lengths must be {low:g} to {high:g} pixels, got fx {refused_number(fx, low, high)}, "
                         f"fy {refused_number(fy, low, high)}")
    if (ratio := max(fx, fy) / min(fx, fy)) > MAX_PIXEL_ASPECT:
        raise CloudError(f"focal lengths fx {fx:g} and fy {fy:g} differ {ratio:.4g}-fold: pixels that far from square "
                         f"are no camera's (at most {MAX_PIXEL_ASPECT:g}:1); a typo?")
    if not (0 <= cx <= width and 0 <= cy <= height):
        raise CloudError(f"principal point ({refused_number(cx, 0, width)}, {refused_number(cy, 0, height)}) lies "
                         f"outside the {width}x{height} image (intrinsics "
                         f"for another resolution?)")
    # fusion.Intrinsics puts pixel centres at integer + 0.5 (its rays start at u + 0.5).
    return Intrinsics(float(fx), float(fy), float(cx) + 0.5, float(cy) + 0.5, int(width), int(height))


def coarsened(depth: np.ndarray, camera: Intrinsics, *,
              max_pixels: int = MAX_VIEW_PIXELS) -> tuple[np.ndarray, Intrinsics, int]:
    """The image thinned to every ``stride``-th row and column when it has more than ``max_pixels``, with the
    intrinsics of the thinned grid; ``(depth, camera, 1)`` unchanged otherwise.

    Every pixel would become a point before the estimate thins them to its own budget: a 4096 x 4096 frame took
    2.8 GB, two of them 4.6 GB. The thinned grid is still far denser than the estimate uses.
    """
    if depth.size <= max_pixels:
        return depth, camera, 1
    height, width = depth.shape
    stride = int(np.ceil(np.sqrt(depth.size / max_pixels)))
    while -(-height // stride) * -(-width // stride) > max_pixels:  # a narrow image thins by less than stride^2
        stride += 1
    thin = np.ascontiguousarray(depth[::stride, ::stride])
    # Pixel k of the thinned grid is pixel stride * k of the image; fusion.Intrinsics puts centres at + 0.5.
    grid = Intrinsics(camera.fx / stride, camera.fy / stride, (camera.cx - 0.5) / stride + 0.5,
                      (camera.cy - 0.5) / stride + 0.5, thin.shape[1], thin.shape[0])
    log.warning("read every %d%s pixel of the %dx%d depth image (%s pixels; at most %s a view are made points)",
                stride, {2: "nd", 3: "rd"}.get(stride, "th"), depth.shape[1], depth.shape[0], f"{depth.size:,}",
                f"{max_pixels:,}")
    return thin, grid, stride


def pose(values: object) -> tuple[np.ndarray, np.ndarray]:
    """Camera-to-world rotation (3, 3) and position (3,) metres from ``tx ty tz qw qx qy qz``.

    Raises:
        CloudError: not seven finite numbers, a position beyond ``tolerances.MAX_COORDINATE_M``, or a
            quaternion whose norm is not 1 (``contracts.unit_quaternion``).
    """
    from scipy.spatial.transform import Rotation

    v = np.asarray(values, dtype=np.float64).ravel()
    if v.shape != (7,) or not np.isfinite(v).all():
        raise CloudError(f"pose: expected seven finite numbers tx ty tz qw qx qy qz, got {v.tolist()}")
    far = float(np.abs(v[:3]).max())
    if far > tol.MAX_COORDINATE_M:
        raise CloudError(f"pose: the camera is {refused_number(far, tol.MAX_COORDINATE_M, digits=3)} m from the origin, beyond "
                         f"the {tol.MAX_COORDINATE_M:g} m "
                         f"an estimate accepts")
    q = unit_quaternion(v[3:], "pose: the quaternion qw qx qy qz")
    # scipy's order is x y z w; ours (MuJoCo's, PCD's VIEWPOINT) is w x y z.
    return Rotation.from_quat(np.r_[q[1:], q[0]]).as_matrix(), v[:3].copy()


def depth_view(depth: np.ndarray, camera: Intrinsics, rotation: np.ndarray,
               position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A depth image's points in the world and its sensor origin.

    Args:
        depth: (h, w) float64 metres, NaN where no return. camera: its intrinsics (size must match).
        rotation: (3, 3) camera-to-world. position: (3,) metres, the camera centre in the world.

    Returns:
        points (n, 3) float64 metres world frame (pixels on depth edges dropped), and the origin (3,).

    Raises:
        CloudError: the image size does not match the intrinsics, or every pixel with a depth is on an edge.
    """
    from estimation.fusion import edge_mask

    # Pixels on a depth edge are where real sensors return "flying pixels" between the object and what is
    # behind it; the sensor's sigma is unknown here, so the jump threshold is fusion's smallest (1 cm).
    edges = edge_mask(depth, 0.0)
    valid = np.isfinite(depth) & (depth > 0)
    if valid.any() and not (valid & ~edges).any():
        # Every return on an edge: millimetres read as metres (--depth-scale 1) step a metre a pixel, and the
        # view was refused as one "with no points".
        raise CloudError(f"every pixel with a depth lies on a depth edge (its neighbours more than 1 cm nearer or "
                         f"further): the depths run {float(depth[valid].min()):.4g}..{float(depth[valid].max()):.4g} m; "
                         f"is the depth scale right (0.001 for millimetres)?")
    depth = np.where(edges, np.nan, depth)
    points, _ = depth_to_points(depth, camera, rotation, position)
    return points, np.asarray(position, dtype=np.float64)
