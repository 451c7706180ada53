"""Convex decomposition of reconstructed meshes with CoACD, cached on disk and run in worker processes.

Collision in MuJoCo is between convex shapes; a concave object (a mug) needs several. CoACD is random
by default, so its seed is part of the settings, and the settings are part of the cache key: the same
mesh and settings always give the same hulls, and a second build runs no CoACD. Each entry carries a sha256
of its hulls, checked on every read: a truncated, empty, corrupt or altered entry is logged, recomputed and
replaced atomically. A cache folder that cannot be written means building without a cache (one warning).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import numbers
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from estimation.contracts import shown
from estimation.errors import TwinError, refused_number
from twin.workers import background_worker

log = logging.getLogger(__name__)

Hull = tuple[np.ndarray, np.ndarray]  # vertices (v, 3) metres, faces (f, 3) int

#: The largest values of CoACD's C ``int`` (its counts) and ``unsigned int`` (its seed): ctypes wraps a larger
#: number without a word (2**32 + 16 hulls were 16; and seed -1 was 4294967295).
C_INT_MAX, C_UINT_MAX = 2**31 - 1, 2**32 - 1


@dataclass(frozen=True)
class CoacdSettings:
    """CoACD's parameters (same names as ``coacd.run_coacd``), seed included.

    ``threshold`` is the concavity tolerance (smaller: more, tighter hulls); ``max_convex_hull`` caps the
    count (-1: no cap); ``max_ch_vertex`` caps vertices per hull (with ``decimate``), which bounds
    collision cost: 32 left a tall cylinder's base uneven enough to tip it over, so 64. The defaults trade CoACD's (threshold 0.05, 150 MCTS iterations: ~60 s on the mug)
    for ~10x less time; bench/twin_step.py shows what that costs in contact accuracy and speed.

    ``mcts_iterations`` 25, not 50: on 48 shapes of scenes/shapes.py (seeds 11 and 23) that go to CoACD,
    50 iterations took 1.37x the CPU (417 s against 304 s) for the same hulls: 12.1 and 12.2 on average,
    surface left outside the hulls p99 0.006 % of the size at the median either way (worst 0.89 and
    0.95 %), hull vertices off the surface 0.42 % at the median (worst 13.8 and 13.2 %). Measured by
    ``.venv/bin/python bench/coacd_settings.py`` (bench/results/coacd_settings.txt).
    """

    threshold: float = 0.08
    max_convex_hull: int = 16
    # Our reconstructions are already closed manifolds; CoACD's remeshing would only cost time.
    preprocess_mode: str = "off"
    preprocess_resolution: int = 50
    resolution: int = 1000
    mcts_nodes: int = 10
    mcts_iterations: int = 25
    mcts_max_depth: int = 3
    merge: bool = True
    decimate: bool = True
    max_ch_vertex: int = 64
    seed: int = 0
    #: Not CoACD's: a mesh whose :func:`concavity` (widest gap to its hull over its size) is at most this
    #: collides as its convex hull and skips CoACD (a can, a ball, a box); 0 sends every mesh to CoACD.
    #: Measured in bench/convexity.py on reconstructions of seeded primitives and scenes/shapes.py shapes
    #: (none of them mixed100's): clouds of convex objects read at most 0.035 at 30k points and 0.056 at
    #: 8k (reconstruction ridges), every real concavity 0.062 (a drilled hole) or more, except a star's
    #: shallow notches (0.017 on the true mesh, 0.032 reconstructed). 0.05 lies between, and is of the
    #: order of CoACD's own concavity threshold. Sparse noisy scans of convex shapes read up to 0.12: those
    #: above it go to CoACD, as a concave object would (the cloud cannot tell them apart).
    convex_tolerance: float = 0.05

    def __post_init__(self) -> None:
        """Refuse what CoACD would abort on (``threshold > 1`` kills the process) or cannot mean.

        Every field is checked for its type too: NaN compares false with every bound, and CoACD takes its
        numbers through ctypes, which wraps a count past a C int without a word (:data:`C_INT_MAX`).

        Raises:
            CoacdSettingsError: ``threshold`` outside (0, 1] (CoACD's documented range is 0.01 to 1),
                ``max_convex_hull`` not -1 or >= 1, ``max_ch_vertex`` below 4 (a hull has 4), a
                resolution or MCTS count below 1, a count that is not a whole number (a bool, a float) or
                past :data:`C_INT_MAX`, ``seed`` not a whole number from 0 to :data:`C_UINT_MAX`,
                ``preprocess_mode`` not auto/on/off, ``merge`` or ``decimate`` not True or False, or
                ``convex_tolerance`` outside [0, 1].
        """
        self._check_real("threshold")
        if not (math.isfinite(self.threshold) and 0 < self.threshold <= 1):
            raise CoacdSettingsError(f"CoACD threshold must be in (0, 1], got {refused_number(self.threshold, 0, 1)}")
        self._check_whole("max_convex_hull", C_INT_MAX)
        if self.max_convex_hull != -1 and self.max_convex_hull < 1:
            raise CoacdSettingsError(f"CoACD max hulls must be -1 (no cap) or >= 1, got {shown(self.max_convex_hull)}")
        self._check_whole("max_ch_vertex", C_INT_MAX)
        if self.max_ch_vertex < 4:
            raise CoacdSettingsError(f"CoACD max_ch_vertex must be >= 4, got {shown(self.max_ch_vertex)}")
        for name in ("preprocess_resolution", "resolution", "mcts_nodes", "mcts_iterations", "mcts_max_depth"):
            self._check_whole(name, C_INT_MAX)
            if getattr(self, name) < 1:
                raise CoacdSettingsError(f"CoACD {name} must be >= 1, got {shown(getattr(self, name))}")
        self._check_whole("seed", C_UINT_MAX)
        if self.seed < 0:
            raise CoacdSettingsError(f"CoACD seed must be >= 0, got {shown(self.seed)}")
        if not isinstance(self.preprocess_mode, str) or self.preprocess_mode not in ("auto", "on", "off"):
            raise CoacdSettingsError(f"CoACD preprocess_mode must be auto, on or off, got {shown(self.preprocess_mode)}")
        for name in ("merge", "decimate"):
            if not isinstance(getattr(self, name), bool):
                raise CoacdSettingsError(f"CoACD {name} must be True or False, got {type(getattr(self, name)).__name__} "
                                         f"{shown(getattr(self, name))}")
        self._check_real("convex_tolerance")
        if not (math.isfinite(self.convex_tolerance) and 0 <= self.convex_tolerance <= 1):
            raise CoacdSettingsError(f"convex_tolerance must be in [0, 1], got {refused_number(self.convex_tolerance, 0, 1)}")

    def _check_real(self, name: str) -> None:
        """Refuse a field that is not a real number (a string, None, a bool) or an integer past any float; a
        numpy float becomes a float, which the cache key's JSON can write.

        Raises:
            CoacdSettingsError: naming the field and what came.
        """
        value = getattr(self, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise CoacdSettingsError(f"CoACD {name} must be a number, got {type(value).__name__} {shown(value)}")
        try:
            as_float = float(value)
        except OverflowError:  # an integer past any float: math.isfinite raised it
            raise CoacdSettingsError(f"CoACD {name} must be a finite number, got {shown(value)}") from None
        if not isinstance(value, int | float):
            object.__setattr__(self, name, as_float)

    def _check_whole(self, name: str, high: int) -> None:
        """Refuse a field that is not a whole number (a float, NaN, a bool, None) or is past ``high`` (what
        CoACD's C type holds); a numpy integer becomes an int, which the cache key's JSON can write.

        Raises:
            CoacdSettingsError: naming the field and what came.
        """
        value = getattr(self, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise CoacdSettingsError(f"CoACD {name} must be a whole number, got {type(value).__name__} {shown(value)}")
        if value > high:
            raise CoacdSettingsError(f"CoACD {name} must be at most {high}, got {shown(value)}")
        if type(value) is not int:
            object.__setattr__(self, name, int(value))


class CoacdSettingsError(TwinError, ValueError):
    """CoACD settings outside the ranges CoACD accepts."""


#: The settings used when none are given.
DEFAULT_SETTINGS = CoacdSettings()

#: The smallest ``threshold`` at which CoACD stays fast: below it CoACD's search takes many times longer.
#: ``bench/coacd_threshold.py`` (a 2,304-face torus, these settings otherwise; ``bench/results/coacd_threshold.txt``):
#: wall seconds 0.9 at the default 0.08, 1.2 at 0.03, 1.9 at 0.02, 3.8 at 0.015, 9.7 at 0.012, 39.7 at 0.01
#: (43x the default); 16 hulls (the cap) from 0.02 down, so the time below 0.02 buys no more of them. A
#: scene's concave objects each pay it.
FAST_THRESHOLD = 0.02


def default_cache_dir() -> Path:
    """``$TWIN_CACHE_DIR``, else ``$XDG_CACHE_HOME/tactile-twin/coacd``, else ``~/.cache/tactile-twin/coacd``.

    An empty ``TWIN_CACHE_DIR`` counts as unset, and so does an empty or relative ``XDG_CACHE_HOME``, as the XDG
    Base Directory spec says: taken as given, they put the cache in (or under) whatever folder the command ran in.
    """
    if env := os.environ.get("TWIN_CACHE_DIR"):
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "tactile-twin" / "coacd"


def cache_key(vertices: np.ndarray, faces: np.ndarray, settings: CoacdSettings) -> str:
    """sha256 of the mesh bytes and the settings."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    h.update(json.dumps(asdict(settings), sort_keys=True).encode())
    return h.hexdigest()


def decompose(
    vertices: np.ndarray, faces: np.ndarray, settings: CoacdSettings = DEFAULT_SETTINGS, *,
    cache_dir: Path | None = None,
) -> tuple[list[Hull], bool]:
    """Convex parts of one closed mesh; returns (hulls, from_cache).

    A failed or empty decomposition falls back to the convex hull of the mesh, with a warning. A cache entry
    that does not verify is recomputed and replaced; a cache folder that cannot be used means no cache, with
    a warning: the cache never fails a build.

    Args:
        vertices: (v, 3) float64, metres, object frame.
        faces: (f, 3) int, indices into ``vertices``.
        settings: CoACD's parameters, seed included.
        cache_dir: the cache folder (default :func:`default_cache_dir`).
    """
    return _decompose(vertices, faces, settings, usable_cache(Path(cache_dir or default_cache_dir())))


def decompose_many(
    meshes: Sequence[Hull], settings: CoacdSettings = DEFAULT_SETTINGS, *, cache_dir: Path | None = None,
    workers: int | None = None, progress: bool = True,
) -> list[tuple[list[Hull], bool]]:
    """:func:`decompose` for several meshes; cache misses run in parallel worker processes."""
    cache = usable_cache(Path(cache_dir or default_cache_dir()))
    results: list[tuple[list[Hull], bool] | None] = [None] * len(meshes)
    misses = []
    for i, (v, f) in enumerate(meshes):
        cached = None if cache is None else load_entry(cache / entry_name(cache_key(v, f, settings)))
        if cached is not None:
            results[i] = (cached, True)
        else:
            misses.append(i)
    if misses:
        workers = workers or min(len(misses), os.cpu_count() or 1)
        bar = ProgressBar(progress, len(misses), "CoACD")
        if workers == 1 or len(misses) == 1:
            for i in misses:
                results[i] = _decompose(*meshes[i], settings, cache, verified_miss=True)
                bar.advance()
        else:
            import multiprocessing as mp

            # spawn: CoACD and MuJoCo hold threads; forking them is not safe.
            with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"),
                                     initializer=background_worker) as pool:
                futures = {pool.submit(_decompose, *meshes[i], settings, cache, verified_miss=True): i
                           for i in misses}
                for future, i in futures.items():
                    results[i] = future.result()
                    bar.advance()
        bar.close()
    return [r for r in results if r is not None]


def _decompose(vertices: np.ndarray, faces: np.ndarray, settings: CoacdSettings, cache: Path | None, *,
               verified_miss: bool = False) -> tuple[list[Hull], bool]:
    """:func:`decompose` with the cache folder already checked (None: no cache).

    ``verified_miss``: the caller has just found no usable entry, so do not read (and warn about) it again.
    """
    key = cache_key(vertices, faces, settings)
    if cache is not None and not verified_miss and (cached := load_entry(cache / entry_name(key))) is not None:
        return cached, True
    hulls = _run_coacd(vertices, faces, settings)
    if cache is not None:
        save_entry(cache / entry_name(key), hulls)
    return hulls, False


# --- the cache: one .npz per (mesh, settings) holding the hulls and a sha256 of their content ---------------

#: Bumped when an entry's layout changes; an entry of another version is recomputed and replaced.
CACHE_VERSION = 2
_warned_folders: set[str] = set()


def entry_name(key: str) -> str:
    """The file name of the cache entry for ``key`` (a :func:`cache_key`)."""
    return f"{key}.npz"


def usable_cache(folder: Path) -> Path | None:
    """``folder`` if cache entries can be written there (created if missing), else None with a warning.

    The check creates and removes a probe file of its own: permission bits say nothing for root, nor about
    read-only mounts.
    """
    import tempfile

    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".probe-", suffix=".tmp"):
            pass
    except OSError as exc:
        if str(folder) not in _warned_folders:  # once per folder and process, not once per object
            _warned_folders.add(str(folder))
            log.warning("CoACD cache folder %s is unusable (%s); building without a cache", folder,
                        exc.strerror or exc)
        return None
    return folder


