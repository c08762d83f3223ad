"""The study server: a thin Starlette application over :class:`StudyService`.

``python -m slotv_jax.study serve --stimuli STIMDIR --db FILE`` runs it under uvicorn on
127.0.0.1 (``--host`` to listen elsewhere) and prints the admin token. Routes validate
the request, call one service function and return JSON; nothing else happens here.

============================================  ==================================================
route                                         what
============================================  ==================================================
``GET /``                                     the participant page (``static/index.html``);
                                              ``?PROLIFIC_PID=&STUDY_ID=&SESSION_ID=`` are kept
``GET /api/texts``                            title, consent and instructions (editable files)
``POST /api/start``                           ``{"consent": true, "ids": {...}}``: a participant
                                              (new, or resumed: see ``StudyService.begin``); sets
                                              the participant cookie (HttpOnly, SameSite)
``POST /api/resume``                          ``{"token": ...}`` of a resume link (``/#resume=``):
                                              sets the cookie, returns the state
``GET /api/state``                            the next unanswered trial, or the completion code
``POST /api/answer``                          ``{"position", "guess", "confidence",
                                              "response_ms"}``: stores it once, returns the state
``GET /api/media/{position}/{clip|still}``    a file of one of the participant's trials
``GET /admin``                                the admin page; its API needs
                                              ``Authorization: Bearer <admin token>``:
``GET /api/admin/progress``                   answers per stimulus and per participant
``GET /api/admin/export/{name}.csv``          answers, trajectories, goals, participants
``POST /api/admin/resume-link/{n}``           a new token for participant ``n`` (the one they
                                              held stops working) and its link ``/#resume=``
============================================  ==================================================

Safety: a participant reaches only their own trials (their token is a random 256-bit
cookie, stored hashed); files are looked up by trial, never by a path from the request;
request bodies are JSON objects of at most :data:`MAX_BODY` bytes with known keys (each
once) and types, and any other body is a 4xx; errors answer ``{"error": "..."}`` and
never a traceback; every response carries a strict Content-Security-Policy and
``nosniff``; a request whose ``Host`` header is not one of ``allowed_hosts`` is refused
(400, JSON), which stops DNS rebinding against a server on 127.0.0.1 (``serve`` allows
only the loopback names there unless ``--allowed-hosts``). Who can resume whom: the
module docstring of :mod:`slotv_jax.webstudy.service` and the README.

>>> app = make_app(StudyService("stim", SQLiteStorage("study.db")), "admin-token")  # doctest: +SKIP
>>> TestClient(app).get("/api/texts").json()["title"]  # doctest: +SKIP
'Which object is the robot reaching for?'
"""

from __future__ import annotations

import json
import logging
import math
import re
import secrets
from collections.abc import Sequence
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from slotv_jax.webstudy.database import Conflict
from slotv_jax.webstudy.export import TABLES, tables
from slotv_jax.webstudy.service import (
    CONFIDENCE,
    ID_PARAMS,
    MAX_RESPONSE_MS,
    MAX_TOKEN,
    Forbidden,
    Invalid,
    StudyService,
    Unauthorized,
)

STATIC = Path(__file__).with_name("static")
COOKIE = "slotv_study"
MAX_BODY = 4096  # bytes of a request body
MAX_ID = 128  # characters of an external id
ID_CHARS = re.compile(r"[A-Za-z0-9_.:@-]+")  # ASCII only: str.isalnum takes any script
HOST = re.compile(r"(?P<name>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)(?::[0-9]{1,5})?")
MEDIA_TYPES = {"clip": "video/mp4", "still": "image/png"}
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; object-src 'none'; base-uri 'none'; "
    "frame-ancestors 'none'; form-action 'self'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
}
log = logging.getLogger("slotv_jax.study")


