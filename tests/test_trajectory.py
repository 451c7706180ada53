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
    # "got 1" alone left the reason to be guessed.
    ("0 -0.3 0 0.56\n1 0 0 0.56\n", r"path.csv:1: expected 4 columns t,x,y,z, got 1 \(separated by white space; the "
     r"separator must be a comma\)$"),
    ("t\tx\ty\tz\n0\t-0.3\t0\t0.56\n", r"path.csv:1: expected 4 columns t,x,y,z, got 1 \(separated by white space"),
    ("0;-0.3;0;0.56\n", r"path.csv:1: expected 4 columns t,x,y,z, got 1 \(separated by ';'; the separator must be "
     r"a comma\)$"),
    ("t,x,y,z\n0,1,two,3\n", r"path.csv:2: not a number in '0,1,two,3'$"),
    ("0,1,2,3\n1,nan,2,3\n", r"path.csv:2: non-finite value"),
    ("0,1,2,3\n1,1,2,inf\n", r"path.csv:2: non-finite value"),
    ("0,1,2,3\n1,1,2,3\n1,1,2,3\n", r"path.csv:3: t = 1 s does not increase \(previous 1 s\)$"),
    ("0,1,2,3\n2,1,2,3\n1,1,2,3\n", r"path.csv:3: t = 1 s does not increase"),
    ("t,x,y,z\n", r"path.csv: no waypoints"),
    ("", r"path.csv: no waypoints"),
    # A stray quote opens one field that runs past csv's 131,072-character limit: a traceback before.
    ('t,x,y,z\n"0,0,0,0.6\n' + "0.001,0.000,0.000,0.600\n" * 8_000, r"path.csv:\d+: not CSV \(field larger than field limit"),
    # One a thousand rows can hold: numpy was told to skip to where the row ended, and read one waypoint.
    ('t,x,y,z\n0,-0.3,0,"0.56\n' + "".join(f"{k / 100},-0.2,0,0.56\n" for k in range(1, 1000)),
     r"path.csv:2: not CSV \(a stray quote runs this row on to line 1001\)$"),
    # An inline comment ends its row for both readers: the bad row is named, not the commented one.
    ("0,1,2,3 # start\n1,1,2,3\n0.5,1,2,3\n", r"path.csv:3: t = 0.5 s does not increase"),
    # A quoted '#' is text to numpy, and now line by line too (it was cut there, and read as t = 0).
    ('"0#1",1,2,3\n', r"path.csv:1: not a number in '0#1,1,2,3'$"),
])
def test_bad_files_are_one_line_errors_naming_file_and_line(tmp_path, text, match):
    with pytest.raises(TrajectoryError, match=match) as err:
        load_trajectory(_write(tmp_path, text))
    assert isinstance(err.value, ValueError) and isinstance(err.value, TwinError)
    assert "\n" not in str(err.value)


def test_an_unreadable_file_is_a_trajectory_error(tmp_path):
    # Python's own words named the exception and repeated the path: "(FileNotFoundError: [Errno 2] ...)".
    with pytest.raises(TrajectoryError, match=r"missing.csv: cannot read trajectory: No such file or directory$"):
        load_trajectory(tmp_path / "missing.csv")
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"0,0,0,0.6\n\x80\x81\n")
    with pytest.raises(TrajectoryError, match=r"binary.csv: not UTF-8 text \(byte 0x80 at offset 10\)$"):
        load_trajectory(binary)
    for data in (b"\xff\xfe\x00\x01", "t,x,y,z\n0,0,0,0.6\n".encode("utf-16-le")):  # Notepad's, with a BOM or not
        binary.write_bytes(data)
        with pytest.raises(TrajectoryError, match=r"binary.csv: the file is UTF-16 encoded; save it as UTF-8 or ASCII$"):
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


SMALL = __import__("pathlib").Path(__file__).parent / "data" / "small.toml"

#: The operator's reach around small.toml's table (1.0 x 0.6 m, top at 0.5 m): 2 m beyond its edges and top.
SMALL_BOX = (np.array([-2.5, -2.3, 0.0]), np.array([2.5, 2.3, 2.5]))


