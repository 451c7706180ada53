"""The wire between the remote scene C and the twin C': messages, key expressions, transports, clocks.

``keys`` owns the key expressions, ``messages`` the wire format and its checks, ``link`` the counted,
checked send and receive over a ``transport`` (``zenoh_transport`` for live runs, ``inprocess`` for
headless ones), and ``clock`` the time every loop reads. Nothing here knows MuJoCo or the scene.
"""
