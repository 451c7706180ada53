"""The Zenoh transport: sessions (the embedded loopback default, ``--connect``, ``--zenoh-config`` files)
and :class:`ZenohTransport`, the :class:`sync.transport.Transport` over one session.

Defaults: peer mode, multicast and gossip scouting off, and listening on 127.0.0.1 only (Zenoh's own
default listens on every interface), so nothing is reachable from another machine unless an endpoint
says so. A config file (Zenoh's JSON5) is taken as it is, then ``listen``/``connect`` given here override
its endpoints: that is where TLS, access control and routers are set (see docs/sync.md, "Beyond one machine").
"""

from __future__ import annotations

import json
import logging
import socket
from pathlib import Path

from estimation.errors import TwinError
from sync.transport import MAX_REPLIES, MAX_REPLY_BYTES, Answer, OnSample

log = logging.getLogger(__name__)


class SessionError(TwinError, RuntimeError):
    """A Zenoh session could not be configured or opened."""


#: Where a session listens when nothing says otherwise: loopback, a port the system picks.
LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def exposed_without_tls(endpoints: list[str]) -> list[str]:
    """The ``endpoints`` another machine could reach in plain text: not loopback, and not ``tls/``/``quic/``.

    ``tcp/127.0.0.1:7447``, ``tcp/localhost:7447`` and ``tcp/[::1]:7447`` stay on this machine; ``tcp/0.0.0.0``,
    ``tcp/[::]`` or an interface's address do not.
    """
    exposed = []
    for endpoint in endpoints:
        proto, _, rest = endpoint.partition("/")
        host = rest.split("#")[0].rsplit(":", 1)[0].strip("[]").lower()
        if proto in ("tls", "quic") or host == "localhost" or host == "::1" or host.startswith("127."):
            continue
        exposed.append(endpoint)
    return exposed


#: Zenoh link protocols whose address is HOST:PORT.
_HOST_PORT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")

#: Every link protocol Zenoh builds may carry (the rest have their own address forms).
_PROTOCOLS = (*_HOST_PORT_PROTOCOLS, "unixsock-stream", "unixpipe", "serial", "vsock")


def check_endpoint(endpoint: str, what: str = "endpoint") -> None:
    """Refuse an endpoint Zenoh would reject with a Rust error, or a HOST:PORT one without a port.

    Form: ``PROTOCOL/ADDRESS[?METADATA][#CONFIG]``, e.g. ``tcp/192.168.1.5:7447`` or ``tls/[::1]:7447``.

    Raises:
        SessionError: naming ``what`` and the endpoint, and the expected form.
    """
    proto, slash, rest = endpoint.partition("/")
    address = rest.split("#")[0].split("?")[0]
    form = "expected PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
    if not slash or proto not in _PROTOCOLS or not address:
        raise SessionError(f"{what} {endpoint!r}: not a Zenoh endpoint ({form})")
    if proto in _HOST_PORT_PROTOCOLS:
        host, colon, port = address.rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise SessionError(f"{what} {endpoint!r}: no valid port ({form})")


def _zenoh_error(exc: Exception) -> str:
    """Zenoh's (Rust) error text as one short line: the JSON5 position if any, no source locations."""
    import re

    text = str(exc)
    where = re.search(r"-->\s*(\d+):(\d+)", text)
    said = re.search(r"=\s*([^\n]+)", text)
    if where and said:
        text = f"{said.group(1)} at line {where.group(1)}, column {where.group(2)}"
    text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", text)
    return "; ".join(line.strip() for line in text.splitlines() if line.strip())


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
            raise SessionError(f"zenoh config {path}: {_zenoh_error(exc)}") from exc
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps([LOOPBACK_ANY_PORT]))
    for what, endpoints in (("listen endpoint", listen), ("connect endpoint", connect)):
        for endpoint in endpoints or ():
            check_endpoint(endpoint, what)
    try:
        if listen is not None:
            conf.insert_json5("listen/endpoints", json.dumps(listen))
        if connect is not None:
            conf.insert_json5("connect/endpoints", json.dumps(connect))
    except Exception as exc:  # zenoh's ZError: an endpoint it still refuses
        raise SessionError(f"Zenoh endpoints {listen or []} {connect or []}: {_zenoh_error(exc)}") from exc
    return conf


def open_session(conf):  # type: ignore[no-untyped-def]
    import zenoh

    try:
        return zenoh.open(conf)
    except Exception as exc:  # e.g. a listen endpoint already in use, or a bad certificate path
        raise SessionError(f"could not open a Zenoh session: {_zenoh_error(exc)}") from exc


class ZenohTransport:
    """:class:`sync.transport.Transport` over an open Zenoh session (which the caller owns and closes).

    Zenoh calls subscriber and queryable callbacks on its own threads; a failing answer is logged and
    dropped there (the querier times out) rather than raised into Zenoh.
    """

    def __init__(self, session) -> None:  # type: ignore[no-untyped-def]
        self.session = session
        self._handles: list[object] = []

    def put(self, key: str, data: bytes) -> None:
        self.session.put(key, data)

    def subscribe(self, keyexpr: str, callback: OnSample) -> None:
        self._handles.append(self.session.declare_subscriber(
            keyexpr, lambda s: callback(str(s.key_expr), s.payload.to_bytes())))

    def queryable(self, keyexpr: str, answer: Answer) -> None:
        import zenoh

        def on_query(query) -> None:  # type: ignore[no-untyped-def]
            # Only the replies whose keys the query matches, as the in-process bus does: Zenoh refuses a reply
            # on any other key with an error, which ended the answer there (a query for one object's keys
            # got at most its cloud) and logged a traceback per query (a flood of narrow queries, a flood
            # of tracebacks).
            asked = query.key_expr
            try:
                for reply_key, data in answer(str(asked)):
                    if asked.intersects(zenoh.KeyExpr(reply_key)):
                        query.reply(reply_key, data)
            except Exception:
                log.exception("answering a query on %s failed", keyexpr)

        self._handles.append(self.session.declare_queryable(keyexpr, on_query))

    def get(self, selector: str, timeout: float) -> list[tuple[str, bytes]]:
        replies: list[tuple[str, bytes]] = []
        total = 0
        for r in self.session.get(selector, timeout=timeout):
            if r.ok is None:
                continue
            data = r.ok.payload.to_bytes()
            total += len(data)
            if len(replies) >= MAX_REPLIES or total > MAX_REPLY_BYTES:
                # Replies are read as they come, so stopping here bounds memory (collecting them all first
                # did not); the handler's channel and the rest go with it.
                log.warning("query %s: more than %d replies or %d MiB; the rest were not read", selector[:200],
                            MAX_REPLIES, MAX_REPLY_BYTES >> 20)
                break
            replies.append((str(r.ok.key_expr), data))
        return replies

    def close(self) -> None:
        for h in self._handles:
            try:
                h.undeclare()  # type: ignore[attr-defined]
            except Exception:
                pass
        self._handles.clear()
