"""Synchronisation between the remote scene C and the local twin C' over Eclipse Zenoh.

``keys`` owns the key expressions, ``messages`` the wire format, ``session`` the Zenoh configuration;
``remote`` and ``local`` are the two sides.
"""