class SecurityHeaders:
    """ASGI middleware: security headers on every response, no caching of the API."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        api = scope["path"].startswith("/api/")

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                headers += [(k.lower().encode(), v.encode()) for k, v in HEADERS.items()]
                if api:
                    headers.append((b"cache-control", b"no-store"))
                message["headers"] = headers
            await send(message)

        await self.app(scope, receive, send_with_headers)


def host_patterns(allowed_hosts: Sequence[str]) -> list[str]:
    """``allowed_hosts`` checked (names, ``"*"`` or ``"*.domain"``) and in lower case."""
    if isinstance(allowed_hosts, str) or not allowed_hosts:
        raise ValueError(
            f"allowed_hosts: expected a non-empty list of names, got {allowed_hosts!r}"
        )
    for p in allowed_hosts:
        wild = p.startswith("*") and p != "*"
        if not p or "*" in p[1:] or (wild and not p.startswith("*.")):
            raise ValueError(f"allowed_hosts: {p!r} is not a name, '*' or '*.domain'")
    return [p.lower() for p in allowed_hosts]


class AllowedHosts:
    """ASGI middleware: a request whose ``Host`` header names none of ``patterns``
    (``"*"``: any; ``"*.example.org"``: its subdomains) is refused, 400 with JSON."""

    def __init__(self, app, patterns: Sequence[str]):
        self.app = app
        self.patterns = host_patterns(patterns)

    def allowed(self, header: str | None) -> bool:
        """Whether a ``Host`` header (a name, an ``[IPv6]``, an optional port) is allowed."""
        if "*" in self.patterns:
            return True
        m = HOST.fullmatch(header or "")
        if m is None:
            return False
        name = m["name"].lower()
        return any(name == p or (p.startswith("*.") and name.endswith(p[1:]))
                   for p in self.patterns)  # fmt: skip

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and not self.allowed(Headers(scope=scope).get("host")):
            refusal = JSONResponse({"error": "this server does not answer that Host name"}, 400)
            return await refusal(scope, receive, send)
        await self.app(scope, receive, send)


# ------------------------------------------------------------------ validation


async def read_json(request: Request) -> dict:
    """The request's JSON object (415, 413 or 400 otherwise)."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise HTTPException(415, "expected Content-Type: application/json")
    length = request.headers.get("content-length")
    if length is not None and (not length.isdigit() or int(length) > MAX_BODY):
        raise HTTPException(413, f"request body over {MAX_BODY} bytes")
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise HTTPException(413, f"request body over {MAX_BODY} bytes")
    try:
        doc = json.loads(body, object_pairs_hook=_unique_keys)
    except RecursionError:  # e.g. 2,000 nested brackets
        raise HTTPException(400, "expected a JSON object (nested too deeply)") from None
    except ValueError as e:  # JSONDecodeError, UnicodeDecodeError, a duplicate key
        detail = str(e) if isinstance(e, DuplicateKey) else "expected a JSON object"
        raise HTTPException(400, detail) from None
    if not isinstance(doc, dict):
        raise HTTPException(400, "expected a JSON object")
    return doc


class DuplicateKey(ValueError):
    """A JSON object names a field twice (refused: which one counts would be a guess)."""


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    doc = dict(pairs)
    if len(doc) != len(pairs):
        seen: set[str] = set()
        dup = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise DuplicateKey(f"field {dup[:40]!r} given twice")
    return doc


def _keys(doc: dict, required: set[str], optional: set[str]) -> None:
    missing, extra = required - set(doc), set(doc) - required - optional
    if missing:
        raise HTTPException(400, f"missing field {sorted(missing)[0]!r}")
    if extra:
        raise HTTPException(400, f"unknown field {sorted(extra)[0]!r}")


def parse_ids(raw) -> dict[str, str | None]:
    """External ids from the page's URL parameters (see ``ID_PARAMS``)."""
    if not isinstance(raw, dict) or len(raw) > 20:
        raise HTTPException(400, "ids: expected an object of URL parameters")
    out: dict[str, str | None] = {}
    for field, names in ID_PARAMS.items():
        vals = [raw[n] for n in names if raw.get(n) not in (None, "")]
        v = vals[0] if vals else None
        if v is not None and (
            not isinstance(v, str) or len(v) > MAX_ID or not ID_CHARS.fullmatch(v)
        ):
            raise HTTPException(
                400, f"ids: {names[0]} must be at most {MAX_ID} ASCII letters, digits or -_.:@"
            )
        out[field] = v
    return out


def parse_answer(doc: dict) -> tuple[int, str, int | None, float]:
    """(position, guess, confidence, response_ms) of an answer body, or 400."""
    _keys(doc, {"position", "guess", "response_ms"}, {"confidence"})
    pos, guess, conf, rt = doc["position"], doc["guess"], doc.get("confidence"), doc["response_ms"]
    if not isinstance(pos, int) or isinstance(pos, bool) or not 0 <= pos < 10_000:
        raise HTTPException(400, "position: expected a trial number")
    if not isinstance(guess, str) or not 1 <= len(guess) <= 16:
        raise HTTPException(400, "guess: expected a goal label")
    if conf is not None and (
        not isinstance(conf, int)
        or isinstance(conf, bool)
        or not CONFIDENCE[0] <= conf <= CONFIDENCE[1]
    ):
        raise HTTPException(400, f"confidence: expected null or {CONFIDENCE[0]}..{CONFIDENCE[1]}")
    if (
        not isinstance(rt, int | float)
        or isinstance(rt, bool)
        or not math.isfinite(rt)
        or not 0 <= rt <= MAX_RESPONSE_MS
    ):
        raise HTTPException(400, f"response_ms: expected milliseconds in 0..{MAX_RESPONSE_MS:.0f}")
    return pos, guess, conf, float(rt)


def set_cookie(request: Request, resp: Response, token: str) -> None:
    """The participant cookie: HttpOnly, SameSite=Strict, Secure behind HTTPS, 30 days."""
    resp.set_cookie(COOKIE, token, httponly=True, samesite="strict",
                    secure=request.url.scheme == "https", max_age=30 * 86400)  # fmt: skip


# ---------------------------------------------------------------------- the app


#: The Host names of a server on the loopback interface.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")