def test_a_file_in_millimetres_is_refused_naming_units_and_read_with_them(tmp_path, capsys):
    from cli.main import main

    path = _write(tmp_path, "t,x,y,z\n0,-300,0,560\n2,300,0,560\n")  # the fuzz pass's tr_mm.csv
    with pytest.raises(TrajectoryError, match=r"path.csv: the target at t = 0 s, \(-300, 0, 560\) m, is outside the "
                                              r"operator's reach \(x -2.5 to 2.5, y -2.3 to 2.3, z 0 to 2.5 m\): "
                                              r"looks like millimetres: pass --units mm$"):
        load_trajectory(path).check_reach(SMALL_BOX)
    at = load_trajectory(path, units="mm")
    at.check_reach(SMALL_BOX)
    assert at(1.0) == pytest.approx([0.0, 0.0, 0.56]) and at(0.0) == pytest.approx([-0.3, 0.0, 0.56])
    assert load_trajectory(_write(tmp_path, "0,-30,0,56\n", "cm.csv"), units="cm")(0.0) == pytest.approx([-0.3, 0, 0.56])
    from estimation.units import UnitsError

    with pytest.raises(UnitsError, match="unknown units 'inch'"):
        load_trajectory(path, units="inch")
    # The CLI checks against the scene's table (sent the end effector to 560 m before, exit 0, no word).
    assert main(["run", str(SMALL), "--script", str(path), "--duration", "0.1", "--no-realtime"]) == 2
    err = capsys.readouterr().err.lstrip("\n")  # (the build's progress display ends with a blank line)
    assert err.count("\n") == 1 and "looks like millimetres: pass --units mm" in err, err
    assert main(["run", str(SMALL), "--script", str(path), "--units", "mm", "--duration", "0.1", "--no-realtime",
                 "--json"]) == 0


def test_a_script_in_metres_read_in_mm_or_cm_is_warned_of_naming_metres(tmp_path, caplog):
    # Read in mm, a push over the table became targets within 0.6 mm of the world origin, on the floor under the
    # table: the end effector pressed on the table's top with 97 N, without a word (a review's probe, session 58).
    # A warning, not a refusal: a small scene without a table has real scripts in cm within 2 cm of the origin.
    path = _write(tmp_path, "t,x,y,z\n0,-0.3,0,0.56\n2,0.3,0,0.56\n")
    for units, far in (("mm", "0.00056"), ("cm", "0.0056")):
        caplog.clear()
        load_trajectory(path, units=units).check_reach(SMALL_BOX)
        assert (f"path.csv: read in {'millimetres' if units == 'mm' else 'centimetres'} (--units {units}) every target "
                f"lies within {far} m of the world origin, and read in metres they fit the operator's reach: if the "
                f"script is in metres, pass --units m") in caplog.text
    caplog.clear()
    load_trajectory(path).check_reach(SMALL_BOX)
    # Near the origin in the units given, but 1000 times out would leave the reach: a script in mm, as meant.
    load_trajectory(_write(tmp_path, "0,-2,0,1\n1,3,0,1\n", "mm.csv"), units="mm").check_reach(SMALL_BOX)
    assert "--units m" not in caplog.text


def test_clock_times_are_refused_as_seconds_from_the_start(tmp_path):
    # Unix times held the end effector at the first target for the whole run, exit 0, no word (a review's probe).
    epoch = _write(tmp_path, "t,x,y,z\n1733590000.0,-0.3,0,0.56\n1733590002.0,0.3,0,0.56\n")
    with pytest.raises(TrajectoryError, match=r"path.csv: the first waypoint is at t = 1733590000 s, 20,065 days after "
                                              r"the session starts: t is in seconds from the start \(clock times\? "
                                              r"subtract the first from each\)$"):
        load_trajectory(epoch)
    load_trajectory(_write(tmp_path, "86400,-0.3,0,0.56\n86402,0.3,0,0.56\n", "day.csv"))  # a day's wait: read


def test_a_file_of_blank_lines_is_refused_without_reading_each_line_in_python(tmp_path, monkeypatch):
    # 128 MiB of line ends took about 320 s to say "no waypoints"; lines are counted in C first.
    import twin.trajectory as trajectory

    monkeypatch.setattr(trajectory, "MAX_LINES", 100)
    for text, lines in (("\n" * 150, 150), ("\r" * 120, 120), ("\r\n" * 101, 101)):
        path = _write(tmp_path, text)
        with pytest.raises(TrajectoryError, match=rf"path.csv: {lines} lines, more than the 100 a trajectory of at most "
                                                  r"5,000,000 waypoints may take \(blank lines\?\)$"):
            load_trajectory(path)
    with pytest.raises(TrajectoryError, match=r"path.csv: no waypoints \(expected rows t,x,y,z\)$"):
        load_trajectory(_write(tmp_path, "\n" * 60 + "# nothing\n" * 30))
    assert load_trajectory(_write(tmp_path, "\n" * 60 + "0,0,0,0.5\n")).times.tolist() == [0.0]


