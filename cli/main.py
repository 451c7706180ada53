"""The ``twin`` command line. Thin: parse, call library functions, print, map errors to exit 2.

Output, the same for every command: the result (a table or summary lines; with --json exactly one JSON
object, SI units named in its keys, nothing else) goes to stdout; progress, status and warnings go to
stderr; an error is one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import logging
import math
import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NoReturn

from cli.outputs import (
    check_mesh_file,
    check_not_input,
    check_record_file,
    mark_mesh,
    replace_file,
    write_failure,
)
from estimation.errors import TwinError, refused_number
from estimation.materials import MAX_DENSITY, MIN_DENSITY
from twin.settings import MAX_RATE_HZ

log = logging.getLogger("twin")

EXIT_BAD_INPUT = 2


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (0 ok, 2 bad input)."""
    import warnings

    parser = _parser()
    args = parser.parse_args(argv)
    stream = logging.StreamHandler(sys.stderr)
    formatter = logging.Formatter if args.verbose else _OneLineFormatter  # -v keeps tracebacks whole
    stream.setFormatter(formatter("%(levelname)s %(name)s: %(message)s"))
    held_log = None
    if args.command in HELD_LOG_COMMANDS and not args.verbose:
        from logging.handlers import MemoryHandler

        # As warnings are below: a failed estimate's stderr is its one error line, not a log warning first.
        held_log = MemoryHandler(MAX_HELD_WARNINGS, flushLevel=logging.CRITICAL + 1, target=stream, flushOnClose=False)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        handlers=[held_log or stream])
    handler: Callable[[argparse.Namespace], int] = args.handler
    # Warnings (numpy's overflow RuntimeWarnings, say) are held: a failed command's stderr is its one error
    # line; a command that succeeds shows them afterwards, one line each. Only the first few are kept, so a
    # live command that runs for hours does not collect them without limit.
    held: list[tuple[type[Warning], str]] = []
    more = 0

    def hold(message, category, *_: object, **__: object) -> None:  # type: ignore[no-untyped-def]
        nonlocal more
        if len(held) < MAX_HELD_WARNINGS:
            held.append((category, str(message)))
        else:
            more += 1

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = hold
        try:
            check_args(args)  # before any work: a bad number should not cost a build
            # MuJoCo's warnings ("Nan, Inf or huge value in QACC") are held with Python's: see mujoco_warnings.
            with (contextlib.nullcontext() if args.command in NO_MUJOCO_COMMANDS
                  else mujoco_warnings(lambda text: warnings.warn(text, MujocoWarning, stacklevel=1))):
                code = handler(args)
        except TwinError as exc:
            _drop_held(held_log)
            print(f"twin {args.command}: error: {one_line(str(exc))}", file=sys.stderr)
            return EXIT_BAD_INPUT
        except MemoryError:
            _drop_held(held_log)
            # numpy raises it as it allocates: the input is larger than this machine holds; one line, not a trace.
            print(f"twin {args.command}: error: out of memory: the input is too large for this machine's memory",
                  file=sys.stderr)
            return EXIT_BAD_INPUT
        except KeyboardInterrupt:
            return 130
        except OSError as exc:
            # A named file's error is an output's only when the disk is full: EIO may be an input's read.
            if exc.errno not in _OUTPUT_ERRNOS or (exc.filename is not None and exc.errno not in _FULL_ERRNOS):
                raise
            # stdout (or an output file) is full or gone (a full disk, a closed pipe): one line, and no second
            # failure at exit when Python flushes stdout again.
            _drop_held(held_log)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            if exc.errno == errno.EPIPE:  # a closed pipe is the reader's choice (| head): said by no one
                return 1
            print(f"twin {args.command}: error: {write_failure(exc, exc.filename or 'the output')}", file=sys.stderr)
            return EXIT_BAD_INPUT
    if held_log is not None:
        held_log.flush()
    for category, message in held:
        log.warning("%s: %s", category.__name__, one_line(message))
    if more:
        log.warning("%d more warnings", more)
    return code


#: errno of a failed write to the standard output: a full disk or quota, a closed pipe, an I/O error.
_OUTPUT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EPIPE, errno.EIO})
#: errno of a full disk or quota: only a write (or a file created) fails so, whichever file it names.
_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})

#: Warnings kept and shown after a command that succeeded; the rest are counted.
MAX_HELD_WARNINGS = 20

#: Commands whose log records are held until they succeed (dropped if they fail, so the error is the one line):
#: the short ones scripts call. Live commands log as they go (past MAX_HELD_WARNINGS records these do too).
HELD_LOG_COMMANDS = frozenset({"estimate"})


#: Commands that never load MuJoCo (0.2 s to import): its warnings need no handler there.
NO_MUJOCO_COMMANDS = frozenset({"estimate", "materials", "schema"})


class MujocoWarning(RuntimeWarning):
    """A warning MuJoCo gave (a huge or NaN state, a full contact buffer), held and shown as Python's are."""


@contextlib.contextmanager
def mujoco_warnings(take: Callable[[str], object]) -> Iterator[None]:
    """Hand MuJoCo's warnings to ``take(text)`` inside the block, then give back the handler there was.

    MuJoCo's own handler prints each on the terminal with a blank line, whatever the command says next (a
    NaN in scene.xml showed its warning above our error line), and appends it to MUJOCO_LOG.TXT in the
    working folder, a file the user never asked for. Called from MuJoCo's threads too (it takes the GIL).
    """
    import mujoco

    before = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(take)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(before)


def _drop_held(held_log) -> None:  # type: ignore[no-untyped-def]
    """Forget the log records ``held_log`` (a MemoryHandler, or None) holds: the command failed."""
    if held_log is not None:
        with held_log.lock:
            held_log.buffer.clear()


#: Longest error line printed, characters: a message quoting a bad value whole (a 12-million-element position in
#: a scene file) was a 60 MB line; its head names the problem.
MAX_ERROR_CHARS = 2000


def one_line(text: str) -> str:
    """``text`` on one line: its non-empty lines joined with '; ' (MuJoCo's compile errors add
    "\nElement name ..."), cut to :data:`MAX_ERROR_CHARS`."""
    line = "; ".join(part.strip() for part in text.splitlines() if part.strip())
    return line if len(line) <= MAX_ERROR_CHARS else line[:MAX_ERROR_CHARS] + " [...]"


class _OneLineFormatter(logging.Formatter):
    """Log records on one line each: a multi-line message (or traceback) is joined with '; '."""

    def format(self, record: logging.LogRecord) -> str:
        return one_line(super().format(record))


#: What ``--mesh-out`` writes: the formats trimesh exports a triangle mesh to (it has no .xyz or .npy writer).
MESH_SUFFIXES = (".stl", ".ply", ".obj")

#: Numeric options: attribute -> (flag, lowest allowed, whether the lowest itself is allowed, highest).
_NUMBERS: dict[str, tuple[str, float, bool, float]] = {
    "duration": ("--duration", 0.0, False, math.inf),
    "rate": ("--rate", 0.0, False, MAX_RATE_HZ),
    "stale_after": ("--stale-after", 0.0, False, math.inf),
    "deadband_mm": ("--deadband-mm", 0.0, True, math.inf),
    "deadband_deg": ("--deadband-deg", 0.0, True, 180.0),  # two orientations are at most 180 degrees apart
    "rerun_rate": ("--rerun-rate", 0.0, False, math.inf),
    "threshold": ("--threshold", 0.0, False, 1.0),  # CoACD's range (it aborts the process past 1)
    "density": ("--density", MIN_DENSITY, True, MAX_DENSITY),  # what scene files and the wire take
    "force_rate": ("--force-rate", 0.0, True, MAX_RATE_HZ),
    # In ms here, an hour at most: sync.netem.MAX_DELAY_S, which said it in seconds ("got 10000000.0" for 1e10 ms).
    "delay_ms": ("--delay", 0.0, True, 3.6e6),
    "jitter_ms": ("--jitter", 0.0, True, 3.6e6),
    "loss_pct": ("--loss", 0.0, True, math.inf),  # and below 100: check_args says why, first
    # At least one physics step (twin.model.TIMESTEP): 0.0004 s ran no tick and reported "89x real time".
    "replay_duration": ("--duration", 1e-3, True, math.inf),
}


