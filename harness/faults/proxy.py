"""A UDP fault proxy: the transport faults of :mod:`harness.faults.inject`, on the wire at wall-clock time.

It listens on one UDP port and relays datagrams to an upstream host:port (an
SNMP agent: `hils emulator serve` or a real controller) and the answers back,
dropping or delaying them on a schedule. Point the middleware at the proxy
(``--target snmp://127.0.0.1:PROXYPORT?...``) to run a fault scenario over real
UDP.

The schedule's times are seconds after the first datagram the proxy receives,
which is the start of the run behind it (its first poll), so a schedule reads
like a scenario's timeline whenever the proxy was started. ``request`` rules act
on datagrams from the client to upstream, ``response`` rules on the answers,
``both`` on either. Everything runs on one asyncio loop; no thread.

``hils faults proxy --listen 127.0.0.1:1162 --upstream 127.0.0.1:1161 --drop 20:35``
prints ``proxying udp:HOST:PORT -> HOST:PORT`` once it relays, and its counts on exit.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from harness.faults.inject import Direction, Window

Address = tuple[str, int]


class Action(StrEnum):
    DROP = "drop"
    DELAY = "delay"


@dataclass(frozen=True, slots=True)
class ProxyRule:
    """Drop (with ``probability``) or delay (by ``delay`` +/- ``jitter`` s) the datagrams of a window."""

    action: Action
    window: Window
    direction: Direction = Direction.BOTH
    probability: float = 1.0
    delay: float = 0.0
    jitter: float = 0.0

    def applies(self, outbound: bool, t: float) -> bool:
        wanted = Direction.REQUEST if outbound else Direction.RESPONSE
        return self.direction in (wanted, Direction.BOTH) and self.window.contains(t)


@dataclass(slots=True)
class ProxyStats:
    """What the proxy did (mutable counters)."""

    forwarded: dict[str, int] = field(default_factory=lambda: {"request": 0, "response": 0})
    dropped: dict[str, int] = field(default_factory=lambda: {"request": 0, "response": 0})
    delayed: dict[str, int] = field(default_factory=lambda: {"request": 0, "response": 0})

    def describe(self) -> str:
        def pair(d: dict[str, int]) -> str:
            return f"{d['request']} requests, {d['response']} responses"
        return f"forwarded {pair(self.forwarded)}; dropped {pair(self.dropped)}; delayed {pair(self.delayed)}"


class _Listener(asyncio.DatagramProtocol):
    def __init__(self, proxy: UdpFaultProxy) -> None:
        self.proxy = proxy

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.proxy._from_client(data, addr)


class _Upstream(asyncio.DatagramProtocol):
    def __init__(self, proxy: UdpFaultProxy, client: Address) -> None:
        self.proxy = proxy
        self.client = client

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.proxy._from_upstream(data, self.client)


class UdpFaultProxy:
    """Relays datagrams between clients and one upstream address, applying a schedule of faults.

    Each client address gets its own upstream socket, so answers find their way back.
    """

    def __init__(self, listen: Address, upstream: Address, rules: Sequence[ProxyRule] = (), *, seed: int = 0) -> None:
        self.listen = listen
        self.upstream = upstream
        self.rules = tuple(rules)
        self.stats = ProxyStats()
        self._rng = random.Random(seed)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._listener: asyncio.DatagramTransport | None = None
        self._upstreams: dict[Address, asyncio.DatagramTransport] = {}
        self._waiting: dict[Address, list[bytes]] = {}  # requests that came before their upstream socket
        self._t0: float | None = None

    async def start(self) -> Address:
        """Bind the listening port; returns the address bound (port 0 picks a free one)."""
        self._loop = asyncio.get_running_loop()
        self._listener, _ = await self._loop.create_datagram_endpoint(lambda: _Listener(self), local_addr=self.listen)
        return self._listener.get_extra_info("sockname")[:2]

    def close(self) -> None:
        for transport in self._upstreams.values():
            transport.close()
        if self._listener is not None:
            self._listener.close()

    def now(self) -> float | None:
        """Seconds since the first datagram, or None before it."""
        return None if self._t0 is None else self._loop.time() - self._t0

    # --- relaying ------------------------------------------------------------------------------

    def _from_client(self, data: bytes, client: Address) -> None:
        if self._t0 is None:
            self._t0 = self._loop.time()
        self._relay(data, True, lambda: self._to_upstream(data, client))

    def _from_upstream(self, data: bytes, client: Address) -> None:
        self._relay(data, False, lambda: self._listener.sendto(data, client))

    def _relay(self, data: bytes, outbound: bool, send: Callable[[], None]) -> None:
        key = "request" if outbound else "response"
        t = self.now()
        delay = 0.0
        for rule in self.rules:
            if not rule.applies(outbound, t):
                continue
            if rule.action is Action.DROP:
                if rule.probability >= 1.0 or self._rng.random() < rule.probability:
                    self.stats.dropped[key] += 1
                    return
            else:
                delay += max(0.0, rule.delay + (self._rng.uniform(-rule.jitter, rule.jitter) if rule.jitter else 0.0))
        self.stats.forwarded[key] += 1
        if delay > 0.0:
            self.stats.delayed[key] += 1
            self._loop.call_later(delay, send)
        else:
            send()

    def _to_upstream(self, data: bytes, client: Address) -> None:
        transport = self._upstreams.get(client)
        if transport is not None:
            transport.sendto(data)
            return
        waiting = self._waiting.setdefault(client, [])
        waiting.append(data)
        if len(waiting) == 1:
            self._loop.create_task(self._connect(client))

    async def _connect(self, client: Address) -> None:
        transport, _ = await self._loop.create_datagram_endpoint(lambda: _Upstream(self, client),
                                                                 remote_addr=self.upstream)
        self._upstreams[client] = transport
        for data in self._waiting.pop(client, []):
            transport.sendto(data)


# --- command line ---------------------------------------------------------------------------------


def parse_address(text: str) -> Address:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host, int(port)


def _window_and_direction(text: str) -> tuple[Window, Direction]:
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"{text!r} is not START:END[:request|response|both]")
    try:
        start, end = float(parts[0]), float(parts[1]) if parts[1] else float("inf")
        direction = Direction(parts[2]) if len(parts) == 3 else Direction.BOTH
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not START:END[:request|response|both]") from None
    if not 0 <= start < end:
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 <= START < END")
    return Window(start, end), direction


def parse_drop(text: str) -> ProxyRule:
    """``START:END[:DIRECTION]``, END empty for never."""
    window, direction = _window_and_direction(text)
    return ProxyRule(Action.DROP, window, direction)


def parse_delay(text: str) -> ProxyRule:
    """``SECONDS[+-JITTER]@START:END[:DIRECTION]``."""
    amount, sep, when = text.partition("@")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r} is not SECONDS[+-JITTER]@START:END[:DIRECTION]")
    mean, _, jitter = amount.partition("+-")
    try:
        delay, spread = float(mean), float(jitter or 0.0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: the delay must be seconds, e.g. 0.3+-0.1@10:20") from None
    if delay < 0 or spread < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the delay and jitter must not be negative")
    window, direction = _window_and_direction(when)
    return ProxyRule(Action.DELAY, window, direction, delay=delay, jitter=spread)


def register_proxy(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "proxy", help="UDP proxy that drops or delays datagrams on a schedule",
        description="Relay UDP datagrams from --listen to --upstream (an SNMP agent) and back, dropping or "
                    "delaying them on a schedule whose times count from the first datagram received. "
                    "Prints a 'proxying' line once it relays, and its counts on exit (Ctrl-C or SIGTERM).")
    p.add_argument("--listen", type=parse_address, default=("127.0.0.1", 0), metavar="HOST:PORT",
                   help="address to listen on; port 0 picks a free one (127.0.0.1:0)")
    p.add_argument("--upstream", type=parse_address, required=True, metavar="HOST:PORT",
                   help="the SNMP agent to relay to")
    p.add_argument("--drop", type=parse_drop, action="append", default=[], metavar="START:END[:DIRECTION]",
                   help="drop datagrams in this window (seconds; DIRECTION request, response or both)")
    p.add_argument("--delay", type=parse_delay, action="append", default=[],
                   metavar="S[+-J]@START:END[:DIRECTION]", help="delay datagrams by S +/- J seconds in this window")
    p.add_argument("--loss", type=float, default=0.0, metavar="P",
                   help="also drop each datagram with probability P, all the time (0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random loss and jitter (0)")
    p.set_defaults(func=_proxy_command)


def _proxy_command(args: argparse.Namespace) -> int:
    if not 0.0 <= args.loss <= 1.0:
        raise SystemExit("hils faults proxy: --loss must be in [0, 1]")
    rules = [*args.drop, *args.delay]
    if args.loss:
        rules.append(ProxyRule(Action.DROP, Window(), probability=args.loss))
    proxy = UdpFaultProxy(args.listen, args.upstream, rules, seed=args.seed)
    asyncio.run(_serve(proxy))
    print(proxy.stats.describe(), flush=True)
    return 0


async def _serve(proxy: UdpFaultProxy) -> None:
    loop = asyncio.get_running_loop()
    stop = loop.create_future()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, lambda: stop.done() or stop.set_result(None))
    host, port = await proxy.start()
    # Scripts and tests wait for this line: it is printed only once datagrams are relayed.
    print(f"proxying udp:{host}:{port} -> {proxy.upstream[0]}:{proxy.upstream[1]}", flush=True)
    try:
        await stop
    finally:
        proxy.close()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(RuntimeError):
                loop.remove_signal_handler(sig)