def test_targets_under_the_floor_or_a_stray_far_one_are_refused_without_a_units_hint(tmp_path):
    under = _write(tmp_path, "t,x,y,z\n0,-0.3,0,0.56\n0.5,0.0,0,-5\n")  # was 25,100 N on the end effector
    with pytest.raises(TrajectoryError, match=r"the target at t = 0.5 s, \(0, 0, -5\) m, is outside the operator's "
                                              r"reach \(x -2.5 to 2.5, y -2.3 to 2.3, z 0 to 2.5 m\)$"):
        load_trajectory(under).check_reach(SMALL_BOX)
    far = _write(tmp_path, "t,x,y,z\n0,-0.3,0,0.56\n0.1,999,999,999\n", "far.csv")
    with pytest.raises(TrajectoryError, match=r"\(999, 999, 999\) m, is outside the operator's reach \(.*\)$"):
        load_trajectory(far).check_reach(SMALL_BOX)
    at = load_trajectory(far)  # read; its reach is checked once the scene is known, as the CLI does
    with pytest.raises(TrajectoryError, match=r"far.csv: the target at t = 0.1 s"):
        at.check_reach(SMALL_BOX)


def test_times_that_look_like_milliseconds_are_warned_about(tmp_path, caplog):
    load_trajectory(_write(tmp_path, "t,x,y,z\n0,-0.3,0,0.56\n2000,0.3,0,0.56\n"))
    assert "runs 2000 s and the target moves at most 0.3 mm/s: if its times are in milliseconds" in caplog.text
    caplog.clear()
    load_trajectory(_write(tmp_path, "0,-0.3,0,0.56\n2,0.3,0,0.56\n", "s.csv"))  # seconds
    load_trajectory(_write(tmp_path, "0,-0.3,0,0.56\n3600,-0.3,0,0.56\n", "hold.csv"))  # an hour holding still
    assert "milliseconds" not in caplog.text


def test_evaluation_agrees_with_numpy_interp_and_copes_with_extreme_times(tmp_path):
    rng = np.random.default_rng(7)
    times = np.cumsum(rng.uniform(1e-4, 0.1, 500))
    points = rng.uniform(-1, 1, (500, 3))
    rows = "\n".join(",".join(repr(float(v)) for v in (t, *p)) for t, p in zip(times, points, strict=True))
    at = load_trajectory(_write(tmp_path, rows + "\n"))
    for t in np.concatenate([rng.uniform(times[0] - 1, times[-1] + 1, 300), times, [times[0] - 5, times[-1] + 5]]):
        reference = [np.interp(t, times, points[:, i]) for i in range(3)]  # the slow path this replaced
        assert at(float(t)) == pytest.approx(reference, abs=1e-12)
    assert at.points.flags.c_contiguous and at.times.flags.c_contiguous
    at(0.5)[:] = 9  # a new array each call: the waypoints stay
    assert at(times[0]) == pytest.approx(points[0])
    huge = load_trajectory(_write(tmp_path, "-1.7e308,0,0,0.5\n1.7e308,1,0,0.5\n", "huge.csv"))
    assert np.isfinite(huge(0.0)).all()


