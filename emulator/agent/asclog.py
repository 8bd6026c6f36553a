"""MaxTime's event-log endpoint for served controllers: ``GET /v1/asclog/xml/full[?since=MM-DD-YYYY HH:MM:SS.f]``.

Rules of this file
------------------
- One HTTP listener per controller, answering with that controller's hi-res log alone, as every Intelight
  MaxTime answers for itself (a field tool names each controller by its address and port).
- Only ``GET`` of :data:`hils.protocol.hires.ASCLOG_PATH` is answered with a log (the format:
  :func:`hils.protocol.hires.asclog_xml`);
  another path is 404, another method 405, a ``since`` that is not ``MM-DD-YYYY HH:MM:SS.f`` 400 with what is
  allowed. Every answer closes its connection (``Connection: close``).
- Serving the log never delays a tick or an SNMP answer: the answer is rendered on the serving loop a few
  events at a time (:data:`CHUNK`), one chunk per turn of the loop whatever the number of clients, and streamed.
- Nothing a client does holds the loop, memory or a connection for long: a request that is malformed, larger
  than :data:`MAX_REQUEST` bytes or not complete within :data:`READ_TIMEOUT` seconds is answered 400 (or
  dropped when the client is gone); a client that takes no more of its answer for :data:`WRITE_TIMEOUT`
  seconds is dropped; beyond :data:`MAX_CONNECTIONS` open connections (of all a process's endpoints) a new
  one is answered 503 at once. A client holds at most the transport's buffer (64 KiB), a chunk and the
  socket's send buffer (:data:`SEND_BUFFER`), never its whole answer.
- Line endings: CRLF, or a bare LF, which RFC 9112 section 2.2 allows a recipient to take ("a recipient MAY
  recognize a single LF as a line terminator and ignore any preceding CR"), as scripts written by hand send it.
  A CR anywhere else makes the request 400 ("A recipient of such a bare CR MUST consider that element to be
  invalid or replace each bare CR with SP", same section).

Theory of operation
-------------------
One asyncio loop ticks the controllers and answers SNMP (:mod:`emulator.agent.serve`); the log lives there
and SimPy's rule holds: nothing of the model is touched from another thread. A request takes a
:class:`emulator.model.datalogger.Snapshot` of its controller's log (the record list and its length: the
logger only appends, so it is O(log n) and stays fixed while the controller logs on) and renders it
:data:`CHUNK` events at a time. Render turns are a FIFO lock the endpoints of a process share: each loop
iteration runs at most one chunk (about 0.3 ms) beside the tick and the datagrams, so a tick is late by one
chunk at most, however many clients ask. The loop is idle most of each 0.1 s tick; the log takes that
idle time, and a flood of requests makes the answers slower, never the ticks.

Why not a thread or a process: rendering is Python code holding the GIL, and the loop's thread must get the GIL
back after each ``select`` and each datagram; CPython hands it over only after the switch interval (5 ms), per
handover. Measured with a 100,000-event log (8.5 MB of XML) on a busy 2-core machine: tick lateness p50
1.1 ms alone, 17 ms beside one rendering thread, 137 ms beside six. A process would need the records copied
to it, O(n) on the loop.

An HTTP/1.1 request gets a chunked answer (RFC 9112 section 7.1) whose last chunk tells a complete log from
one cut short; an HTTP/1.0 one, which may not be sent a transfer coding (section 6.1), gets the log delimited
by the connection's close.

``since`` keeps the events at or after that time: a collector that polls from its last event's time sees that
event again and drops it as a duplicate, as Signal-Replay's collector does with its watermark.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import socket
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from enum import StrEnum
from http import HTTPStatus
from typing import TYPE_CHECKING
from urllib.parse import parse_qs, urlsplit

from hils.protocol.hires import ASCLOG_HEAD, ASCLOG_PATH, ASCLOG_TAIL, AsclogError, asclog_rows, parse_time

if TYPE_CHECKING:
    from emulator.model.datalogger import Snapshot

log = logging.getLogger(__name__)

MAX_REQUEST = 8192  # bytes of request line and headers
READ_TIMEOUT = 5.0  # s to send them
WRITE_TIMEOUT = 10.0  # s a client may take no more of its answer (a few TCP retransmissions of a slow link)
MAX_CONNECTIONS = 16  # open at once, of all a process's endpoints
CHUNK = 64  # events rendered in one turn of the loop: about 0.3 ms, 5 KB
SEND_BUFFER = 128 * 1024  # bytes of the kernel's send buffer per connection (Linux doubles it)
LINGER = 1.0  # s a refused connection is read before it is closed, so that the 503 is not lost to a reset
_VERSION = re.compile(r"HTTP/(\d)\.(\d)")


class BadRequest(ValueError):
    """A request that is not HTTP as this endpoint reads it; says why."""


class Dropped(StrEnum):
    """Why a connection was closed without its whole answer."""

    NOT_READING = "not reading"  # the client took nothing for WRITE_TIMEOUT seconds
    GONE = "gone"  # the client closed or reset the connection


@dataclass(slots=True)
class HttpStats:
    """Counters of the event-log endpoints (mutable: updated per connection)."""

    answered: Counter[HTTPStatus] = field(default_factory=Counter)
    dropped: Counter[Dropped] = field(default_factory=Counter)

    def add(self, other: HttpStats) -> None:
        self.answered.update(other.answered)
        self.dropped.update(other.dropped)

    def describe(self) -> str:
        answered = ", ".join(f"{status.value} {n}" for status, n in sorted(self.answered.items()))
        dropped = ", ".join(f"{reason.value} {n}" for reason, n in self.dropped.most_common())
        return (f"event log: answered {self.answered.total()} requests ({answered or 'none'}); dropped "
                f"{self.dropped.total()} connections" + (f" ({dropped})" if dropped else ""))


class Connections:
    """What the event-log endpoints of one process share: the count of open connections and the render turn."""

    def __init__(self, limit: int = MAX_CONNECTIONS) -> None:
        self.limit = limit
        self.open = 0
        self.turn = asyncio.Lock()  # FIFO: the renders take turns, one chunk each


class AsclogServer:
    """The event-log endpoint of one controller; ``snapshot(since)`` takes its log from ``since`` on."""

    def __init__(self, snapshot: Callable[[datetime | None], Snapshot], connections: Connections | None = None,
                 write_timeout: float = WRITE_TIMEOUT) -> None:
        self.snapshot = snapshot
        self.connections = connections or Connections()
        self.write_timeout = write_timeout
        self.stats = HttpStats()
        self._server: asyncio.Server | None = None
        self._clients: dict[asyncio.StreamWriter, asyncio.Task[None]] = {}  # every connection, with its task

    async def start(self, host: str, port: int) -> tuple[str, int]:
        """Listen on ``host:port`` (0: a free port); returns the address bound."""
        self._server = await asyncio.start_server(self._serve, host, port, limit=MAX_REQUEST)
        return self._server.sockets[0].getsockname()[:2]

    def close(self) -> None:
        """Stop listening and cut the connections still open: their tasks end at their next read or write."""
        if self._server is not None:
            self._server.close()
        for writer in self._clients:
            writer.transport.abort()

    async def wait_closed(self) -> None:
        """Once the connections cut by :meth:`close` have ended."""
        await asyncio.gather(*self._clients.values())

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._clients[writer] = asyncio.current_task()
        try:
            await self._connected(reader, writer)
        finally:
            del self._clients[writer]

    async def _connected(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        shared = self.connections
        if shared.open >= shared.limit:
            await self._refuse(reader, writer)
            return
        shared.open += 1
        try:
            await self._answer(reader, writer)
        except ConnectionError:
            self.stats.dropped[Dropped.GONE] += 1
            log.debug("asclog client went away before its answer")
        except TimeoutError:
            self.stats.dropped[Dropped.NOT_READING] += 1
            log.debug("asclog client took nothing for %g s: dropped", self.write_timeout)
            # Reset, not closed: the kernel would go on offering the rest of the answer to a client that takes none.
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        finally:
            shared.open -= 1
            if writer.transport.get_write_buffer_size():
                writer.transport.abort()  # an answer cut short: closing would wait for a client that does not read
            else:
                writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()

    async def _answer(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            async with asyncio.timeout(READ_TIMEOUT):
                lines = await read_head(reader)
            method, target, version = request_line(lines[0])
        except TimeoutError:
            await self._send_error(writer, HTTPStatus.BAD_REQUEST, f"request not complete within {READ_TIMEOUT:g} s")
            return
        except BadRequest as exc:
            await self._send_error(writer, HTTPStatus.BAD_REQUEST, f"malformed request: {exc}")
            return
        url = urlsplit(target)
        if url.path != ASCLOG_PATH:
            await self._send_error(writer, HTTPStatus.NOT_FOUND, f"no such log; the event log is at {ASCLOG_PATH}")
            return
        if method != "GET":
            await self._send_error(writer, HTTPStatus.METHOD_NOT_ALLOWED, "allowed: GET", "Allow: GET\r\n")
            return
        since = parse_qs(url.query).get("since")
        try:
            start = parse_time(since[0]) if since else None
        except AsclogError as exc:
            await self._send_error(writer, HTTPStatus.BAD_REQUEST, f"since: {exc}")
            return
        await self._send_log(writer, self.snapshot(start), chunked=version >= (1, 1))

    async def _send_log(self, writer: asyncio.StreamWriter, snapshot: Snapshot, *, chunked: bool) -> None:
        """``snapshot`` as MaxTime's XML, :data:`CHUNK` events per turn of the loop."""
        self.stats.answered[HTTPStatus.OK] += 1
        framing = "Transfer-Encoding: chunked\r\n" if chunked else ""
        frame = _chunk if chunked else bytes
        await self._write(writer, _status_line(HTTPStatus.OK) + f"Content-Type: application/xml\r\n{framing}"
                          "Connection: close\r\n\r\n".encode() + frame(ASCLOG_HEAD))
        for first in range(0, len(snapshot), CHUNK):
            async with self.connections.turn:
                rows = asclog_rows(snapshot.events(first, CHUNK), first + 1)
                # The turn is held to the loop's next iteration, which runs no other chunk: one per iteration.
                await asyncio.sleep(0)
            await self._write(writer, frame(rows))
        await self._write(writer, frame(ASCLOG_TAIL) + (b"0\r\n\r\n" if chunked else b""), last=True)

    async def _write(self, writer: asyncio.StreamWriter, data: bytes, *, last: bool = False) -> None:
        """``data`` written and drained below the transport's limit (``last``: all of it) within the write
        timeout."""
        writer.write(data)
        if last:
            writer.transport.set_write_buffer_limits(high=0)
        async with asyncio.timeout(self.write_timeout):
            await writer.drain()

    async def _send_error(self, writer: asyncio.StreamWriter, status: HTTPStatus, text: str,
                          headers: str = "") -> None:
        self.stats.answered[status] += 1
        body = (text + "\n").encode()
        await self._write(writer, _status_line(status) + f"Content-Type: text/plain\r\n{headers}Content-Length: "
                          f"{len(body)}\r\nConnection: close\r\n\r\n".encode() + body, last=True)

    async def _refuse(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """503 at once; then what the client sent is read for a moment, as closing a socket with unread data
        resets the connection and the client may lose the answer."""
        self.stats.answered[HTTPStatus.SERVICE_UNAVAILABLE] += 1
        body = f"busy: {self.connections.open} event-log connections open; retry in a second\n".encode()
        writer.write(_status_line(HTTPStatus.SERVICE_UNAVAILABLE) + "Content-Type: text/plain\r\nRetry-After: 1\r\n"
                     f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode() + body)
        with contextlib.suppress(OSError):  # the client gone already (reset, not connected), or the linger over
            writer.write_eof()
            async with asyncio.timeout(LINGER):
                while await reader.read(MAX_REQUEST):
                    pass
        writer.transport.abort()


async def read_head(reader: asyncio.StreamReader) -> list[str]:
    """The request line and header lines, each without its line ending (CRLF or a bare LF), up to the empty line
    that ends them (empty lines before the request line are skipped, RFC 9112 section 2.2)."""
    lines: list[str] = []
    size = 0
    while True:
        try:
            line = await reader.readuntil(b"\n")
        except asyncio.IncompleteReadError:
            raise BadRequest("the connection ended inside the request") from None
        except asyncio.LimitOverrunError:
            raise BadRequest(f"a line beyond {MAX_REQUEST} bytes") from None
        size += len(line)
        if size > MAX_REQUEST:
            raise BadRequest(f"request line and headers beyond {MAX_REQUEST} bytes")
        text = line.removesuffix(b"\n").removesuffix(b"\r")
        if b"\r" in text:
            raise BadRequest("a CR not followed by LF")
        if text:
            lines.append(text.decode("latin-1"))
        elif lines:
            return lines


def request_line(line: str) -> tuple[str, str, tuple[int, int]]:
    """Method, target and HTTP version of a request line (``GET /path HTTP/1.1``)."""
    parts = line.split(" ")
    version = _VERSION.fullmatch(parts[-1])
    if len(parts) != 3 or version is None:
        raise BadRequest("the request line is not METHOD TARGET HTTP/x.y")
    return parts[0], parts[1], (int(version[1]), int(version[2]))


def _status_line(status: HTTPStatus) -> bytes:
    return f"HTTP/1.1 {status.value} {status.phrase}\r\n".encode()


def _chunk(data: bytes) -> bytes:
    """``data`` as one chunk of a chunked body (RFC 9112 section 7.1)."""
    return f"{len(data):X}\r\n".encode() + data + b"\r\n"