def content_checksum(hulls: Sequence[Hull]) -> str:
    """sha256 of the hulls' arrays (shapes and bytes, as float64 / int64), in order."""
    h = hashlib.sha256(f"tactile-twin coacd cache v{CACHE_VERSION}".encode())
    for v, f in hulls:
        for a in (np.ascontiguousarray(v, dtype=np.float64), np.ascontiguousarray(f, dtype=np.int64)):
            h.update(repr(a.shape).encode())
            h.update(a.tobytes())
    return h.hexdigest()


def save_entry(path: Path, hulls: Sequence[Hull]) -> bool:
    """Write an entry atomically (a temp file in the same folder, then ``os.replace``); False if that failed.

    A failed write is a warning, never an error: CoACD has already run and the hulls are good.
    """
    import tempfile

    arrays = _pack(list(hulls))
    arrays["version"] = np.array(CACHE_VERSION)
    arrays["checksum"] = np.array(content_checksum(hulls))
    tmp = None
    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.stem[:16]}-", suffix=".tmp",
                                         delete=False) as fh:
            tmp = Path(fh.name)
            np.savez(fh, **arrays)
        os.replace(tmp, path)  # atomic: a reader sees the old entry or the new one, never half of one
        return True
    except OSError as exc:
        log.warning("cannot write CoACD cache entry %s (%s); continuing without caching it", path, exc)
        if tmp is not None:
            tmp.unlink(missing_ok=True)  # our own temp file, nothing else
        return False


