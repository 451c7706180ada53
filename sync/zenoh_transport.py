"""The Zenoh transport: sessions (the embedded loopback default, ``--connect``, ``--zenoh-config`` files)
and :class:`ZenohTransport`, the :class:`sync.transport.Transport` over one session.

Defaults: peer mode, multicast and gossip scouting off, and listening on 127.0.0.1 only (Zenoh's own
default listens on every interface), so nothing is reachable from another machine unless an endpoint
says so. A config file (Zenoh's JSON5) is where TLS, access control and routers are set (see docs/sync.md,
"Beyond one machine"); what it leaves out of those defaults gets them too, and ``listen``/``connect`` given
here override its endpoints. :func:`make_config` is the one place that knows this policy: the effective
listen endpoints and scouting, file or not, must stay on this machine or be TLS unless ``insecure``.
Host names in endpoints are resolved when they are checked (:func:`check_endpoint`), within
:data:`RESOLVE_TIMEOUT`: Zenoh retries a name that does not resolve for as long as a session waits, and a
listen endpoint's name is judged by the addresses it stands for.
"""

from __future__ import annotations

import json
import logging
import re
import socket
from dataclasses import dataclass, replace
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

    ``tcp/127.0.0.1:7447`` and ``tcp/[::1]:7447`` stay on this machine; ``tcp/0.0.0.0``, ``tcp/[::]`` or an
    interface's address do not. A host name is judged by the addresses it resolves to, all of which must be
    loopback (``tcp/localhost:7447`` usually is; a name that also resolves to a public address is not). An
    endpoint :func:`check_endpoint` refuses (a host that does not resolve included), or one of another protocol
    without a host (a serial line, a vsock), counts as exposed: only a known loopback host is not, or a Unix
    socket or pipe (a file on this machine, guarded by its permissions).
    """
    exposed = []
    for endpoint in endpoints:
        try:
            checked = check_endpoint(endpoint)
        except SessionError:
            exposed.append(endpoint)
            continue
        if _exposes(checked):
            exposed.append(endpoint)
    return exposed


def _exposes(checked: Endpoint) -> bool:
    """Whether another machine could reach ``checked`` (from :func:`check_endpoint`) in plain text."""
    import ipaddress

    if checked.protocol in ("tls", "quic", "unixsock-stream", "unixpipe"):  # encrypted, or local to this machine
        return False
    if checked.host is None or not checked.addresses:
        return True
    for address in checked.addresses:
        ip = ipaddress.ip_address(address)
        if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:  # ::ffff:127.0.0.1
            ip = ip.ipv4_mapped
        if not ip.is_loopback:  # 0.0.0.0 and :: are every interface, not loopback
            return True
    return False


#: Zenoh link protocols whose address is HOST:PORT.
_HOST_PORT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")

#: Every link protocol Zenoh builds may carry (the rest have their own address forms).
_PROTOCOLS = (*_HOST_PORT_PROTOCOLS, "unixsock-stream", "unixpipe", "serial", "vsock")

#: One label of a host name (RFC 1123; underscores too, as resolvers and container networks allow them).
_LABEL = re.compile(r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?")

#: The longest host name DNS carries, characters.
_MAX_HOST_NAME = 253

#: Longest wait for a host name to resolve, seconds: the system resolver's own wait for one DNS server before
#: it tries the next (resolv.conf(5), ``timeout``, default 5 s). A name not resolved by then has a server that
#: does not answer, and the resolver would go on for attempts x servers x that; the command (and ``twin local``'s
#: 10 s wait for a remote) with it.
RESOLVE_TIMEOUT = 5.0


@dataclass(frozen=True)
class Endpoint:
    """A Zenoh endpoint, ``PROTOCOL/ADDRESS[?METADATA][#CONFIG]``, split.

    Attributes:
        protocol: e.g. 'tcp'.
        address: what follows the protocol, without metadata and config.
        host: for HOST:PORT protocols, the IP address or name, IPv6 without its brackets; else None.
        port: for HOST:PORT protocols, 0 to 65535 (0: any free port, for listening); else None.
        addresses: the IP addresses ``host`` stands for, once :func:`check_endpoint` has resolved it; else ().
    """

    protocol: str
    address: str
    host: str | None = None
    port: int | None = None
    addresses: tuple[str, ...] = ()


def parse_endpoint(endpoint: str, what: str = "endpoint") -> Endpoint:
    """Split and check an endpoint: the one place that knows Zenoh's endpoint syntax here.

    Form: ``PROTOCOL/ADDRESS[?METADATA][#CONFIG]``, e.g. ``tcp/192.168.1.5:7447``, ``tls/[::1]:7447`` or
    ``tcp/router.local:7447``. Zenoh takes a malformed address (``tcp/999.0.0.1:1``) without a word and retries
    it for as long as a session waits; so it is refused here, at once.

    Raises:
        SessionError: naming ``what``, the endpoint and what is wrong: no protocol, one Zenoh does not know,
            no port or one past 65535, an IPv4 address with a bad octet, an IPv6 one without brackets, or a
            host name with characters no host name has.
    """
    proto, slash, rest = endpoint.partition("/")
    address = rest.split("#")[0].split("?")[0]
    form = "expected PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
    said = f"{what} {endpoint!r}"
    if not slash or not address:
        raise SessionError(f"{said}: not a Zenoh endpoint ({form})")
    if proto not in _PROTOCOLS:
        raise SessionError(f"{said}: unknown protocol {proto!r}, not one of {', '.join(_PROTOCOLS)} ({form})")
    if proto not in _HOST_PORT_PROTOCOLS:
        return Endpoint(proto, address)
    host, colon, port = address.rpartition(":")
    if not colon or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise SessionError(f"{said}: no valid port ({form})")
    problem = _host_problem(host)
    if problem:
        raise SessionError(f"{said}: {problem} ({form})")
    return Endpoint(proto, address, host[1:-1] if host.startswith("[") else host, int(port))


def _host_problem(host: str) -> str | None:
    """What is wrong with the HOST of a HOST:PORT endpoint (brackets still on an IPv6 one), or None."""
    import ipaddress

    if host.startswith("[") and host.endswith("]"):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            return f"{host[1:-1]!r} is not an IPv6 address"
        return None
    if ":" in host or "[" in host or "]" in host:
        return f"{host!r} is not a host; an IPv6 address goes in brackets, e.g. tcp/[::1]:7447"
    if all(part.isdigit() for part in host.split(".")):  # only numbers: an IPv4 address, dotted quad
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f"{host!r} is not an IPv4 address (four numbers 0-255)"
        return None
    name = host.removesuffix(".")  # a fully qualified name may end in a dot
    if len(name) > _MAX_HOST_NAME or not all(_LABEL.fullmatch(label) for label in name.split(".")):
        return f"{host!r} is not a host name"
    return None


def check_endpoint(endpoint: str, what: str = "endpoint", *, connect: bool = False) -> Endpoint:
    """Refuse an endpoint :func:`parse_endpoint` refuses, one whose host does not resolve (within
    :data:`RESOLVE_TIMEOUT`), and, to ``connect`` to, port 0 (no one listens there).

    Returns:
        The endpoint, split, with ``addresses`` its host resolves to (an IP address stands for itself).

    Raises:
        SessionError: naming ``what`` and the endpoint, and what is wrong (the expected form, or the host and
            the resolver's reason).
    """
    parsed = parse_endpoint(endpoint, what)
    if connect and parsed.port == 0:
        raise SessionError(f"{what} {endpoint!r}: port 0 means any free port, for listening; connect to the port "
                           f"a peer listens on")
    if parsed.host is None:
        return parsed
    return replace(parsed, addresses=_resolve(parsed.host, f"{what} {endpoint!r}"))


def _resolve(host: str, said: str) -> tuple[str, ...]:
    """The IP addresses ``host`` (an address, or a name :func:`parse_endpoint` accepted) stands for, in the
    resolver's order; ``said`` starts the error."""
    import ipaddress
    import threading

    try:
        return (str(ipaddress.ip_address(host)),)  # no resolver for an address
    except ValueError:
        pass
    outcome: list[object] = []

    def lookup() -> None:
        try:
            outcome.append(socket.getaddrinfo(host, None, type=socket.SOCK_STREAM))
        except (OSError, UnicodeError) as exc:  # socket.gaierror; an IDNA-invalid name raises UnicodeError
            outcome.append(exc)

    # getaddrinfo takes no timeout: it runs on a daemon thread, left to finish on its own if it outlasts ours.
    thread = threading.Thread(target=lookup, name=f"resolve {host}", daemon=True)
    thread.start()
    thread.join(RESOLVE_TIMEOUT)
    if not outcome:
        raise SessionError(f"{said}: host {host!r} did not resolve within {RESOLVE_TIMEOUT:g} s")
    found = outcome[0]
    if isinstance(found, BaseException):
        reason = found.strerror if isinstance(found, OSError) and found.strerror else str(found)
        raise SessionError(f"{said}: host {host!r} does not resolve ({reason})")
    addresses = tuple(dict.fromkeys(str(info[4][0]) for info in found))  # type: ignore[attr-defined]
    if not addresses:
        raise SessionError(f"{said}: host {host!r} does not resolve (no addresses)")
    return addresses


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
                config_file: str | Path | None = None, mode: str = "peer", insecure: bool = False,
                listen_default: str = LOOPBACK_ANY_PORT, connect_default: str | None = None,
                listen_name: str = "listen endpoint",
                connect_name: str = "connect endpoint", insecure_flag: str | None = "--insecure"):  # type: ignore[no-untyped-def]
    """A ``zenoh.Config``: the file's settings (if any), the safe defaults for what it leaves out, then the
    endpoints given here; refused if it would expose the session in plain text, unless ``insecure``.

    Without a file: ``mode``, multicast and gossip scouting off, listening on ``listen_default``. With one,
    the file's mode is kept, and a file that sets no ``listen/endpoints`` (or sets Zenoh's own defaults,
    which listen on every interface) listens on ``listen_default``; one that sets no
    ``scouting/multicast/enabled`` or ``scouting/gossip/enabled`` has them off. ``connect_default`` is
    connected to when neither ``connect`` nor the file names an endpoint to connect to.

    Args:
        listen: endpoints to listen on, replacing the file's.
        connect: endpoints to connect to, replacing the file's.
        config_file: a Zenoh JSON5 config.
        mode: the mode without a file ('peer', 'client' or 'router').
        insecure: allow exposure (below), with a warning (the CLI's ``--insecure``).
        listen_default: where to listen when neither ``listen`` nor the file says.
        connect_default: where to connect when neither ``connect`` nor the file says, or None.
        listen_name, connect_name: what errors call ``listen`` and ``connect`` (and the defaults), e.g. the
            CLI's flags, '--listen' and '--connect'.
        insecure_flag: what the exposure errors offer as the way to allow it; None for a command that has none
            (``twin demo``, loopback only).

    Raises:
        SessionError: the file is missing or Zenoh refuses it; an endpoint, given here, in the file or as a
            default, that :func:`check_endpoint` refuses (a host that does not resolve included); or, unless
            ``insecure``, exposure: an effective listen endpoint :func:`exposed_without_tls` would name (each
            endpoint is resolved once, here), or multicast scouting the file turns on (it announces the
            session to the whole network and joins whoever answers).
    """
    import zenoh

    listening: dict[str, Endpoint] = {}  # every listen endpoint checked, with the addresses it resolved to

    def check(endpoints: list[str] | None, what: str, connecting: bool) -> None:
        for endpoint in endpoints or ():
            checked = check_endpoint(endpoint, what, connect=connecting)
            if not connecting:
                listening[endpoint] = checked

    if mode not in ("peer", "client", "router"):  # Zenoh's own message quoted a Rust source path
        raise SessionError(f"zenoh mode must be 'peer', 'client' or 'router', got {str(mode)[:40]!r}")
    for endpoints, name in ((listen, listen_name), (connect, connect_name)):
        # A string is a sequence too: "tcp/127.0.0.1:7447" was read as the endpoints 't', 'c', 'p', ...
        if endpoints is not None and (isinstance(endpoints, str | bytes)
                                      or not all(isinstance(e, str) for e in endpoints)):
            raise SessionError(f"{name}: expected a list of endpoint strings, got {str(endpoints)[:60]!r}")
    # The caller's endpoints first: a malformed one is named as given, before the file is read.
    check(listen, listen_name, False)
    check(connect, connect_name, True)
    source = "" if config_file is None else f"zenoh config {config_file}: "
    if config_file is not None:
        path = Path(config_file)
        text = _config_text(path)
        check_config_text(text, path)
        if path.suffix.lower() in (".json", ".json5") and not _opens_an_object(text):
            # Zenoh reads "[]" as an empty config: every setting the user meant would be silently dropped.
            raise SessionError(f"zenoh config {path}: not a JSON5 object ({{ ... }}) at the top level")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:  # zenoh raises its own ZError for JSON5 or schema problems
            raise SessionError(f"zenoh config {path}: {_zenoh_error(exc)}") from exc
        for key in FILE_KEYS:  # Zenoh reads them when the session opens: a FIFO hung it, /dev/zero ate memory
            named = json.loads(conf.get_json(key))
            # One not made yet is Zenoh's to report when it opens a TLS link (configs/ ships names, not files).
            if named is not None and Path(str(named)).exists():
                _check_small_file(Path(str(named)), f"zenoh config {path}: {key}", MAX_CONFIG_BYTES)
    else:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(mode))
    file_mode = json.loads(conf.get_json("mode")) or "peer"  # Zenoh's default mode is peer
    file_listen = _mode_endpoints(conf, "listen/endpoints", file_mode)
    # A file without listen endpoints reads back as Zenoh's defaults (every interface, one list per mode).
    if json.loads(conf.get_json("listen/endpoints")) == json.loads(zenoh.Config().get_json("listen/endpoints")):
        file_listen = None
    file_connect = _mode_endpoints(conf, "connect/endpoints", file_mode) or None
    check(file_listen, f"{source}listen endpoint", False)
    check(file_connect, f"{source}connect endpoint", True)
    multicast = json.loads(conf.get_json("scouting/multicast/enabled"))
    for key in ("scouting/multicast/enabled", "scouting/gossip/enabled"):
        if json.loads(conf.get_json(key)) is None:  # not in the file: off, as without one
            conf.insert_json5(key, "false")

    effective_listen = listen if listen is not None else file_listen if file_listen is not None else [listen_default]
    effective_connect = connect if connect is not None else file_connect or ([connect_default] if connect_default
                                                                             else None)
    if listen is None and file_listen is None:
        check([listen_default], listen_name, False)
    if connect is None and not file_connect and connect_default:
        check([connect_default], connect_name, True)
    exposed = [endpoint for endpoint in effective_listen if _exposes(listening[endpoint])]
    if not insecure:
        allow = f" or pass {insecure_flag}" if insecure_flag else " (this command runs on loopback only)"
        if exposed:
            said = f"{source}listen endpoint" if listen is None and file_listen is not None else listen_name
            raise SessionError(f"{said} {exposed[0]!r} is reachable from other machines in plain text; listen on "
                               f"a tls/ endpoint (certificates in a zenoh config){allow}")
        if multicast:
            raise SessionError(f"{source}scouting/multicast/enabled is true: it announces this session to every "
                               f"machine on the network in plain text; remove it{allow}")
    if exposed:
        log.warning("listening on %s without TLS: anyone on that network can read and drive this scene",
                    ", ".join(exposed))
    if multicast:
        log.warning("multicast scouting on (zenoh config %s): any machine on the network can find this session "
                    "and join it", config_file)
    try:
        conf.insert_json5("listen/endpoints", json.dumps(effective_listen))
        if effective_connect is not None:
            conf.insert_json5("connect/endpoints", json.dumps(effective_connect))
    except Exception as exc:  # zenoh's ZError: an endpoint it still refuses
        raise SessionError(f"Zenoh endpoints {effective_listen} {effective_connect or []}: "
                           f"{_zenoh_error(exc)}") from exc
    return conf


#: Largest zenoh config (and TLS key or certificate it names) read, bytes: they are a few kB; a 200 MB one took
#: 16 GB and a minute to load.
MAX_CONFIG_BYTES = 1 << 20

#: Deepest nesting of brackets a zenoh config may have: Zenoh's JSON5 parser recursed past its stack (a
#: segmentation fault) at 15,000 levels; a real config has five or six.
MAX_CONFIG_DEPTH = 64

#: The files a zenoh config names (TLS keys and certificates, authentication dictionaries and keys), checked as
#: :func:`make_config` reads it: a user-password dictionary that was a FIFO hung the session and ignored Ctrl-C.
FILE_KEYS = (
    *(f"transport/link/tls/{key}" for key in ("root_ca_certificate", "listen_private_key", "listen_certificate",
                                              "connect_private_key", "connect_certificate")),
    "transport/auth/usrpwd/dictionary_file",
    *(f"transport/auth/pubkey/{key}" for key in ("public_key_file", "private_key_file", "known_keys_file")),
)


def _check_small_file(path: Path, what: str, limit: int) -> None:
    """Refuse ``path`` unless it is a regular file of at most ``limit`` bytes.

    Raises:
        SessionError: naming ``what`` and why (missing, a folder, a device or pipe, too large).
    """
    import stat

    try:
        info = path.stat()
    except OSError:
        raise SessionError(f"{what} {path}: no such file") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a folder" if stat.S_ISDIR(info.st_mode) else "a device or a pipe"
        raise SessionError(f"{what} {path}: is {kind}, not a file")
    if info.st_size > limit:
        raise SessionError(f"{what} {path}: {info.st_size:,} bytes, more than the {limit:,} such a file may hold")


def _config_text(path: Path) -> str:
    """A zenoh config's text, checked by :func:`_check_small_file` first.

    Raises:
        SessionError: as :func:`_check_small_file`, or not readable as UTF-8.
    """
    _check_small_file(path, "zenoh config", MAX_CONFIG_BYTES)
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError(f"zenoh config {path}: cannot read it ({exc})") from None


def _opens_an_object(text: str) -> bool:
    """Whether the first thing in a JSON5 text, past blanks and comments, is ``{``."""
    i, n = 0, len(text)
    while i < n:
        if text[i].isspace():
            i += 1
        elif text.startswith("//", i):
            i = n if (j := text.find("\n", i)) < 0 else j
        elif text.startswith("/*", i):
            i = n if (j := text.find("*/", i + 2)) < 0 else j + 2
        else:
            return text[i] == "{"
    return False


def check_config_text(text: str, path: Path) -> None:
    """Refuse a zenoh config whose brackets nest deeper than :data:`MAX_CONFIG_DEPTH` (strings and comments
    skipped), before Zenoh's parser recurses into it.

    Raises:
        SessionError: naming the file and the depth.
    """
    depth = deepest = 0
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in "\"'":  # a string: to its closing quote, escapes skipped
            i += 1
            while i < n and text[i] != c:
                i += 2 if text[i] == "\\" else 1
        elif text.startswith("//", i) or c == "#":  # JSON5 and YAML line comments
            i = text.find("\n", i)
            i = n if i < 0 else i
        elif text.startswith("/*", i):
            i = text.find("*/", i + 2)
            i = n if i < 0 else i + 1
        elif c in "{[":
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_CONFIG_DEPTH:
                raise SessionError(f"zenoh config {path}: nested more than {MAX_CONFIG_DEPTH} levels deep")
        elif c in "}]":
            depth -= 1
        i += 1


def _mode_endpoints(conf, key: str, mode: str) -> list[str] | None:  # type: ignore[no-untyped-def]
    """The endpoints at ``key`` (a list, or one per mode) for ``mode``; None if there are none for it."""
    value = json.loads(conf.get_json(key))
    if isinstance(value, dict):
        value = value.get(mode)
    return None if value is None else [str(endpoint) for endpoint in value]


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
        # Zenoh's default priority and batching: bench/zenoh_qos.py measured the others (docs/sync.md).
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