def check_args(args: argparse.Namespace) -> None:
    """Refuse option values no command can use, before the command does any work.

    Raises:
        TwinError: a non-finite or out-of-range number (--loss of 100 % or more), a non-finite --viewpoint,
            --units other than m without --script, or a --rerun save path whose folder does not exist or cannot
            be written.
    """
    from estimation.contracts import check_number  # here: numpy, which --help does not need

    loss = getattr(args, "loss_pct", None)
    if loss is not None and loss >= 100:  # the link model takes a loss of 1; a session under it measures nothing
        raise TwinError(f"--loss must be below 100 (at 100 % every packet is lost both ways and the run would "
                        f"measure nothing), got {refused_number(loss, 100)}")
    for attr, (flag, low, low_ok, high) in _NUMBERS.items():
        value = getattr(args, attr, None)
        if value is None:
            continue
        check_number(value, flag, low=low, low_ok=low_ok, high=high, error=TwinError)
    for viewpoint in getattr(args, "viewpoint", None) or ():  # once per view
        if not all(math.isfinite(x) for x in viewpoint):
            raise TwinError(f"--viewpoint must be three finite numbers, got {viewpoint}")
    if getattr(args, "points", None) is not None:
        from scenes.scenefile import MAX_POINTS, MIN_POINTS  # a scene file's own bounds on an object's cloud

        if not MIN_POINTS <= args.points <= MAX_POINTS:
            raise TwinError(f"--points must be from {MIN_POINTS} to {MAX_POINTS}, got {args.points}")
    if getattr(args, "max_hulls", None) is not None and args.max_hulls != -1 and args.max_hulls < 1:
        raise TwinError(f"--max-hulls must be -1 (no cap) or >= 1, got {args.max_hulls}")
    _check_cache_dir(getattr(args, "cache_dir", None))
    # run, local and replay scale only the --script file by --units: without it, --units mm did nothing, silently.
    if "script" in vars(args) and args.script is None and args.units != "m":
        raise TwinError(f"--units applies to --script's file, and no --script is given: drop --units {args.units} "
                        "(everything else is in metres)")
    inputs = _input_files(args)
    if getattr(args, "record", None) is not None:
        _check_writable_file(Path(args.record), "--record")
        check_record_file(Path(args.record), inputs)
    rerun = getattr(args, "rerun", None)
    if rerun and rerun[0] == "save" and len(rerun) == 2:
        _check_writable_file(Path(rerun[1]), "--rerun save")
        check_not_input(Path(rerun[1]), inputs, "--rerun save")
        out = getattr(args, "out", None)
        # A build replaces --out whole: the .rrd would go with it, or (written after) block the next build.
        if args.command == "build" and out is not None and Path(out).resolve() in Path(rerun[1]).resolve().parents:
            raise TwinError(f"--rerun save {rerun[1]}: inside --out {out}, which the build replaces whole; save it "
                            "beside the folder")


def _check_cache_dir(folder: Path | None) -> None:
    """Refuse a ``--cache-dir`` that is the current folder, as ``--out`` is: ``--cache-dir ''`` (an unset shell
    variable's) is one, and CoACD's entries (one ``<sha256>.npz`` per mesh) were strewn among the user's files.

    Raises:
        TwinError: ``folder`` resolves to the current folder.
    """
    if folder is None:
        return
    try:
        resolved, here = Path(folder).resolve(), Path.cwd().resolve()
    except (OSError, RuntimeError):  # no current folder, a loop of links: the cache's own check warns
        return
    if resolved == here:
        raise TwinError(f"--cache-dir {resolved}: is the current folder (so is an empty --cache-dir); the CoACD "
                        f"cache writes a file per mesh there: give it a folder of its own, or leave --cache-dir out "
                        f"for the default (see --help)")


#: Options naming files a command reads (``local --scene`` is a name, not a file: only paths count).
_INPUT_OPTIONS = ("scene", "script", "replay_operator", "recording", "zenoh_config")


def _input_files(args: argparse.Namespace) -> list[Path]:
    """The files the command reads, for refusing an output that is one of them."""
    found = [v for a in _INPUT_OPTIONS if isinstance(v := getattr(args, a, None), Path)]
    return found + list(getattr(args, "views", None) or ())


def _check_writable_file(path: Path, flag: str) -> None:
    """``path`` can be created: its folder exists and a probe file can be written there (and is removed)."""
    import tempfile

    if path.is_dir():
        raise TwinError(f"{flag}: {path} is a folder, not a file")
    folder = path.parent
    if not folder.is_dir():
        raise TwinError(f"{flag}: folder {folder} does not exist")
    try:  # a real write: permission bits say nothing for root or read-only mounts
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".twin-probe-"):
            pass
    except OSError as exc:
        raise TwinError(f"{flag}: cannot write in {folder} ({exc.strerror or exc})") from None


def to_json(record: object) -> str:
    """``record`` as strict JSON: NaN and infinities become null, never the invalid ``NaN`` token."""

    def clean(x: object) -> object:
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [clean(v) for v in x]
        if hasattr(x, "item") and hasattr(x, "dtype") and getattr(x, "ndim", None) == 0:
            x = x.item()  # numpy scalars
        if isinstance(x, float) and not math.isfinite(x):
            return None
        return x

    return json.dumps(clean(record), allow_nan=False)


