"""MaxTime's event-log endpoint for served controllers: ``GET /v1/asclog/xml/full[?since=MM-DD-YYYY HH:MM:SS.f]``.

Rules of this file
------------------
- One HTTP listener per controller, answering with that controller's hi-res log alone, as every Intelight
  MaxTime answers for itself (a field tool names each controller by its address and port).
- Only ``GET`` of :data:`hils.protocol.hires.ASCLOG_PATH` is answered with a log (the format:
  :func:`hils.protocol.hires.asclog_xml`);
  another path is 404, another method 405, a ``since`` that is not ``MM-DD-YYYY HH:MM:SS.f`` 400 with what is
  allowed. Every answer closes its connection (``Connection: close``).
- A request that is malformed, larger than :data:`MAX_REQUEST` bytes or not complete within
  :data:`READ_TIMEOUT` seconds is answered 400 (or dropped when the client is gone): nothing a client sends
  stops the listener or the controllers.
- Handlers run on the serving loop between two ticks, so an answer holds whole ticks only.

``since`` keeps the events at or after that time: a collector that polls from its last event's time sees that
event again and drops it as a duplicate, as Signal-Replay's collector does with its watermark.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from datetime import datetime
from http import HTTPStatus
from urllib.parse import parse_qs, urlsplit

from hils.protocol.hires import ASCLOG_PATH, AsclogError, Event, asclog_xml, parse_time

log = logging.getLogger(__name__)

MAX_REQUEST = 8192  # bytes of request line and headers
READ_TIMEOUT = 5.0  # s to send them


class AsclogServer:
    """The event-log endpoint of one controller; ``events(since)`` reads its log."""

    def __init__(self, events: Callable[[datetime | None], list[Event]]) -> None:
        self.events = events
        self.requests = 0
        self._server: asyncio.Server | None = None

    async def start(self, host: str, port: int) -> tuple[str, int]:
        """Listen on ``host:port`` (0: a free port); returns the address bound."""
        self._server = await asyncio.start_server(self._serve, host, port, limit=MAX_REQUEST)
        return self._server.sockets[0].getsockname()[:2]

    def close(self) -> None:
        if self._server is not None:
            self._server.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), READ_TIMEOUT)
                status, body, content = self.answer(head)
            except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError, UnicodeDecodeError):
                status, body, content = HTTPStatus.BAD_REQUEST, b"malformed request\n", "text/plain"
            self.requests += 1
            writer.write(f"HTTP/1.1 {status.value} {status.phrase}\r\nContent-Type: {content}\r\n"
                         f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode() + body)
            await writer.drain()
        except ConnectionError:
            log.debug("asclog client went away before its answer")
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()

    def answer(self, head: bytes) -> tuple[HTTPStatus, bytes, str]:
        """Status, body and content type of the request whose line and headers are ``head``."""
        parts = head.decode("latin-1").split("\r\n", 1)[0].split()
        if len(parts) != 3 or not parts[2].startswith("HTTP/"):
            return HTTPStatus.BAD_REQUEST, b"malformed request line\n", "text/plain"
        method, target, _ = parts
        url = urlsplit(target)
        if url.path != ASCLOG_PATH:
            return HTTPStatus.NOT_FOUND, f"no such log; the event log is at {ASCLOG_PATH}\n".encode(), "text/plain"
        if method != "GET":
            return HTTPStatus.METHOD_NOT_ALLOWED, b"allowed: GET\n", "text/plain"
        since = parse_qs(url.query).get("since")
        try:
            start = parse_time(since[0]) if since else None
        except AsclogError as exc:
            return HTTPStatus.BAD_REQUEST, f"since: {exc}\n".encode(), "text/plain"
        return HTTPStatus.OK, asclog_xml(self.events(start)), "application/xml"
