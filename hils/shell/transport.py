"""The transport interface: GET and SET of NTCIP objects as SimPy events.

Every request returns a SimPy event on the run's environment. It succeeds with
the values (GET) or None (SET), or fails with :class:`CommunicationTimeout`
when no answer came within tau_udp, or with :class:`hils.protocol.ntcip.SnmpError` when
the controller refused. Requests are never retried here: the manager counts
failures and decides.

:class:`LocalTransport` reaches an object surface in the same process (the
emulator's MIB view) with a modeled latency and loss, for virtual time. The SNMP
transport in :mod:`hils.shell.snmp` implements the same interface over UDP.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import Protocol

import simpy

from hils.protocol.ntcip import Latency, Oid, SnmpError, Value
from hils.shell.fastpath import ChangeFeed

VarBind = tuple[Oid, int]

__all__ = [
    "CommunicationTimeout",
    "Latency",
    "LocalTransport",
    "ObjectSurface",
    "SecurityRefused",
    "SnmpError",
    "Transport",
    "TransportError",
]


class TransportError(Exception):
    """A request that got no usable answer."""


class CommunicationTimeout(TransportError):
    """No answer within tau_udp."""


class SecurityRefused(TransportError):
    """SNMPv3's user-based security refused the exchange (the agent's Report says why), or this end cannot
    secure it at all: sending again does not help until the user, its keys or the environment change."""


class Transport(Protocol):
    env: simpy.Environment

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        """GET of several objects in one PDU; the event's value is a tuple in the same order."""
        ...

    def set(self, varbinds: Sequence[VarBind]) -> simpy.Event:
        """SET of several objects in one PDU; the event's value is None."""
        ...

    def close(self) -> None: ...


class ObjectSurface(Protocol):
    """What answers NTCIP get and set by OID: the emulator's MIB view, for one."""

    def get_many(self, oids: Sequence[Oid]) -> tuple[Value, ...]: ...

    def set_many(self, varbinds: Sequence[VarBind]) -> None: ...


class LocalTransport:
    """In-process transport for virtual time, with modeled latency and loss.

    The request reaches the surface at once (the controller sees a SET when it
    is sent); the answer comes back after the drawn latency. A lost request, or
    an answer later than tau_udp, fails the event at tau_udp.

    ``change_feed`` (the surface's, when it has one) is offered to the poller only when a GET
    draws nothing at random (no loss, no jitter): a poll left out then (:mod:`hils.shell.fastpath`) is one whose
    answer, and its time, are known without sending it, and the draws of every other request stay the same. It
    is this transport's own (it is a :class:`hils.shell.fastpath.Foresight`), not the transport interface's.
    """

    def __init__(self, env: simpy.Environment, surface: ObjectSurface, *, tau_udp: float = 1.0,
                 get_latency: Latency | None = None, set_latency: Latency | None = None,
                 loss: float = 0.0, seed: int = 0, change_feed: ChangeFeed | None = None) -> None:
        self.env = env
        self.surface = surface
        self.tau_udp = tau_udp
        self.get_latency = get_latency or Latency(0.002)
        self.set_latency = set_latency or Latency(0.0075)
        self._rng = random.Random(seed)
        self._feed = change_feed
        self._loss = loss

    @property
    def change_feed(self) -> ChangeFeed | None:
        return self._feed if self._loss == 0.0 and self.get_latency.jitter <= 0.0 else None

    @property
    def loss(self) -> float:
        """Probability that a request is lost (settable during a run, e.g. to model an outage)."""
        return self._loss

    @loss.setter
    def loss(self, value: float) -> None:
        self._loss = value
        if self._feed is not None:
            self._feed.bump()  # a poller sleeping through quiet time must start sending again

    def get(self, oids: Sequence[Oid]) -> simpy.Event:
        return self._request(lambda: self.surface.get_many(oids), self.get_latency)

    def set(self, varbinds: Sequence[VarBind]) -> simpy.Event:
        return self._request(lambda: self.surface.set_many(varbinds), self.set_latency)

    def close(self) -> None:
        """Nothing to release in process."""

    def _request(self, call, latency: Latency) -> simpy.Event:
        delay = latency.draw(self._rng)
        if (self._loss and self._rng.random() < self._loss) or delay > self.tau_udp:
            done = self.env.event()
            self.env.timeout(self.tau_udp).callbacks.append(
                lambda _: done.fail(CommunicationTimeout(f"no answer within {self.tau_udp} s")))
            return done
        try:
            value = call()
        except SnmpError as exc:
            done = self.env.event()
            self.env.timeout(delay, exc).callbacks.append(lambda ev: done.fail(ev.value))
            return done
        # The answer arrives after the latency: the timeout itself is the request's event.
        return self.env.timeout(delay, value)