class _Parser(argparse.ArgumentParser):
    """argparse's parser with one-line usage errors (the CLI's contract: a clear line, exit 2), pointing at
    ``--help`` instead of printing the whole usage first (eight lines before the error for ``twin estimate``).
    Subcommands' parsers are of this class too (``add_subparsers`` takes the parent's)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        # argparse takes "-1e-3" (and "-inf") for an option: its own pattern knows only -1 and -1.5, so
        # "--support-plane 0 0 1 -1e-3" was "unrecognized arguments: -1e-3". No option of ours starts with a digit.
        # A comma list of numbers (--delays -5,0) is a value too, and said negative by the command.
        number = r"(?:(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?|inf(?:inity)?|nan)"
        self._negative_number_matcher = re.compile(rf"^-{number}(?:,-?{number})*$", re.I)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="twin", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages to stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("estimate", help="estimate volume, mass, centre of mass and inertia from a cloud",
                       description="Several VIEWs are views of one object: points in one shared world frame, each "
                                   "with its sensor origin (a PCD's VIEWPOINT header, or --viewpoint once per view). "
                                   "Depth images (16-bit PNG in millimetres, .npy) need --intrinsics.")
    p.add_argument("views", nargs="+", type=Path, metavar="VIEW",
                   help="PLY, PCD, XYZ/TXT, NPY or NPZ point cloud; with --intrinsics, a depth image (.png, .npy)")
    dens = p.add_mutually_exclusive_group()
    dens.add_argument("--density", type=float, help="kg/m^3")
    dens.add_argument("--material", help="a name or alias from the material table (e.g. wood_oak, PLA, "
                                          "aluminum; list: twin materials)")
    _units_option(p, "the file", checked=True)
    p.add_argument("--method", default="auto", choices=["auto", "obb", "hull", "surface"])
    p.add_argument("--viewpoint", type=float, nargs=3, metavar=("X", "Y", "Z"), action="append",
                   help="sensor position (file units) to orient estimated normals towards; once per VIEW, in "
                        "order (replaces a PCD VIEWPOINT header)")
    p.add_argument("--support-plane", nargs="+", metavar="PLANE",
                   help="the plane the object rests on: 'auto' (found in the data, else the horizontal plane "
                        "through the lowest point, z up, unless a sensor lies below it: then none) or A B C D with A x + B y + C z + D = 0 (D in file "
                        "units), normal pointing up into the object's side; its points are cut away and the "
                        "object's base is closed on it")
    p.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                   help="pinhole intrinsics in pixels (OpenCV/Open3D convention): every VIEW is a depth image")
    p.add_argument("--depth-scale", type=float,
                   help="metres per depth unit (default 0.001 for integer images, 1 for float .npy; the inverse "
                        "of Open3D's depth_scale)")
    p.add_argument("--viewpoint-pose", type=float, nargs=7, action="append",
                   metavar=("TX", "TY", "TZ", "QW", "QX", "QY", "QZ"),
                   help="a depth image's camera-to-world pose (metres; camera axes x right, y down, z forward), "
                        "once per depth image (default: identity, points in the camera frame)")
    p.add_argument("--mesh-out", type=Path, help="write the reconstructed mesh (.stl, .ply, .obj); an existing "
                   "file is replaced only if it is a mesh --mesh-out wrote")
    p.add_argument("--keep-strays", action="store_true",
                   help="keep clusters of points apart from the object, each under 1 %% of the points (by default "
                        "they are dropped as outliers, with a warning)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    _rerun_option(p)
    p.set_defaults(handler=_cmd_estimate)

    p = sub.add_parser("build", help="build a scene file into DIR: scene.xml, assets/, objects/<id>.xml, "
                                     "estimates.json")
    p.add_argument("scene", type=Path, help="scene TOML file")
    p.add_argument("--out", type=Path, required=True, help="output directory (replaced atomically)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    _coacd_options(p)
    _rerun_option(p)
    p.set_defaults(handler=_cmd_build)

    p = sub.add_parser("run", help="run the local twin loop, paced to real time")
    p.add_argument("scene", type=Path, help="scene TOML file or a built directory with scene.xml")
    p.add_argument("--duration", type=float, default=5.0, help="simulated seconds (default 5)")
    p.add_argument("--rate", type=float, default=None,
                   help="loop rate, Hz: a whole number of physics steps per iteration, so 1000 Hz divided by a whole "
                        "number at the 1 ms step (1000, 500, 333.333, 250, ...; default one step per iteration: "
                        "1000 Hz for a built scene, 1 / timestep for a folder's own model); --duration stays "
                        "simulated seconds and real-time pacing real")
    p.add_argument("--viewer", action="store_true", help="open MuJoCo's passive viewer (needs a display)")
    p.add_argument("--script", type=Path, help="end-effector trajectory CSV: rows t,x,y,z (seconds, increasing; "
                                               "metres or --units, world frame), an optional header row t,x,y,z, '#' "
                                               "comments; linear between rows, held after the last; every target "
                                               "within the operator's reach of the table; default: a push")
    _units_option(p, "the --script file's positions")
    p.add_argument("--no-realtime", action="store_true", help="run as fast as possible")
    p.add_argument("--json", action="store_true")
    _coacd_options(p)
    _rerun_option(p)
    p.set_defaults(handler=_cmd_run)

    p = sub.add_parser("demo", help="remote scene and local twin synchronised over Zenoh on loopback (no server)")
    p.add_argument("--duration", type=float, default=5.0, help="seconds of pushing after the twin is built")
    p.add_argument("--scene", type=Path, help="scene TOML for the remote (default: the paper's objects); its "
                   "[end_effector] push aims the push (default 2.2 m along +x)")
    p.add_argument("--zenoh-config", type=Path, help="a Zenoh JSON5 config for both sides")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    _sensor_option(p)
    _hold_option(p)
    _rerun_option(p)
    _record_option(p)
    p.set_defaults(handler=_cmd_demo)

    p = sub.add_parser("remote", help="the remote scene C: ground truth, sensor, publishes clouds and poses")
    p.add_argument("scene", type=Path, help="scene TOML file")
    p.add_argument("--duration", type=float, default=3600.0, help="seconds to run (default 1 h)")
    p.add_argument("--points", type=int, help="points per object cloud (default: the scene's)")
    p.add_argument("--deadband-mm", type=float, default=1.0, help="pose deadband, position (default 1 mm)")
    p.add_argument("--deadband-deg", type=float, default=0.5, help="pose deadband, angle (default 0.5 deg)")
    _sensor_option(p)
    _network_options(p, listen_default="tcp/127.0.0.1:7447")
    _rerun_option(p)
    _record_option(p)
    p.set_defaults(handler=_cmd_remote)

    p = sub.add_parser("local", help="the local twin C': follows a remote scene over Zenoh")
    p.add_argument("--scene", help="scene name (default: the one remote that answers)")
    p.add_argument("--duration", type=float, default=3600.0, help="seconds to run (default 1 h)")
    p.add_argument("--stale-after", type=float, default=1.0, help="seconds of silence before the link is stale")
    p.add_argument("--json", action="store_true", help="print the session report as JSON at the end")
    _hold_option(p)
    _network_options(p, connect_default="tcp/127.0.0.1:7447")
    _rerun_option(p)
    _record_option(p)
    operator = p.add_mutually_exclusive_group()
    operator.add_argument("--script", type=Path, help="operator targets from a trajectory CSV: rows t,x,y,z "
                                                      "(seconds of twin time, increasing; metres or --units, world "
                                                      "frame), an optional header row t,x,y,z, '#' comments; linear "
                                                      "between rows, held after the last; every target within the "
                                                      "operator's reach of the table")
    _units_option(p, "the --script file's positions")
    operator.add_argument("--replay-operator", type=Path, metavar="RECORDING",
                          help="operator targets from a recording (.mcap), on the twin's time")
    operator.add_argument("--operator-topic", action="store_true",
                          help="follow a device driver's OperatorTarget messages on twin/<scene>/operator/target")
    p.add_argument("--force-rate", type=float, default=1000.0,
                   help="OperatorForce messages per second on twin/<scene>/operator/force (default 1000, the "
                        "loop rate; 0: none)")
    p.set_defaults(handler=_cmd_local)

    p = sub.add_parser("replay", help="re-run a recorded session headless on the simulated clock")
    p.add_argument("recording", type=Path, help="a .mcap file written by --record")
    p.add_argument("--script", type=Path, help="operator targets from this trajectory CSV (t,x,y,z) instead")
    _units_option(p, "the --script file's positions")
    p.add_argument("--scene", type=Path, help="scene TOML (default: the one in the recording)")
    _sensor_option(p, replay=True)
    p.add_argument("--delay", dest="delay_ms", type=float, help="one-way delay each way, ms")
    p.add_argument("--jitter", dest="jitter_ms", type=float, help="delay standard deviation, ms (at most delay/3)")
    p.add_argument("--loss", dest="loss_pct", type=float, help="independent packet loss each way, percent")
    p.add_argument("--seed", type=int, help="seed of the emulated network (default: the recording's, else 0)")
    p.add_argument("--duration", dest="replay_duration", type=float,
                   help="twin seconds to run (default: as long as the recording; at most 3600)")
    p.add_argument("--out", type=Path, help="folder for summary.json and replay.mcap")
    p.add_argument("--cache-dir", type=Path, help="CoACD cache folder, not the current one (default "
                   "$TWIN_CACHE_DIR, else $XDG_CACHE_HOME/tactile-twin/coacd, else ~/.cache/tactile-twin/coacd)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(handler=_cmd_replay)

    from cli.experiment import add_parser as add_experiment

    add_experiment(sub)

    p = sub.add_parser("materials", help="list the material table")
    p.set_defaults(handler=_cmd_materials)

    p = sub.add_parser("schema", help="print a file format's JSON Schema (scene: the scene TOML's, as docs/scene.schema.json)")
    p.add_argument("kind", choices=["scene"], help="which format")
    p.set_defaults(handler=_cmd_schema)
    return parser


def _estimate_progress(points: int):  # type: ignore[no-untyped-def]
    """What ``twin estimate`` shows while it works: a line per stage on stderr for clouds larger than one pass
    takes (``tolerances.POINT_BUDGET`` points), which take seconds; nothing for smaller ones."""
    from estimation.tolerances import POINT_BUDGET

    if points <= POINT_BUDGET:
        return None
    start = time.perf_counter()

    def show(line: str) -> None:
        print(f"twin estimate: {time.perf_counter() - start:5.1f} s  {line}", file=sys.stderr, flush=True)

    return show


def _cmd_estimate(args: argparse.Namespace) -> int:
    import numpy as np

    from estimation import estimate, make_cloud
    from estimation.materials import resolve_density
    from estimation.units import unit_scale
    from estimation.views import assess, estimate_views

    scale = unit_scale(args.units or "m")
    if args.mesh_out is not None:  # before the work, and before anything is written
        check_mesh_file(args.mesh_out, args.views, "--mesh-out", suffixes=MESH_SUFFIXES)
    density, mat = resolve_density(args.material, args.density)
    name = None if mat is None else mat.name
    support = _support_plane(args.support_plane, scale)
    with _open_rerun(args, "estimate") as rlog, _logged_warnings("estimation") as logged:
        t0 = time.perf_counter()
        loaded = _estimate_views(args, scale)
        views = [v for v, _ in loaded]
        read = time.perf_counter() - t0
        single = len(views) == 1 and views[0].origin is None and support is None
        progress = _estimate_progress(sum(len(v.points) for v in views))
        if args.method != "auto" or single:
            if len(views) > 1 or support is not None:
                raise TwinError(f"several views and --support-plane need --method auto, not {args.method}")
            # One cloud with no sensor origin: the estimate orients its normals by the flood fill.
            cloud = loaded[0][1] if loaded[0][1] is not None else make_cloud(views[0].points)
            origin = views[0].origin
            result = estimate(cloud, density, method=args.method, material=name, read_seconds=read,
                              viewpoint=origin if origin is not None and origin.ndim == 1 else None,
                              keep_strays=args.keep_strays, progress=progress)
            # The points the surface was built from, with their outward normals: a face counts only where they
            # face it (a single view's slab has a far face nothing measured).
            cov = assess(result, result.points.astype(np.float64), 0.0,
                         normals=result.normals.astype(np.float64))[0] if result.method == "auto" else None
            bounds, warnings, plane = result.volume_bounds_m3, result.warnings, None
        else:
            fused = estimate_views(views, density, support=support, material=name, keep_strays=args.keep_strays,
                                   progress=progress)
            result, cov, bounds, warnings, plane = (fused.estimate, fused.coverage, fused.volume_bounds_m3,
                                                    fused.warnings, fused.plane)
        read_points = np.concatenate([v.points for v in views])
        if args.units is None:  # depth images too: millimetres read as metres made an 848 m object, exit 0
            # The estimate's own box: after the strays and the support plane went. Its points, if it kept them
            # ('auto'), else those read: where a few far points make the box vast, they are named.
            used = read_points if result.points is None else result.points.astype(np.float64)
            _check_units(result.obb.extents, depth=args.intrinsics is not None, points=used,
                         keep_strays=args.keep_strays)
        if args.mesh_out is not None:
            _write_mesh(result.vertices, result.faces, args.mesh_out)
        seconds = time.perf_counter() - t0
        rlog.estimate(args.views[0].stem, result, read_points)
    record = estimate_to_json(result, seconds)
    record["volume_bounds_m3"] = None if bounds is None else list(bounds)
    record["coverage"] = cov
    record["views"] = {"count": len(views), "points": [len(v.points) for v in views]}
    # Points read, as for one file: the views' own, not what fusion thinned them to before the estimate (a
    # run of 172,836 points said 11,862 in).
    record["points_in"] = sum(len(v.points) for v in views)
    record["support_plane"] = None if plane is None else list(plane.as_abcd())
    # What the readers only logged (normals or colours left out, a PCD's WIDTH x HEIGHT not its POINTS) is said in
    # the record too: a script reading the JSON saw none of it.
    record["warnings"] = [*warnings, *(w for w in dict.fromkeys(logged) if w not in warnings)]
    if args.json:
        print(to_json(record))
    else:
        _print_estimate(record)
    return 0


@contextlib.contextmanager
def _logged_warnings(name: str) -> Iterator[list[str]]:
    """The messages of the warnings the ``name`` logger and its children log inside the block, as a list."""
    messages: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if len(messages) < MAX_HELD_WARNINGS:
                messages.append(one_line(record.getMessage()))

    keep = Keep(logging.WARNING)
    logger = logging.getLogger(name)
    logger.addHandler(keep)
    try:
        yield messages
    finally:
        logger.removeHandler(keep)


def _support_plane(words: list[str] | None, scale: float):  # type: ignore[no-untyped-def]
    """--support-plane as 'auto', a Plane in metres (D scaled from file units), or None."""
    if words is None:
        return None
    if words == ["auto"]:
        return "auto"
    from estimation.views import plane_from_abcd

    try:
        a, b, c, d = (float(w) for w in words)
    except ValueError:
        raise TwinError(f"--support-plane takes 'auto' or four numbers A B C D, got {' '.join(words)}") from None
    return plane_from_abcd([a, b, c, d * scale])


def _estimate_views(args: argparse.Namespace, scale: float) -> list[tuple]:  # type: ignore[type-arg]
    """The VIEWs in metres with their sensor origins (clouds, or depth images with --intrinsics), each with
    its loaded cloud (None for a depth image)."""
    import numpy as np

    from estimation.errors import CloudError
    from estimation.views import View

    n = len(args.views)
    depth = args.intrinsics is not None
    if args.viewpoint is not None and len(args.viewpoint) != n:
        raise TwinError(f"--viewpoint given {len(args.viewpoint)} times for {n} views: give it once per VIEW, in order")
    if not depth and (args.depth_scale is not None or args.viewpoint_pose is not None):
        raise TwinError("--depth-scale and --viewpoint-pose are for depth images: pass --intrinsics FX FY CX CY")
    if depth and args.units not in (None, "m"):
        raise TwinError("--units is for point files: a depth image's unit is set by --depth-scale")
    if depth and args.viewpoint is not None:
        raise TwinError("a depth image's sensor origin is its camera: give --viewpoint-pose, not --viewpoint")
    if depth and args.viewpoint_pose is not None and len(args.viewpoint_pose) != n:
        raise TwinError(f"--viewpoint-pose given {len(args.viewpoint_pose)} times for {n} depth images: give it once "
                        f"per VIEW, in order")
    views, total = [], 0
    for k, path in enumerate(args.views):
        try:
            if depth:
                from estimation.carving import DepthView
                from estimation.depthimage import coarsened, depth_view, intrinsics, pose, read_depth

                image = read_depth(path, scale=args.depth_scale)
                camera = intrinsics(*args.intrinsics, width=image.shape[1], height=image.shape[0])
                image, camera, _ = coarsened(image, camera)
                rot, pos = pose(args.viewpoint_pose[k] if args.viewpoint_pose else [0, 0, 0, 1, 0, 0, 0])
                points, origin = depth_view(image, camera, rot, pos)
                view = (View(points, origin, path.name, DepthView(image, 0.0, camera, rot, pos)), None)
            else:
                cloud = _load_view(path, scale, total)
                total += len(cloud.points)
                origin = cloud.sensor_origins
                if args.viewpoint is not None:
                    origin = np.asarray(args.viewpoint[k], dtype=np.float64) * scale
                elif origin is not None and origin.strides[0] == 0:
                    origin = origin[0]  # one origin for the whole file (a PCD VIEWPOINT)
                view = (View(cloud.points, origin, path.name), cloud)
        except CloudError as exc:
            raise TwinError(exc if str(path) in str(exc) else f"{path}: {exc}") from exc
        views.append(view)
    return views


def _load_view(path: Path, scale: float, total: int):  # type: ignore[no-untyped-def]
    """One VIEW's cloud, refused if it would take the views together past ``cloudfile.MAX_POINTS`` (``total``
    read before it): the cap is per file, and forty copies of a 1M-point file passed 5 GB."""
    from estimation import load_cloud
    from estimation.cloudfile import MAX_POINTS
    from estimation.errors import CloudError

    together = f"{path}: the views together hold more than {MAX_POINTS:,} points, the most one estimate reads"
    left = MAX_POINTS - total
    if left < 1:
        raise TwinError(together)
    try:
        return load_cloud(path, scale=scale, max_points=left)
    except CloudError as exc:
        if total and "max_points=" in str(exc):
            raise TwinError(together) from exc
        raise


def estimate_to_json(result, seconds: float) -> dict:  # type: ignore[no-untyped-def]
    """The stable JSON form of a :class:`~estimation.PhysicalEstimate` (the CLI contract)."""
    m = result.mass
    return {
        "volume_m3": m.volume,
        "mass_kg": m.mass,
        "density_kg_m3": m.density,
        "material": result.material,
        "center_of_mass_m": m.center_of_mass.tolist(),
        "inertia_kg_m2": m.inertia.tolist(),
        "principal_moments_kg_m2": m.principal_moments.tolist(),
        "principal_axes": m.principal_axes.tolist(),
        "obb": {
            "center_m": result.obb.center.tolist(),
            "extents_m": result.obb.extents.tolist(),
            "rotation": result.obb.rotation.tolist(),
        },
        "method": result.method,
        "points_in": result.points_in,
        "points_used": result.points_used,
        "watertight": result.watertight,
        "cell_m": result.cell,
        "seconds": seconds,
        "timings_s": {k: getattr(result.timings, k) for k in
                      ("read", "downsample", "normals", "reconstruct", "mass_properties")},
        "volume_bounds_m3": None if result.volume_bounds_m3 is None else list(result.volume_bounds_m3),
        "warnings": list(result.warnings),
    }


def _print_estimate(record: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"estimate ({record['method']})", show_header=False)
    com = ", ".join(f"{x:.4f}" for x in record["center_of_mass_m"])
    rows = [
        ("volume", f"{record['volume_m3']:.6g} m^3 ({record['volume_m3'] * 1e6:.2f} cm^3)"),
        ("density", f"{record['density_kg_m3']:g} kg/m^3" + (f" ({record['material']})" if record["material"] else "")),
        ("mass", f"{record['mass_kg']:.6g} kg"),
        ("centre of mass", f"[{com}] m"),
        ("principal moments", ", ".join(f"{x:.4g}" for x in record["principal_moments_kg_m2"]) + " kg m^2"),
        ("OBB extents", ", ".join(f"{x:.4f}" for x in record["obb"]["extents_m"]) + " m"),
        ("points", f"{record['points_in']} in, {record['points_used']} used"),
        ("watertight", str(record["watertight"])),
        ("time", f"{record['seconds']:.3f} s"),
    ]
    if record.get("volume_bounds_m3"):
        low, high = record["volume_bounds_m3"]
        rows.insert(1, ("volume bounds", f"{low * 1e6:.2f} .. {high * 1e6:.2f} cm^3"))
    if record.get("coverage") is not None:
        rows.insert(2, ("coverage", f"{100 * record['coverage']:.0f} % of the surface observed, "
                                    f"{record['views']['count']} view(s)"))
    for key, value in rows:
        table.add_row(key, value)
    console = Console()
    console.print(table)
    for warning in record["warnings"]:
        console.print(f"[yellow]warning:[/yellow] {warning}")


def _write_mesh(vertices, faces, path: Path) -> None:  # type: ignore[no-untyped-def]
    """Write the mesh next to ``path`` and move it there: a failed export leaves an existing file whole."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)

    def write(tmp: Path) -> None:
        data = mesh.export(file_type=path.suffix.lstrip(".").lower())
        tmp.write_bytes(mark_mesh(path.suffix, data if isinstance(data, bytes) else data.encode()))

    try:
        replace_file(path, write)
    except (OSError, ValueError) as exc:
        raise TwinError(f"{path}: cannot write mesh ({exc})") from exc


