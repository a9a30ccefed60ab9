"""A cluster's address for `cnep evaluate --executor dask|ray ADDRESS`: checked before anything runs, and reached within
CONNECT_SECONDS or refused in one line.

    parse_address("dask", "tcp://10.0.0.5:8786")  # ("tcp", "10.0.0.5", 8786); PipelineError naming the problem
    reach("dask", "tcp://10.0.0.5:8786")          # PipelineError: nothing listens, or no Dask scheduler does

Dask's own client waits without end for a listener that never answers, and reads the first 8 bytes of any answer as
the length of its handshake (an HTTP server's "HTTP/1.0" asks for 3 EiB). A Dask scheduler speaks first: it sends
its handshake as soon as a connection is accepted, so `reach` connects, reads those 8 bytes within the time limit and
closes (the scheduler logs a connection closed before its handshake completed). A Ray head's protocol waits for its
client, so for Ray `reach` checks only that something listens.
"""

from __future__ import annotations

import socket
import struct
import time

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.constants import EXECUTORS, LOCAL

CONNECT_SECONDS = 10.0  # the time to connect and, for Dask, to receive the scheduler's first bytes
SCHEMES = {"dask": ("tcp", "tls"), "ray": ("ray",)}  # the schemes an address may name; without one, the first
RAY_AUTO = "auto"  # Ray's name for the cluster that `ray start` began on this machine
_HANDSHAKE_LENGTH = struct.Struct("Q")  # how Dask's TCP messages start: their length (bytes), in the machine's order
MAX_HANDSHAKE_BYTES = 1 << 20  # a Dask handshake is a few hundred bytes


def check_executor(executor: str, address: str | None) -> None:
    """PipelineError unless `executor` is one of EXECUTORS and `address` fits it: none for the local pool, a
    well-formed one (`parse_address`) or none for a cluster."""
    if executor not in EXECUTORS:
        raise PipelineError(f"unknown executor {executor!r}; choose one of {', '.join(EXECUTORS)}")
    if address is not None and executor == LOCAL:
        raise PipelineError(f"--executor local takes no address, got {address!r}; name dask or ray with it")
    if address is not None:
        parse_address(executor, address)


def parse_address(executor: str, address: str) -> tuple[str, str, int]:
    """(scheme, host, port) of `address` for `executor` ("dask" or "ray"; Ray's "auto" is ("", "auto", 0)):
    `[scheme://]host:port`, an IPv6 host in brackets; PipelineError naming the option and the problem."""
    if executor == "ray" and address == RAY_AUTO:
        return "", RAY_AUTO, 0
    scheme, separator, rest = address.partition("://")
    if not separator:
        scheme, rest = SCHEMES[executor][0], address
    schemes = SCHEMES[executor]
    shape = f"[{'|'.join(f'{s}://' for s in schemes)}]HOST:PORT"
    if scheme not in schemes:
        raise _bad(executor, address, f"the scheme {scheme!r} is not one of {', '.join(schemes)}; give {shape}")
    host, colon, port = rest.rpartition(":")
    if not colon or "/" in rest or (host.startswith("[") != host.endswith("]")) or "]" in port:
        raise _bad(executor, address, f"no port; give {shape}")
    if not host.strip("[]"):
        raise _bad(executor, address, f"no host; give {shape}")
    if not host.startswith("[") and not _is_host_name(host):
        raise _bad(executor, address, f"the host {host[:80]!r} is not a host name or IP address; give {shape}")
    if not (port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        raise _bad(executor, address, f"the port {port!r} is not a number from 1 to 65535; give {shape}")
    return scheme, host.strip("[]"), int(port)


def _is_host_name(host: str) -> bool:
    """True where `host` can be looked up: labels of 1 to 63 characters (an IDNA name's, once encoded), 253 in all."""
    try:
        encoded = host.encode("idna")
    except UnicodeError:  # a label empty or longer than 63 characters, or a character no name may hold
        return False
    return 0 < len(encoded) <= 253


def reach(executor: str, address: str) -> None:
    """Connect to the scheduler at `address` within CONNECT_SECONDS, and for a Dask scheduler over TCP receive the start
    of its handshake; PipelineError naming the option and what was found there."""
    scheme, host, port = parse_address(executor, address)
    if host == RAY_AUTO and not port:
        return
    deadline = time.monotonic() + CONNECT_SECONDS
    try:
        connection = socket.create_connection((host, port), timeout=CONNECT_SECONDS)
    except TimeoutError:
        raise _bad(
            executor, address, f"no answer within {CONNECT_SECONDS} s; check the host and its firewall"
        ) from None
    except OSError as exc:
        raise _bad(executor, address, f"cannot connect ({exc.strerror or exc}); is the scheduler running?") from None
    with connection:
        if executor != "dask" or scheme != "tcp":
            return
        head = _receive(connection, _HANDSHAKE_LENGTH.size, deadline)
    if len(head) < _HANDSHAKE_LENGTH.size:
        raise _bad(
            executor,
            address,
            f"the listener there sent no Dask handshake within {CONNECT_SECONDS} s: it is not a Dask scheduler (the "
            f"scheduler's port is 8786 unless it was started with another)",
        )
    (length,) = _HANDSHAKE_LENGTH.unpack(head)
    if length > MAX_HANDSHAKE_BYTES:
        said = head.decode("latin-1")
        raise _bad(executor, address, f"the listener there answered {said!r}, not a Dask scheduler's handshake")


def _receive(connection: socket.socket, size: int, deadline: float) -> bytes:
    """Up to `size` bytes from `connection`, fewer where it closes or the deadline (time.monotonic) passes."""
    data = b""
    while len(data) < size and (left := deadline - time.monotonic()) > 0:
        connection.settimeout(left)
        try:
            chunk = connection.recv(size - len(data))
        except (TimeoutError, OSError):
            break
        if not chunk:
            break
        data += chunk
    return data


def _bad(executor: str, address: str, problem: str) -> PipelineError:
    return PipelineError(f"--executor {executor} {address}: {problem}")