#: How an .npz archive (a zip file) starts: what every cache entry is.
_NPZ_MAGIC = b"PK\x03\x04"


def load_entry(path: Path) -> list[Hull] | None:
    """The hulls in a cache entry, or None if there is none or it does not verify (with a warning).

    An entry verifies when it loads, its version is :data:`CACHE_VERSION`, every hull is a finite (v, 3)
    float array with in-range (f, 3) integer faces, and the sha256 of that content equals the stored one.
    """
    import zipfile

    if not path.is_file():
        return None
    try:
        with path.open("rb") as f:  # else numpy takes it for a pickle and advises allow_pickle, never right here
            if f.read(len(_NPZ_MAGIC)) != _NPZ_MAGIC:
                raise ValueError("not an .npz archive")
        with np.load(path, allow_pickle=False) as data:
            version = int(data["version"])
            stored = str(data["checksum"])
            hulls = _unpack(data)
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        log.warning("unreadable CoACD cache entry %s (%s); recomputing", path.name, exc)
        return None
    if version != CACHE_VERSION:
        log.warning("CoACD cache entry %s is version %d, not %d; recomputing", path.name, version, CACHE_VERSION)
        return None
    if not hulls or not all(_valid_hull(v, f) for v, f in hulls):
        log.warning("CoACD cache entry %s holds malformed hulls; recomputing", path.name)
        return None
    if content_checksum(hulls) != stored:
        log.warning("CoACD cache entry %s fails its checksum; recomputing", path.name)
        return None
    return hulls


