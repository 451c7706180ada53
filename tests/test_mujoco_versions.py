"""The built MJCF loads in every MuJoCo the package allows: the oldest and the newest release its pin admits.

The release the venv has is checked in every run. Another release (when the pin admits more than one) is
installed into its own venv under the user's cache (pip, from the package index) and checked in the slow
suite: ``pytest -m slow tests/test_mujoco_versions.py``.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import venv
from pathlib import Path

import mujoco
import pytest
from packaging.requirements import Requirement
from packaging.version import Version

from cli.main import main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).parent.parent
SMALL = Path(__file__).parent / "data" / "small.toml"

LOAD = """
import json, sys, mujoco
out = {"version": mujoco.__version__, "bodies": {}}
for path in sys.argv[1:]:
    m = mujoco.MjModel.from_xml_path(path)
    d = mujoco.MjData(m)
    mujoco.mj_step(m, d, 10)
    out["bodies"][path] = [m.nbody, m.ngeom, float(m.body_mass.sum())]
print(json.dumps(out))
"""


def mujoco_requirement() -> Requirement:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (req,) = [Requirement(d) for d in deps if Requirement(d).name == "mujoco"]
    return req


def admitted_releases() -> list[Version]:
    """Every release on the package index the pin admits, oldest first (from ``pip index versions``)."""
    out = subprocess.run([sys.executable, "-m", "pip", "index", "versions", "mujoco"], capture_output=True,
                         text=True, timeout=120)
    if out.returncode != 0:
        pytest.fail(f"pip index versions mujoco failed: {out.stderr.strip()[-300:]}")
    listed = re.search(r"Available versions: (.*)", out.stdout)
    assert listed, out.stdout
    spec = mujoco_requirement().specifier
    return sorted(v for v in map(Version, listed.group(1).split(", ")) if v in spec and not v.is_prerelease)


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> list[str]:
    """scene.xml and every objects/<id>.xml of the small scene, built with the venv's MuJoCo."""
    out = tmp_path_factory.mktemp("built") / "small"
    cache = tmp_path_factory.getbasetemp() / "coacd"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TWIN_CACHE_DIR", str(cache))
        assert main(["build", str(SMALL), "--out", str(out)]) == 0
    files = [out / "scene.xml", *sorted((out / "objects").glob("*.xml"))]
    assert len(files) >= 3
    return [str(f) for f in files]


def _load_with(python: str, files: list[str]) -> dict:
    done = subprocess.run([python, "-c", LOAD, *files], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)


def test_the_installed_mujoco_is_one_the_pin_admits_and_loads_the_output(built):
    assert Version(mujoco.__version__) in mujoco_requirement().specifier
    loaded = _load_with(sys.executable, built)
    assert loaded["version"] == mujoco.__version__
    scene = loaded["bodies"][built[0]]
    assert scene[0] >= 3 and scene[2] > 0  # world, table, objects; positive mass


@pytest.mark.slow
@pytest.mark.parametrize("which", ["oldest", "newest"])
def test_the_oldest_and_newest_admitted_mujoco_load_the_output(which, built):
    releases = admitted_releases()
    assert releases, f"no release on the index admits {mujoco_requirement()}"
    version = releases[0] if which == "oldest" else releases[-1]
    if version == Version(mujoco.__version__):
        python = sys.executable
    else:
        home = Path.home() / ".cache" / "tactile-twin" / f"mujoco-{version}"
        python = str(home / "bin" / "python")
        if not Path(python).exists():
            venv.create(home, with_pip=True)
            subprocess.run([python, "-m", "pip", "install", "-q", f"mujoco=={version}", "numpy"], check=True,
                           timeout=600)
    loaded = _load_with(python, built)
    assert Version(loaded["version"]) == version
    # Same model in every admitted release: same bodies, geoms and mass as the venv's MuJoCo.
    assert loaded["bodies"] == _load_with(sys.executable, built)["bodies"]
