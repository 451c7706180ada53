"""The trajectory reader: the CSV format of --script, interpolation, and one-line errors for bad files."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.errors import TwinError
from twin.trajectory import TrajectoryError, load_trajectory


def _write(tmp_path, text: str, name: str = "path.csv"):  # type: ignore[no-untyped-def]
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("header", ["t,x,y,z\n", "", "# a push\nT, X, Y, Z\n\n", "\ufefft,x,y,z\n", "\ufeff"])
def test_waypoints_are_interpolated_linearly_and_the_ends_held(tmp_path, header):
    path = _write(tmp_path, header + "0.0,0.1,0.0,0.2\n1.0,0.3,-0.2,0.2\n3.0,0.3,-0.2,0.6\n")
    at = load_trajectory(path)
    assert at(0.5) == pytest.approx([0.2, -0.1, 0.2])
    assert at(2.0) == pytest.approx([0.3, -0.2, 0.4])
    assert at(-1.0) == pytest.approx([0.1, 0.0, 0.2])  # before the first waypoint: the first
    assert at(10.0) == pytest.approx([0.3, -0.2, 0.6])  # after the last: held there
    assert at(1.0).shape == (3,) and at(1.0).dtype == np.float64


def test_one_waypoint_is_held_for_ever(tmp_path):
    at = load_trajectory(_write(tmp_path, "t,x,y,z\n0,1,2,3\n"))
    assert at(0.0) == pytest.approx([1, 2, 3]) and at(5.0) == pytest.approx([1, 2, 3])


@pytest.mark.parametrize("text, match", [
    ("t,x,y\n0,1,2\n", r"path.csv:1: expected 4 columns t,x,y,z, got 3$"),
    ("t,x,y,z\n0,1,2,3\n1,1,2\n", r"path.csv:3: expected 4 columns"),
    ("t,x,y,z\n0,1,two,3\n", r"path.csv:2: not a number in '0,1,two,3'$"),
    ("0,1,2,3\n1,nan,2,3\n", r"path.csv:2: non-finite value"),
    ("0,1,2,3\n1,1,2,inf\n", r"path.csv:2: non-finite value"),
    ("0,1,2,3\n1,1,2,3\n1,1,2,3\n", r"path.csv:3: t = 1 s does not increase \(previous 1 s\)$"),
    ("0,1,2,3\n2,1,2,3\n1,1,2,3\n", r"path.csv:3: t = 1 s does not increase"),
    ("t,x,y,z\n", r"path.csv: no waypoints"),
    ("", r"path.csv: no waypoints"),
    # A stray quote opens one field that runs past csv's 131,072-character limit: a traceback before.
    ('t,x,y,z\n"0,0,0,0.6\n' + "0.001,0.000,0.000,0.600\n" * 8_000, r"path.csv:\d+: not CSV \(field larger than field limit"),
])
def test_bad_files_are_one_line_errors_naming_file_and_line(tmp_path, text, match):
    with pytest.raises(TrajectoryError, match=match) as err:
        load_trajectory(_write(tmp_path, text))
    assert isinstance(err.value, ValueError) and isinstance(err.value, TwinError)
    assert "\n" not in str(err.value)


def test_an_unreadable_file_is_a_trajectory_error(tmp_path):
    with pytest.raises(TrajectoryError, match=r"missing.csv: cannot read trajectory \(FileNotFoundError"):
        load_trajectory(tmp_path / "missing.csv")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(TrajectoryError, match=r"binary.csv: cannot read trajectory \(UnicodeDecodeError"):
        load_trajectory(binary)
    with pytest.raises(TrajectoryError, match="cannot read trajectory"):
        load_trajectory(tmp_path)  # a directory


def test_a_fifo_or_a_folder_is_refused_without_blocking(tmp_path, capsys):
    import os
    from pathlib import Path

    from cli.main import main

    fifo = tmp_path / "script.csv"
    os.mkfifo(fifo)  # opening it for reading would wait for a writer for ever
    with pytest.raises(TrajectoryError, match="not a regular file"):
        load_trajectory(fifo)
    small = Path(__file__).parent / "data" / "small.toml"
    for command in (["run", str(small), "--script", str(fifo)], ["local", "--script", str(fifo)]):
        assert main(command) == 2  # before any build or session
        err = capsys.readouterr().err
        assert "not a regular file" in err and err.count("\n") == 1, err


def test_positions_beyond_the_wire_bound_are_refused(tmp_path, capsys):
    from pathlib import Path

    from cli.main import main
    from sync.messages import MAX_COORDINATE

    path = _write(tmp_path, "0,0,0,0\n1,1e300,0,0\n")
    with pytest.raises(TrajectoryError, match=rf":2: a position beyond {MAX_COORDINATE:g} m"):
        load_trajectory(path)
    assert main(["run", str(Path(__file__).parent / "data" / "small.toml"), "--script", str(path)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