def _valid_hull(v: np.ndarray, f: np.ndarray) -> bool:
    return (v.ndim == 2 and v.shape[1] == 3 and len(v) >= 4 and v.dtype.kind == "f" and bool(np.isfinite(v).all())
            and f.ndim == 2 and f.shape[1] == 3 and len(f) >= 4 and f.dtype.kind in "iu"
            and int(f.min()) >= 0 and int(f.max()) < len(v))


def _run_coacd(vertices: np.ndarray, faces: np.ndarray, settings: CoacdSettings) -> list[Hull]:
    import coacd

    if skips_coacd(concavity(vertices, faces), settings):
        return [_convex_hull(vertices)]
    coacd.set_log_level("error")
    params = asdict(settings)
    del params["convex_tolerance"]
    if has_open_edges(vertices, faces):
        # CoACD on an open mesh without its manifold preprocessing searches for minutes; with it, seconds.
        # A closed mesh with a few edges shared by more than two faces (as reconstructions have, where a
        # speck touches the surface) does not need it, and it costs 4x: 11.8 s against 3.1 s of CPU for
        # a 3000-face scan, for 16 and 15 hulls.
        params["preprocess_mode"] = "on"
    try:
        parts = coacd.run_coacd(coacd.Mesh(np.asarray(vertices, float), np.asarray(faces, np.int32)), **params)
    except Exception as exc:  # CoACD raises bare RuntimeErrors from C++; any failure means fall back.
        log.warning("CoACD failed (%s); using the convex hull", exc)
        parts = []
    hulls = [(np.asarray(v, float), np.asarray(f, np.int64)) for v, f in parts if len(f) >= 4]
    if not hulls:
        log.warning("CoACD gave no convex parts; using the convex hull")
        hulls = [_convex_hull(vertices)]
    return hulls


