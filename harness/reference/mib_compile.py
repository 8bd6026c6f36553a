"""Compile the NTCIP 1202 v03 MIB into the reference every served and used object is checked against.

``python -m harness.reference.mib_compile`` reads the MIB texts of :data:`FOLDER` (NTCIP1202-v03.mib, the standard's
1202v0328 of 30 May 2019, and the NTCIP8004v02.mib it imports), compiles them with pysmi and writes
``ntcip1202v03.json`` beside them: per accessible object its name, OID, type on the wire, the MIB's syntax, access,
status and range, size or enumeration, and per table its INDEX and the object that counts its rows. The notice of
the MIB texts (NOTICE.txt, the NTCIP MIB Distribution Notice) goes into the JSON too, as it asks of every copy.
``--check`` writes nothing and fails when the JSON is not what the texts compile to.

Rules of this file
------------------
- The texts are the standard's, as published: they are never edited on disk. pysmi 2.0 does not take them as they
  are; the mends that make it do are applied in memory, each in :data:`MENDS` with why, and each must change exactly
  what it names (a mend that finds nothing to mend is an error: the text is not the one this was written for).
- The base IETF modules (RFC1155-SMI, RFC-1212, RFC1213-MIB and the SNMPv2 modules pysmi maps them to) are
  stand-ins (:data:`STAND_INS`): each defines only what the NTCIP modules take from it, as the RFCs define it.
  Nothing of the NTCIP objects comes from them but the types IpAddress, Counter32 and DisplayString.
- The output is deterministic (no dates, no host): the same texts and pysmi give the same bytes, so a test can
  hold the checked-in JSON to what the texts compile to.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: The MIB texts, their notice and the compiled reference.
FOLDER = Path(__file__).with_name("ntcip_mib")
OUTPUT = FOLDER / "ntcip1202v03.json"
MODULE = "NTCIP1202-v03"

#: Where the texts come from: the repository's files, before the notice was put at the head of the 1202 copy.
UPSTREAM = {
    "repository": "ibrahimkesim/ntcip-2025",
    "commit": "30b5f8dff9822636e46fda347f57012d1e87acd5",
    "files": {
        "NTCIP1202-v03.mib": {"path": "doc/mib_dosyalari/NTCIP1202-v03",
                              "sha256": "b935734dbc79915ab825162b2b7821b2a585dea357f3255f5f5d2eb5f5dd707f"},
        "NTCIP8004v02.mib": {"path": "doc/mib_dosyalari/NTCIP8004v02.mib",
                             "sha256": "863785a775e678bfccb1bacb1c78ff94c8547802e8d2452d3eee98b8f1678fea"},
    },
}
#: The line that ends the notice put at the head of the 1202 copy (the upstream file has none).
NOTICE_END = b"-- End of the notice: the repository's file follows.\r\n"

#: The base modules, reduced to what the NTCIP texts import (pysmi reads SMIv1's RFC1155-SMI names as SNMPv2-SMI's
#: and RFC1213-MIB's ifIndex as IF-MIB's). Types as RFC 2578 (SNMPv2-SMI) and RFC 2579 (SNMPv2-TC) define them;
#: ifIndex as RFC 2863 does.
STAND_INS = {
    "SNMPv2-SMI": """SNMPv2-SMI DEFINITIONS ::= BEGIN
org OBJECT IDENTIFIER ::= { iso 3 }
dod OBJECT IDENTIFIER ::= { org 6 }
internet OBJECT IDENTIFIER ::= { dod 1 }
mgmt OBJECT IDENTIFIER ::= { internet 2 }
mib-2 OBJECT IDENTIFIER ::= { mgmt 1 }
private OBJECT IDENTIFIER ::= { internet 4 }
enterprises OBJECT IDENTIFIER ::= { private 1 }
IpAddress ::= [APPLICATION 0] IMPLICIT OCTET STRING (SIZE (4))
Counter32 ::= [APPLICATION 1] IMPLICIT INTEGER (0..4294967295)
Gauge32 ::= [APPLICATION 2] IMPLICIT INTEGER (0..4294967295)
Unsigned32 ::= [APPLICATION 2] IMPLICIT INTEGER (0..4294967295)
TimeTicks ::= [APPLICATION 3] IMPLICIT INTEGER (0..4294967295)
Integer32 ::= INTEGER (-2147483648..2147483647)
END
""",
    "SNMPv2-TC": """SNMPv2-TC DEFINITIONS ::= BEGIN