def _coacd_options(p: argparse.ArgumentParser) -> None:
    from twin.decompose import CoacdSettings

    d = CoacdSettings()
    p.add_argument("--threshold", type=float, default=d.threshold,
                   help=f"CoACD concavity, in (0, 1] (default {d.threshold})")
    p.add_argument("--max-hulls", type=int, default=d.max_convex_hull,
                   help=f"CoACD max hulls, >= 1 or -1 for no cap (default {d.max_convex_hull})")
    p.add_argument("--cache-dir", type=Path, help="CoACD cache folder, not the current one (default "
                   "$TWIN_CACHE_DIR, else $XDG_CACHE_HOME/tactile-twin/coacd, else ~/.cache/tactile-twin/coacd)")


def _coacd_settings(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """The command's CoACD settings; a warning on stderr when --threshold makes CoACD slow (called just before
    a build: a command refused earlier keeps its one error line)."""
    from twin.decompose import FAST_THRESHOLD, CoacdSettings

    settings = CoacdSettings(threshold=args.threshold, max_convex_hull=args.max_hulls)
    if settings.threshold < FAST_THRESHOLD:
        print(f"twin {args.command}: warning: --threshold {settings.threshold:g} is below {FAST_THRESHOLD:g}, where "
              f"CoACD slows sharply (a 2,300-face torus: 2 s at 0.02, 40 s at 0.01); each concave object may take "
              f"minutes", file=sys.stderr)
    return settings


def _cmd_build(args: argparse.Namespace) -> int:
    from cli.outputs import check_creatable
    from scenes.build import build_scene, check_output, write_scene
    from scenes.scenefile import load_scene

    scene = load_scene(args.scene)
    keep = (args.scene, *(Path(str(o.value)) for o in scene.objects if o.source in ("mesh", "cloud")))
    check_creatable(args.out)
    check_output(args.out, keep=keep)  # before the work: a refused folder should not cost a build
    from rich.console import Console

    err = Console(stderr=True)

    def progress(k: int, n: int, obj, report) -> None:  # type: ignore[no-untyped-def]
        est = obj.estimate
        how = ("cached" if obj.hull_cached else f"collides as a {obj.primitive.kind}, no CoACD" if obj.primitive
               else "near-convex, no CoACD" if report.skipped_coacd else "CoACD")
        err.print(f"[{k + 1}/{n}] {obj.id}: estimated in {report.source_seconds + report.estimate_seconds:.1f} s "
                  f"({est.mass.mass:.3f} kg, {est.method}"
                  f"{', ' + str(len(est.warnings)) + ' warning(s)' if est.warnings else ''}), "
                  f"{len(obj.hulls)} hull(s) in {report.hull_seconds:.1f} s ({how})", soft_wrap=True)  # a line each

    with _open_rerun(args, "scene") as rlog:  # before the work: a bad --rerun should not cost a build
        coacd = _coacd_settings(args)
        err.print(f"building {scene.name!r}: {len(scene.objects)} objects")
        built = build_scene(scene, coacd=coacd, cache_dir=args.cache_dir, on_object=progress)
        cached = sum(o.hull_cached for o in built.objects)
        skipped = sum(r.skipped_coacd for r in built.reports.values())
        err.print(f"convex decomposition: {built.decompose_seconds:.1f} s over {built.workers} worker(s) ({cached} of "
                  f"{len(built.objects)} objects from the cache, {skipped} near-convex without CoACD)", soft_wrap=True)
        path = write_scene(built.spec, args.out, keep=keep, built=built)
        _log_built(rlog, built)
    if args.json:
        print(to_json({"scene_xml": str(path), "estimates_json": str(path.parent / "estimates.json"),
                       "seconds": built.seconds, "decompose_seconds": built.decompose_seconds,
                       "objects": [{"id": o.id, "mass_kg": o.estimate.mass.mass, "volume_m3": o.estimate.volume,
                                    "hull_count": len(o.hulls), "hulls_cached": o.hull_cached,
                                    "estimate_seconds": built.estimate_seconds.get(o.id),
                                    "warnings": list(o.estimate.warnings),
                                    "mjcf": str(path.parent / "objects" / f"{o.id}.xml")}
                                   for o in built.objects]}))
        _print_warnings(built)  # stderr, as without --json: the JSON holds them too, but stdout may go to a file
        return 0
    _print_objects(built)
    _print_warnings(built)
    print(f"wrote {path}, objects/<id>.xml and estimates.json in {path.parent} ({built.seconds:.1f} s)")
    return 0


def _print_objects(built) -> None:  # type: ignore[no-untyped-def]
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"scene {built.scene.name}")
    for col in ("object", "mass kg", "volume cm^3", "hulls", "cached", "estimate s", "material"):
        table.add_column(col, justify="right" if col != "object" else "left")
    for o in built.objects:
        secs = built.estimate_seconds.get(o.id)
        table.add_row(o.id, f"{o.estimate.mass.mass:.3f}", f"{o.estimate.volume * 1e6:.1f}", str(len(o.hulls)),
                      "yes" if o.hull_cached else "no", "-" if secs is None else f"{secs:.1f}",
                      o.estimate.material or f"{o.estimate.mass.density:g} kg/m^3")
    Console().print(table)


