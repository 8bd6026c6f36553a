"""The dashboard's web server: one Starlette app for a live run and for a replay.

Routes::

    GET  /                   the page (static/index.html; its script and style beside it)
    GET  /static/{file}      app.js, style.css: shipped as package data, nothing from the internet
    GET  /api/meta           {"mode": "live"|"replay", "control": bool, "end": s, "realtime": factor}
    GET  /api/snapshot?t=S   the board now (live) or at sim time S (replay)
    GET  /api/stream         live: server-sent events, one board snapshot per change, at most 4 a second
    POST /api/recover        live with control: ask the manager to recover from TIMEOUT; 403 otherwise
         ?intersection=TLS   (a run of several: whose manager; required there, refused with one)

A live run serves from the run's own asyncio loop (the wall-clock driver's): :class:`LiveServer`
starts uvicorn's ``Server.serve()`` as a task there, so every handler runs on the thread that steps
SimPy, between two SimPy steps. A handler only reads the board, or hands a recovery request to the
run through its ``recover`` callable (which schedules it as a SimPy event); nothing else touches the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from importlib import resources
from typing import Any

import orjson
import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import Response, StreamingResponse
from starlette.routing import Route

from hils.dashboard import DashboardError
from hils.dashboard.board import Board, Panels, Replay

#: Seconds between two looks at the board for the event stream.
STREAM_PERIOD = 0.25

_ASSETS = {"app.js": "text/javascript", "style.css": "text/css", "index.html": "text/html"}


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


def create_app(source: Live | Replay, *, realtime: float = 1.0) -> Starlette:
    """The app serving ``source``: a live run's board, or a finished run's replay."""
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

    return Starlette(routes=[
        Route("/", page), Route("/static/{name}", static), Route("/api/meta", meta),
        Route("/api/snapshot", snapshot), Route("/api/stream", stream), Route("/api/recover", recover,
                                                                              methods=["POST"]),
    ])


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


def url(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    return f"http://{host}:{port}/"


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
        self.server = server(create_app(live))
        # The task runs whenever the loop does: while the driver steps SimPy to the wall clock.
        self.task = loop.create_task(self.server.serve(sockets=[sock]))

    @property
    def url(self) -> str:
        return url(self.sock)

    def stop(self) -> None:
        """End the event streams and the server; call while the loop is not running (after the run)."""
        self.live.closing = True
        self.server.should_exit = True
        if not self.loop.is_closed() and not self.task.done():
            with contextlib.suppress(TimeoutError):  # wait_for has cancelled it then
                self.loop.run_until_complete(asyncio.wait_for(self.task, 5.0))
        self.sock.close()
