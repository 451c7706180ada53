"""Small hostile files against the limits that keep them small: time and peak memory of each, as the CLI runs it.

    .venv/bin/python bench/hostile_inputs.py      # output in bench/results/hostile_inputs.txt

Each input is written to a temporary folder, then given to ``twin`` in a child process; the table shows the file's
size, the exit code, wall seconds, the command's peak resident memory (``ru_maxrss``) and its first error or
warning line:
- a recording of 16 M empty messages packed into four zstd chunks (43 KB: every message 31 bytes, the same);
  before ``sync.recording.MAX_RECORDS_PER_BYTE`` it took 4 GB and 87 s to read (a fuzzing run at 0fbb4fc);
- a 4096 x 4096 16-bit depth PNG of a box on a floor (~40 KB), estimated as a view; before
  ``estimation.depthimage.coarsened`` every pixel became a point (2.8 GB, 20 s in that run);
- an .npz of 2,000 points whose deflated 'normals' (2 MB) declare (2000, 125000) zeros: unpacked to 2 GB
  before session 56 (refused now from the member's header: more than four values a point);
- a PLY whose 0.9 MB header declares 50,000 empty elements before its vertices: each name was compared with
  every one before it, 35.9 s at ffe99a1 before session 56's fix (a hostile-input review's find: 99.8 s for
  74,000);
- a binary PCD of 200,000 points with an unused field of 4096 doubles each (6.5 GB apparent, a sparse file:
  its bytes column is what it takes on disk): read whole into memory before session 56 (6.5 GB), in blocks
  of the fields used now (``cloudtable.read_binary_rows``).
Run it at an older commit for the "before" (``git worktree``; the figures above are that fuzzing run's).
The first row, ``twin --help`` run the same way, is the baseline: what starting the command costs.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TWIN = ROOT / ".venv" / "bin" / "twin"
MESSAGES_PER_CHUNK = 4_000_000
CHUNKS = 4


def packed_recording(path: Path) -> None:
    """A valid session header, then ``CHUNKS`` zstd chunks of ``MESSAGES_PER_CHUNK`` empty messages each."""
    import zstandard
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk, Message
    from mcap.writer import IndexType, Writer

    from sync.recording import SCHEMA_VERSION

    with path.open("wb") as f:
        w = Writer(f, use_chunking=False, use_statistics=False, use_summary_offsets=False, index_types=IndexType.NONE)
        w.start(profile="tactile-twin", library="bench")
        w.add_metadata("tactile_twin.session", {"schema_version": str(SCHEMA_VERSION), "scene_toml": ""})
        channel = w.register_channel("/wire/twin/received/x", "msgpack", 0)
        record = RecordBuilder()
        Message(channel_id=channel, sequence=0, log_time=1000, publish_time=0, data=b"").write(record)
        raw = record.end() * MESSAGES_PER_CHUNK
        packed = zstandard.ZstdCompressor(level=19).compress(raw)
        for _ in range(CHUNKS):
            Chunk(compression="zstd", data=packed, message_start_time=1000, message_end_time=1000,
                  uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw)).write(w._Writer__record_builder)
        w.finish()


def big_depth(path: Path) -> None:
    """A 4096 x 4096 depth image, millimetres: the floor at 1 m, a box's top 10 cm above it in the middle."""
    from PIL import Image

    depth = np.full((4096, 4096), 1000, np.uint16)
    depth[1365:2731, 1365:2731] = 900
    Image.fromarray(depth).save(path, optimize=True)


def _ball(n: int = 2000) -> np.ndarray:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(n, 3))
    return 0.05 * points / np.linalg.norm(points, axis=1, keepdims=True)


