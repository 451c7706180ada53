"""Opening Zenoh sessions: the embedded loopback default, ``--connect``, and ``--zenoh-config`` files.

Defaults: peer mode with multicast scouting off, so nothing leaves the machine unless an endpoint says
so. A config file (Zenoh's JSON5) is taken as it is, then ``listen``/``connect`` given here override its
endpoints: that is where TLS, access control and routers are set (see README, "Beyond one machine").
"""

from __future__ import annotations

import json
import logging
import socket
from pathlib import Path

from estimation.errors import TwinError

log = logging.getLogger(__name__)


class SessionError(TwinError, RuntimeError):
    """A Zenoh session could not be configured or opened."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def make_config(*, listen: list[str] | None = None, connect: list[str] | None = None,
                config_file: str | Path | None = None, mode: str = "peer"):  # type: ignore[no-untyped-def]
    """A ``zenoh.Config``: the file's settings (if any), then mode, scouting off, and the endpoints."""
    import zenoh

    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise SessionError(f"zenoh config {path}: no such file")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:  # zenoh raises its own ZError for JSON5 or schema problems
            raise SessionError(f"zenoh config {path}: {exc}") from exc
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
    if listen is not None:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if connect is not None:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    return conf


def open_session(conf):  # type: ignore[no-untyped-def]
    import zenoh

    try:
        return zenoh.open(conf)
    except Exception as exc:  # e.g. a listen endpoint already in use, or a bad certificate path
        raise SessionError(f"could not open a Zenoh session: {exc}") from exc
