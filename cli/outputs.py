"""Where the commands write, checked before any work: never over an input, never into a user's own folder.

An output folder (``twin experiment --out``, ``twin replay --out``) must be new, empty, or one this
command wrote before (it holds the command's marker file); an output file (``--record``, ``--rerun save``,
the files written into an output folder) must not be one of the command's inputs. ``twin build --out``
follows the same rule with its own check (:func:`scenes.build.check_output`), since it replaces the
folder whole.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from collections.abc import Callable, Iterable
from pathlib import Path

from estimation.errors import TwinError
from sync.replacing import HEAD_BYTES, file_sha256, found_at, hidden_sibling, listed_files, marker_text


def same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (the same inode, or the same resolved path if either is new)."""
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # RuntimeError: a loop of links, on Python 3.11
        return False


def check_not_input(output: Path, inputs: Iterable[Path | None], flag: str) -> None:
    """Refuse an output file that is one of the inputs.

    Raises:
        TwinError: naming the flag, the file and the input it would overwrite.
    """
    for source in inputs:
        if source is not None and same_file(Path(output), Path(source)):
            raise TwinError(f"{flag} {output}: is the input {source}; writing it would destroy the input, choose another file")


def check_output_file(path: Path, inputs: Iterable[Path | None], flag: str, *, suffixes: Iterable[str]) -> None:
    """Refuse an output file before any work: one of the inputs, a format not among ``suffixes``, or a folder
    that does not exist. What may stand at the path is the output's own check (:func:`check_mesh_file`).

    Raises:
        TwinError: naming the flag, the file and why.
    """
    check_not_input(path, inputs, flag)
    suffixes = sorted(suffixes)
    if path.suffix.lower() not in suffixes:
        named = repr(path.suffix) if path.suffix else "(no suffix)"
        raise TwinError(f"{flag} {path}: unknown format {named}; use one of {', '.join(suffixes)}")
    if not path.parent.is_dir():
        raise TwinError(f"{flag} {path}: the folder {path.parent} does not exist")


def check_creatable(out: Path, flag: str = "--out") -> None:
    """Refuse a folder that cannot be made: its nearest existing ancestor is not a folder this user may write
    into (a file on the way, /proc), so that the command fails before its work, in one line.

    Raises:
        TwinError: naming the flag, the folder and the ancestor in the way.
    """
    import os

    out = Path(out)
    try:
        if out.is_dir():
            return
        ancestor = out.parent
        while not ancestor.exists() and ancestor != ancestor.parent:
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise TwinError(f"{flag} {out}: cannot be made: {ancestor} is not a folder")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise TwinError(f"{flag} {out}: cannot be made: {ancestor} is not writable")
    except OSError as exc:  # a name too long, a permission denied on the way
        raise TwinError(f"{flag} {out}: cannot be made ({exc.strerror or exc})") from None


def check_output_folder(out: Path, *, marker: str, command: str, flag: str = "--out", writes: Iterable[str] = (),
                        inputs: Iterable[Path | None] = ()) -> None:
    """Refuse an output folder this command must not write into: it exists and is not a folder, or holds
    files and not ``marker`` (so it is not this command's); a file the marker lists was edited since
    ``command`` wrote it (as ``twin build`` refuses its folder, :func:`scenes.build.check_output`); or one of
    the files it ``writes`` there is one of the ``inputs``, or a folder, device or pipe (which a file cannot
    replace).

    Raises:
        TwinError: naming the folder and why.
    """
    out = Path(out)
    check_creatable(out, flag)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / marker).is_file())):
        raise TwinError(f"{flag} {out}: exists and is not empty (and not a folder this command wrote); "
                        "choose a new folder")
    for name, digest in _listed(out, marker).items():
        # A report.md the user added to was replaced by the re-run, exit 0: their edits are theirs.
        path = out / name
        try:
            # A link planted there is no edit of ours: it is replaced, never written through (replace_file).
            edited = digest is not None and path.is_file() and not path.is_symlink() and file_sha256(path) != digest
        except OSError as exc:
            raise TwinError(f"{flag} {out}: cannot check {name} ({exc.strerror or exc})") from None
        if edited:
            raise TwinError(f"{flag} {out}: {name} was edited since {command} wrote it; move the folder aside or "
                            "give --out a new folder")
    inputs = tuple(inputs)
    for name in writes:
        check_not_input(out / name, inputs, flag)
        try:
            mode = (out / name).lstat().st_mode
        except OSError:  # not there (or not examinable: the write says so)
            continue
        if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):  # a link is replaced, never written through
            # An experiment ran all its sessions, then stopped on IsADirectoryError, a traceback.
            raise TwinError(f"{flag} {out}: {name} there is a folder or a device, not a file this command can "
                            "replace")