DisplayString ::= OCTET STRING (SIZE (0..255))
END
""",
    "SNMPv2-CONF": "SNMPv2-CONF DEFINITIONS ::= BEGIN\nEND\n",
    "RFC1155-SMI": "RFC1155-SMI DEFINITIONS ::= BEGIN\nEND\n",
    "RFC-1212": "RFC-1212 DEFINITIONS ::= BEGIN\nEND\n",
    "RFC1213-MIB": "RFC1213-MIB DEFINITIONS ::= BEGIN\nEND\n",
    "IF-MIB": """IF-MIB DEFINITIONS ::= BEGIN
IMPORTS mib-2 FROM SNMPv2-SMI;
interfaces OBJECT IDENTIFIER ::= { mib-2 2 }
ifTable OBJECT IDENTIFIER ::= { interfaces 2 }
ifEntry OBJECT IDENTIFIER ::= { ifTable 1 }
ifIndex OBJECT-TYPE
    SYNTAX INTEGER (1..2147483647)
    ACCESS read-only
    STATUS mandatory
    ::= { ifEntry 1 }
END
""",
}


def strip_comments(text: str) -> str:
    """The text without its ``--`` comments (to the end of the line; not inside a quoted string)."""
    out = []
    quoted = False
    i = 0
    while i < len(text):
        if quoted:
            end = text.find('"', i)
            end = len(text) if end < 0 else end + 1
            out.append(text[i:end])
            quoted, i = False, end
        elif text.startswith('"', i):
            out.append('"')
            quoted, i = True, i + 1
        elif text.startswith("--", i):
            i = min((j for j in (text.find("\r", i), text.find("\n", i)) if j >= 0), default=len(text))
        else:
            nxt = min((j for j in (text.find('"', i), text.find("--", i)) if j >= 0), default=len(text))
            out.append(text[i:nxt])
            i = nxt
    return "".join(out)


def _rejoin_wrapped_comments(text: str) -> str:
    fragments = ("-- enum custom, FIO,TS1,BIU,SIU,AUX,\r\nreserved\r\n",
                 "-- enum custom,\r\nFIO,TS1,BIU,SIU,AUX, reserved\r\n",
                 "-- 0=STD, else nemaPrivate vendor\r\ncode\r\n")
    for fragment in fragments:
        if text.count(fragment) != 1:
            raise ValueError(f"mend of wrapped comments: {fragment!r} is not in the text once")
        text = text.replace(fragment, fragment.replace("\r\n", " ", 1))
    return text


def _strip_comments_checked(text: str) -> str:
    stripped = strip_comments(text)
    if stripped == text:
        raise ValueError("mend of comments: the text has no comment")
    return stripped


@dataclass(frozen=True, slots=True)
class Mend:
    """One change of a text in memory before pysmi reads it, and why pysmi needs it."""

    module: str
    why: str
    apply: Callable[[str], str]


MENDS = (
    Mend(MODULE, "Three comments of the AscIOinputMapTableEntry and AscIOoutputMapTableEntry SEQUENCEs wrap onto a "
                 "line of their own without '--' ('reserved', 'FIO,TS1,BIU,SIU,AUX, reserved', 'code'), which the "
                 "parser takes for ASN.1: each is joined back to the comment it continues.", _rejoin_wrapped_comments),
    Mend(MODULE, "Comments are removed: pysmi skips EXPORTS ... ; and MACRO ... END before it reads comments, so a "
                 "comment naming one of these words swallows the text up to the next ';' or END.",
         _strip_comments_checked),
    Mend("NTCIP8004v02", "Comments are removed, for the same reason: its revision history says 'Removed embedded "
                         "comment indicator between EXPORTS and EVERYTHING'.", _strip_comments_checked),
)


def read_texts(folder: Path = FOLDER) -> dict[str, str]:
    """The NTCIP modules by name, as published (the 1202 copy without the notice put at its head), checked against
    the upstream files' SHA-256."""
    out = {}
    for module, name in ((MODULE, "NTCIP1202-v03.mib"), ("NTCIP8004v02", "NTCIP8004v02.mib")):
        data = (folder / name).read_bytes()
        if module == MODULE:
            _, found, data = data.partition(NOTICE_END)
            if not found:
                raise ValueError(f"{folder / name}: no line {NOTICE_END!r} ends the notice at its head")
        digest = hashlib.sha256(data).hexdigest()
        if digest != UPSTREAM["files"][name]["sha256"]:
            raise ValueError(f"{folder / name}: SHA-256 {digest} is not the upstream file's "
                             f"{UPSTREAM['files'][name]['sha256']}")
        # The 1202 text is UTF-8; the 8004 text is Windows-1252 (a typographic apostrophe in its history).
        out[module] = data.decode("utf-8" if module == MODULE else "cp1252")
    return out


