"""The CoACD cache: entries verified by checksum, bad ones recomputed and replaced, unusable folders skipped."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import trimesh

from twin import decompose as dec
from twin.decompose import (
    CoacdSettings,
    cache_key,
    decompose,
    decompose_many,
    entry_name,
    load_entry,
    save_entry,
)

#: A box is near-convex, so it skips CoACD and these tests stay fast; the cache treats it like any mesh.
BOX = trimesh.creation.box(extents=(0.1, 0.06, 0.04))
SETTINGS = CoacdSettings()


@pytest.fixture(autouse=True)
def _fresh_warnings(monkeypatch):
    monkeypatch.setattr(dec, "_warned_folders", set())


def _entry(folder):  # type: ignore[no-untyped-def]
    return folder / entry_name(cache_key(BOX.vertices, BOX.faces, SETTINGS))


def _same(a, b) -> None:  # type: ignore[no-untyped-def]
    assert len(a) == len(b)
    for (va, fa), (vb, fb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(va, vb)
        np.testing.assert_array_equal(fa, fb)


def test_an_entry_is_written_once_and_read_back_verified(tmp_path):
    first, cached = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)
    assert not cached
    with np.load(_entry(tmp_path)) as data:
        assert str(data["checksum"]) == dec.content_checksum(first)
    again, cached = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)
    assert cached
    _same(first, again)
    assert sorted(p.name for p in tmp_path.iterdir()) == [_entry(tmp_path).name]  # no temp or probe files left


def _truncate(path):  # type: ignore[no-untyped-def]
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _empty(path):  # type: ignore[no-untyped-def]
    path.write_bytes(b"")


def _garbage(path):  # type: ignore[no-untyped-def]
    path.write_bytes(np.random.default_rng(0).bytes(path.stat().st_size))


def _wrong_hulls(path):  # type: ignore[no-untyped-def]
    """A well-formed entry whose hulls were changed after the checksum was taken."""
    with np.load(path) as data:
        arrays = dict(data)
    arrays["v0"] = arrays["v0"] * 2.0
    np.savez(path, **arrays)


def _old_format(path):  # type: ignore[no-untyped-def]
    """An entry as the previous version wrote them: hulls, no version, no checksum."""
    with np.load(path) as data:
        arrays = {k: v for k, v in data.items() if k not in ("version", "checksum")}
    np.savez(path, **arrays)


@pytest.mark.parametrize(
    ("damage", "message"),
    [(_truncate, "unreadable"), (_empty, "unreadable"), (_garbage, "unreadable"),
     (_wrong_hulls, "fails its checksum"), (_old_format, "unreadable")],
)
def test_a_bad_entry_is_logged_recomputed_and_replaced(tmp_path, caplog, damage, message):
    good, _ = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)
    mine = tmp_path / "notes.txt"
    mine.write_text("not the cache's")
    damage(_entry(tmp_path))
    assert load_entry(_entry(tmp_path)) is None
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="twin.decompose"):
        hulls, cached = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)
    assert not cached
    assert any(message in r.getMessage() and _entry(tmp_path).name in r.getMessage() for r in caplog.records)
    assert "pickle" not in caplog.text  # numpy's advice for a file that is no .npz: to load it unsafely
    _same(hulls, good)
    replaced = load_entry(_entry(tmp_path))  # replaced by a verifying entry
    assert replaced is not None
    _same(replaced, good)
    assert decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)[1]  # the next build hits it
    assert mine.read_text() == "not the cache's"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([_entry(tmp_path).name, "notes.txt"])


def test_an_entry_of_another_version_is_recomputed(tmp_path, caplog):
    decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)
    with np.load(_entry(tmp_path)) as data:
        arrays = dict(data)
    arrays["version"] = np.array(dec.CACHE_VERSION + 1)
    np.savez(_entry(tmp_path), **arrays)
    with caplog.at_level(logging.WARNING, logger="twin.decompose"):
        assert not decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path)[1]
    assert "version" in caplog.text
    assert load_entry(_entry(tmp_path)) is not None


def test_malformed_hulls_with_a_matching_checksum_are_refused(tmp_path):
    flat = (np.zeros((4, 3)), np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 2, 9]]))  # face index out of range
    assert save_entry(tmp_path / "x.npz", [flat])
    assert load_entry(tmp_path / "x.npz") is None


@pytest.mark.parametrize("kind", ["file in its place", "under a file", "in /proc"])
def test_an_unusable_cache_folder_means_no_cache_and_one_warning(tmp_path, caplog, kind):
    blocker = tmp_path / "cache"
    blocker.write_text("a file, not a folder")
    folder = {"file in its place": blocker, "under a file": blocker / "coacd",
              "in /proc": Path("/proc/tactile-twin-cache")}[kind]  # not creatable, even by root
    meshes = [(BOX.vertices, BOX.faces), (BOX.vertices * 2, BOX.faces), (BOX.vertices * 3, BOX.faces)]
    with caplog.at_level(logging.WARNING, logger="twin.decompose"):
        results = decompose_many(meshes, SETTINGS, cache_dir=folder, workers=1, progress=False)
        again = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=folder)
    assert [cached for _, cached in results] == [False, False, False] and not again[1]
    hull = trimesh.Trimesh(*results[1][0][0])
    assert hull.volume == pytest.approx(BOX.volume * 8, rel=1e-9)  # the build went on without the cache
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "building without a cache" in warnings[0].getMessage()
    assert blocker.read_text() == "a file, not a folder"


def test_a_failed_write_is_a_warning_and_leaves_nothing(tmp_path, caplog):
    hulls, _ = decompose(BOX.vertices, BOX.faces, SETTINGS, cache_dir=tmp_path / "ok")
    target = tmp_path / "ok" / "is-a-folder.npz"
    target.mkdir()  # os.replace onto a folder fails after the temp file is written
    with caplog.at_level(logging.WARNING, logger="twin.decompose"):
        assert save_entry(target, hulls) is False
    assert "cannot write CoACD cache entry" in caplog.text
    assert not list((tmp_path / "ok").glob("*.tmp")) and target.is_dir()


@pytest.mark.parametrize(("change", "match"), [
    ({"threshold": 1.5}, r"threshold must be in \(0, 1\], got 1.5"),  # CoACD aborts the process past 1
    ({"threshold": 0.0}, r"threshold must be in \(0, 1\]"),
    ({"threshold": float("nan")}, r"threshold must be in \(0, 1\]"),
    ({"max_convex_hull": 0}, r"max hulls must be -1 \(no cap\) or >= 1"),
    ({"max_ch_vertex": 3}, r"max_ch_vertex must be >= 4"),
    ({"resolution": 0}, r"resolution must be >= 1"),
    ({"preprocess_mode": "sometimes"}, r"preprocess_mode must be auto, on or off"),
])
def test_coacd_settings_outside_coacds_ranges_are_refused(change, match):
    from dataclasses import replace

    from twin.decompose import CoacdSettingsError

    with pytest.raises(CoacdSettingsError, match=match):
        replace(SETTINGS, **change)


@pytest.mark.parametrize("xdg", ["", "relative/cache"])
def test_an_empty_or_relative_xdg_cache_home_counts_as_unset(monkeypatch, tmp_path, xdg):
    # Taken as given, they put the cache under the folder the command ran in (./tactile-twin/coacd/<sha>.npz).
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("TWIN_CACHE_DIR", "")  # empty: unset too
    monkeypatch.setenv("XDG_CACHE_HOME", xdg)
    assert dec.default_cache_dir() == tmp_path / ".cache" / "tactile-twin" / "coacd"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))  # an absolute one is used
    assert dec.default_cache_dir() == tmp_path / "xdg" / "tactile-twin" / "coacd"


@pytest.mark.parametrize("folder", ["", "."])
def test_a_cache_dir_that_is_the_current_folder_is_refused(monkeypatch, tmp_path, capsys, folder):
    # ``--cache-dir ''`` wrote <sha>.npz among the user's files, as ``--out ''`` is refused from doing.
    from cli.main import main

    scene = Path(__file__).parent / "data" / "small.toml"
    monkeypatch.chdir(tmp_path)
    assert main(["build", str(scene), "--out", "out", "--cache-dir", folder]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == [f"twin build: error: --cache-dir {tmp_path.resolve()}: is the current folder (so is an empty "
                   f"--cache-dir); the CoACD cache writes a file per mesh there: give it a folder of its own, or "
                   f"leave --cache-dir out for the default (see --help)"]
    assert not any(tmp_path.iterdir())
