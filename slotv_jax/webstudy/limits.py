"""How the study server bounds what its clients hold: timeouts and a number of connections.

uvicorn arms its keep-alive timeout only once a response is sent, so a connection that
sends nothing, or only part of a request, stays open for ever; and its
``limit_concurrency`` answers 503 to requests beyond the limit while every socket stays
open. One client that opens thousands of half-sent requests then holds all the server's
file descriptors, and no participant gets an answer. ``serve`` therefore runs uvicorn's
h11 protocol inside :class:`BoundedConnection`, one per connection, under three
:class:`Limits` (the ``serve`` flags):

- **client timeout** (``--client-timeout``, s): a request, head and body, must arrive
  within it, counted from the connection's opening or from the request's first byte
  (a client that sends a byte now and then gains nothing); a reply that the client stops
  reading (the socket's buffer stays full) for as long ends the connection too.
- **keep-alive** (``--keep-alive``, s): a connection idle between requests is closed
  after it (uvicorn's ``timeout_keep_alive``).
- **connections** (``--max-connections``): at most this many are open. When one more
  arrives, of the connections waiting on their own client (idle between requests, or
  still sending one) the one whose last request began longest ago is closed to make
  room (found at once while the first in that order waits); only when every connection
  is busy in the application does the newcomer get ``503`` (and ``Retry-After``). So a
  participant gets through at once while one client holds every connection with requests
  it never finishes; while it holds them with replies it never reads, the participant
  gets 503 until those are cut, one client timeout after they stalled.

The wrapper reads the state of uvicorn's h11 parser (``H11Protocol.conn``, an
``h11.Connection``: is the client still owing a request?); ``tests/test_study_limits.py``
checks each limit on a real server. What the server cannot bound alone (how often one
address may start participants, for one) is the reverse proxy's job: the README's
paragraph "Online, the server bounds what one client can hold".

>>> server = make_server(app, "127.0.0.1", 8000, Limits())  # doctest: +SKIP
>>> server.run()  # doctest: +SKIP
"""

from __future__ import annotations

import asyncio
import dataclasses
import errno
import math
import resource
import socket

import h11
import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

FD_MARGIN = 64  # file descriptors kept beside the connections (the database, files, logs)
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\n"
    b"content-type: text/plain; charset=utf-8\r\n"
    b"content-length: 42\r\n"
    b"retry-after: 5\r\n"
    b"connection: close\r\n\r\n"
    b"The study server is busy: try again soon.\n"
)
WAITING = (h11.IDLE, h11.SEND_BODY)  # the client's h11 states in which it owes us bytes


@dataclasses.dataclass(frozen=True)
class Limits:
    """What one client may hold of the server (the ``serve`` flags; module docstring)."""

    client_timeout: float = 10.0  # s to send a whole request, or to read on a stalled reply
    keep_alive: float = 5.0  # s a connection may stay idle between requests
    max_connections: int = 500  # open connections at most

    def __post_init__(self):
        for flag, v in (
            ("--client-timeout", self.client_timeout),
            ("--keep-alive", self.keep_alive),
        ):
            if not (isinstance(v, int | float) and math.isfinite(v) and 0 < v <= 3600):
                raise ValueError(f"{flag} {v}: expected seconds in (0, 3600]")
        n = self.max_connections
        if not (isinstance(n, int) and 1 <= n <= 1_000_000):
            raise ValueError(f"--max-connections {n}: expected an integer in 1..1000000")


class _Pool:
    """The open connections of one server, the one whose request began longest ago first
    (an ordered set: a connection moves to the end when a request of it begins)."""

    def __init__(self, limits: Limits):
        self.limits = limits
        self.open: dict[BoundedConnection, None] = {}

    def begin(self, c: BoundedConnection) -> None:
        """``c`` begins a request (or opens): it goes last."""
        self.open.pop(c, None)
        self.open[c] = None

    def make_room(self) -> bool:
        """Close the connection that has waited longest on its client: the first, in the
        order of their requests' beginnings, idle or still sending its request (the first
        in the order usually is, so this is quick); False if every one is busy in the
        application."""
        oldest = next((c for c in self.open if c.waiting()), None)
        if oldest is None:
            return False
        del self.open[oldest]
        oldest.drop()
        return True


