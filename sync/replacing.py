"""Replacing a file with an output: which existing file an output may replace, and how it is written.

Outputs are written to a hidden sibling (:func:`hidden_sibling`) and renamed onto their path, so whatever stood
there is gone. One rule for every output that may meet an earlier file at its path (recordings, ``--record``;
rerun files, ``--rerun save``; meshes, ``--mesh-out``): an output replaces only what is its own, that is nothing,
an empty regular file (nothing of a user's is lost) or a regular file whose first bytes say this program wrote
it (an MCAP header naming tactile-twin, a rerun recording of its application id, a mesh's own mark: a file of
the output's kind alone was not enough, as a ROS 2 bag is an MCAP). Anything else is the user's: a folder, a
device, pipe or socket (the rename would delete the node, and reading a FIFO blocks), or a file of any other
kind. Each output refuses in its own words, naming its flag
(:func:`sync.recording.check_record_destination`, :func:`twin.rerunlog.parse_target`,
:func:`cli.outputs.check_mesh_file`).
"""

from __future__ import annotations

import hashlib
import os
import stat
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

#: Bytes of an existing file an output's recogniser is shown: past every format's signature (a binary STL's
#: 84-byte header, a PLY header's trimesh comment).
HEAD_BYTES = 512

#: What :func:`found_at` may find: ``nothing`` (the output is new), ``own`` (an empty file, or one of the
#: output's kind), ``folder``, ``special`` (a device, pipe or socket), ``other`` (a file of another kind),
#: ``unchecked`` (the path cannot be looked at) or ``unreadable`` (a regular file that cannot be read).
Kind = Literal["nothing", "own", "folder", "special", "other", "unchecked", "unreadable"]


@dataclass(frozen=True)
class Found:
    """What stands at an output's path (:func:`found_at`).

    Attributes:
        kind: what it is (:data:`Kind`).
        error: why it could not be looked at or read (``unchecked``, ``unreadable``): the OSError's words.
    """

    kind: Kind
    error: str = ""

    @property
    def replaceable(self) -> bool:
        """Whether the output may replace it: nothing is there, or a file that is its own."""
        return self.kind in ("nothing", "own")


def found_at(path: Path, own: Callable[[bytes, int], bool]) -> Found:
    """What stands at ``path``, the output's path, following links (a link is replaced, its target checked).

    Args:
        path: where the output goes.
        own: whether a non-empty regular file is of the output's kind, from its first :data:`HEAD_BYTES` bytes
            and its size in bytes.

    Returns:
        The finding; :attr:`Found.replaceable` says whether the output may replace it.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        return Found("nothing")
    except OSError as exc:  # a loop of links, a name too long, a folder we may not enter
        return Found("unchecked", str(exc.strerror or exc))
    if stat.S_ISDIR(st.st_mode):
        return Found("folder")
    if not stat.S_ISREG(st.st_mode):  # not opened: reading a FIFO blocks, /dev/zero never ends
        return Found("special")
    try:
        with path.open("rb") as f:
            head = f.read(HEAD_BYTES)
    except OSError as exc:
        return Found("unreadable", str(exc.strerror or exc))
    return Found("own" if st.st_size == 0 or own(head, st.st_size) else "other")


def hidden_sibling(path: Path, suffix: str) -> tuple[int, Path]:
    """Create ``.<name>.<random><suffix>`` beside ``path``, to be written and then renamed onto ``path``; return
    its open descriptor and path. It gets the permissions a plain ``open()`` would give a new file (0666 less
    the umask), not ``mkstemp``'s 0600: the renamed file would otherwise replace an earlier file's 0644 with
    0600. The one way the project makes such files (:class:`sync.recording.Recorder`,
    :func:`cli.outputs.replace_file`).

    Raises:
        OSError: the file cannot be created.
    """
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)
    except BaseException:
        os.close(fd)
        Path(name).unlink(missing_ok=True)
        raise
    return fd, Path(name)


#: The line of an output folder's marker file after which the files the command wrote there are listed, one a
#: line: the path in the folder (POSIX), a tab, the sha256 it was written with. ``twin build``, ``twin
#: experiment`` and ``twin replay`` mark their folders so, and refuse to replace a listed file that changed since:
#: the user's edits to a report are theirs.
FILES_HEADER = "files:"


def file_sha256(path: Path) -> str:
    """The sha256 of the file at ``path``, hex. Raises: OSError: it cannot be read."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def marker_text(intro: str, digests: Mapping[str, str]) -> str:
    """A marker file's text: ``intro`` (one line), then the files ``digests`` maps to their sha256, by name."""
    return intro.rstrip("\n") + "\n" + "\n".join([FILES_HEADER, *(f"{name}\t{digests[name]}" for name in sorted(digests))]) + "\n"


def listed_files(text: str) -> dict[str, str | None] | None:
    """The files a marker's ``text`` (:func:`marker_text`) lists, each with its sha256 (None where it gives none);
    None for a marker that lists none (one written before the lists)."""
    lines = text.splitlines()
    if FILES_HEADER not in lines:
        return None
    listed = (line.split("\t", 1) for line in lines[lines.index(FILES_HEADER) + 1:] if line)
    return {parts[0]: parts[1] if len(parts) > 1 else None for parts in listed}
