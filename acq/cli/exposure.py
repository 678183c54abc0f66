"""A warning when a simulated or replayed device is served on every network interface."""

from __future__ import annotations

import ipaddress
import socket
import sys
from urllib.parse import urlsplit

__all__ = ["every_interface", "warn_if_exposed"]


def every_interface(address: str) -> bool:
    """Whether the listen address (``tcp://HOST:PORT``, ``http://HOST:PORT/PATH`` or
    ``HOST:PORT``) names every interface: 0.0.0.0, ``::`` or a spelling of them (``0``);
    a host name is not looked up (False)."""
    try:
        host = urlsplit(address if "://" in address else f"tcp://{address}").hostname
    except ValueError:  # a malformed address: the server refuses it
        return False
    if not host:
        return False
    try:
        found = socket.getaddrinfo(host, None, flags=socket.AI_NUMERICHOST)
    except (socket.gaierror, UnicodeError):
        return False
    return any(ipaddress.ip_address(str(a[4][0]).split("%")[0]).is_unspecified for a in found)


def warn_if_exposed(prog: str, option: str, address: str | None) -> None:
    """One line on stderr when ``address`` (the value of ``option``) is every interface."""
    if address is not None and every_interface(address):
        print(
            f"{prog}: warning: {option} {address}: listening on every network interface; "
            "the device is reachable from the network, without authentication",
            file=sys.stderr,
            flush=True,
        )