def mended(texts: Mapping[str, str]) -> dict[str, str]:
    out = dict(texts)
    for mend in MENDS:
        out[mend.module] = mend.apply(out[mend.module])
    return out


def compile_pysmi(texts: Mapping[str, str]) -> dict[str, Any]:
    """pysmi's JSON of the 1202 module (its JsonCodeGen's document), from the mended texts and the stand-ins."""
    from pysmi.codegen.jsondoc import JsonCodeGen
    from pysmi.compiler import MibCompiler
    from pysmi.parser.dialect import smi_v1_relaxed
    from pysmi.parser.smi import parserFactory
    from pysmi.reader.callback import CallbackReader
    from pysmi.writer.callback import CallbackWriter

    sources = {**STAND_INS, **texts}
    written: dict[str, str] = {}
    compiler = MibCompiler(parserFactory(**smi_v1_relaxed)(), JsonCodeGen(),
                           CallbackWriter(lambda name, data, ctx: written.__setitem__(name, data)))
    compiler.add_sources(CallbackReader(lambda name, ctx: sources.get(name, "")))
    status = compiler.compile(MODULE, genTexts=True, rebuild=True)
    failed = {name: str(getattr(s, "error", s)) for name, s in status.items() if s != "compiled"}
    if failed:
        raise RuntimeError(f"pysmi did not compile every module: {failed}")
    return json.loads(written[MODULE])


#: The type each syntax of the texts is carried as on the wire (SMIv1's Counter is SNMPv2's Counter32).
_WIRE = {"INTEGER": "INTEGER", "OCTET STRING": "OCTET STRING", "DisplayString": "OCTET STRING",
         "IpAddress": "IpAddress", "Counter": "Counter32", "OBJECT IDENTIFIER": "OBJECT IDENTIFIER"}
_ROWS = re.compile(r"number of rows in (?:this|the) table (?:is|shall be) (?:equal to )?(?:the )?(\w+)", re.I)