def _listed(out: Path, marker: str) -> dict[str, str | None]:
    """The files ``out``'s ``marker`` lists with their sha256 (:func:`sync.replacing.listed_files`); none for a
    folder without one, or with a marker from before the lists (what it wrote is not known: not checked).

    Raises:
        TwinError: the marker cannot be read.
    """
    try:
        text = (out / marker).read_text(errors="replace") if (out / marker).is_file() else ""
    except OSError as exc:
        raise TwinError(f"{out}: cannot read {marker} ({exc.strerror or exc})") from None
    return listed_files(text) or {}


def claim_output_folder(out: Path, *, marker: str, command: str) -> None:
    """Create ``out`` (checked by :func:`check_output_folder`) and mark it as ``command``'s, keeping the files its
    marker lists that are still there (checked unedited): a run that stops before rewriting one still guards it."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        kept = {name: digest for name, digest in _listed(out, marker).items()
                if digest is not None and (out / name).is_file()}
        replace_file(out / marker, lambda tmp: tmp.write_text(marker_text(f"written by {command}", kept)))
    except OSError as exc:  # the file system changed since check_output_folder, or refuses anyway
        raise TwinError(f"{out}: cannot write the output folder ({exc.strerror or exc})") from None


def write_output(out: Path, name: str, write: Callable[[Path], object], *, marker: str) -> Path:
    """Write ``out / name`` as :func:`replace_file` does, and list it with its sha256 in ``out``'s ``marker``
    (:func:`claim_output_folder` made it), so that the next run refuses to replace it once the user edits it.

    Raises:
        TwinError: the write, or the marker's, failed (:func:`write_failure`).
    """
    path = out / name
    replace_file(path, write)
    try:
        listed = {n: d for n, d in _listed(out, marker).items() if d is not None}
        listed[name] = file_sha256(path)
        intro = (out / marker).read_text(errors="replace").splitlines()[:1] or [""]
    except OSError as exc:
        raise TwinError(write_failure(exc, out / marker)) from None
    replace_file(out / marker, lambda tmp: tmp.write_text(marker_text(intro[0], listed)))
    return path


def replace_file(path: Path, write: Callable[[Path], object]) -> None:
    """Write ``path`` by ``write(temporary path)`` beside it, then move it into place.

    What stood at ``path`` is replaced, not written through: a symbolic link planted in an output folder
    (``summary.json`` -> a user's file elsewhere) had that file overwritten by the next run. A failed
    ``write`` leaves ``path`` as it was and no temporary file behind. The file gets the permissions a plain
    ``open()`` would have given it, not ``mkstemp``'s 0600 (:func:`sync.replacing.hidden_sibling`, which
    recordings use too).

    Raises:
        TwinError: the write or the move failed (a full disk, a folder now at ``path``): :func:`write_failure`.
    """
    fd, tmp = hidden_sibling(path, path.suffix)
    os.close(fd)
    try:
        try:
            write(tmp)
            os.replace(tmp, path)
        except OSError as exc:  # a full disk; a folder put in its place since the command's checks
            raise TwinError(write_failure(exc, path)) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_failure(exc: OSError, what: object) -> str:
    """Why writing ``what`` (a path, or "the output" for stdout) failed, in one line: a full disk or quota said
    so, since their ``strerror`` names no file; anything else with the system's reason."""
    if exc.errno == errno.ENOSPC:
        return f"no space left writing {what}"
    if exc.errno == errno.EDQUOT:
        return f"disk quota exceeded writing {what}"
    return f"cannot write {what}: {exc.strerror or exc}"


def check_record_file(path: Path, inputs: Iterable[Path | None], flag: str = "--record") -> None:
    """Refuse a recording path that is an input, a folder, a device or pipe, or an existing file that is not
    an MCAP recording (a user's own file, which the recording would replace); the same check the recorder
    makes when it opens (:func:`sync.recording.check_record_destination`), here before any work.

    Raises:
        TwinError: naming the flag, the file and why.
    """
    from sync.recording import check_record_destination

    check_not_input(path, inputs, flag)
    check_record_destination(path, f"{flag} {path}")