def _print_warnings(built) -> None:  # type: ignore[no-untyped-def]
    """Each object's estimate's warnings on stderr, with or without --json."""
    from rich.console import Console
    from rich.markup import escape

    # Said here (on stderr, as every warning), not only counted in the progress lines and kept in
    # estimates.json: a 1 mm disc's +400 % mass comes with the estimate's own warning that the volume is not
    # known. One line each (no wrapping), and escaped: a "[...]" in a warning is text, not rich markup.
    err = Console(stderr=True)
    for o in built.objects:
        for warning in o.estimate.warnings:
            err.print(f"[yellow]warning:[/yellow] {escape(o.id)}: {escape(warning)}", soft_wrap=True)


def _load_twin(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """A Twin from a scene file (built now) or a directory written by ``twin build``."""
    from twin.sim import Twin

    path = Path(args.scene)
    if path.is_dir():
        import mujoco

        xml = path / "scene.xml"
        if not xml.exists():
            raise TwinError(f"{path}: no scene.xml (build it with 'twin build')")
        if not xml.is_file():  # a link to /dev/zero was "no scene.xml"; a FIFO would block MuJoCo's read
            raise TwinError(f"{xml}: not a regular file (a folder, device or pipe); 'twin build' writes a file there")
        from cli.modelsize import check_model_size

        check_model_size(xml)  # MuJoCo expands <replicate> while it parses: a nested pair never came back
        warned: list[str] = []  # what MuJoCo doubts in the XML ("XML contains a 'NaN'"): said in our error line
        with mujoco_warnings(warned.append):
            try:  # RuntimeError: what MuJoCo's binding raises for a C++ exception (a builtin mesh far too fine)
                spec = mujoco.MjSpec.from_file(str(xml))
            except (ValueError, RuntimeError) as exc:
                raise TwinError(f"{xml}: MuJoCo cannot load it ({exc})") from exc
            try:  # here, not in Twin: a mesh file gone or a negative size since 'twin build' is the folder's fault
                model = spec.compile()
            except (ValueError, RuntimeError) as exc:
                first = str(exc).strip().splitlines()[0].removeprefix("Error: ") if str(exc).strip() else "no reason given"
                also = f"; MuJoCo warned: {warned[0]}" if warned else ""
                raise TwinError(f"{path}: MuJoCo cannot compile its scene.xml ({first}{also})") from exc
        _check_compiled(xml, model)
        if warned:  # a folder 'twin build' wrote loads without a warning: this one was edited into doubt
            raise TwinError(f"{xml}: MuJoCo warns of it: {warned[0]}")
        from scenes.placement import check_placement

        twin = Twin(spec, model, strict=True)  # a run that diverges says so (DivergedError), not "moved 1e29 m"
        try:  # the folder may have been edited since 'twin build' checked it
            check_placement(str(path), twin.model, set(twin.object_ids()), twin.data)
        except Exception:
            twin.close()
            raise
        return twin, None
    from scenes.build import build_scene
    from scenes.scenefile import load_scene

    built = build_scene(load_scene(path), coacd=_coacd_settings(args), cache_dir=args.cache_dir)
    return Twin(built.spec, built.model, strict=True), built


#: Physics timesteps ``twin run`` takes from a built folder, seconds: 'twin build' writes 1 ms; a 1 ns step
#: asked for a million steps per loop iteration, and 0 or NaN divided by zero.
TIMESTEP_RANGE_S = (1e-5, 0.1)


def _check_compiled(xml: Path, model) -> None:  # type: ignore[no-untyped-def]
    """Refuse an edited folder's model whose timestep is outside TIMESTEP_RANGE_S or whose bodies start at
    non-finite places (a NaN position ran, logging a non-finite state every step) or further than
    :data:`sync.messages.MAX_COORDINATE` from their parents.

    Raises:
        TwinError: naming the file and the value.
    """
    import numpy as np

    from sync.messages import MAX_COORDINATE

    low, high = TIMESTEP_RANGE_S
    step = float(model.opt.timestep)
    if not low <= step <= high:  # NaN fails too
        raise TwinError(f"{xml}: timestep {refused_number(step, low, high)} s is outside [{low:g}, {high:g}] s")
    for name, values in (("body position", model.body_pos), ("body orientation", model.body_quat),
                         ("initial joint position", model.qpos0)):
        if not np.isfinite(values).all():
            raise TwinError(f"{xml}: a {name} is not finite")
    # A body 1e30 m out ran "successfully": MuJoCo warned of a huge value each step and the twin put it back
    # where it started, out there. A scene is metres across; no message may carry a coordinate past this either.
    far = float(np.abs(model.body_pos).max(initial=0.0))
    if far > MAX_COORDINATE:
        raise TwinError(f"{xml}: a body position is {refused_number(far, MAX_COORDINATE)} m from its parent, "
                        f"beyond {MAX_COORDINATE:g} m")


def _trajectory(args: argparse.Namespace, twin):  # type: ignore[no-untyped-def]
    """The default operator of ``twin run``: a push from where the end effector starts."""
    import numpy as np

    from twin.trajectory import push_trajectory

    start = twin.data.mocap_pos[0].copy() if twin.model.nmocap else np.zeros(3)
    return push_trajectory(start, start + np.array([1.0, 0.0, -0.15]), max(args.duration, 1e-3))


def _cmd_run(args: argparse.Namespace) -> int:
    from twin.loop import steps_per_iteration
    from twin.model import DEFAULT_PHYSICS, OPERATOR_REACH, model_reach_corners
    from twin.sim import DivergedError, run_paced
    from twin.trajectory import load_trajectory

    if args.rate is not None and not Path(args.scene).is_dir():  # before the build (a folder's own timestep:
        steps_per_iteration(args.rate, DEFAULT_PHYSICS.timestep)  # checked by run_paced)
    # Before the build: a bad script costs nothing. Its reach is checked once the scene's table is known.
    script = None if args.script is None else load_trajectory(args.script, units=args.units)
    with _open_rerun(args, "twin") as rlog:
        twin, built = _load_twin(args)
        with twin:
            if built is not None:
                _log_built(rlog, built)
            else:
                rlog.model_geometry(twin)
            if script is not None:
                script.check_reach(model_reach_corners(twin.model, OPERATOR_REACH))
            trajectory = (script or _trajectory(args, twin)) if twin.model.nmocap else None
            if args.rate is None:  # one physics step an iteration, whatever the model's timestep
                args.rate = 1.0 / float(twin.model.opt.timestep)
            start = {i: twin.pose(i) for i in twin.object_ids()}
            try:
                if args.viewer:
                    stats = _run_with_viewer(twin, args, trajectory)
                else:
                    stats = run_paced(twin, args.duration, args.rate, trajectory=trajectory,
                                      realtime=not args.no_realtime, rlog=rlog)
            except DivergedError as exc:  # the model's fault: name it
                raise TwinError(f"{args.scene}: {exc}") from None
            record = {"steps": stats.steps, "rate_hz": args.rate, "step_p50_ms": stats.p50 * 1e3,
                      "step_p99_ms": stats.p99 * 1e3, "step_max_ms": stats.max * 1e3, "missed_deadlines": stats.missed,
                      "wall_s": stats.wall, "sim_time_s": twin.time, "objects": len(twin.object_ids()),
                      "ee_force_n": twin.end_effector_force().tolist() if twin.model.nmocap else None,
                      "per_object": [_pose_record(i, *twin.pose(i), *start[i]) for i in twin.object_ids()
                                     if i in start]}
    if args.json:
        print(to_json(record))
    else:
        print(f"{record['steps']} loop iterations at {args.rate:g} Hz over {stats.wall:.2f} s wall: "
              f"step p50 {record['step_p50_ms']:.3f} ms, p99 {record['step_p99_ms']:.3f} ms, "
              f"max {record['step_max_ms']:.3f} ms, missed deadlines {stats.missed}")
        for o in record["per_object"]:
            x, y, z = o["position_m"]
            print(f"  {o['id']}: at ({x:.3f}, {y:.3f}, {z:.3f}) m, moved {o['displacement_m'] * 1e3:.1f} mm "
                  f"and turned {o['rotation_deg']:.1f} deg")
    return 0


def _pose_record(object_id: str, position, quat, start_position, start_quat) -> dict:  # type: ignore[no-untyped-def]
    """Where an object ended (centre of mass, world frame; quaternion w x y z) and how far it went."""
    import numpy as np

    from twin.poses import angle_deg

    return {"id": object_id, "position_m": position.tolist(), "quat_wxyz": quat.tolist(),
            "displacement_m": float(np.linalg.norm(position - start_position)),
            "rotation_deg": angle_deg(quat, start_quat)}


def _run_with_viewer(twin, args, trajectory):  # type: ignore[no-untyped-def]
    import os

    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise TwinError("--viewer needs a display (DISPLAY is not set); run headless without --viewer")
    import mujoco.viewer

    from twin.sim import run_paced

    with mujoco.viewer.launch_passive(twin.model, twin.data) as handle:
        stats = None
        while handle.is_running() and (stats is None or twin.time < args.duration):
            # A 60 Hz frame, or one iteration where the loop runs slower: a shorter frame would run none.
            stats = run_paced(twin, max(1.0 / 60, 1.0 / args.rate), args.rate, trajectory=trajectory)
            handle.sync()
    return stats


def _units_option(p: argparse.ArgumentParser, what: str, *, checked: bool = False) -> None:
    """``--units``: the length unit of ``what`` (the names of :data:`estimation.units.UNIT_SCALE`, written out:
    importing it loads numpy, which ``--help`` does not need). ``checked``: not given, it is metres and an object
    of an implausible size is refused (:func:`_check_units`); None then stands for "not given"."""
    if checked:
        p.add_argument("--units", default=None, choices=["m", "cm", "mm"],
                       help=f"units of {what} (default m; an object outside {_PLAUSIBLE} across is then refused "
                            f"as probably in other units: give --units m to take it as metres)")
    else:
        p.add_argument("--units", default="m", choices=["m", "cm", "mm"], help=f"units of {what} (default m)")


#: tolerances.PLAUSIBLE_EXTENT_M as --help says it (written out: importing it loads numpy).
_PLAUSIBLE = "2 mm to 5 m"


def _check_units(extents, *, depth: bool = False, points=None, keep_strays: bool = False) -> None:  # type: ignore[no-untyped-def]
    """Refuse an estimate whose object, read as metres, is a size no object here is: ``extents`` (metres) of its
    box, measured after stray points and the support plane are gone (a 5 cm cube written in mm read as 85 m across
    and 125 m^3). --units, given, says the size is meant and only warns. ``depth``: the views are depth images,
    whose unit is --depth-scale's (--units mm is refused beside --intrinsics), so the message names that.
    ``points`` (metres, the estimate's): when a few far points make the object vast and the rest is of a plausible
    size, those are named instead of the units (one point 3 m off a box kept by ``keep_strays``, --keep-strays).

    Raises:
        TwinError: the object's size, the plausible range and the option that sets the unit, or the far points.
    """
    from estimation.cloud import far_points, without_far_points
    from estimation.units import implausible_size

    largest, side = float(max(extents)), implausible_size(extents)
    if side == 0:
        return
    size = (f"object is {largest:.3g} m across, more than" if side > 0 else
            f"object is {largest * 1000:.3g} mm across, less than")
    if side > 0 and points is not None and (far := far_points(points)):
        rest = without_far_points(points)
        if implausible_size(rest.max(axis=0) - rest.min(axis=0)) == 0:
            raise TwinError(f"object is {largest:.3g} m across because of {far}: remove them"
                            + (", or drop --keep-strays, which keeps them" if keep_strays else ""))
    if depth:
        raise TwinError(f"{size} the {_PLAUSIBLE} an object here is: the depth images are probably in other units "
                        f"(check --depth-scale, metres per depth unit: default 0.001 for integer images, 1 for float "
                        f".npy; or give --units m to take the size as meant)")
    if side > 0:
        raise TwinError(f"{size} the {_PLAUSIBLE} an object here is: the file is "
                        f"probably in other units (give --units mm or --units cm, or --units m to take it as metres)")
    raise TwinError(f"{size} the {_PLAUSIBLE} an object here is: give --units m to take the points as metres")


def _sensor_option(p: argparse.ArgumentParser, *, replay: bool = False) -> None:
    """``--sensor``: the remote's (the names of :data:`scenes.headless.SENSORS`, written out: importing it loads
    MuJoCo, which ``--help`` does not need). ``replay``: the default is the one the recording names."""
    if replay:
        p.add_argument("--sensor", choices=["surface", "cameras"], default=None,
                       help="the remote's sensor to replay with (default: the one the recording names; 'surface' "
                            "for a recording that names none: twin local's, and those made before sensors were "
                            "recorded)")
        return
    p.add_argument("--sensor", choices=["surface", "cameras"], default="surface",
                   help="what the remote publishes: 'surface' (default: whole true surfaces, simulator poses) or "
                        "'cameras' (3 ray-cast depth cameras around the table with a Kinect v1 noise model, "
                        "segmented and fused, ICP poses; not the default: on the demo's paper scene volumes are off "
                        "by 5.1 %% at the median and up to 17.0 %% (three objects touch; each is cut from their "
                        "segment by the simulator's segmentation image); the 20-object clutter 1.1 / 7.3 %%; "
                        "bench/results/cameras.txt)")


def _hold_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-hold", dest="hold", action="store_false",
                   help="do not pin objects the remote reports at rest to its pose while nothing touches them")