#: Points sampled on the convex hull by :func:`concavity` (and 20 times as many on the mesh): the gap is
#: found to within about the mesh samples' spacing: 1.2 mm on a 10 cm cube (a convex one reads 0.012).
CONCAVITY_SAMPLES = 5000


def has_open_edges(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Some edge belongs to one face only (after merging coincident vertices): the mesh has a hole.

    Not trimesh's ``is_watertight``, which also refuses closed meshes with an edge shared by four faces.
    """
    import trimesh
    from trimesh.grouping import group_rows

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    return len(group_rows(mesh.edges_sorted, require_count=1)) > 0


def concavity(vertices: np.ndarray, faces: np.ndarray) -> float:
    """How far a closed mesh is from convex: the widest gap between its convex hull and it (the largest
    distance from a point of the hull's surface to the mesh's surface), over the hull's largest extent.

    0 for a convex mesh (up to the sampling: 0.012 for a cube), 0.25 for an L of three unit cubes (the middle
    of the hull's cut face is 0.5 from the nearest face; the largest extent is 2); ``inf`` for a mesh
    with no positive (signed) volume (open or inside out: CoACD, with its preprocessing, judges those).

    The widest gap, not an average and not the hull's volume ratio: a reconstruction's noise and the 1-2 mm
    ridges along a box's edges spread small gaps over the whole surface (adding 10-30 % to the hull's
    volume), while a real concavity (a handle, a hole, an inside corner) makes one wide gap: it is the width
    that tells them apart (bench/convexity.py). Distances are measured between seeded surface samples, so
    the same mesh always gives the same value.

    Args:
        vertices: (v, 3) float64, metres.
        faces: (f, 3) int, outward winding.
    """
    import trimesh
    from scipy.spatial import cKDTree

    from estimation.inertia import signed_volumes

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    key = hashlib.sha256(v.tobytes() + f.tobytes()).hexdigest()
    if key in _concavity_memo:  # the build asks again for its report, after the decision
        return _concavity_memo[key]
    if float(signed_volumes(v[f]).sum()) <= 0:
        return float("inf")
    hv, hf = _convex_hull(v)
    rng = np.random.default_rng(0)
    on_hull, _ = trimesh.sample.sample_surface(trimesh.Trimesh(hv, hf, process=False), CONCAVITY_SAMPLES, seed=rng)
    on_mesh, _ = trimesh.sample.sample_surface(trimesh.Trimesh(v, f, process=False), 20 * CONCAVITY_SAMPLES, seed=rng)
    gap = float(cKDTree(np.vstack([on_mesh, v])).query(np.vstack([on_hull, hv]))[0].max())
    if len(_concavity_memo) >= 8:
        _concavity_memo.pop(next(iter(_concavity_memo)))
    _concavity_memo[key] = result = gap / float(np.ptp(hv, axis=0).max())
    return result


#: The last few :func:`concavity` results by mesh sha256 (a handful of floats: one object at a time per process).
_concavity_memo: dict[str, float] = {}


def skips_coacd(concavity_: float, settings: CoacdSettings) -> bool:
    """A mesh of this :func:`concavity` collides as its convex hull, CoACD not run (a box, a can, a ball)."""
    return settings.convex_tolerance > 0 and concavity_ <= settings.convex_tolerance


def _convex_hull(vertices: np.ndarray) -> Hull:
    from estimation.hull import convex_hull

    return convex_hull(np.asarray(vertices, float))


def _pack(hulls: list[Hull]) -> dict[str, np.ndarray]:
    out = {}
    for i, (v, f) in enumerate(hulls):
        out[f"v{i}"], out[f"f{i}"] = v, f
    return out


def _unpack(data) -> list[Hull]:  # type: ignore[no-untyped-def]
    n = sum(1 for name in data.files if name[0] == "v" and name[1:].isdigit())
    return [(data[f"v{i}"], data[f"f{i}"]) for i in range(n)]


class ProgressBar:
    """A rich progress bar on stderr (gone when closed), or nothing; ``label`` names what is counted."""

    def __init__(self, enabled: bool, total: int, label: str) -> None:
        self._bar = None
        if enabled:
            from rich.console import Console
            from rich.progress import Progress

            self._bar = Progress(console=Console(stderr=True), transient=True)
            self._bar.start()
            self._task = self._bar.add_task(label, total=total)

    def advance(self) -> None:
        if self._bar is not None:
            self._bar.advance(self._task)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.stop()