#: What marks a mesh as one ``--mesh-out`` wrote (:func:`mark_mesh`): the binary STL's 80-byte header, a comment
#: line in a PLY's header (after its format line) or an OBJ's first line. trimesh's own marks (a zeroed STL header,
#: its comment line) were taken for this command's until a hostile-input review replaced a user's trimesh-saved
#: part with exit 0.
MESH_MARK = b"written by tactile-twin: twin estimate --mesh-out"
_STL_HEADER = MESH_MARK.ljust(80, b"\0")
_PLY_MARK, _OBJ_MARK = b"comment " + MESH_MARK + b"\n", b"# " + MESH_MARK + b"\n"
#: A PLY header's face count: a mesh has one above 0.
_PLY_FACES = re.compile(rb"^element face (\d+)\s*$", re.M)


def mark_mesh(suffix: str, data: bytes) -> bytes:
    """``data``, a mesh trimesh exported in the format ``suffix`` names (binary STL, PLY, OBJ), with this command's
    mark (:data:`MESH_MARK`) put in."""
    suffix = suffix.lower()
    if suffix == ".stl":
        return _STL_HEADER + data[80:]
    if suffix == ".ply":
        first, _, rest = data.partition(b"\n")
        fmt, _, rest = rest.partition(b"\n")
        return first + b"\n" + fmt + b"\n" + _PLY_MARK + rest
    if suffix == ".obj":
        return _OBJ_MARK + data
    raise ValueError(f"no mesh mark for {suffix!r}")


def written_mesh(suffix: str, head: bytes, size: int, tail: bytes = b"") -> bool:
    """Whether a non-empty file of ``size`` bytes starting with ``head`` (its first
    :data:`sync.replacing.HEAD_BYTES`) and ending with ``tail`` (as many last bytes) is a mesh as ``--mesh-out``
    writes it in the format ``suffix`` names (:func:`mark_mesh`): a binary STL with this command's header whose
    triangle count (above 0) matches its size, a PLY carrying its comment whose header declares faces, an OBJ
    starting with its comment whose last line is a face (trimesh writes the faces last). A user's CAD export, a
    mesh or point cloud trimesh wrote, and any other file are not."""
    suffix = suffix.lower()
    if suffix == ".stl":
        count = int.from_bytes(head[80:84], "little")
        return len(head) >= 84 and head[:80] == _STL_HEADER and count > 0 and size == 84 + 50 * count
    if suffix == ".ply":
        header = head.split(b"end_header", 1)[0]
        faces = _PLY_FACES.search(header)
        return head.startswith(b"ply\n") and _PLY_MARK in header and faces is not None and int(faces[1]) > 0
    if suffix == ".obj":
        lines = tail.split(b"\n")
        last = next((line for line in reversed(lines) if line.strip()), b"")
        return head.startswith(_OBJ_MARK) and last.startswith(b"f ")
    return False


def _tail(path: Path, size: int) -> bytes:
    """The last :data:`sync.replacing.HEAD_BYTES` bytes of ``path`` (``size`` bytes long), or b"" if unreadable
    (then it is not a mesh this command wrote, and is refused)."""
    try:
        with path.open("rb") as f:
            f.seek(max(0, size - HEAD_BYTES))
            return f.read(HEAD_BYTES)
    except OSError:
        return b""


def check_mesh_file(path: Path, inputs: Iterable[Path | None], flag: str, *, suffixes: Iterable[str]) -> None:
    """:func:`check_output_file`, and refuse what an output may not replace (:func:`sync.replacing.found_at`):
    a folder, a device or pipe, or an existing file that is neither empty nor a mesh this command wrote
    (:func:`written_mesh`); the rule ``--record`` and ``--rerun save`` follow.

    Raises:
        TwinError: naming the flag, the file and why.
    """
    check_output_file(path, inputs, flag, suffixes=suffixes)
    found = found_at(path, lambda head, size: written_mesh(path.suffix, head, size, _tail(path, size)))
    if found.kind == "unchecked":
        raise TwinError(f"{flag} {path}: cannot check it ({found.error})")
    if found.kind in ("folder", "special"):  # the mesh moved into place would delete a FIFO or device node
        raise TwinError(f"{flag} {path}: exists and is not a regular file; refusing to replace it")
    if not found.replaceable:
        raise TwinError(f"{flag} {path}: exists and is not a mesh this command wrote; refusing to replace it")