def _npy_header(shape: tuple[int, ...]) -> bytes:
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': {shape!r}, }}"
    header += " " * (64 - (10 + len(header) + 1) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode()


def npz_member_bomb(path: Path, columns: int = 125_000) -> None:
    """2,000 good points and a deflated 'normals' member of (2000, ``columns``) zeros: 2 GB unpacked."""
    import io
    import zipfile

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        buffer = io.BytesIO()
        np.save(buffer, _ball())
        archive.writestr("points.npy", buffer.getvalue())
        with archive.open("normals.npy", "w", force_zip64=True) as fh:
            fh.write(_npy_header((2000, columns)))
            zeros, left = bytes(1 << 24), 2000 * columns * 8
            while left > 0:
                fh.write(zeros[:min(left, len(zeros))])
                left -= len(zeros)


def ply_many_elements(path: Path, count: int = 50_000) -> None:
    """A PLY whose 1 MB header declares ``count`` empty elements before 2,000 good vertices."""
    elements = "".join(f"element e{i} 0\n" for i in range(count))
    header = ("ply\nformat binary_little_endian 1.0\n" + elements + "element vertex 2000\nproperty float x\n"
              "property float y\nproperty float z\nend_header\n")
    path.write_bytes(header.encode() + _ball().astype("<f4").tobytes())


def wide_sparse_pcd(path: Path, points: int = 200_000, count: int = 4096) -> None:
    """A binary PCD of ``points`` zero points with an unused field of ``count`` doubles each: 6.5 GB apparent, a
    sparse file of a few KB on disk."""
    header = (f"VERSION 0.7\nFIELDS x y z pad\nSIZE 4 4 4 8\nTYPE F F F F\nCOUNT 1 1 1 {count}\nWIDTH {points}\n"
              f"HEIGHT 1\nPOINTS {points}\nDATA binary\n").encode()
    with path.open("wb") as f:
        f.write(header)
        f.truncate(len(header) + points * (12 + 8 * count))


#: Runs the command and prints its exit code and peak memory (KB) last on stderr: a fresh parent per command,
#: since RUSAGE_CHILDREN's ru_maxrss is the largest of all its children so far.
_MEASURE = ("import resource, subprocess, sys; code = subprocess.run(sys.argv[1:]).returncode; "
            "print(code, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)")


def run(args: list[str]) -> tuple[int, float, float, str]:
    """Exit code, wall seconds, the command's peak resident memory (MB) and its first stderr line."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", _MEASURE, str(TWIN), *args], capture_output=True, text=True,
                          timeout=600)
    seconds = time.perf_counter() - t0
    *lines, last = done.stderr.splitlines()
    code, peak_kb = map(int, last.split())
    said = [ln for ln in lines if "error" in ln or "WARNING" in ln] or [ln for ln in lines if ln.strip()] or [""]
    return code, seconds, peak_kb / 1024, said[0]


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rows.append(("twin --help (baseline)", 0, *run(["--help"])))
        depth = folder / "depth_4096.png"
        big_depth(depth)
        rows.append(("4096 x 4096 depth PNG, estimated", depth.stat().st_size,
                     *run(["estimate", str(depth), "--intrinsics", "3686", "3686", "2048", "2048",
                           "--support-plane", "auto", "--json"])))
        bomb = folder / "normals_bomb.npz"
        npz_member_bomb(bomb)
        rows.append(("npz, 2 GB of deflated normals", bomb.stat().st_size, *run(["estimate", str(bomb), "--json"])))
        many = folder / "many_elements.ply"
        ply_many_elements(many)
        rows.append(("PLY header of 50,000 elements", many.stat().st_size, *run(["estimate", str(many), "--json"])))
        wide = folder / "wide_sparse.pcd"
        wide_sparse_pcd(wide)
        rows.append(("PCD, 32 KiB unused a point, sparse", wide.stat().st_blocks * 512,
                     *run(["estimate", str(wide), "--json"])))
        wide.unlink()
        recording = folder / "packed.mcap"
        packed_recording(recording)
        rows.append((f"{CHUNKS * MESSAGES_PER_CHUNK / 1e6:.0f} M empty messages, replayed", recording.stat().st_size,
                     *run(["replay", str(recording), "--duration", "0.05"])))
    lines = ["bench/hostile_inputs.py: small hostile files, as `twin` runs them (peak memory: ru_maxrss)", "",
             f"{'input':36s} {'bytes':>8s} {'exit':>4s} {'wall s':>7s} {'peak MB':>8s}  first stderr line"]
    for name, size, code, seconds, peak, line in rows:
        lines.append(f"{name:36s} {size:8,d} {code:4d} {seconds:7.2f} {peak:8.0f}  {line[:150]}")
    text = "\n".join(lines)
    print(text)
    out = ROOT / "bench" / "results" / "hostile_inputs.txt"
    out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
