"""The emulator's MIB view: NTCIP get and set by OID over a live controller model.

This is the single surface that both the in-process transport (virtual time)
and the SNMP agent (wall-clock time) use. Outcomes are SNMP-style: an unknown
object raises ``SnmpError(NO_SUCH_NAME)``, a read-only one ``NOT_WRITABLE``, a
value of the wrong type ``WRONG_TYPE`` and one out of range ``WRONG_VALUE``; the
agent maps these to each SNMP version's codes. A multi-varbind SET is checked
whole before anything is applied, so a refused SET changes nothing.

The phase timing table is read-only here: timings come from the intersection
config, and changing them live is not something the middleware does.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache

from emulator.controller import Controller, tenths
from emulator.delays import DelayedController
from hils.ntcip import (
    CHANNEL_TABLE,
    CONTROL_TABLE,
    MAX_PHASE_GROUPS,
    MAX_PHASES,
    PHASE_TABLE,
    SEQUENCE_DATA,
    STATUS_TABLE,
    SYSTEM_PATTERN_CONTROL,
    UNIT_BACKUP_TIME,
    UNIT_CONTROL_STATUS,
    UNIT_FLASH_STATUS,
    Access,
    ChannelColumn,
    ControlColumn,
    ErrorStatus,
    ObjectDef,
    Oid,
    PhaseColumn,
    SnmpError,
    StatusColumn,
    Syntax,
    groups_to_phases,
    phases_to_groups,
    sequence_oid,
)

Value = int | bytes


@dataclass(frozen=True, slots=True)
class Instance:
    oid: Oid
    obj: ObjectDef
    read: Callable[[], Value]
    write: Callable[[int], None] | None = None


class MibView:
    """get/set/next by OID over one controller (bare, or behind its delays)."""

    def __init__(self, controller: Controller | DelayedController) -> None:
        self.controller = controller
        self.set_count = 0
        instances = self._build()
        self._by_oid = {i.oid: i for i in instances}
        self._sorted = sorted(self._by_oid)

    # --- the surface -------------------------------------------------------------------

    def get(self, oid: Oid) -> Value:
        return self.get_many((oid,))[0]

    def get_many(self, oids: Sequence[Oid]) -> tuple[Value, ...]:
        out = []
        for index, oid in enumerate(oids, start=1):
            inst = self._by_oid.get(tuple(oid))
            if inst is None:
                raise SnmpError(ErrorStatus.NO_SUCH_NAME, index, f"no object {'.'.join(map(str, oid))}")
            out.append(inst.read())
        return tuple(out)

    def set_many(self, varbinds: Sequence[tuple[Oid, Value]]) -> None:
        checked = []
        for index, (oid, value) in enumerate(varbinds, start=1):
            inst = self._by_oid.get(tuple(oid))
            if inst is None:
                raise SnmpError(ErrorStatus.NO_SUCH_NAME, index, f"no object {'.'.join(map(str, oid))}")
            if inst.write is None or inst.obj.access is not Access.READ_WRITE:
                raise SnmpError(ErrorStatus.NOT_WRITABLE, index, f"{inst.obj.name} is read-only")
            if isinstance(value, bool) or not isinstance(value, int):
                raise SnmpError(ErrorStatus.WRONG_TYPE, index, f"{inst.obj.name} is an INTEGER")
            if not inst.obj.low <= value <= inst.obj.high:
                raise SnmpError(ErrorStatus.WRONG_VALUE, index,
                                f"{inst.obj.name} = {value} outside {inst.obj.low}..{inst.obj.high}")
            checked.append((inst, value))
        for inst, value in checked:
            inst.write(value)
        self.set_count += 1

    def next_oid(self, oid: Oid) -> Oid | None:
        """The first instance strictly after ``oid`` in OID order (GETNEXT), or None at the end."""
        i = bisect.bisect_right(self._sorted, tuple(oid))
        return self._sorted[i] if i < len(self._sorted) else None

    def syntax(self, oid: Oid) -> Syntax:
        return self._by_oid[tuple(oid)].obj.syntax

    def __contains__(self, oid: Oid) -> bool:
        return tuple(oid) in self._by_oid

    @property
    def oids(self) -> list[Oid]:
        return list(self._sorted)

    # --- building the instances ------------------------------------------------------------

    def _build(self) -> list[Instance]:
        c = self.controller
        cfg = c.config
        groups = cfg.groups
        out = [
            Instance(MAX_PHASES.instance(), MAX_PHASES, lambda: max(cfg.phases)),
            Instance(MAX_PHASE_GROUPS.instance(), MAX_PHASE_GROUPS, lambda: groups),
            Instance(UNIT_BACKUP_TIME.instance(), UNIT_BACKUP_TIME, lambda: c.backup_time,
                     lambda v: setattr(c, "backup_time", v)),
            Instance(UNIT_CONTROL_STATUS.instance(), UNIT_CONTROL_STATUS, lambda: int(c.control_status)),
            Instance(UNIT_FLASH_STATUS.instance(), UNIT_FLASH_STATUS, lambda: int(c.flash_status)),
            Instance(SYSTEM_PATTERN_CONTROL.instance(), SYSTEM_PATTERN_CONTROL, lambda: c.pattern,
                     lambda v: setattr(c, "pattern", v)),
        ]
        for p, ph in cfg.phases.items():
            concurrent = bytes(sorted(q for q in cfg.phases if cfg.compatible(p, q)))
            values: dict[PhaseColumn, Value] = {
                PhaseColumn.MINIMUM_GREEN: int(ph.min_green),
                PhaseColumn.PASSAGE: 0,
                PhaseColumn.MAXIMUM1: int(ph.max_green),
                PhaseColumn.MAXIMUM2: int(ph.max_green),
                PhaseColumn.YELLOW_CHANGE: tenths(ph.yellow),
                PhaseColumn.RED_CLEAR: tenths(ph.red_clear),
                PhaseColumn.STARTUP: int(ph.startup),
                PhaseColumn.OPTIONS: 1,  # bit 0: phase enabled
                PhaseColumn.RING: ph.ring,
                PhaseColumn.CONCURRENCY: concurrent,
            }
            out += [Instance(PHASE_TABLE[col].instance(p), PHASE_TABLE[col], lambda v=v: v)
                    for col, v in values.items()]
        status: dict[StatusColumn, Callable[[], frozenset[int]]] = {
            StatusColumn.REDS: lambda: c.reds,
            StatusColumn.YELLOWS: lambda: c.yellows,
            StatusColumn.GREENS: lambda: c.greens,
            StatusColumn.DONT_WALKS: lambda: frozenset(cfg.phases),
            StatusColumn.PED_CLEARS: frozenset,
            StatusColumn.WALKS: frozenset,
            StatusColumn.VEH_CALLS: lambda: c.calls,
            StatusColumn.PED_CALLS: lambda: c.control[ControlColumn.PED_CALL] - c.control[ControlColumn.PED_OMIT],
            StatusColumn.PHASE_ONS: lambda: c.phase_ons,
            StatusColumn.PHASE_NEXTS: lambda: c.phase_nexts,
        }
        channels = {ChannelColumn.REDS: status[StatusColumn.REDS], ChannelColumn.YELLOWS: status[StatusColumn.YELLOWS],
                    ChannelColumn.GREENS: status[StatusColumn.GREENS]}
        for g in range(1, groups + 1):
            out += [Instance(STATUS_TABLE[col].instance(g), STATUS_TABLE[col], _group_reader(read, g, groups))
                    for col, read in status.items()]
            # Channel i is driven by phase i: the emulator's load switches follow its phases one to one.
            out += [Instance(CHANNEL_TABLE[col].instance(g), CHANNEL_TABLE[col], _group_reader(read, g, groups))
                    for col, read in channels.items()]
            out += [Instance(CONTROL_TABLE[col].instance(g), CONTROL_TABLE[col],
                             _group_reader(lambda col=col: c.control[col], g, groups), _group_writer(c, col, g))
                    for col in ControlColumn]
        for r, order in enumerate(cfg.rings, start=1):
            out.append(Instance(sequence_oid(1, r), SEQUENCE_DATA, lambda o=order: bytes(o)))
        return out


# Status is read at 10-100 Hz and takes few distinct values: convert each phase set once.
_masks = lru_cache(maxsize=1024)(phases_to_groups)


def _group_reader(read: Callable[[], frozenset[int]], group: int, groups: int) -> Callable[[], int]:
    return lambda: _masks(read(), groups)[group - 1]


def _group_writer(c: Controller | DelayedController, column: ControlColumn, group: int) -> Callable[[int], None]:
    base = 8 * (group - 1)

    def write(mask: int) -> None:
        others = {p for p in c.control[column] if not base < p <= base + 8}
        c.set_control(column, others | {base + p for p in groups_to_phases((mask,))})

    return write
