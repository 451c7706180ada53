"""The wire between the remote scene C and the twin C': messages, key expressions, transports, clocks.

``keys`` owns the key expressions, ``messages`` the wire format and its checks, ``link`` the counted,
checked send and receive over a ``transport`` (``zenoh_transport`` for live runs, ``inprocess`` for
headless ones), ``ordering`` newest-wins per sender for senders without heartbeats, and ``clock`` the time
every loop reads. Nothing here knows MuJoCo or the scene.

The public names below load on first use (PEP 562): ``import sync`` imports neither Zenoh nor msgspec.
"""

from __future__ import annotations

from estimation.lazyexports import lazy_exports

#: public name -> the module that defines it.
_EXPORTS = {
    "Clock": "sync.clock",
    "RealClock": "sync.clock",
    "REAL_CLOCK": "sync.clock",
    "SimClock": "sync.clock",
    "Transport": "sync.transport",
    "Link": "sync.link",
    "LinkCounters": "sync.link",
    "Keys": "sync.keys",
    "InProcessBus": "sync.inprocess",
    "InProcessTransport": "sync.inprocess",
    "ZenohTransport": "sync.zenoh_transport",
    "SessionError": "sync.zenoh_transport",
    "make_config": "sync.zenoh_transport",
    "open_session": "sync.zenoh_transport",
    "free_port": "sync.zenoh_transport",
    "MessageError": "sync.messages",
    "encode": "sync.messages",
    "decode": "sync.messages",
    "Network": "sync.netem",
    "Conditions": "sync.netem",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports("sync", _EXPORTS, globals())