class BoundedConnection(asyncio.Protocol):
    """One connection: uvicorn's h11 protocol inside, the server's :class:`Limits` around it.

    Made by uvicorn with its own keyword arguments (``config``, ``server_state``,
    ``app_state``, ``_loop``), through the factory that :func:`make_server` passes as
    uvicorn's ``http`` protocol.
    """

    def __init__(self, pool: _Pool, **uvicorn_kwargs):
        self._pool = pool
        self._inner = H11Protocol(**uvicorn_kwargs)
        self._loop = self._inner.loop
        self._transport: asyncio.Transport | None = None
        self._deadline: asyncio.TimerHandle | None = None  # the request must be in by then
        self._stalled: asyncio.TimerHandle | None = None  # the client must read on by then
        self._refused = False

    # ------------------------------------------------------------ the limits

    def waiting(self) -> bool:
        """True while the connection waits on its client: idle, or a request half sent."""
        return not self._refused and self._inner.conn.their_state in WAITING

    def drop(self) -> None:
        """Close the connection now (abort: what is still unsent is not waited for, even
        by a close already under way)."""
        if self._transport is not None:
            self._transport.abort()

    def _late(self) -> None:
        if self.waiting():  # the request is not in yet
            self.drop()

    def _begin_request(self) -> None:
        self._pool.begin(self)
        self._deadline = self._loop.call_later(self._pool.limits.client_timeout, self._late)

    def _end_request(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _read_on(self) -> None:
        if self._stalled is not None:
            self._stalled.cancel()
            self._stalled = None

    # ------------------------------------------------------------ asyncio.Protocol

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        self._transport = transport
        pool = self._pool
        if len(pool.open) >= pool.limits.max_connections and not pool.make_room():
            self._refused = True
            transport.write(BUSY)
            transport.close()
            return
        self._inner.connection_made(transport)
        self._begin_request()  # the first request is due from the opening

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if self._deadline is None and self.waiting():  # a new request's first bytes
            self._begin_request()
        self._inner.data_received(data)
        if not self.waiting():  # the whole request is in: the application has it
            self._end_request()

    def eof_received(self) -> bool | None:
        return None if self._refused else self._inner.eof_received()

    def pause_writing(self) -> None:  # the client does not read what it is sent
        if self._refused:
            return
        if self._stalled is None:
            self._stalled = self._loop.call_later(self._pool.limits.client_timeout, self.drop)
        self._inner.pause_writing()

    def resume_writing(self) -> None:
        self._read_on()
        if not self._refused:
            self._inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        self._end_request()
        self._read_on()
        self._pool.open.pop(self, None)
        if not self._refused:
            self._inner.connection_lost(exc)


def check_file_limit(limits: Limits) -> None:
    """Make sure the process may open ``max_connections`` sockets and :data:`FD_MARGIN`
    more files: raise its soft limit (``ulimit -n``) up to the hard one if need be, else
    refuse, naming ``--max-connections``."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = limits.max_connections + FD_MARGIN
    if soft != resource.RLIM_INFINITY and soft < need:
        if hard == resource.RLIM_INFINITY or hard >= need:
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, hard))
        else:
            raise ValueError(
                f"--max-connections {limits.max_connections}: this process may open only "
                f"{hard} files (ulimit -Hn); expected at most {hard - FD_MARGIN}"
            )


def bind(host: str, port: int) -> socket.socket:
    """A socket bound to ``host:port`` as uvicorn binds one (``SO_REUSEADDR``; IPv6 for a
    host with a colon), for ``uvicorn.Server.run(sockets=[...])``: bound before the server
    creates its database, so a port in use is refused (naming ``--port``; an address that
    is not this machine's, ``--host``) with nothing written, and cannot be taken between
    the check and the serving."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        if e.errno == errno.EADDRINUSE:
            raise ValueError(
                f"--port {port}: already in use on {host} (another server?); expected a free port"
            ) from None
        if e.errno in (errno.EACCES, errno.EPERM):
            raise ValueError(
                f"--port {port}: not allowed to listen on it ({e.strerror}); expected a "
                "port >= 1024, or the right to bind lower ones"
            ) from None
        raise ValueError(
            f"--host {host}: cannot listen there ({e.strerror or e}); expected an address of "
            "this machine"
        ) from None
    return sock


def make_server(app, host: str, port: int, limits: Limits, **config) -> uvicorn.Server:
    """A uvicorn server of ``app`` on ``host:port`` whose connections keep to ``limits``
    (``config``: more of ``uvicorn.Config``'s arguments, e.g. ``log_level``)."""
    pool = _Pool(limits)

    def connection(**uvicorn_kwargs) -> BoundedConnection:
        return BoundedConnection(pool, **uvicorn_kwargs)

    cfg = uvicorn.Config(app, host=host, port=port, http=connection, ws="none",
                         timeout_keep_alive=limits.keep_alive, **config)  # fmt: skip
    return uvicorn.Server(cfg)