def _rerun_option(p: argparse.ArgumentParser) -> None:
    from twin.rerunlog import DEFAULT_RATE_HZ

    p.add_argument("--rerun", nargs="+", metavar="MODE",
                   help="log to rerun: 'spawn' (a viewer), 'save FILE.rrd', or 'connect [HOST:PORT]'")
    p.add_argument("--rerun-rate", type=float, default=DEFAULT_RATE_HZ,
                   help=f"poses and forces logged per simulated second (default {DEFAULT_RATE_HZ:g})")


def _open_rerun(args: argparse.Namespace, layout: str = "sync"):  # type: ignore[no-untyped-def]
    """The rerun log the command's --rerun asks for (off without it), in the viewer layout ``layout``."""
    from twin.rerunlog import RerunLog, parse_target

    target = None if args.rerun is None else parse_target(args.rerun, args.rerun_rate)
    if target is not None and target.mode == "save":
        print(f"rerun: recording to {target.address} (open it with: rerun {target.address})", file=sys.stderr)
    return RerunLog.open(target, layout=layout)


def _log_built(rlog, built) -> None:  # type: ignore[no-untyped-def]
    t = built.scene.table
    if t is not None:
        rlog.table(t.size, t.height)
    for obj in built.objects:
        rlog.object("twin", obj)


