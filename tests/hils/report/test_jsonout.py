"""Every JSON file is JSON: non-finite floats become null, and the document says why."""

from __future__ import annotations

import json

from hils.report import jsonout
from hils.report.latency import Stats


def test_nan_and_infinity_become_null_and_are_noted():
    doc = {"hold_s": Stats.of([]).as_dict(), "rate": float("inf"), "rows": [1.5, float("-inf")],
           "notes": ["kept"]}

    def refuse(name):
        raise AssertionError(f"{name} written")

    out = json.loads(jsonout.dumps(doc), parse_constant=refuse)
    assert out["hold_s"]["n"] == 0 and out["hold_s"]["mean"] is None
    assert out["rate"] is None and out["rows"] == [1.5, None]
    assert out["notes"][0] == "kept"
    assert any(note.startswith("hold_s.mean: null") for note in out["notes"])
    assert any(note.startswith("rows[1]: null") for note in out["notes"])


def test_a_finite_document_is_unchanged():
    doc = {"a": 1, "b": [0.25, "x", None, True], "c": {"d": 2.0}}
    assert json.loads(jsonout.dumps(doc)) == doc