def make_app(
    service: StudyService, admin_token: str, allowed_hosts: Sequence[str] = ("*",)
) -> Starlette:
    """The ASGI application of one study (see the module docstring). ``allowed_hosts``:
    the ``Host`` header values it answers (``"*"``: any; ``"*.example.org"``: subdomains)."""
    if len(admin_token) < 16:
        raise ValueError("admin_token: expected at least 16 characters")
    patterns = host_patterns(allowed_hosts)

    def admin(request: Request) -> None:
        auth = request.headers.get("authorization", "")
        given = auth[7:] if auth.startswith("Bearer ") else ""
        if not secrets.compare_digest(given.encode(), admin_token.encode()):
            raise HTTPException(401, "admin token required")

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html")

    async def admin_page(request: Request) -> Response:
        return FileResponse(STATIC / "admin.html")

    async def texts(request: Request) -> Response:
        return JSONResponse(await run_in_threadpool(service.texts))

    async def start(request: Request) -> Response:
        doc = await read_json(request)
        _keys(doc, {"consent"}, {"ids"})
        if doc["consent"] is not True:
            raise HTTPException(400, "consent: the study starts only with consent")
        ids = parse_ids(doc.get("ids", {}))
        ua = request.headers.get("user-agent", "")[:200]
        p, token = await run_in_threadpool(service.begin, request.cookies.get(COOKIE), ids, ua)
        resp = JSONResponse(await run_in_threadpool(service.state, p))
        if token is not None:
            set_cookie(request, resp, token)
        return resp

    async def resume(request: Request) -> Response:
        doc = await read_json(request)
        _keys(doc, {"token"}, set())
        token = doc["token"]
        if not isinstance(token, str) or not 1 <= len(token) <= MAX_TOKEN:
            raise HTTPException(400, "token: expected the token of a resume link")
        p = await run_in_threadpool(service.require, token)
        resp = JSONResponse(await run_in_threadpool(service.state, p))
        set_cookie(request, resp, token)
        return resp

    async def state(request: Request) -> Response:
        token = request.cookies.get(COOKIE)
        return JSONResponse(await run_in_threadpool(service.state_for, token))

    async def answer(request: Request) -> Response:
        token = request.cookies.get(COOKIE)
        if not token:
            raise Unauthorized("no participant")
        pos, guess, conf, rt = parse_answer(await read_json(request))
        return JSONResponse(
            await run_in_threadpool(service.answer_for, token, pos, guess, conf, rt)
        )

    async def media(request: Request) -> Response:
        token, which = request.cookies.get(COOKIE), request.path_params["which"]
        pos = request.path_params["position"]
        path = await run_in_threadpool(service.media_for, token, pos, which)
        return FileResponse(path, media_type=MEDIA_TYPES[which])

    async def progress(request: Request) -> Response:
        admin(request)
        return JSONResponse(await run_in_threadpool(service.progress))

    async def resume_link(request: Request) -> Response:
        admin(request)
        n = request.path_params["participant"]
        token = await run_in_threadpool(service.reissue, n)
        url = f"{str(request.base_url).rstrip('/')}/#resume={token}"
        return JSONResponse({"participant": n, "url": url})

    async def export(request: Request) -> Response:
        admin(request)
        name = request.path_params["name"]
        if name not in TABLES:
            raise HTTPException(404, "not found")
        text = (await run_in_threadpool(tables, service.storage))[name]
        return Response(text, media_type="text/csv", headers={
            "content-disposition": f'attachment; filename="{name}.csv"'})  # fmt: skip

    async def health(request: Request) -> Response:
        return JSONResponse({"ok": True})

    async def http_error(request: Request, exc: HTTPException) -> Response:
        return JSONResponse({"error": exc.detail}, status_code=exc.status_code)

    async def invalid(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": str(exc)}, status_code=400)

    async def unauthorized(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": "no participant: start the study from its first page"},
                            status_code=401)  # fmt: skip

    async def forbidden(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": "not found"}, status_code=404)

    async def conflict(request: Request, exc: Exception) -> Response:
        return JSONResponse({"error": str(exc)}, status_code=409)

    async def internal(request: Request, exc: Exception) -> Response:
        log.exception("internal error on %s %s", request.method, request.url.path)
        return JSONResponse({"error": "internal error"}, status_code=500)

    routes = [
        Route("/", index),
        Route("/admin", admin_page),
        Route("/healthz", health),
        Route("/api/texts", texts),
        Route("/api/start", start, methods=["POST"]),
        Route("/api/resume", resume, methods=["POST"]),
        Route("/api/state", state),
        Route("/api/answer", answer, methods=["POST"]),
        Route("/api/media/{position:int}/{which:str}", media),
        Route("/api/admin/progress", progress),
        Route("/api/admin/export/{name:str}.csv", export),
        Route("/api/admin/resume-link/{participant:int}", resume_link, methods=["POST"]),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(
        routes=routes,
        exception_handlers={
            HTTPException: http_error,
            Invalid: invalid,
            Forbidden: forbidden,
            Unauthorized: unauthorized,
            Conflict: conflict,
            Exception: internal,
        },
    )
    app.add_middleware(AllowedHosts, patterns=patterns)
    app.add_middleware(SecurityHeaders)  # the outermost: headers on refusals too
    return app