def _record_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--record", type=Path, metavar="FILE.mcap",
                   help="record the session (wire messages both ways, operator targets and force, ground truth "
                        "where this process has it) to an MCAP file; replay it with 'twin replay'")


class _ReplayProgress:
    """``twin replay``'s progress on stderr, from its first report on (a recording refused before that leaves its
    one error line alone): a bar on a terminal, removed when done; elsewhere a line at the build and at each
    tenth of the simulated time."""

    def __init__(self) -> None:
        self._bar = None
        self._task = None
        self._next = 0.0
        self._live = sys.stderr.isatty()

    def __enter__(self) -> _ReplayProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()

    def __call__(self, stage: str, done: float, total: float) -> None:
        if not self._live:
            if stage == "building":
                print("twin replay: building the scene", file=sys.stderr, flush=True)
            elif done >= self._next or done >= total:
                print(f"twin replay: {done:.3g} / {total:.3g} s simulated", file=sys.stderr, flush=True)
                self._next = done + total / 10
            return
        if self._bar is None:
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self._bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[done]}"),
                                 TimeElapsedColumn(), console=Console(stderr=True), transient=True)
            self._bar.start()
            self._task = self._bar.add_task("building the scene", total=None, done="")
        if stage != "building":
            self._bar.update(self._task, description="replaying", completed=done, total=total,
                             done=f"{done:.3g} / {total:.3g} s simulated")


def _cmd_replay(args: argparse.Namespace) -> int:
    from cli.record import check_replay_inputs, check_replay_out, network_from_options, print_summary, replay
    from sync.netem import MAX_SEED

    if args.seed is not None and not 0 <= args.seed <= MAX_SEED:  # always: a recording's network takes it too
        raise TwinError(f"--seed must be a whole number from 0 to {MAX_SEED}, got {args.seed}")
    check_replay_inputs(args.recording)
    if args.out is not None:
        check_replay_out(args.out, args.recording, args.script, args.scene)
    network = network_from_options(delay_ms=args.delay_ms, jitter_ms=args.jitter_ms, loss_pct=args.loss_pct,
                                   seed=args.seed or 0)
    with _ReplayProgress() as progress:
        result = replay(args.recording, script=args.script, units=args.units, scene=args.scene, network=network,
                        seed=args.seed, sensor=args.sensor,
                        duration=args.replay_duration, out=args.out, cache_dir=args.cache_dir, progress=progress)
    if result.summary["damage"]:
        print(f"twin replay: warning: {result.summary['damage']}", file=sys.stderr)
    if args.seed is not None and result.summary["network"] is None:  # the seed is the emulated network's only
        print("twin replay: warning: --seed changed nothing: the replay has no emulated network (the recording had "
              "none; give --delay, --jitter or --loss)", file=sys.stderr)
    if args.json:
        print(to_json(result.summary))
    else:
        print_summary(result.summary)
    return 0


def _network_options(p: argparse.ArgumentParser, *, listen_default: str | None = None,
                     connect_default: str | None = None) -> None:
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"Zenoh endpoint to connect to, e.g. tcp/HOST:7447 (a zenohd router); repeatable"
                        f"{f' (default {connect_default})' if connect_default else ''}")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help=f"Zenoh endpoint to listen on{f' (default {listen_default})' if listen_default else ''}")
    p.add_argument("--zenoh-config", type=Path, help="a Zenoh JSON5 config (TLS, access control, routers)")
    p.add_argument("--insecure", action="store_true",
                   help="allow listening on a non-loopback address without TLS, by --listen or the "
                        "--zenoh-config file, and multicast scouting the file turns on (anyone on that network "
                        "can then read the scene and drive it)")
    p.set_defaults(listen_default=listen_default, connect_default=connect_default)


