"""The address of a Ray cluster (``sapga experiment --backend ray --address``), checked
before Ray is asked: ``HOST:PORT``, ``ray://HOST:PORT`` (Ray Client) or ``auto``.

Ray retries an address it cannot reach for ever; ``reach`` first opens one TCP connection
to it, bounded by ``CONNECT_TIMEOUT_S``, and checks that a gRPC server answers there (Ray's
GCS and Ray Client both speak gRPC: an HTTP/2 server answers a client's connection preface
with a SETTINGS frame), so an unreachable address, or one where something else listens, is
one line and exit status 2 instead of a hang.
"""
from __future__ import annotations

import re
import socket

from sapga_ros.errors import ConfigError

CONNECT_TIMEOUT_S = 10.0
_SETTINGS = 0x4                 # HTTP/2 frame type
_PREFACE = b'PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n' + bytes([0, 0, 0, _SETTINGS, 0, 0, 0, 0, 0])
_HOST = r'(?:[A-Za-z0-9](?:[A-Za-z0-9-]{0,62})(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,62}))*' \
        r'|\[[0-9A-Fa-f:.]{2,45}\])'
_ADDRESS = re.compile(rf'(ray://)?({_HOST}):([0-9]{{1,5}})')


def parse_address(address: str) -> tuple[str, int] | None:
    """(host, port) of ``address``; None for ``auto``; ConfigError if it is neither."""
    if address == 'auto':
        return None
    m = _ADDRESS.fullmatch(address) if isinstance(address, str) and len(address) <= 300 \
        else None
    if m is None or not 1 <= int(m.group(3)) <= 65535:
        raise ConfigError(f'--address: expected HOST:PORT, ray://HOST:PORT or auto, got '
                          f'{str(address)[:60]!r}')
    return m.group(2).strip('[]'), int(m.group(3))


def reach(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """ConfigError unless a TCP connection to ``address`` opens within ``timeout`` s."""
    target = parse_address(address)
    if target is None:
        return
    try:
        conn = socket.create_connection(target, timeout=timeout)
    except OSError as exc:
        reason = 'timed out' if isinstance(exc, TimeoutError) else (exc.strerror or exc)
        raise ConfigError(f'--address {address}: no Ray cluster reachable there '
                          f'({reason}; waited at most {timeout:.0f} s)') from None
    head = b''
    with conn:   # something accepted: a reset or silence now means it is not gRPC
        try:
            conn.settimeout(timeout)
            conn.sendall(_PREFACE)
            while len(head) < 9 and (chunk := conn.recv(9 - len(head))):
                head += chunk
        except OSError:
            pass
    if len(head) < 9 or head[3] != _SETTINGS:
        raise ConfigError(f'--address {address}: something answers there, but not a Ray '
                          'cluster (no gRPC server)')
