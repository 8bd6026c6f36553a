"""The compiled NTCIP 1202 v03 MIB (harness/reference/ntcip_mib/) and the checks that judge by it, without a network:
the reference is what the standard's text compiles to, carries its notice, and hils' own object definitions agree
with it; the conformance checks find what they must in made-up walks."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from harness.reference import mib_compile, mib_conformance
from harness.reference.mib import REFERENCE, load
from harness.reference.mib_conformance import (
    Verdict,
    Walked,
    definition_findings,
    parse_walk,
    set_findings,
    walk_findings,
)
from hils.protocol.ntcip import (
    ALL_OBJECTS,
    MAX_PREEMPTS,
    PATTERN_TABLE,
    PREEMPT_STATUS,
    PREEMPT_TABLE,
    V03_CHANGES,
    Access,
    PatternColumn,
    PhaseColumn,
    PreemptColumn,
    Version,
    phase_oid,
)

MIB = load()


#: Where the standard's text contradicts itself: preemptExitType is ``::= { preemptEntry 28 }`` (what ASN.1 reads,
#: and pysmi), while its DESCRIPTION says "<Object Identifier> 1.3.6.1.4.1.1206.4.2.1.6.2.1.27".
DESCRIBED_OTHERWISE = {"preemptExitType": "1.3.6.1.4.1.1206.4.2.1.6.2.1.27"}
_BLOCK = re.compile(r'^(\w+)\s+OBJECT-TYPE\s+SYNTAX\s+(.+?)\s+ACCESS\s+([\w-]+)\s+STATUS\s+(\w+)\s+'
                    r'DESCRIPTION\s+"([^"]*)"', re.M | re.S)


def test_the_reference_agrees_with_the_text_read_by_a_second_reader() -> None:
    """pysmi is not installed for the tests (see pyproject.toml): the checked-in reference is held to the text by a
    reader of its own, regular expressions over each OBJECT-TYPE: access, status, a plain range or enumeration, and
    the OID its DESCRIPTION states."""
    text = (mib_compile.FOLDER / "NTCIP1202-v03.mib").read_text(encoding="utf-8")
    blocks = {m[1]: m for m in _BLOCK.finditer(text)}
    differ = {}
    for name, obj in MIB.objects.items():
        m = blocks[name]
        syntax = " ".join(m[2].split())
        described = re.search(r"<Object\s+Identifier>\s*([\d.]+\d)", m[5])
        plain = re.fullmatch(r"INTEGER\s*\((-?\d+)\s*\.\.\s*(-?\d+)\)", syntax)
        named = dict((k, int(v)) for k, v in re.findall(r"([\w-]+)\s*\(\s*(\d+)\s*\)", syntax))
        if (m[3], m[4]) != (obj.access.value, obj.status):
            differ[name] = f"{m[3]} {m[4]}"
        elif described and described[1] != ".".join(map(str, obj.oid)):
            differ[name] = described[1]
        elif ((plain and obj.ranges != ((int(plain[1]), int(plain[2])),))
              or (syntax.startswith("INTEGER {") and named != dict(obj.enumeration or {}))):
            differ[name] = syntax
    assert differ == DESCRIBED_OTHERWISE
    assert len(MIB.objects) == sum(m[3] != "not-accessible" for m in blocks.values())


def test_the_standard_defines_437_accessible_objects_242_of_them_read_write() -> None:
    assert (MIB.accessible, MIB.writable) == (437, 242)
    assert MIB.objects["maxPreempts"].describe() == "INTEGER (1..255)"
    assert MIB.objects["patternSplitNumber"].access is Access.READ_ONLY
    assert MIB.tables["preemptTable"].rows == "maxPreempts"
    assert MIB.object_for(PREEMPT_TABLE[PreemptColumn.DELAY].instance(3)).name == "preemptDelay"


def test_every_copy_carries_the_distribution_notice() -> None:
    notice = (mib_compile.FOLDER / "NOTICE.txt").read_text(encoding="utf-8")
    assert "DISTRIBUTION NOTICE" in notice and "each copy you make and/or distribute contains this Notice" in notice
    assert MIB.notice == notice
    for name in ("NTCIP1202-v03.mib", "NTCIP8004v02.mib"):
        text = (mib_compile.FOLDER / name).read_text(encoding="cp1252" if "8004" in name else "utf-8")
        assert "--                        DISTRIBUTION NOTICE" in text, name


def test_a_text_other_than_the_published_one_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "ntcip_mib"
    shutil.copytree(mib_compile.FOLDER, folder)
    text = folder / "NTCIP1202-v03.mib"
    text.write_bytes(text.read_bytes().replace(b"SYNTAX INTEGER (1..255)", b"SYNTAX INTEGER (0..255)", 1))
    with pytest.raises(ValueError, match="SHA-256"):
        mib_compile.read_texts(folder)


def test_a_mend_that_finds_nothing_to_mend_is_an_error() -> None:
    texts = mib_compile.read_texts()
    with pytest.raises(ValueError, match="wrapped comments"):
        mib_compile.mended({**texts, mib_compile.MODULE: mib_compile.mended(texts)[mib_compile.MODULE]})


def test_comments_go_and_quoted_text_stays() -> None:
    text = 'a "x -- y" -- gone EXPORTS\r\nb -- "not a quote\nc'
    assert mib_compile.strip_comments(text) == 'a "x -- y" \r\nb \nc'


def test_hils_defines_each_object_as_the_mib_does() -> None:
    findings = definition_findings(MIB)
    assert [f for f in findings if f.verdict is Verdict.FINDING] == []
    # patternSplitNumber is defined as v02 does (read-write), which v03 changed: said, not hidden.
    assert {f.name for f in findings if f.verdict is Verdict.V02} == {"patternSplitNumber"}


def test_each_change_of_v03_is_listed_on_an_object_defined_as_v02_does() -> None:
    defined = {d.name: d for d in ALL_OBJECTS}
    assert V03_CHANGES and all(defined[name].version is Version.V02 for name in V03_CHANGES)
    assert PATTERN_TABLE[PatternColumn.SPLIT_NUMBER].access is Access.READ_WRITE


def test_net_snmp_output_is_read_by_type() -> None:
    text = (".1.3.6.1.4.1.1206.4.2.1.1.1.0 = INTEGER: 8\n"
            ".1.3.6.1.4.1.1206.4.2.1.1.2.1.23.1 = Hex-STRING: 05 06 \n"
            '.1.3.6.1.4.1.1206.4.2.1.6.2.1.14.1 = ""\n'
            ".1.3.6.1.4.1.1206.4.2.1.9.9.0 = No more variables left in this MIB View (It is past the end of the MIB "
            "tree)\n")
    assert parse_walk(text) == [Walked((1, 3, 6, 1, 4, 1, 1206, 4, 2, 1, 1, 1, 0), "INTEGER", 8),
                                Walked((1, 3, 6, 1, 4, 1, 1206, 4, 2, 1, 1, 2, 1, 23, 1), "OCTET STRING", b"\x05\x06"),
                                Walked((1, 3, 6, 1, 4, 1, 1206, 4, 2, 1, 6, 2, 1, 14, 1), "OCTET STRING", b"")]


def _walked(oid: tuple[int, ...], value: int | bytes, kind: str = "INTEGER") -> Walked:
    return Walked(oid, kind, value)


def test_the_walk_checks_find_what_departs_from_the_mib() -> None:
    max_preempts = MAX_PREEMPTS.instance()
    delay = PREEMPT_TABLE[PreemptColumn.DELAY]
    walked = [
        _walked(max_preempts, 0),  # outside 1..255
        _walked(delay.instance(1), 5),
        _walked(delay.instance(3), 5),  # a row past maxPreempts
        _walked((*delay.prefix, 1, 2), 5),  # two index parts: the table has one
        _walked(PREEMPT_TABLE[PreemptColumn.TRACK_PHASE].instance(1), 7),  # an INTEGER where the MIB has a string
        _walked((1, 3, 6, 1, 4, 1, 1206, 4, 2, 1, 99, 0), 1),  # no such object
        _walked((*MAX_PREEMPTS.prefix, 1), 1),  # a scalar's instance is .0
    ]
    found = {(f.name, f.check) for f in walk_findings(MIB, walked)}
    assert found == {("maxPreempts", "value"), ("preemptTable", "rows"), ("preemptDelay", "index"),
                     ("preemptTrackPhase", "type"), ("?", "known"), ("maxPreempts", "index")}
    assert all(f.verdict is Verdict.FINDING for f in walk_findings(MIB, walked))


def test_an_object_v03_added_served_under_v02_is_a_finding() -> None:
    walked = [_walked(PREEMPT_STATUS.instance(), 0)]
    assert [(f.name, f.check) for f in walk_findings(MIB, walked, Version.V02)] == [("preemptStatus", "edition")]
    assert walk_findings(MIB, walked, Version.V03) == []


def test_hils_defines_each_object_as_v03_does_when_it_serves_v03() -> None:
    findings = definition_findings(MIB, edition=Version.V03)
    assert [f for f in findings if f.verdict in (Verdict.FINDING, Verdict.V02)] == []


class _Agent:
    """An agent of one value that refuses every SET outside 0..255 with wrongValue, but keeps the refused value when
    ``leaky``, and refuses ``bad`` too. A request of several values is taken whole or refused whole."""

    def __init__(self, leaky: bool, bad: int | None = None) -> None:
        self.leaky = leaky
        self.bad = bad
        self.value = 5
        self.requests = 0

    def set(self, varbinds: list[tuple[tuple[int, ...], int]]) -> str:
        self.requests += 1
        values = [value for _, value in varbinds]
        if all(0 <= v <= 255 and v != self.bad for v in values):
            self.value = values[-1]
            return "noError"
        if self.leaky:
            self.value = values[-1]
        return "wrongValue"

    def get(self, oids: list[tuple[int, ...]]) -> list[int]:
        return [self.value for _ in oids]


@pytest.mark.parametrize("leaky", [False, True])
def test_a_refused_set_that_changes_the_value_is_a_finding(leaky: bool) -> None:
    offset = PATTERN_TABLE[PatternColumn.OFFSET_TIME].instance(1)  # 0..255 in the MIB and here
    found = set_findings(MIB, _Agent(leaky), [_walked(offset, 5)])
    assert [f.detail for f in found] == (["refused SETs changed it: 5 became 256"] if leaky else [])


def test_the_edges_are_set_in_batches_and_one_refused_is_found_in_its_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mib_conformance, "BATCH", 4)
    columns = (PhaseColumn.WALK, PhaseColumn.PEDESTRIAN_CLEAR, PhaseColumn.MINIMUM_GREEN, PhaseColumn.PASSAGE,
               PhaseColumn.MAXIMUM1, PhaseColumn.MAXIMUM2, PhaseColumn.RED_CLEAR, PhaseColumn.RED_REVERT)
    instances = ([_walked(phase_oid(col, 1), 5) for col in columns]
                 + [_walked(PATTERN_TABLE[col].instance(1), 5) for col in (PatternColumn.CYCLE_TIME,
                                                                           PatternColumn.OFFSET_TIME)])
    agent = _Agent(leaky=False)
    assert set_findings(MIB, agent, instances) == []  # every one 0..255, in the MIB and here
    # 2 past-edge SETs each (-1, 256), then 0, 255 and the put-back in batches of 4: 3 requests each.
    assert agent.requests == 2 * 10 + 3 * 3
    found = set_findings(MIB, _Agent(leaky=False, bad=255), instances)
    assert len(found) == 10 and {f.detail for f in found} == {"an edge, 255, refused wrongValue, inside INTEGER "
                                                              "(0..255)"}


def test_a_table_served_without_its_row_count_is_a_finding() -> None:
    walked = [_walked(PREEMPT_TABLE[PreemptColumn.DELAY].instance(1), 5)]
    assert [(f.name, f.check) for f in walk_findings(MIB, walked)] == [("preemptTable", "rows")]


def test_the_reference_is_json_with_its_source_and_mends() -> None:
    doc = json.loads(REFERENCE.read_text(encoding="utf-8"))
    assert doc["source"]["repository"] == "ibrahimkesim/ntcip-2025"
    assert len(doc["mends"]) == len(mib_compile.MENDS) and doc["compiled_by"].startswith("pysmi 2.0")
    assert doc["source"] == mib_compile.UPSTREAM and doc["stand_ins"] == sorted(mib_compile.STAND_INS)


def test_a_config_that_cannot_be_read_is_said_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(SystemExit) as info:
        mib_conformance.main(["--config", str(missing)])
    err = capsys.readouterr().err
    assert info.value.code == 2 and str(missing) in err and "cannot be read" in err and err.count("\n") == 1
