"""Collecting a controller's hi-res log from its MaxTime event-log endpoint, within bounds whatever answers.

``GET http://HOST:PORT/v1/asclog/xml/full?since=...`` (:mod:`hils.protocol.hires`: the format and the URL) is how
a field tool collects an Intelight MaxTime's log, and `hils run --asclog` collects the log of the controller it
drove (``hils emulator serve --http``, or the real one). Whatever answers there, a broken controller or a hostile
server, collection ends within :attr:`Bounds.seconds` and reads at most :attr:`Bounds.max_bytes`:

- every receive, from the connection to the body's last byte (the status line and the headers too), waits at
  most :attr:`Bounds.read_timeout`, and never beyond the collection's deadline;
- the body is read as it arrives (:class:`hils.protocol.hires.AsclogReader`): its events are kept, not the body;
- whatever goes wrong is one :class:`CollectError`, whose text says in one line what happened (no answer, an
  answer that is not HTTP, an HTTP error, a body cut short, too large or too slow, a log that cannot be read).
"""

from __future__ import annotations

import http.client
import socket
import time
import urllib.parse
from dataclasses import dataclass
from datetime import datetime

from hils.protocol.hires import AsclogError, AsclogReader, Event, asclog_url

#: What a body is read in.
_CHUNK = 65536


@dataclass(frozen=True, slots=True)
class Bounds:
    """How long a collection may take and how much it may read."""

    seconds: float = 120.0  # the whole collection, from connecting to the body's last byte
    max_bytes: int = 100 * 2**20  # of the body: a day of the shipped four-leg's actuated controller is 19 MB
    read_timeout: float = 15.0  # each receive

    def __post_init__(self) -> None:
        if not (self.seconds > 0 and self.read_timeout > 0 and self.max_bytes > 0):
            raise ValueError(f"collection bounds must be positive, got {self}")


class CollectError(Exception):
    """A log that could not be collected; the text is one line saying why."""


def collect(base: str, since: datetime | None = None, bounds: Bounds = Bounds()) -> list[Event]:
    """The events of the controller's log at ``base`` (``http://HOST:PORT``) from ``since`` on, in time order."""
    url = urllib.parse.urlsplit(asclog_url(base, since))
    if url.scheme != "http" or not url.hostname:
        raise CollectError(f"{base!r} is not an http://HOST:PORT address")
    deadline = time.monotonic() + bounds.seconds
    while True:
        connection = _Connection(url.hostname, url.port or 80, deadline, bounds.read_timeout)
        try:
            return _read(connection, f"{url.path}?{url.query}" if url.query else url.path, deadline, bounds)
        except _Busy as busy:  # a controller serving its log to others asks to come back (503, Retry-After)
            if time.monotonic() + busy.seconds >= deadline:
                raise CollectError(f"the endpoint stayed busy (HTTP 503) for {bounds.seconds:g} s") from None
            time.sleep(busy.seconds)
        finally:
            connection.close()


class _Busy(Exception):
    def __init__(self, seconds: float) -> None:
        self.seconds = seconds


def _read(connection: _Connection, path: str, deadline: float, bounds: Bounds) -> list[Event]:
    received = 0
    try:
        connection.request("GET", path)
        answer = connection.getresponse()
        if answer.status == http.client.SERVICE_UNAVAILABLE:
            retry = answer.getheader("Retry-After", "1")
            raise _Busy(min(float(retry), bounds.seconds) if retry.isdigit() else 1.0)
        if answer.status != http.client.OK:
            raise CollectError(f"the endpoint answered HTTP {answer.status} {answer.reason}".rstrip())
        reader = AsclogReader()
        while chunk := answer.read1(_CHUNK):
            received += len(chunk)
            if received > bounds.max_bytes:
                raise CollectError(f"the log is larger than the {bounds.max_bytes / 2**20:g} MB allowed")
            reader.feed(chunk)
            if time.monotonic() >= deadline:
                raise TimeoutError
        if answer.length:  # the connection closed before the length the answer announced
            raise http.client.IncompleteRead(b"", answer.length)
        events = reader.close()
    except TimeoutError:
        if time.monotonic() >= deadline:
            raise CollectError(f"not collected within {bounds.seconds:g} s ({received} bytes of the body read)"
                               ) from None
        raise CollectError(f"no answer within {bounds.read_timeout:g} s ({received} bytes of the body read)") from None
    except http.client.IncompleteRead as exc:
        more = "" if exc.expected is None else f", {exc.expected} more announced"
        raise CollectError(f"the answer ended early ({received + len(exc.partial)} bytes of the body read{more})"
                           ) from None
    except http.client.RemoteDisconnected:
        raise CollectError("the endpoint closed the connection without an answer") from None
    except http.client.HTTPException as exc:
        raise CollectError(f"not an HTTP answer ({type(exc).__name__}: {str(exc)[:80]!r})") from None
    except OSError as exc:
        raise CollectError(exc.strerror or str(exc)) from None
    except AsclogError as exc:
        raise CollectError(str(exc)) from None
    events.sort(key=lambda e: e.time)  # a log out of order would mislead every measure made from it
    return events


class _Connection(http.client.HTTPConnection):
    """An HTTP connection whose every receive ends by the deadline (:class:`_DeadlineSocket`)."""

    def __init__(self, host: str, port: int, deadline: float, read_timeout: float) -> None:
        super().__init__(host, port, timeout=read_timeout)
        self.deadline = deadline
        self.read_timeout = read_timeout

    def connect(self) -> None:
        plain = socket.create_connection((self.host, self.port), timeout=_wait(self.deadline, self.read_timeout))
        self.sock = _DeadlineSocket(plain.family, plain.type, plain.proto, fileno=plain.detach())
        self.sock.deadline, self.sock.read_timeout = self.deadline, self.read_timeout
        self.sock.settimeout(_wait(self.deadline, self.read_timeout))  # the sends too: a socket made from a bare fd



class _DeadlineSocket(socket.socket):
    """A socket whose receives time out after the read timeout or at the deadline, whichever comes first: http.client
    reads the status line, the headers and the body through it, so a server that drips any of them is cut off."""

    deadline: float
    read_timeout: float

    def recv_into(self, buffer: bytearray | memoryview, nbytes: int = 0, flags: int = 0) -> int:
        if time.monotonic() >= self.deadline:
            raise TimeoutError("the collection's deadline passed")
        self.settimeout(_wait(self.deadline, self.read_timeout))
        return super().recv_into(buffer, nbytes, flags)


def _wait(deadline: float, read_timeout: float) -> float:
    return max(0.001, min(read_timeout, deadline - time.monotonic()))
