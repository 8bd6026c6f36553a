"""The NTCIP 1202 v03 MIB as the standard defines it: the reference every served and used object is checked against.

:func:`load` reads ``ntcip_mib/ntcip1202v03.json``, compiled once from the standard's MIB text by
:mod:`harness.reference.mib_compile` (which says where the text comes from and how it is compiled), and carrying
the text's notice. Nothing here judges: :mod:`harness.reference.mib_conformance` does, with these definitions.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from hils.protocol.ntcip import Access, Oid, Value, parse_oid

REFERENCE = Path(__file__).with_name("ntcip_mib") / "ntcip1202v03.json"
#: An INTEGER on the wire is 32 bits: a range edge's neighbour past these cannot be sent.
INTEGER32 = (-(2**31), 2**31 - 1)


@dataclass(frozen=True, slots=True)
class MibObject:
    """One accessible object of the MIB: a scalar (instance .0) or a column of a table."""

    name: str
    oid: Oid
    group: str  # the node under asc it belongs to: phase, detector, unit, coord, ...
    node: str  # "scalar" or "column"
    type: str  # on the wire: INTEGER, OCTET STRING, IpAddress, Counter32, OBJECT IDENTIFIER
    syntax: str  # as the MIB writes it (DisplayString, a textual convention of its own, or the type)
    access: Access
    status: str
    table: str | None = None
    ranges: tuple[tuple[int, int], ...] = ()
    sizes: tuple[tuple[int, int], ...] = ()
    enumeration: Mapping[str, int] | None = None

    @property
    def values(self) -> tuple[int, ...]:
        """The values an enumerated INTEGER may take."""
        return tuple(sorted(self.enumeration.values())) if self.enumeration else ()

    def allows(self, value: Value) -> bool:
        """Whether the MIB's syntax admits this value (its range or enumeration; its size for a string)."""
        if isinstance(value, bytes):
            return not self.sizes or any(lo <= len(value) <= hi for lo, hi in self.sizes)
        if self.enumeration:
            return value in self.values
        return not self.ranges or any(lo <= value <= hi for lo, hi in self.ranges)

    def edges(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """For a writable INTEGER: the edge values the MIB admits (each range's ends, an enumeration's first and
        last), and their neighbours one past that it does not (those an INTEGER can carry)."""
        if self.enumeration:
            inside = (self.values[0], self.values[-1])
        else:
            inside = tuple(sorted({v for lo, hi in self.ranges or (INTEGER32,) for v in (lo, hi)}))
        past = {v + d for v in inside for d in (-1, 1)}
        return inside, tuple(sorted(v for v in past if INTEGER32[0] <= v <= INTEGER32[1] and not self.allows(v)))

    def describe(self) -> str:
        """The syntax in the MIB's words: ``INTEGER (1..255)``, ``INTEGER {other(1), ...}``, ``OCTET STRING``."""
        if self.enumeration:
            return f"INTEGER {{{', '.join(f'{k}({v})' for k, v in self.enumeration.items())}}}"
        if self.ranges:
            return f"{self.syntax} ({' | '.join(f'{lo}..{hi}' for lo, hi in self.ranges)})"
        if self.sizes:
            return f"{self.syntax} (SIZE ({' | '.join(f'{lo}..{hi}' for lo, hi in self.sizes)}))"
        return self.syntax


@dataclass(frozen=True, slots=True)
class MibTable:
    name: str
    oid: Oid
    index: tuple[str, ...]  # the INDEX objects of its rows (another module's as MODULE::name)
    rows: str | None  # the scalar the MIB says its number of rows equals (single-index tables), if it says one


@dataclass(frozen=True, slots=True)
class Mib:
    """The compiled MIB: its objects by name and OID, its tables, its groups and its notice."""

    objects: Mapping[str, MibObject]
    tables: Mapping[str, MibTable]
    groups: Mapping[str, Oid]
    notice: str
    title: str
    by_oid: Mapping[Oid, MibObject]

    def object_for(self, oid: Oid) -> MibObject | None:
        """The object an instance OID belongs to (the longest object OID it extends), or None."""
        for n in range(len(oid) - 1, 0, -1):
            obj = self.by_oid.get(tuple(oid[:n]))
            if obj is not None:
                return obj
        return None

    @property
    def accessible(self) -> int:
        return len(self.objects)

    @property
    def writable(self) -> int:
        return sum(o.access is Access.READ_WRITE for o in self.objects.values())


def _object(raw: Mapping[str, Any]) -> MibObject:
    return MibObject(raw["name"], parse_oid(raw["oid"]), raw["group"], raw["node"], raw["type"], raw["syntax"],
                     Access(raw["access"]), raw["status"], raw.get("table"),
                     tuple((lo, hi) for lo, hi in raw.get("range", ())),
                     tuple((lo, hi) for lo, hi in raw.get("size", ())), raw.get("enumeration"))


@cache
def load(path: Path = REFERENCE) -> Mib:
    """The compiled MIB of ``path`` (the checked-in reference by default)."""
    doc = json.loads(path.read_text(encoding="utf-8"))
    objects = {o["name"]: _object(o) for o in doc["objects"]}
    return Mib(objects,
               {name: MibTable(name, parse_oid(t["oid"]), tuple(t["index"]), t["rows"])
                for name, t in doc["tables"].items()},
               {g: parse_oid(oid) for g, oid in doc["groups"].items()}, doc["notice"], doc["title"],
               {o.oid: o for o in objects.values()})
