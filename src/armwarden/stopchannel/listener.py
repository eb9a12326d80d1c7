"""Open the stop channel's listening socket, loopback only unless explicitly allowed.

Why a separate step: bind errors (port in use, unknown host, a non-loopback address nobody
allowed) must surface as a clear `ConfigurationError` at start-up, before anything is served.
"""

from __future__ import annotations

import ipaddress
import socket

from armwarden.core.errors import ConfigurationError

__all__ = ["is_loopback", "open_listener"]


def is_loopback(address: str) -> bool:
    """Whether the numeric `address` (IPv4 or IPv6, optional ``%zone``) is a loopback address; an
    IPv4-mapped IPv6 address (a dual-stack socket's IPv4 peer, ``::ffff:127.0.0.1``) counts as
    the IPv4 address it carries."""
    try:
        parsed = ipaddress.ip_address(address.split("%")[0])
    except ValueError:
        return False
    if isinstance(parsed, ipaddress.IPv6Address) and parsed.ipv4_mapped is not None:
        parsed = parsed.ipv4_mapped
    return parsed.is_loopback


def open_listener(host: str, port: int, *, allow_non_loopback: bool = False) -> socket.socket:
    """A non-blocking socket listening on `host`:`port` (0 = any free port)."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except OSError as exc:
        raise ConfigurationError(f"stop channel cannot resolve host {host!r}: {exc}") from exc
    if not allow_non_loopback and not is_loopback(str(address[0])):
        raise ConfigurationError(
            f"stop channel refuses to listen on non-loopback address {address[0]} "
            "(allowed only with allow_non_loopback=True, i.e. with bearer tokens configured)"
        )
    listener = socket.socket(family, kind, proto)
    try:
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(address)
        listener.listen(socket.SOMAXCONN)
        listener.setblocking(False)
    except OSError as exc:
        listener.close()
        raise ConfigurationError(f"stop channel cannot listen on {host}:{port}: {exc.strerror or exc}") from exc
    return listener
