"""What each intersection's controller is reached by: the in-process emulator, a target factory, or a real
controller (or ``hils emulator serve``) at an ``snmp://`` URL.

A run has one clock: either every controller is reached in virtual time (``virtual``, a factory) or every
one at the wall clock (URLs). A wall-clock target is parsed and its host resolved once, before anything starts,
so that a bad one is refused in one line naming its intersection. ``virtual`` is found through the
``hils.shell.targets`` entry point, so that ``hils`` never imports the emulator.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib.metadata import entry_points
from typing import Any

import simpy

from hils.protocol.config import IntersectionConfig
from hils.protocol.errors import UserError
from hils.shell.fastpath import Foresight
from hils.shell.transport import LocalTransport, Transport

__all__ = ["VIRTUAL", "TargetError", "TargetFactory", "check_target", "connect", "target_specs",
           "virtual_target_factory"]

VIRTUAL = "virtual"

#: ``(env, config, *, seed, fast_path, hires) -> target``: a target with a ``transport`` (and its ``foresight``, a
#: :class:`hils.shell.fastpath.Foresight`, when that transport knows when its answer can change), or a ``surface``
#: (with ``get_latency`` and ``set_latency``, and its ``change_feed`` when it has one) that an in-process transport
#: reaches. ``hires``: the run keeps the
#: controller's hi-res record (a target that keeps one offers ``hires()`` and ``hires_to()``); when it does not,
#: a controller held in process runs no data logger.
TargetFactory = Callable[..., Any]


class TargetError(UserError, ValueError):
    """A target that is neither ``virtual`` nor a usable ``snmp://`` URL."""


def virtual_target_factory() -> TargetFactory:
    """The in-process emulator, found through the ``hils.shell.targets`` entry point."""
    found = [ep for ep in entry_points(group="hils.targets") if ep.name == VIRTUAL]
    if not found:
        raise RuntimeError("no virtual target installed: the emulator package is needed for virtual-time runs "
                           "(or give target='snmp://HOST:PORT')")
    return found[0].load()


def target_specs(target: str | TargetFactory | Mapping[str, str | TargetFactory],
                  configs: Mapping[str, IntersectionConfig]) -> dict[str, str | TargetFactory]:
    """Each intersection's target: one for all, or a mapping naming every one; all in virtual time (the
    emulator, a factory) or all at the wall clock (URLs), since a run has one clock."""
    if isinstance(target, Mapping):
        missing, unknown = sorted(set(configs) - set(target)), sorted(set(target) - set(configs))
        if missing or unknown:
            raise TargetError(f"targets: {'no target for ' + ', '.join(missing) if missing else ''}"
                              f"{'; ' if missing and unknown else ''}"
                              f"{'no intersection ' + ', '.join(unknown) if unknown else ''}; allowed: one "
                              f"target per intersection of the run ({', '.join(configs)})")
        specs = {name: target[name] for name in configs}
    else:
        if isinstance(target, str) and target != VIRTUAL and len(configs) > 1:
            raise TargetError(f"target {target!r}: a run of {len(configs)} controllers needs one target per "
                              f"intersection ({', '.join(configs)}): a mapping, or a TOML file of TLS = URL lines")
        specs = dict.fromkeys(configs, target)
    urls = [spec for spec in specs.values() if isinstance(spec, str) and spec != VIRTUAL]
    if urls and len(urls) != len(specs):
        raise TargetError("targets: either every controller is reached at the wall clock (snmp:// URLs) or none "
                          "is (virtual): a run has one clock")
    return specs


def check_target(url: str, label: str | None) -> tuple[Any, tuple[str, int]]:
    """The :class:`hils.shell.snmp.SnmpTarget` of ``url`` and its host's address; a URL that is not one, or whose host
    does not resolve, is refused (``label``: how the message names the intersection)."""
    from hils.shell.snmp import SnmpTarget, resolve, url_shown
    from hils.shell.transport import TransportError

    light = f"{label}: " if label else ""
    if not url.startswith("snmp://"):
        raise TargetError(f"{light}target {url_shown(url)!r}: allowed: 'virtual' or "
                          "snmp://HOST[:PORT][?community=NAME&version=1|2c]")
    try:
        target = SnmpTarget.parse(url)
        return target, resolve(target)
    except ValueError as exc:
        raise TargetError(f"{light}{exc}") from None
    except TransportError as exc:
        raise TargetError(f"{light}target {url_shown(url)!r}: {exc}; allowed: a host name this machine resolves, "
                          "or an IPv4 address") from None


def connect(env: simpy.Environment, config: IntersectionConfig, spec: str | TargetFactory,
            wall: tuple[Any, tuple[str, int]] | None, driver: Any, *, seed: int, fast_path: bool, hires: bool
            ) -> tuple[Any, Transport, Foresight | None, str, str | None]:
    """Reach one intersection's controller: its target, the transport to it, that transport's foresight (None
    over the wire, and for a target whose transport has none), how messages name it (where) and the community it is
    written with (None in process). ``wall``: the parsed URL and address of a wall-clock target
    (:func:`check_target`), reached through ``driver``. ``seed``, ``fast_path``, ``hires``: the run's, for a target
    made in process (:data:`TargetFactory`)."""
    if wall is None:
        factory = virtual_target_factory() if spec == VIRTUAL else spec
        target = factory(env, config, seed=seed, fast_path=fast_path, hires=hires)
        # A target brings its transport, or an object surface that an in-process transport reaches.
        transport = getattr(target, "transport", None)
        if transport is not None:
            return target, transport, getattr(target, "foresight", None), "the in-process emulator", None
        feed = getattr(target, "change_feed", None)
        local = LocalTransport(env, target.surface, tau_udp=config.middleware.tau_udp, get_latency=target.get_latency,
                               set_latency=target.set_latency, seed=seed, change_feed=feed)
        return target, local, local if feed is not None else None, "the in-process emulator", None
    from hils.shell.snmp import SnmpTransport

    target, address = wall
    transport = SnmpTransport(env, driver, target, tau_udp=config.middleware.tau_udp, address=address)
    return target, transport, None, f"{target.host}:{target.port}", getattr(target, "community", None)