def test_numpy_and_the_line_by_line_reader_agree(tmp_path):
    from twin.trajectory import _read_checked, _read_fast

    path = _write(tmp_path, '\ufeff# comment\n\nT, X, Y, Z\n0, 0.1,0,0.2\n"1","0.2","0","0.3"\n# note\n2,0.3,0,0.4\n')
    fast, slow = _read_fast(path, 0.001), _read_checked(path, 0.001)
    assert fast is not None and np.array_equal(fast, slow) and fast.shape == (3, 4)
    assert fast[1] == pytest.approx([1.0, 2e-4, 0.0, 3e-4])
    # An indented comment is a row of one empty value to numpy: read line by line instead.
    indented = _write(tmp_path, "0,0.1,0,0.2\n  # note\n1,0.2,0,0.3\n", "indented.csv")
    assert _read_fast(indented, 1.0) is None
    assert load_trajectory(indented)(0.5) == pytest.approx([0.15, 0, 0.25])
    # An inline comment: the same rows both ways.
    inline = _write(tmp_path, "0,0.1,0,0.2 # start\n1,0.2,0,0.3#\n", "inline.csv")
    fast, slow = _read_fast(inline, 1.0), _read_checked(inline, 1.0)
    assert fast is not None and np.array_equal(fast, slow) and fast.shape == (2, 4)
    # What numpy does not read but Python's float does is still read, line by line.
    assert load_trajectory(_write(tmp_path, "0,1_0.0,0,0.5\n", "u.csv"))(0) == pytest.approx([10.0, 0, 0.5])


@pytest.mark.parametrize("comment", ['#,"hello\n', '# say "hi\n', "# " + "a" * 200_000 + "\n"])
@pytest.mark.parametrize("header", ["t,x,y,z\n", ""])
def test_comments_before_the_data_never_reach_the_csv_parser(tmp_path, comment, header):
    """A quote in a comment opened a field that ran on ("not CSV"); one over 128 KiB passed csv's field limit."""
    from twin.trajectory import _read_checked, _read_fast

    for text in (header + comment, comment + header):
        path = _write(tmp_path, text + "0,-0.3,0,0.56\n1,-0.2,0,0.56\n" + comment)
        fast, slow = _read_fast(path, 1.0), _read_checked(path, 1.0)
        assert fast is not None and np.array_equal(fast, slow) and fast.shape == (2, 4)
        assert load_trajectory(path)(0.5) == pytest.approx([-0.25, 0.0, 0.56])


@pytest.mark.parametrize("columns", [1_000, 20_000])
def test_a_wide_first_row_is_named_before_numpy_allocates_for_it(tmp_path, capsys, columns):
    """numpy allocates 5,000,001 rows of the first row's columns up front: "out of memory" for a 2 KB file."""
    from cli.main import main

    path = _write(tmp_path, "t,x,y,z\n" + ",".join(["0"] * columns) + "\n")
    with pytest.raises(TrajectoryError, match=rf"path.csv:2: expected 4 columns t,x,y,z, got {columns}$"):
        load_trajectory(path)
    assert main(["run", str(SMALL), "--script", str(path)]) == 2
    err = capsys.readouterr().err.lstrip("\n")
    assert err.count("\n") == 1 and f"expected 4 columns t,x,y,z, got {columns}" in err, err


def test_an_overlong_line_is_refused_without_being_read_whole(tmp_path):
    """A 60 MB line of values took 2.6 GB split into cells, then was "out of memory"."""
    import tracemalloc

    wide = _write(tmp_path, "t,x,y,z\n" + "0," * 5_000_000 + "0\n", "wide.csv")  # 10 MB
    tracemalloc.start()
    try:
        with pytest.raises(TrajectoryError, match=r"wide.csv:2: a line of more than 65,536 characters where a row "
                                                  r"t,x,y,z was expected$"):
            load_trajectory(wide)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**20, peak  # bytes: the line's first 64 KiB, not its 5 million cells
    from twin.trajectory import MAX_LINE_CHARS

    # After a good row: numpy refuses it, and the line-by-line reader names it.
    later = _write(tmp_path, "0,0,0,0.5\n" + "0," * MAX_LINE_CHARS + "0\n", "later.csv")
    with pytest.raises(TrajectoryError, match=r"later.csv:2: a line of more than"):
        load_trajectory(later)
    # A row of exactly the limit is read, and "\r\n" split by the limit still ends one line: line 4 is named.
    row = "0,0,0,0." + "5" * (MAX_LINE_CHARS - 8)
    exact = _write(tmp_path, f"t,x,y,z\r\n{row}\r\n1,0,0,0.5\r\n0.5,0,0,0.5\r\n", "exact.csv")
    with pytest.raises(TrajectoryError, match=r"exact.csv:4: t = 0.5 s does not increase"):
        load_trajectory(exact)
    assert load_trajectory(_write(tmp_path, f"{row}\r\n1,0,0,0.5\r\n", "ok.csv"))(0.0) == pytest.approx([0, 0, 5 / 9])
    with pytest.raises(TrajectoryError, match=r"long.csv:1: a line of more than"):
        load_trajectory(_write(tmp_path, f"{row}5\r\n1,0,0,0.5\r\n", "long.csv"))


