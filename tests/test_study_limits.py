"""The study server's limits (slotv_jax.webstudy.limits), on a real uvicorn server on
127.0.0.1 run in a thread: slow and idle connections are closed, the number of connections
is bounded, and a participant gets through while one client holds every connection."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time

import httpx
import pytest
from study_fixtures import free_port, write_dot_set

from slotv_jax.study import cli as study_cli
from slotv_jax.webstudy import limits, web_cli
from slotv_jax.webstudy.database import SQLiteStorage
from slotv_jax.webstudy.server import make_app
from slotv_jax.webstudy.service import StudyService

TIMEOUT = 0.5  # s: the short client timeout or keep-alive under test
LONG = 30.0  # s: a limit that must not be what closes a connection
HALF = b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n"  # a request head without its end
GET = HALF + b"\r\n"
ADMIN = "admin-token-for-tests-0123456789"


@pytest.fixture(scope="module")
def dot_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("dots") / "stim"
    write_dot_set(out, n=2)
    return out


@pytest.fixture
def app(dot_set, tmp_path):
    return make_app(StudyService(dot_set, SQLiteStorage(tmp_path / "study.db")), ADMIN)


@contextlib.contextmanager
def serving(app, bounds: limits.Limits, **config):
    """The app under ``make_server`` (as ``serve`` runs it) on a free port: yields the port."""
    server = limits.make_server(app, "127.0.0.1", 0, bounds, log_level="warning",
                                timeout_graceful_shutdown=2, **config)  # fmt: skip
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.01)
    try:
        yield server.servers[0].sockets[0].getsockname()[1]
    finally:
        server.should_exit = True
        thread.join(10)


def connect(port: int, data: bytes = b"") -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.sendall(data)
    return s


def closes_within(s: socket.socket, seconds: float) -> tuple[float, bytes]:
    """Read until the server closes ``s`` (EOF or reset): the seconds it took and what was
    read. Fails if ``s`` is still open after ``seconds``."""
    t0, got = time.monotonic(), b""
    s.settimeout(seconds)
    try:
        while chunk := s.recv(65536):
            got += chunk
    except ConnectionResetError:
        pass
    except TimeoutError:
        pytest.fail(f"the connection is still open after {seconds} s")
    return time.monotonic() - t0, got


def is_open(s: socket.socket) -> bool:
    s.settimeout(0.1)
    try:
        return s.recv(1) != b""
    except TimeoutError:
        return True
    except ConnectionResetError:
        return False


def test_half_sent_requests_are_closed_after_the_client_timeout(app):
    """A request head without its end, one sent a byte at a time, and a head whose body
    never comes: each closed once the client timeout has passed since its first byte."""
    with serving(app, limits.Limits(client_timeout=TIMEOUT, keep_alive=LONG)) as port:
        t0 = time.monotonic()
        half = connect(port, HALF)
        head = b"POST /api/start HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\n"
        body = connect(port, head + b"{")
        trickle = connect(port, b"G")
        for byte in HALF[1:]:  # a byte every 0.1 s: the deadline stays where it was
            time.sleep(0.1)
            try:
                trickle.sendall(bytes([byte]))
            except OSError:
                break
        assert time.monotonic() - t0 < 10 * TIMEOUT, "the trickle was not cut"
        for s in (half, body, trickle):
            closes_within(s, 10 * TIMEOUT)
        assert time.monotonic() - t0 >= TIMEOUT
        assert httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=5).status_code == 200


def test_idle_connections_are_closed(app):
    """A connection that sends nothing goes after the client timeout; one idle after a
    request goes after the keep-alive time (and not before its reply)."""
    with serving(app, limits.Limits(client_timeout=TIMEOUT, keep_alive=LONG)) as port:
        t0 = time.monotonic()
        silent = [connect(port) for _ in range(5)]
        for s in silent:
            assert closes_within(s, 10 * TIMEOUT)[1] == b""
        assert time.monotonic() - t0 >= 0.8 * TIMEOUT  # not at once: they had their time
    with serving(app, limits.Limits(client_timeout=LONG, keep_alive=TIMEOUT)) as port:
        kept = connect(port, GET)
        took, got = closes_within(kept, 10 * TIMEOUT)
        assert got.startswith(b"HTTP/1.1 200 ") and took >= 0.8 * TIMEOUT


def test_a_participant_gets_through_while_one_client_holds_every_connection(app):
    """One client holds all 8 connections with half-sent requests (and a long client
    timeout): a participant starts at once, the held connection that waited longest is
    closed to make room, the others stay open."""
    bounds = limits.Limits(client_timeout=LONG, keep_alive=LONG, max_connections=8)
    with serving(app, bounds) as port:
        held = []
        for _ in range(8):
            held.append(connect(port, HALF))
            time.sleep(0.02)  # in order: held[0] has waited longest
        assert all(is_open(s) for s in held)
        t0 = time.monotonic()
        r = httpx.post(f"http://127.0.0.1:{port}/api/start",
                       json={"consent": True, "ids": {}}, timeout=10)  # fmt: skip
        assert r.status_code == 200 and r.json()["stage"] in ("practice", "trial"), r.text
        assert time.monotonic() - t0 < 10 < LONG  # served at once, not after a timeout
        assert [is_open(s) for s in held] == [False] + [True] * 7


def test_busy_connections_are_kept_and_the_newcomer_gets_503():
    """When every connection is busy in the application, one more gets 503 at once (and
    the busy ones finish); none is closed under a request being answered."""
    release = threading.Event()

    async def slow(scope, receive, send):
        while not release.is_set():
            await asyncio.sleep(0.01)
        await send({"type": "http.response.start", "status": 200,
                    "headers": [(b"content-length", b"2")]})  # fmt: skip
        await send({"type": "http.response.body", "body": b"ok"})

    with serving(slow, limits.Limits(max_connections=2), lifespan="off") as port:
        busy = [connect(port, GET) for _ in range(2)]
        time.sleep(0.3)  # both requests are in the application
        _, got = closes_within(connect(port), 5)
        assert got.startswith(b"HTTP/1.1 503 ") and b"retry-after: 5" in got
        release.set()
        for s in busy:
            s.settimeout(5)
            assert s.recv(4096).startswith(b"HTTP/1.1 200 ")


def test_a_reply_the_client_does_not_read_is_cut_after_the_client_timeout():
    """A client that stops reading a long reply (the socket's buffers full) is dropped
    after the client timeout; one that reads gets all of it."""
    size = 64 << 20  # more than the loopback's socket buffers hold

    async def big(scope, receive, send):
        await send({"type": "http.response.start", "status": 200,
                    "headers": [(b"content-length", str(size).encode())]})  # fmt: skip
        chunk = b"x" * (1 << 20)
        for i in range(size >> 20):
            await send({"type": "http.response.body", "body": chunk, "more_body": i < 63})

    bounds = limits.Limits(client_timeout=TIMEOUT, keep_alive=LONG)
    with serving(big, bounds, lifespan="off") as port:
        stalled = connect(port, GET)
        time.sleep(3 * TIMEOUT)  # not reading
        _, got = closes_within(stalled, 10)
        assert 0 < len(got) < size
        r = httpx.get(f"http://127.0.0.1:{port}/", timeout=30)
        assert r.status_code == 200 and len(r.content) == size


def test_serve_runs_under_its_limits(dot_set, tmp_path, monkeypatch, capsys):
    """`serve` builds its server with the flags' limits (defaults: limits.Limits()), and
    refuses a bad limit in one line before opening the database."""
    seen = {}

    class Server:
        def run(self, sockets=None):
            seen["listening"] = [sock.getsockname()[1] for sock in sockets]

    def fake(app, host, port, bounds, **config):
        seen.update(host=host, port=port, bounds=bounds)
        return Server()

    monkeypatch.setattr(limits, "make_server", fake)
    port = free_port()
    base = ["serve", "--stimuli", str(dot_set), "--db", str(tmp_path / "a.db"), "--port", str(port)]
    assert study_cli.main(base) == 0
    assert seen["bounds"] == limits.Limits() and seen["listening"] == [port]
    flags = ["--client-timeout", "3", "--keep-alive", "2", "--max-connections", "40"]
    assert study_cli.main(base + flags) == 0
    assert seen["bounds"] == limits.Limits(3.0, 2.0, 40)
    capsys.readouterr()
    for flag, value in [("--client-timeout", "0"), ("--keep-alive", "nan"),
                        ("--max-connections", "0")]:  # fmt: skip
        with pytest.raises(SystemExit) as e:
            study_cli.main(["serve", "--stimuli", str(dot_set), "--db",
                            str(tmp_path / "b.db"), flag, value])  # fmt: skip
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: {flag} "), err
    assert not (tmp_path / "b.db").exists()
    assert web_cli.limits is limits


def test_the_file_limit_is_raised_or_the_bound_refused(monkeypatch):
    """--max-connections needs as many file descriptors (and a margin): the soft limit is
    raised up to the hard one, and a bound above that is refused in one line."""
    calls = []
    monkeypatch.setattr(limits.resource, "getrlimit", lambda what: (1024, 2048))
    monkeypatch.setattr(limits.resource, "setrlimit", lambda what, v: calls.append(v))
    limits.check_file_limit(limits.Limits(max_connections=500))
    assert calls == []
    limits.check_file_limit(limits.Limits(max_connections=1500))
    assert calls == [(1500 + limits.FD_MARGIN, 2048)]
    with pytest.raises(ValueError, match=r"^--max-connections 4000: .* at most 1984$"):
        limits.check_file_limit(limits.Limits(max_connections=4000))
