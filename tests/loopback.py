"""A remote scene and local twins on real Zenoh loopback sessions, shared by the sync and rerun tests."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from scenes.remote import Remote
from scenes.scenefile import parse_scene
from sync.zenoh_transport import ZenohTransport, make_config, open_session
from twin.debuglog import OFF
from twin.rerunlog import RerunLog
from twin.runtime import Local, LocalSettings

SCENE = {
    "name": "synctest",
    "table": {"size": [1.0, 0.6, 0.04], "height": 0.5},
    "end_effector": {"radius": 0.02, "position": [-0.3, 0.0, 0.56]},
    "objects": [
        {"id": "crate", "primitive": {"type": "box", "size": [0.12, 0.08, 0.06]}, "material": "wood_pine",
         "position": [0.0, 0.0], "points": 8000},
        {"id": "can", "primitive": {"type": "cylinder", "size": [0.03, 0.1]}, "density": 700,
         "position": [0.2, 0.1], "points": 8000},
    ],
}


class RemoteRunner:
    """A remote scene stepping in a thread; stop() and start() make it fall silent and come back."""

    def __init__(self, remote: Remote) -> None:
        self.remote = remote
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self.remote.run, args=(600.0,), kwargs={"stop": self._stop})
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


@contextlib.contextmanager
def running_remote(endpoint: str, cache_dir: Path, rlog: RerunLog = OFF,
                   **remote) -> Iterator[RemoteRunner]:  # type: ignore[no-untyped-def]
    """The SCENE's remote (``remote``: more Remote arguments), listening on ``endpoint`` and stepping in a
    thread until the block ends."""
    session = open_session(make_config(listen=[endpoint]))
    r = Remote(parse_scene(SCENE), ZenohTransport(session), cache_dir=cache_dir, rlog=rlog, **remote)
    runner = RemoteRunner(r)
    runner.start()
    try:
        yield runner
    finally:
        runner.stop()
        r.close()
        session.close()


def open_local(endpoint: str, cache_dir: Path, rlog: RerunLog = OFF, **settings) -> Local:  # type: ignore[no-untyped-def]
    """A twin connected to ``endpoint``; close it with :func:`close_local`."""
    session = open_session(make_config(connect=[endpoint]))
    local = Local(ZenohTransport(session), settings=LocalSettings(cache_dir=cache_dir, **settings), rlog=rlog)
    local._session = session  # type: ignore[attr-defined]  # closed with it
    return local


def close_local(local: Local) -> None:
    local.close()
    local._session.close()  # type: ignore[attr-defined]


def wait_objects(local: Local, n: int, timeout: float = 60.0) -> None:
    local.run(timeout, until=lambda: len(local.objects) >= n)
    assert len(local.objects) == n, f"only {local.objects} arrived in {timeout} s"


def wait_until(condition, timeout: float = 30.0, what: str = "condition") -> None:  # type: ignore[no-untyped-def]
    """Poll ``condition`` until it holds; the deadline is a failsafe for a hung side, not a measurement."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)