def test_too_large_files_and_too_many_waypoints_are_refused(tmp_path, monkeypatch):
    import twin.trajectory as trajectory

    path = _write(tmp_path, "".join(f"{i},0,0,0.5\n" for i in range(10)))
    monkeypatch.setattr(trajectory, "MAX_TRAJECTORY_BYTES", 50)
    with pytest.raises(TrajectoryError, match=r"path.csv: trajectory file is 0 MiB, more than the 0 MiB"):
        load_trajectory(path)
    monkeypatch.setattr(trajectory, "MAX_TRAJECTORY_BYTES", 2**20)
    monkeypatch.setattr(trajectory, "MAX_WAYPOINTS", 5)
    with pytest.raises(TrajectoryError, match=r"path.csv: more than 5 waypoints \(thin them\)$"):
        load_trajectory(path)
    bad = _write(tmp_path, "".join(f"{i},0,0,0.5\n" for i in range(10)) + "x,0,0,0\n", "bad.csv")
    with pytest.raises(TrajectoryError, match=r"bad.csv: more than 5 waypoints"):  # the line-by-line reader too
        load_trajectory(bad)


def test_a_huge_value_is_quoted_short(tmp_path):
    with pytest.raises(TrajectoryError, match=r"path.csv:1: non-finite value in '0,1{78}\.\.\.'$"):
        load_trajectory(_write(tmp_path, "0," + "1" * 5000 + ",0,0.56\n"))


def test_held_targets_hold_each_target_until_the_next_and_check_their_reach():
    """A recorded operator (--replay-operator, twin replay): the trajectory and its reach check from one decode."""
    from twin.trajectory import HeldTargets

    held = HeldTargets(np.array([0.5, 1.0]), np.array([[0.1, 0.0, 0.6], [0.2, 0.0, 0.6]]), source="rec.mcap")
    assert held(0.0) is None and held(0.4999) is not None  # half a millisecond early: a float sum of steps
    np.testing.assert_array_equal(held(0.7), [0.1, 0.0, 0.6])
    np.testing.assert_array_equal(held(99.0), [0.2, 0.0, 0.6])
    held.check_reach(SMALL_BOX)
    far = HeldTargets(np.array([0.0, 0.02]), np.array([[0.1, 0.0, 0.6], [999.0, 0.0, 0.6]]), source="rec.mcap")
    with pytest.raises(TrajectoryError, match=r"^rec.mcap: the target at t = 0.02 s, \(999, 0, 0.6\) m, is outside "
                                              r"the operator's reach \(x -2.5 to 2.5, y -2.3 to 2.3, z 0 to 2.5 m\)$"):
        far.check_reach(SMALL_BOX)  # no --units hint: a recording is in metres
    never = HeldTargets(np.zeros(0), np.zeros((0, 3)))
    assert never(1.0) is None
    never.check_reach(SMALL_BOX)


@pytest.mark.parametrize("argv", [["run", "s.toml"], ["local"], ["replay", "r.mcap"],
                                  ["local", "--replay-operator", "r.mcap"]])
def test_units_without_a_script_is_refused(capsys, argv):
    """--units scales only the --script file: without one, --units mm was ignored and the run went on in metres."""
    from cli.main import main

    assert main([*argv, "--units", "mm"]) == 2
    err = capsys.readouterr().err
    assert err == (f"twin {argv[0]}: error: --units applies to --script's file, and no --script is given: drop "
                   "--units mm (everything else is in metres)\n")


def test_every_units_option_takes_the_unit_table():
    """--units was written out on four parsers (one helper now): each must offer exactly the units read."""
    import argparse

    from cli.main import _parser
    from estimation.units import UNIT_SCALE

    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    units = {name: a for name, p in sub.choices.items() for a in p._actions if "--units" in a.option_strings}
    assert sorted(units) == ["estimate", "local", "replay", "run"]
    for name, action in units.items():
        assert action.choices == list(UNIT_SCALE), name
        assert action.help.startswith("units of ") and "(default m" in action.help, name
        # estimate's "not given" refuses an implausible size; the scripts' is metres
        assert action.default == (None if name == "estimate" else "m"), name
