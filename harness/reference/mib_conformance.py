"""The emulator's objects against the MIB the standard defines: a walk with net-snmp, object by object.

``python -m harness.reference.mib_conformance`` serves the emulator (``hils emulator serve``, a config of your
choice), walks it with net-snmp's ``snmpwalk -On`` over real UDP, and checks every answered object against the
compiled NTCIP 1202 v03 MIB (:mod:`harness.reference.mib`); then, with ``snmpset``, SETs each read-only object
(refused?) and each writable INTEGER at its range edges (accepted?) and one past them (refused with wrongValue?),
putting every value back. ``--target snmp://HOST:PORT`` walks another agent instead, without SETs unless ``--set``
is given (a SET at a range edge of a real controller changes what it does: systemPatternControl 255 is flash).

Rules of this file
------------------
- The MIB is the judge; what the emulator does never is. Every check compares what net-snmp saw with the compiled
  MIB text, and a departure is a :attr:`Verdict.FINDING` unless a listed reason covers it, quoted from a source:
  - :attr:`Verdict.V02`: the object is served as NTCIP 1202 v02 defines it (the edition a Cobalt speaks, the
    emulator's default) and v03 changed it (:data:`hils.protocol.ntcip.V03_CHANGES` says how);
  - :attr:`Verdict.RESTRICTED`: a writable object refuses values the MIB admits, outside the sub-range hils
    declares for it (:class:`hils.protocol.ntcip.ObjectDef`'s ``low..high``): the MIB's Distribution Notice allows
    exactly this, "the syntax field may be modified only to reflect a more restrictive sub-range or enumerated
    values";
  - :attr:`Verdict.LIMITATION`: a writable object the emulator serves read-only, because the model takes it from
    the intersection config (:data:`emulator.agent.mib.NOT_WRITABLE_HERE` says why for each).
- Checks, in order: the definitions hils holds (:func:`definition_findings`: OID, type, access, declared range
  within the MIB's), then per walked instance (:func:`walk_findings`: known to the MIB, type, value within the
  syntax, index shape and range, a static table's rows numbered 1..its max object), then the SETs
  (:func:`set_findings`, one instance of each object).
- The exit status is 1 when a finding is left: the goal is none.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path

from emulator.agent.mib import NOT_WRITABLE_HERE
from harness.bench.processes import start_emulator, tool
from harness.reference.mib import Mib, MibObject, load
from hils.protocol import config as config_mod
from hils.protocol.ntcip import (
    ALL_OBJECTS,
    ASC,
    DEFAULT_VERSION,
    V03_CHANGES,
    Access,
    ObjectDef,
    Oid,
    Syntax,
    Value,
    Version,
    object_for,
    oid_str,
    parse_oid,
)

#: net-snmp's names of the types it shows (``-On -Ox``), as the MIB's compiled types say them.
_TYPES = {"INTEGER": "INTEGER", "Hex-STRING": "OCTET STRING", "STRING": "OCTET STRING", "Counter32": "Counter32",
          "IpAddress": "IpAddress", "OID": "OBJECT IDENTIFIER", "Gauge32": "Gauge32", "Timeticks": "TimeTicks"}
_LINE = re.compile(r"^\.(?P<oid>[\d.]+) = (?:(?P<type>[\w-]+): (?P<value>.*)|(?P<empty>\"\"))$")
#: What an agent answers to a SET of an object it does not let be written (SNMPv2c; readOnly is SNMPv1's).
REFUSED_NOT_WRITABLE = ("notWritable", "readOnly")


class Verdict(StrEnum):
    FINDING = "finding"  # departs from the v03 MIB for no listed reason: a fault to fix
    V02 = "v02"  # served as NTCIP 1202 v02 defines it, where v03 changed the object
    RESTRICTED = "restricted"  # a declared sub-range of what the MIB admits (the Distribution Notice's (ii))
    LIMITATION = "limitation"  # writable in the MIB, read-only here: the model takes it from the config


@dataclass(frozen=True, slots=True)
class Finding:
    verdict: Verdict
    name: str  # the object (or table) concerned
    check: str  # definition, known, type, value, index, rows, set
    detail: str
    oid: str = ""

    def line(self) -> str:
        return f"{self.verdict:<10} {self.name:<40} {self.check:<10} {self.detail}"


@dataclass(frozen=True, slots=True)
class Walked:
    """One instance as net-snmp showed it: its OID, its type as the MIB names types, its value (an INTEGER as
    int, an OCTET STRING as bytes, anything else as net-snmp's text)."""

    oid: Oid
    type: str
    value: Value | str


def parse_walk(text: str) -> list[Walked]:
    """The instances of ``snmpwalk -On -Ox`` output (numeric OIDs, strings in hex)."""
    out = []
    for line in text.splitlines():
        m = _LINE.match(line.rstrip())
        if m is None:
            continue
        oid = parse_oid(m["oid"])
        if m["empty"]:
            out.append(Walked(oid, "OCTET STRING", b""))
            continue
        kind, value = _TYPES.get(m["type"], m["type"]), m["value"].strip()
        if m["type"] == "INTEGER":
            out.append(Walked(oid, kind, int(value.split("(")[-1].rstrip(")")) if "(" in value else int(value)))
        elif m["type"] == "Hex-STRING":
            out.append(Walked(oid, kind, bytes.fromhex(value)))
        elif m["type"] == "STRING":
            out.append(Walked(oid, kind, value.strip('"').encode()))
        else:
            out.append(Walked(oid, kind, value))
    return out


@dataclass(frozen=True, slots=True)
class NetSnmp:
    """net-snmp's tools against one agent (SNMPv2c: the error statuses of a refused SET are v2's)."""

    host: str
    port: int
    read_community: str
    write_community: str
    timeout_s: float = 3.0  # a 20-value SET on a loaded 2-core machine (the suite's two workers) may take seconds

    def _run(self, program: str, community: str, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([tool(program), "-v2c", "-c", community, "-On", "-Ox", "-t", str(self.timeout_s),
                               "-r", "2", f"{self.host}:{self.port}", *args], capture_output=True, text=True,
                              timeout=600)

    def walk(self, root: Oid = ASC) -> list[Walked]:
        done = self._run("snmpwalk", self.read_community, oid_str(root))
        if done.returncode != 0:
            raise RuntimeError(f"snmpwalk of {self.host}:{self.port} failed: {done.stderr.strip() or done.stdout}")
        return parse_walk(done.stdout)

    def get(self, oids: Sequence[Oid]) -> list[Value | str]:
        """The values of instances, in one GET (as :class:`Walked` holds them)."""
        done = self._run("snmpget", self.read_community, *map(oid_str, oids))
        got = parse_walk(done.stdout)
        if done.returncode != 0 or [w.oid for w in got] != [tuple(o) for o in oids]:
            raise RuntimeError(f"snmpget of {len(oids)} instances at {self.host}:{self.port} failed: "
                               f"{done.stderr.strip() or done.stdout.strip()}")
        return [w.value for w in got]

    def set(self, varbinds: Sequence[tuple[Oid, Value]]) -> str:
        """SET values in one request; ``noError`` or the error status net-snmp reports (``notWritable``,
        ``wrongValue``...)."""
        args = [part for oid, value in varbinds for part in (
            oid_str(oid), *(("i", str(value)) if isinstance(value, int) else ("x", value.hex()) if value
                            else ("s", "")))]
        done = self._run("snmpset", self.write_community, *args)
        if done.returncode == 0:
            return "noError"
        reason = re.search(r"Reason: (\w+)", done.stderr)
        if reason:
            return reason[1]
        raise RuntimeError(f"snmpset of {len(varbinds)} values at {self.host}:{self.port} got no answer: "
                           f"{done.stderr.strip()}")


# --- the definitions hils holds ----------------------------------------------------------------------------------


def _v02_change(name: str, edition: Version) -> str | None:
    """How v03 changed an object hils serves as v02 does in this edition, or None (not listed, or served as v03
    defines it)."""
    declared = next((d for d in ALL_OBJECTS if d.name == name), None)
    served = declared.in_edition(edition) if declared is not None else None
    return V03_CHANGES.get(name) if served is not None and served.version is Version.V02 else None


def _integer_bounds(obj: MibObject) -> tuple[int, int] | None:
    if obj.enumeration:
        return obj.values[0], obj.values[-1]
    if obj.ranges:
        return min(lo for lo, _ in obj.ranges), max(hi for _, hi in obj.ranges)
    return None


def definition_findings(mib: Mib, objects: Iterable[ObjectDef] = ALL_OBJECTS,
                        edition: Version = DEFAULT_VERSION) -> list[Finding]:
    """hils' object definitions (:mod:`hils.protocol.ntcip`) as ``edition`` serves them, against the MIB: name and
    OID, type, access, and a declared range that is the MIB's or a sub-range of it."""
    out = []
    for d in filter(None, (o.in_edition(edition) for o in objects)):
        ref = mib.objects.get(d.name)
        if ref is None:
            out.append(Finding(Verdict.FINDING, d.name, "definition", "no object of this name in the MIB",
                               oid_str(d.prefix)))
            continue
        listed = _v02_change(d.name, edition)
        if ref.oid != d.prefix:
            out.append(Finding(Verdict.FINDING, d.name, "definition",
                               f"OID {oid_str(d.prefix)}; the MIB's is {oid_str(ref.oid)}", oid_str(d.prefix)))
        if ref.type != d.syntax.value:
            out.append(Finding(Verdict.FINDING, d.name, "definition",
                               f"type {d.syntax.value}; the MIB's is {ref.type}"))
        if ref.access is not d.access:
            verdict = Verdict.V02 if listed else Verdict.FINDING
            out.append(Finding(verdict, d.name, "definition", f"{d.access.value}; v03 says {ref.access.value}"
                               + (f" ({listed})" if listed else "")))
        bounds = _integer_bounds(ref) if d.syntax is Syntax.INTEGER else None
        if bounds is not None:
            if not (ref.allows(d.low) and ref.allows(d.high)):
                out.append(Finding(Verdict.FINDING, d.name, "definition",
                                   f"declared {d.low}..{d.high} is not within {ref.describe()}"))
            elif (d.low, d.high) != bounds and d.access is Access.READ_WRITE:
                out.append(Finding(Verdict.RESTRICTED, d.name, "definition",
                                   f"declared {d.low}..{d.high} of {ref.describe()}"))
    return out


# --- what the agent answers --------------------------------------------------------------------------------------


def _index(mib: Mib, obj: MibObject, instance: Oid) -> list[str]:
    """What is wrong with the index part of an instance OID (a scalar's is .0; a column's, one value per INDEX
    object of its table, each within that object's range)."""
    suffix = instance[len(obj.oid):]
    if obj.table is None:
        return [] if suffix == (0,) else [f"a scalar's instance is .0, not .{oid_str(suffix)}"]
    index = mib.tables[obj.table].index
    if len(suffix) != len(index):
        return [f"index .{oid_str(suffix)} has {len(suffix)} part(s); {obj.table} is indexed by {', '.join(index)}"]
    return [f"index {name} = {v} outside {mib.objects[name].describe()}" for name, v in zip(index, suffix, strict=True)
            if name in mib.objects and not mib.objects[name].allows(v)]


def walk_findings(mib: Mib, walked: Sequence[Walked], edition: Version = DEFAULT_VERSION) -> list[Finding]:
    """Every walked instance against the MIB: known, its type, its value, its index; and each static table whose
    number of rows the MIB ties to a max object, its rows numbered 1..that value."""
    out = []
    rows: dict[str, set[int]] = defaultdict(set)
    for w in walked:
        obj = mib.object_for(w.oid)
        shown = oid_str(w.oid)
        if obj is None:
            out.append(Finding(Verdict.FINDING, "?", "known", "no object of the MIB has this OID", shown))
            continue
        if object_for(w.oid, edition) is None and object_for(w.oid, Version.V03) is not None:
            out.append(Finding(Verdict.FINDING, obj.name, "edition", f"served under {edition}, which has no such "
                               "object (v03 added it)", shown))
        if w.type != obj.type:
            out.append(Finding(Verdict.FINDING, obj.name, "type", f"{w.type}; the MIB's is {obj.type}", shown))
        elif isinstance(w.value, int | bytes) and not obj.allows(w.value):
            listed = _v02_change(obj.name, edition)
            out.append(Finding(Verdict.V02 if listed else Verdict.FINDING, obj.name, "value",
                               f"{w.value!r} outside {obj.describe()}" + (f" ({listed})" if listed else ""), shown))
        out += [Finding(Verdict.FINDING, obj.name, "index", problem, shown) for problem in _index(mib, obj, w.oid)]
        if obj.table is not None and len(w.oid) > len(obj.oid):
            rows[obj.table].add(w.oid[len(obj.oid)])
    scalars = ((mib.object_for(w.oid), w) for w in walked)
    values = {obj.name: w.value for obj, w in scalars if obj is not None and obj.table is None}
    for table, numbers in rows.items():
        count = mib.tables[table].rows
        if count is None:
            continue
        if count not in values:
            out.append(Finding(Verdict.FINDING, table, "rows", f"served without {count}, the number of its rows"))
        elif numbers != set(range(1, int(values[count]) + 1)):
            out.append(Finding(Verdict.FINDING, table, "rows",
                               f"rows {_ranges(numbers)}; {count} = {values[count]} says 1..{values[count]}"))
    return out


def _ranges(numbers: Iterable[int]) -> str:
    """``1..4, 7`` for {1, 2, 3, 4, 7}."""
    out: list[list[int]] = []
    for n in sorted(numbers):
        if out and n == out[-1][1] + 1:
            out[-1][1] = n
        else:
            out.append([n, n])
    return ", ".join(f"{a}..{b}" if b > a else f"{a}" for a, b in out)


# --- SETs -------------------------------------------------------------------------------------------------------


#: Varbinds per request of a batch: well inside what an agent takes in one datagram.
BATCH = 20


@dataclass(frozen=True, slots=True)
class _Edges:
    """A writable INTEGER's values to SET: those to be refused (one past the edges of the MIB's range and of the
    declared one) and those to be taken (the edges)."""

    w: Walked
    obj: MibObject
    declared: ObjectDef | None
    refused: tuple[int, ...]
    taken: tuple[int, ...]

    @classmethod
    def of(cls, obj: MibObject, declared: ObjectDef | None, w: Walked) -> _Edges:
        inside, past = obj.edges()
        values = sorted({*inside, *past} | ({declared.low, declared.high, declared.low - 1, declared.high + 1}
                                            if declared is not None else set()))

        def admitted(value: int) -> bool:
            return obj.allows(value) and (declared is None or declared.low <= value <= declared.high)

        return cls(w, obj, declared, tuple(v for v in values if not admitted(v)), tuple(filter(admitted, values)))


def set_findings(mib: Mib, agent: NetSnmp, walked: Sequence[Walked], edition: Version = DEFAULT_VERSION
                 ) -> list[Finding]:
    """One instance of each walked object: a read-only one (for the MIB or here) SET to its own value, refused; a
    writable INTEGER SET one past the edges of the MIB's range and of hils' declared one (refused with wrongValue,
    and a GET then reads the value the walk read: nothing changed), then at the edges (taken), then its value put
    back. The SETs that must be taken go in batches, the k-th edge of every object in one request."""
    out = []
    first: dict[str, Walked] = {}
    for w in walked:
        obj = mib.object_for(w.oid)
        if obj is not None and isinstance(w.value, int | bytes):
            first.setdefault(obj.name, w)
    edges = []
    for name, w in first.items():
        obj, declared = mib.objects[name], object_for(w.oid, edition)
        writable_here = declared is not None and declared.access is Access.READ_WRITE and name not in NOT_WRITABLE_HERE
        shown = oid_str(w.oid)
        if obj.access is Access.READ_ONLY or not writable_here:
            status = agent.set([(w.oid, w.value)])
            if status in REFUSED_NOT_WRITABLE:
                if obj.access is Access.READ_WRITE:
                    why = NOT_WRITABLE_HERE.get(name)
                    out.append(Finding(Verdict.LIMITATION if why else Verdict.FINDING, name, "set",
                                       f"refused {status}, the MIB says read-write" + (f": {why}" if why else ""),
                                       shown))
                continue
            if status == "noError" and obj.access is Access.READ_ONLY:
                listed = _v02_change(name, edition)
                out.append(Finding(Verdict.V02 if listed else Verdict.FINDING, name, "set",
                                   "a SET of a read-only object is accepted" + (f" ({listed})" if listed else ""),
                                   shown))
            elif status != "noError":
                out.append(Finding(Verdict.FINDING, name, "set",
                                   f"a SET of a read-only object is refused {status}, not notWritable", shown))
                continue
        if isinstance(w.value, int):
            edges.append(_Edges.of(obj, declared, w))
    out += _refused(agent, edges)
    for k in range(max((len(e.taken) for e in edges), default=0)):
        out += _taken(agent, [(e, e.taken[k]) for e in edges if k < len(e.taken)], "an edge")
    out += _taken(agent, [(e, e.w.value) for e in edges], "its value put back")
    return out


def _refused(agent: NetSnmp, edges: Sequence[_Edges]) -> list[Finding]:
    """Each value past an edge SET alone: wrongValue; then the values read back in batches, each the walk's."""
    out = []
    for e in edges:
        shown = oid_str(e.w.oid)
        for value in e.refused:
            status = agent.set([(e.w.oid, value)])
            if status == "wrongValue":
                continue
            if e.obj.allows(value):
                out.append(Finding(Verdict.FINDING, e.obj.name, "set", f"{value} outside the declared "
                                   f"{e.declared.low}..{e.declared.high} answered {status}, not wrongValue", shown))
            else:
                out.append(Finding(Verdict.FINDING, e.obj.name, "set", f"{value} outside {e.obj.describe()} "
                                   f"answered {status}, not wrongValue", shown))
    for start in range(0, len(edges), BATCH):
        batch = edges[start:start + BATCH]
        held = agent.get([e.w.oid for e in batch])
        out += [Finding(Verdict.FINDING, e.obj.name, "set", f"refused SETs changed it: {e.w.value!r} became "
                        f"{value!r}", oid_str(e.w.oid)) for e, value in zip(batch, held, strict=True)
                if value != e.w.value]
    return out


def _taken(agent: NetSnmp, sets: Sequence[tuple[_Edges, int]], what: str) -> list[Finding]:
    """Values the agent must take, in batches; a batch refused is SET again one by one to find which was."""
    out = []
    for start in range(0, len(sets), BATCH):
        batch = sets[start:start + BATCH]
        if agent.set([(e.w.oid, value) for e, value in batch]) == "noError":
            continue
        for e, value in batch:
            status = agent.set([(e.w.oid, value)])
            if status != "noError":
                out.append(Finding(Verdict.FINDING, e.obj.name, "set", f"{what}, {value}, refused {status}, inside "
                                   f"{e.obj.describe()}", oid_str(e.w.oid)))
    return out


# --- the report --------------------------------------------------------------------------------------------------


@dataclass
class Report:
    title: str
    edition: Version  # the edition of NTCIP 1202 the agent was checked as serving
    accessible: int
    writable: int
    served: dict[str, list[str]]  # objects answered, by group of the MIB
    groups: dict[str, int]  # accessible objects of each group of the MIB
    instances: int
    findings: list[Finding] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        return {v.value: sum(f.verdict is v for f in self.findings) for v in Verdict}

    def text(self) -> str:
        served = sum(len(v) for v in self.served.values())
        lines = [f"{self.title}: {self.accessible} accessible objects, {self.writable} read-write",
                 f"served as NTCIP 1202 {self.edition}: {served} objects ({self.instances} instances)", "",
                 "group                served / MIB"]
        lines += [f"{g:<20} {len(self.served.get(g, ())):>6} / {n}" for g, n in self.groups.items()]
        lines += ["", "  ".join(f"{k}: {n}" for k, n in self.counts.items())]
        lines += [f.line() for f in sorted(self.findings, key=lambda f: (list(Verdict).index(f.verdict), f.name))]
        return "\n".join(lines)

    def to_json(self) -> dict[str, object]:
        return {"mib": self.title, "edition": self.edition.value, "accessible": self.accessible,
                "read-write": self.writable,
                "served": {g: sorted(v) for g, v in self.served.items()}, "instances": self.instances,
                "counts": self.counts, "findings": [asdict(f) for f in self.findings]}


def check(agent: NetSnmp, *, sets: bool, mib: Mib | None = None, edition: Version = DEFAULT_VERSION) -> Report:
    """Walk the agent, which serves ``edition``, and check it against the MIB (with SETs when ``sets``)."""
    mib = mib or load()
    walked = agent.walk()
    findings = definition_findings(mib, edition=edition) + walk_findings(mib, walked, edition)
    if sets:
        findings += set_findings(mib, agent, walked, edition)
    served: dict[str, set[str]] = defaultdict(set)
    for w in walked:
        obj = mib.object_for(w.oid)
        if obj is not None:
            served[obj.group].add(obj.name)
    groups: dict[str, int] = defaultdict(int)
    for obj in mib.objects.values():
        groups[obj.group] += 1
    return Report(mib.title, edition, mib.accessible, mib.writable, {g: sorted(v) for g, v in served.items()},
                  dict(groups), len(walked), findings)


@contextmanager
def served_emulator(config: str | None, edition: Version = DEFAULT_VERSION) -> Iterator[NetSnmp]:
    """`hils emulator serve --ntcip EDITION` on a free loopback port for the time of the check."""
    with tempfile.TemporaryDirectory(prefix="hils-mib-") as tmp:
        server = start_emulator(Path(tmp) / "serve.log", "--ntcip", edition.value,
                                *(["--config", config] if config else []))
        try:
            yield NetSnmp("127.0.0.1", server.port, "public", "private")
        finally:
            server.stop()


def _target(url: str) -> NetSnmp:
    from hils.shell.snmp import SnmpTarget, SnmpVersion

    target = SnmpTarget.parse(url)
    if target.version is not SnmpVersion.V2C:
        raise ValueError(f"{url}: the check speaks SNMPv2c (its error statuses are v2's); add version=2c")
    return NetSnmp(target.host, target.port, target.community, target.community)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m harness.reference.mib_conformance",
        description="Walk an NTCIP 1202 agent with net-snmp (snmpwalk -On) and check every object it answers "
                    "against the compiled NTCIP 1202 v03 MIB: known, type, value within the syntax, index, rows of "
                    "static tables; then SET each read-only object (refused?) and each writable INTEGER at its range "
                    "edges (accepted?) and one past them (refused with wrongValue?), putting each value back. "
                    "By default the emulator is served for the check; exit status 1 when findings are left.")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--config", metavar="FILE", help="the emulator's intersection config (default: the shipped "
                                                        "four-leg)")
    which.add_argument("--target", metavar="URL", help="another agent: snmp://HOST:PORT?community=NAME (SNMPv2c); "
                                                       "walked without SETs unless --set")
    parser.add_argument("--set", action="store_true", help="with --target: SET its objects too (a SET at a range "
                                                           "edge changes what a controller does: never on a street)")
    parser.add_argument("--ntcip", choices=[v.value for v in Version], default=DEFAULT_VERSION.value,
                        help="the edition of NTCIP 1202 the agent serves (the emulator is served with it): under v02 "
                             "an object v03 added is a finding, and v02's definitions where v03 changed them are "
                             f"verdicts of their own ({DEFAULT_VERSION.value})")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the report as JSON")
    args = parser.parse_args(argv)
    edition = Version(args.ntcip)
    try:
        if args.target:
            report = check(_target(args.target), sets=args.set, edition=edition)
        else:
            config_mod.load(args.config)  # a config that cannot serve is said in one line, before anything starts
            with served_emulator(args.config, edition) as agent:
                report = check(agent, sets=True, edition=edition)
    except (ValueError, RuntimeError) as exc:
        parser.exit(2, f"{parser.prog}: {exc}\n")
    print(report.text())
    if args.json:
        args.json.write_text(json.dumps(report.to_json(), indent=1) + "\n", encoding="utf-8")
    return 1 if report.counts[Verdict.FINDING.value] else 0


if __name__ == "__main__":
    sys.exit(main())