def _session(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from sync.zenoh_transport import LOOPBACK_ANY_PORT, make_config, open_session

    # make_config knows the policy: every endpoint checked and its host resolved, the flags' first (named as
    # the flags); loopback and scouting off where neither the flags nor the file say; and exposure (from the
    # flags or the file) refused unless --insecure.
    return open_session(make_config(listen=args.listen, connect=args.connect, config_file=args.zenoh_config,
                                    insecure=args.insecure, listen_default=args.listen_default or LOOPBACK_ANY_PORT,
                                    connect_default=args.connect_default, listen_name="--listen",
                                    connect_name="--connect"))


def _cmd_remote(args: argparse.Namespace) -> int:
    from scenes.scenefile import load_scene

    scene = load_scene(args.scene)
    if args.deadband_mm < 0 or args.deadband_deg < 0:
        raise TwinError("--deadband-mm and --deadband-deg must be >= 0")
    with _open_rerun(args, "remote") as rlog:
        _run_remote(args, scene, rlog)
    return 0


def _run_remote(args: argparse.Namespace, scene, rlog) -> None:  # type: ignore[no-untyped-def]
    from cli.demo import remote_sensor
    from cli.record import open_recorder, recording_transport
    from scenes.remote import Deadband, Remote
    from sync.clock import REAL_CLOCK
    from sync.zenoh_transport import ZenohTransport

    session = _session(args)
    recorder = open_recorder(args.record, clock=REAL_CLOCK, command="remote", side="remote", scene_path=args.scene,
                             sensor=args.sensor)
    started = False
    try:
        remote = Remote(scene, recording_transport(ZenohTransport(session), recorder, "remote"),
                        deadband=Deadband(args.deadband_mm * 1e-3, args.deadband_deg), sensor=remote_sensor(args.sensor, scene),
                        points=args.points, progress=True, rlog=rlog, recorder=recorder)
        started = True
        print(f"remote scene {scene.name!r}: {len(scene.objects)} objects published; running (Ctrl-C stops)",
              file=sys.stderr)  # status, not the result
        stats = remote.run(args.duration)
        c = remote.link.counters
        print(f"ran {stats.steps} steps; sent {c.messages_sent} messages, {c.bytes_sent:,} bytes; "
              f"{remote.pose_updates} pose updates" + (f"; the sensor lost sight of objects {remote.unseen_reports} "
                                                        "time(s)" if remote.unseen_reports else ""))
        remote.close()
    finally:
        session.close()
        _finish_recording(recorder, started)


def _finish_recording(recorder, started: bool, **end: object) -> None:  # type: ignore[no-untyped-def]
    """Put the recording in place if the session started; else drop it, leaving any earlier file untouched."""
    if recorder is None:
        return
    if started:
        recorder.close(**end)
    else:
        recorder.discard()


def _arrivals(local, every: int = 50):  # type: ignore[no-untyped-def]
    """A loop hook (``until`` that never stops the loop) printing objects in flight to stderr: each cloud as
    it starts estimating, each object as it becomes touchable, with the seconds since the twin started.
    Looked at every ``every`` iterations (50 ms at 1 kHz), so the loop's step does not pay for it."""
    t0 = time.perf_counter()
    seen_pending: set[str] = set()
    seen_ready: set[str] = set()
    calls = 0

    def check() -> bool:
        nonlocal calls
        calls += 1
        if calls % every:
            return False
        pending, ready = local.pending, local.objects
        for i in pending:
            if i not in seen_pending:
                seen_pending.add(i)
                print(f"twin: {i}: cloud received, estimating ({len(pending)} in flight)", file=sys.stderr)
        for i in ready:
            if i not in seen_ready:
                seen_ready.add(i)
                seen_pending.discard(i)  # a replacement cloud of the same object is news again
                print(f"twin: {i}: touchable after {time.perf_counter() - t0:.1f} s ({len(ready)} in the twin, "
                      f"{len(pending)} in flight)", file=sys.stderr)
        seen_ready.intersection_update(ready + pending)  # removed objects may come back
        return False

    return check


def _cmd_local(args: argparse.Namespace) -> int:
    with _open_rerun(args) as rlog:
        _run_local(args, rlog)
    return 0


def _run_local(args: argparse.Namespace, rlog) -> None:  # type: ignore[no-untyped-def]
    from cli.record import open_recorder, recorded_targets, recording_transport
    from sync.clock import REAL_CLOCK
    from sync.recording import read_recording
    from sync.zenoh_transport import ZenohTransport
    from twin.hold import HoldSettings
    from twin.runtime import Local, LocalSettings, OperatorSettings, SyncError
    from twin.trajectory import HeldTargets, Waypoints, load_trajectory

    # Before any session: a bad script or recording costs nothing. Its reach: once the remote's table is known.
    trajectory: Waypoints | HeldTargets | None = None
    if args.script is not None:
        trajectory = load_trajectory(args.script, units=args.units)
    elif args.replay_operator is not None:
        recording = read_recording(args.replay_operator)
        if recording.damage:  # what is intact still drives the twin; said, as twin replay and experiment say it
            log.warning("%s", recording.damage)
        trajectory = recorded_targets(recording)  # read and decoded once
        if not len(trajectory.times):
            raise TwinError(f"{args.replay_operator}: the recording has no operator targets")
    session = _session(args)
    recorder = open_recorder(args.record, clock=REAL_CLOCK, command="local", side="twin", scene_name=args.scene or "")
    started = False
    try:
        try:
            local = Local(recording_transport(ZenohTransport(session), recorder, "twin"), scene=args.scene,
                          settings=LocalSettings(stale_after=args.stale_after, hold=HoldSettings(enabled=args.hold)),
                          operator=OperatorSettings(listen=args.operator_topic, force_rate=args.force_rate),
                          rlog=rlog, recorder=recorder)
        except (SyncError, ValueError) as exc:
            raise TwinError(str(exc)) from exc
        started = True
        if trajectory is not None:  # outside the workspace, as live targets are dropped
            trajectory.check_reach(local.workspace)
        stats = local.run(args.duration, trajectory=trajectory, until=None if args.json else _arrivals(local))
        r, c = local.report, local.link.counters
        record = {"objects_synced": r.objects_synced, "pose_updates": r.pose_updates,
                  "dropped_malformed": c.dropped_malformed, "dropped_by_reason": dict(c.dropped_by_reason),
                  "out_of_scene": r.out_of_scene, "out_of_order": r.out_of_order,
                  "estimation_errors": r.estimation_errors, "failed_edits": r.failed_edits,
                  "evicted": dict(r.evicted), "resyncs": r.resyncs, "stale_events": r.stale_events,
                  "snaps": r.snaps, "holds": r.holds, "warned_objects": r.warned_objects,
                  "operator_targets": r.operator_targets,
                  "operator_dropped": dict(r.operator_dropped), "forces_sent": r.forces_sent,
                  "step_p99_ms": stats.p99 * 1e3, "missed_deadlines": stats.missed,
                  "objects": local.objects, "objects_pending": local.pending}
        record["per_object"] = _local_objects(local)
        if args.json:
            print(to_json(record))
        else:
            print("  ".join(f"{k} {v}" for k, v in record.items() if k not in ("objects", "per_object")))
            for o in record["per_object"]:
                warned = f"; its estimate warns ({len(o['warnings'])}, on stderr)" if o["warnings"] else ""
                print(f"  {o['id']}: {o['estimated_mass_kg']:.3f} kg, touchable {o['add_latency_s'] or 0:.2f} s "
                      f"after its cloud arrived, {(o['twin_minus_remote_m'] or 0) * 1e3:.1f} mm from the remote{warned}")
        local.close()
        _finish_recording(recorder, started, twin_time_s=local.twin.time)
    finally:
        session.close()
        _finish_recording(recorder, started)


def _local_objects(local) -> list[dict]:  # type: ignore[no-untyped-def]
    """Per-object records of a twin following a remote (:func:`cli.demo.object_records`)."""
    import numpy as np

    from cli.demo import body_masses, object_estimates, object_records

    ids = local.objects
    drift = {i: float(np.linalg.norm(local.twin.pose(i)[0] - r[0])) for i in ids
             if (r := local.remote_pose(i)) is not None}
    return object_records(local.report, body_masses(local.twin.model, ids), {i: local.twin.pose(i) for i in ids},
                          drift, estimates=object_estimates(local))


def _cmd_demo(args: argparse.Namespace) -> int:
    from cli.demo import check_demo_records, run_demo

    if args.duration <= 0:
        raise TwinError("--duration must be > 0")
    if args.scene is not None:
        from scenes.scenefile import load_scene

        load_scene(args.scene)  # a bad scene fails here with its own message, not in the remote process
    if args.record is not None:  # the remote's file beside it too, before rerun starts writing
        check_demo_records(args.record, tuple(_input_files(args)))
    with _open_rerun(args) as rlog:
        record = run_demo(duration=args.duration, scene_path=args.scene, progress=not args.json,
                          zenoh_config=None if args.zenoh_config is None else str(args.zenoh_config), rlog=rlog,
                          hold=args.hold, record=args.record, sensor=args.sensor)
    if args.json:
        print(to_json(record))
    return 0


def _cmd_materials(args: argparse.Namespace) -> int:
    from estimation.materials import aliases, materials

    also: dict[str, list[str]] = {}
    for alias, name in aliases().items():
        also.setdefault(name, []).append(alias)
    for mat in materials().values():
        names = f"  also: {', '.join(also[mat.name])}" if mat.name in also else ""
        print(f"{mat.name:18s} {mat.density:8.0f} kg/m^3  friction {mat.friction:.2f}{names}")
    return 0


def _cmd_schema(args: argparse.Namespace) -> int:
    from scenes.scenefile import scene_schema_text

    sys.stdout.write(scene_schema_text())
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
