"""The dashboard's web server: one Starlette app for a live run and for a replay.

Routes::

    GET  /                   the page (static/index.html; its script and style beside it)
    GET  /static/{file}      app.js, style.css: shipped as package data, nothing from the internet
    GET  /api/meta           {"mode": "live"|"replay", "control": bool, "end": s, "realtime": factor}
    GET  /api/snapshot?t=S   the board now (live) or at sim time S (replay)
    GET  /api/stream         live: server-sent events, one board snapshot per change, at most 4 a second
    POST /api/recover        live with control: ask the manager to recover from TIMEOUT; 403 otherwise
         ?intersection=TLS   (a run of several: whose manager; required there, refused with one)
         X-Hils-Token: SECRET  the run's secret (below)

Only the page this server serves may use it (:class:`_Guard`, before any route): a request naming another
host (``Host: evil.example``, a DNS name rebound to 127.0.0.1) or sent by a page of another origin (another
site, or another port of this machine) is answered 403, whatever it asks for. A live run that may be
controlled has a secret, drawn at start and printed in the page's URL (``?token=...``, as Jupyter does); the
page sends it with every POST, and a POST without it is answered 403 too. A page of another origin cannot
read the secret (same-origin policy) and cannot send the header without the server's leave (CORS preflight,
which nothing here grants), so it cannot press Recover even with ``fetch(..., {mode: "no-cors"})``.

A live run serves from the run's own asyncio loop (the wall-clock driver's): :class:`LiveServer`
starts uvicorn's ``Server.serve()`` as a task there, so every handler runs on the thread that steps
SimPy, between two SimPy steps. A handler only reads the board, or hands a recovery request to the
run through its ``recover`` callable (which schedules it as a SimPy event); nothing else touches the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import secrets
import socket
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from importlib import resources
from typing import Any

import orjson
import uvicorn
from starlette.applications import Starlette
from starlette.datastructures import Headers
from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route
from starlette.types import ASGIApp, Receive, Scope, Send

from hils.dashboard import DashboardError
from hils.dashboard.board import Board, Panels, Replay

#: Seconds between two looks at the board for the event stream.
STREAM_PERIOD = 0.25

_ASSETS = {"app.js": "text/javascript", "style.css": "text/css", "index.html": "text/html"}
#: The header that carries the run's secret (see the module's doc).
TOKEN_HEADER = "X-Hils-Token"
_SAFE_METHODS = frozenset({"GET", "HEAD"})


@dataclass
class Live:
    """A running run's board (or panels); ``recover(tls)`` (None: read-only) asks the run to recover the manager
    (of traffic light ``tls`` in a run of several, else None) from TIMEOUT and says what came of the request."""

    board: Board | Panels
    recover: Callable[[str | None], str] | None = None
    closing: bool = False


def _json(data: Any, status: int = 200) -> Response:
    return Response(orjson.dumps(data), status_code=status, media_type="application/json",
                    headers={"Cache-Control": "no-store"})


def _asset(name: str) -> Response:
    if name not in _ASSETS:
        return _json({"error": f"no asset {name!r}; allowed: {sorted(_ASSETS)}"}, 404)
    body = resources.files("hils.dashboard").joinpath("static", name).read_bytes()
    return Response(body, media_type=_ASSETS[name], headers={"Cache-Control": "no-cache"})


class _Guard:
    """403 for a request to another host, from a page of another origin, or controlling the run without its secret
    (ASGI middleware in front of every route)."""

    def __init__(self, app: ASGIApp, address: tuple[str, int], secret: str | None) -> None:
        host, port = address
        names = {host, "localhost"} if host == "127.0.0.1" else {host}
        self.app = app
        self.hosts = frozenset(f"{name}:{port}" for name in names)
        self.origins = frozenset(f"http://{h}" for h in self.hosts)
        self.secret = secret

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            refusal = self._refusal(scope["method"], Headers(scope=scope))
            if refusal is not None:
                await _json({"error": refusal}, 403)(scope, receive, send)
                return
        await self.app(scope, receive, send)

    def _refusal(self, method: str, headers: Headers) -> str | None:
        host = headers.get("host", "")
        if host not in self.hosts:
            return f"Host {host!r} is not this dashboard's; allowed: {', '.join(sorted(self.hosts))}"
        origin = headers.get("origin")
        if origin is not None and origin not in self.origins:
            return f"a page of {origin} may not use this dashboard; allowed: its own page"
        if method in _SAFE_METHODS or self.secret is None:
            return None
        if not hmac.compare_digest(headers.get(TOKEN_HEADER, "").encode(), self.secret.encode()):
            return (f"controlling the run needs its secret in {TOKEN_HEADER}: open the dashboard's URL printed at "
                    "start (…/?token=…)")
        return None


def create_app(source: Live | Replay, address: tuple[str, int], *, realtime: float = 1.0,
               secret: str | None = None) -> Starlette:
    """The app serving ``source`` (a live run's board, or a finished run's replay) on ``address``, the host and
    port it is reached at; ``secret``: what a POST must carry to control a live run (see the module's doc)."""
    live = source if isinstance(source, Live) else None
    replay = source if isinstance(source, Replay) else None

    async def page(request: Request) -> Response:
        return _asset("index.html")

    async def static(request: Request) -> Response:
        return _asset(request.path_params["name"])

    async def meta(request: Request) -> Response:
        if live is not None:
            return _json({"mode": "live", "control": live.recover is not None, "end": None, "realtime": 1.0})
        return _json({"mode": "replay", "control": False, "end": replay.end, "realtime": realtime})

    async def snapshot(request: Request) -> Response:
        if live is not None:
            return _json(live.board.snapshot())
        raw = request.query_params.get("t", str(replay.end))
        try:
            t = float(raw)
        except ValueError:
            return _json({"error": f"t={raw!r}: allowed: sim seconds from 0 to {replay.end:g}"}, 400)
        return _json(replay.at(t).snapshot())

    async def stream(request: Request) -> Response:
        if live is None:
            return _json({"error": "a replay has no event stream: use /api/snapshot?t=S"}, 404)
        return StreamingResponse(_events(live), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def recover(request: Request) -> Response:
        if live is None or live.recover is None:
            return _json({"error": "read-only dashboard: start the run with --dashboard-control to recover "
                                   "from here"}, 403)
        tls = request.query_params.get("intersection")
        if isinstance(live.board, Panels) and tls not in live.board.boards:
            return _json({"error": f"intersection={tls}: allowed: {', '.join(live.board.boards)}"}, 400)
        if isinstance(live.board, Board) and tls is not None:
            return _json({"error": f"intersection={tls}: a run of one intersection; allowed: no intersection"}, 400)
        return _json({"recover": live.recover(tls)})

    app = Starlette(routes=[
        Route("/", page), Route("/static/{name}", static), Route("/api/meta", meta),
        Route("/api/snapshot", snapshot), Route("/api/stream", stream), Route("/api/recover", recover,
                                                                              methods=["POST"]),
    ])
    app.add_middleware(_Guard, address=address, secret=secret)
    return app


async def _events(live: Live) -> AsyncIterator[bytes]:
    seen = -1
    while True:
        board = live.board
        if board.records != seen or live.closing:
            seen = board.records
            yield b"data: " + orjson.dumps(board.snapshot()) + b"\n\n"
        if live.closing:
            return
        await asyncio.sleep(STREAM_PERIOD)


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (port 0: any free one), or a DashboardError saying why not."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise DashboardError(f"dashboard port {port}: cannot listen on {host}:{port}: {exc.strerror}; "
                             "allowed: a free TCP port (0: any free one)") from None
    sock.listen(64)
    sock.setblocking(False)
    return sock


def url(sock: socket.socket, secret: str | None = None) -> str:
    """The page's URL on ``sock``, with the run's secret when it has one."""
    host, port = sock.getsockname()[:2]
    return f"http://{host}:{port}/" + (f"?token={secret}" if secret else "")


def address(sock: socket.socket) -> tuple[str, int]:
    host, port = sock.getsockname()[:2]
    return host, port


class _Server(uvicorn.Server):
    """uvicorn's server without its own signal handling: the run (or ``hils view``) owns the signals."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


def server(app: Starlette, *, own_signals: bool = False) -> uvicorn.Server:
    config = uvicorn.Config(app, log_level="warning", lifespan="off", timeout_graceful_shutdown=1,
                            access_log=False)
    return uvicorn.Server(config) if own_signals else _Server(config)


class LiveServer:
    """The dashboard of a wall-clock run, served as a task on the run's asyncio loop."""

    def __init__(self, live: Live, sock: socket.socket, loop: asyncio.AbstractEventLoop) -> None:
        self.live = live
        self.sock = sock
        self.loop = loop
        # Drawn afresh for every run: only who saw the URL printed at start may recover from the page.
        self.secret = secrets.token_urlsafe(24) if live.recover is not None else None
        self.server = server(create_app(live, address(sock), secret=self.secret))
        # The task runs whenever the loop does: while the driver steps SimPy to the wall clock.
        self.task = loop.create_task(self.server.serve(sockets=[sock]))

    @property
    def url(self) -> str:
        return url(self.sock, self.secret)

    def stop(self) -> None:
        """End the event streams and the server; call while the loop is not running (after the run)."""
        self.live.closing = True
        self.server.should_exit = True
        if not self.loop.is_closed() and not self.task.done():
            with contextlib.suppress(TimeoutError):  # wait_for has cancelled it then
                self.loop.run_until_complete(asyncio.wait_for(self.task, 5.0))
        self.sock.close()