def reference(doc: Mapping[str, Any], notice: str) -> dict[str, Any]:
    """The reference: pysmi's document reduced to what a check needs, objects in OID order."""
    symbols = {k: v for k, v in doc.items() if isinstance(v, dict) and "class" in v}
    asc = symbols["asc"]["oid"]
    groups = {v["oid"]: k for k, v in symbols.items() if v.get("oid", "").rsplit(".", 1)[0] == asc
              and v["class"] == "objectidentity"}
    tables: dict[str, dict[str, Any]] = {}
    for sym in symbols.values():
        if sym.get("nodetype") != "row":
            continue
        table = sym["oid"].rsplit(".", 1)[0]
        table_name = next(k for k, v in symbols.items() if v.get("oid") == table)
        index = [i["object"] if i["module"] == MODULE else f"{i['module']}::{i['object']}" for i in sym["indices"]]
        rows = _ROWS.search(symbols[table_name]["description"])
        tables[table_name] = {"oid": table, "index": index,
                              "rows": rows[1] if rows and rows[1] in symbols and len(index) == 1 else None}
    by_table_oid = {t["oid"]: name for name, t in tables.items()}
    objects = []
    for name, sym in symbols.items():
        if sym.get("nodetype") not in ("scalar", "column"):
            continue
        syntax = sym["syntax"]
        own = symbols.get(syntax["type"], {})  # a type the module defines: its base and constraints
        base = own["type"] if own.get("class") == "type" else syntax
        constraints = {**base.get("constraints", {}), **syntax.get("constraints", {})}
        group = next(g for oid, g in groups.items() if sym["oid"].startswith(oid + "."))
        obj: dict[str, Any] = {"name": name, "oid": sym["oid"], "group": group, "node": sym["nodetype"],
                               "type": _WIRE[base["type"]], "syntax": syntax["type"], "access": sym["maxaccess"],
                               "status": sym["status"]}
        if sym["nodetype"] == "column":
            obj["table"] = by_table_oid[sym["oid"].rsplit(".", 2)[0]]
        if "range" in constraints:
            obj["range"] = [[r["min"], r["max"]] for r in constraints["range"]]
        if "size" in constraints:
            obj["size"] = [[r["min"], r["max"]] for r in constraints["size"]]
        if "enumeration" in constraints:
            obj["enumeration"] = dict(sorted(constraints["enumeration"].items(), key=lambda kv: kv[1]))
        objects.append(obj)
    objects.sort(key=lambda o: tuple(map(int, o["oid"].split("."))))
    return {
        "module": MODULE,
        "title": "NTCIP 1202 v03 Object Definitions for Actuated Signal Controllers (ASC) Interface, MIB 1202v0328, "
                 "May 30, 2019",
        "notice": notice,
        "source": UPSTREAM,
        "compiled_by": _pysmi_version(),
        "mends": [{"module": m.module, "why": m.why} for m in MENDS],
        "stand_ins": sorted(STAND_INS),
        "counts": {"accessible": len(objects), "read-write": sum(o["access"] == "read-write" for o in objects)},
        "groups": {g: oid for oid, g in sorted(groups.items(), key=lambda kv: tuple(map(int, kv[0].split("."))))},
        "tables": dict(sorted(tables.items(), key=lambda kv: tuple(map(int, kv[1]["oid"].split("."))))),
        "objects": objects,
    }


def _pysmi_version() -> str:
    from pysmi import __version__

    return f"pysmi {__version__}"


def build(folder: Path = FOLDER) -> str:
    """The reference's JSON text, from the texts of ``folder``."""
    doc = compile_pysmi(mended(read_texts(folder)))
    notice = (folder / "NOTICE.txt").read_text(encoding="utf-8")
    return json.dumps(reference(doc, notice), indent=1, ensure_ascii=False) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m harness.reference.mib_compile",
        description=f"Compile the NTCIP 1202 v03 MIB texts of {FOLDER} with pysmi into {OUTPUT.name}, the reference "
                    "the emulator's objects are checked against. Needs pysmi 2.0 and nothing else of hils: best in an "
                    "environment of its own (pip install 'pysmi>=2.0,<2.1'; PYTHONPATH=REPOSITORY), as pysnmp, where "
                    "pysmi is importable, builds pysmi's parser at an engine's first request.")
    parser.add_argument("--check", action="store_true",
                        help=f"write nothing; exit 1 when {OUTPUT.name} is not what the texts compile to")
    args = parser.parse_args(argv)
    text = build()
    if args.check:
        same = OUTPUT.exists() and OUTPUT.read_text(encoding="utf-8") == text
        print(f"{OUTPUT}: {'up to date' if same else 'NOT what the texts compile to: run without --check'}")
        return 0 if same else 1
    OUTPUT.write_text(text, encoding="utf-8")
    counts = json.loads(text)["counts"]
    print(f"wrote {OUTPUT}: {counts['accessible']} accessible objects, {counts['read-write']} read-write")
    return 0


if __name__ == "__main__":
    sys.exit(main())
