"""ATSPM measures of a run, computed from its controllers' hi-res logs by the ``atspm`` package.

Automated Traffic Signal Performance Measures are what a DOT judges a signal by; the ``atspm`` Python
package (Shawn Strasser's, in production at Oregon DOT) computes them from a hi-res log in the ATSPM layout
(:mod:`hils.protocol.hires`) and a detector configuration. It pulls DuckDB and ibis, so it is an optional extra
(``pip install 'hils[atspm]'``); without it :func:`measures` says so instead of measuring.

Per controller (``DeviceId``), phase and 15-minute bin:

- **split failures**: cycles whose green occupancy and red occupancy (the first 5 s of red) of the phase's
  presence detectors both reach 80 % (the package's ``split_failures`` with its documented example settings:
  ``red_time`` 5, both thresholds 0.80, detectors combined per approach), with the mean green and red
  occupancy;
- **arrivals on green**: detector-on events while the phase shows green, and their share (``arrival_on_green``).
  ATSPM counts arrivals at an advance detector, upstream of any queue; the emulator's detectors are the
  stop-bar presence loops SUMO actuates (20 m), so a vehicle queued beyond the loop arrives at it on green:
  the share is an upper bound of what an advance detector would count;
- **actuations** of the phase's detectors (``actuations``, summed per phase);
- **terminations**: gap-outs, max-outs and force-offs (``terminations``, events 4, 5 and 6).

Every detector of the config is both a presence and an arrival detector of its phase.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from hils.protocol.config import IntersectionConfig
from hils.report.outfiles import write_whole

BIN_MINUTES = 15
SPLIT_FAILURE = {"red_time": 5, "red_occupancy_threshold": 0.80, "green_occupancy_threshold": 0.80,
                 "by_approach": True}
#: The extra that installs the package.
INSTALL = "pip install 'hils[atspm]'"
#: Why split failures and arrivals on green are not measured in a run whose controllers read no detector.
NO_DETECTORS = ("no detector actuations in the log: the controller ran on the middleware's calls or a pretimed plan "
                "alone, so split failures and arrivals on green are not measured (--agent actuated or coordinated "
                "runs the controller on its detectors)")
#: The columns of a run's ``atspm.csv``, one row per controller, phase and bin.
FIELDS = ("TimeStamp", "DeviceId", "Phase", "split_failures", "green_occupancy", "red_occupancy", "arrivals",
          "arrivals_on_green", "percent_on_green", "actuations", "gap_outs", "max_outs", "force_offs")
_TERMINATIONS = {"GapOut": "gap_outs", "MaxOut": "max_outs", "ForceOff": "force_offs"}


@dataclass(frozen=True)
class Measures:
    """The measures of a run: one row per controller, phase and bin (keys :data:`FIELDS`), or why there are none."""

    rows: tuple[dict[str, Any], ...] = ()
    missing: str | None = None  # why nothing was measured (the package is not installed)

    def totals(self) -> dict[int, dict[int, dict[str, Any]]]:
        """Per controller and phase, the measures over the whole run (occupancies: the mean of the bins)."""
        out: dict[int, dict[int, dict[str, Any]]] = {}
        for row in self.rows:
            t = out.setdefault(row["DeviceId"], {}).setdefault(row["Phase"], {
                "split_failures": 0, "arrivals": 0, "arrivals_on_green": 0, "actuations": 0, "gap_outs": 0,
                "max_outs": 0, "force_offs": 0, "_occupancy": []})
            for name in ("split_failures", "arrivals", "arrivals_on_green", "actuations", "gap_outs", "max_outs",
                         "force_offs"):
                t[name] += row[name] or 0
            if row["green_occupancy"] is not None:
                t["_occupancy"].append((row["green_occupancy"], row["red_occupancy"]))
        for phases in out.values():
            for t in phases.values():
                occupancy = t.pop("_occupancy")
                t["percent_on_green"] = _share(t["arrivals_on_green"], t["arrivals"])
                t["green_occupancy"] = _mean(g for g, _ in occupancy)
                t["red_occupancy"] = _mean(r for _, r in occupancy)
        return out

    def run_figures(self) -> dict[str, Any]:
        """The run's headline figures over every controller and phase: split failures and percent on green (None
        when no detector was actuated: a controller run on the middleware's calls alone reads no detectors), and the
        terminations."""
        totals = [t for phases in self.totals().values() for t in phases.values()]
        detected = any(t["actuations"] for t in totals)
        out = {"split_failures": sum(t["split_failures"] for t in totals) if detected else None,
               "percent_on_green": _share(sum(t["arrivals_on_green"] for t in totals),
                                          sum(t["arrivals"] for t in totals))}
        return out | {name: sum(t[name] for t in totals) for name in ("gap_outs", "max_outs", "force_offs")}

    def write(self, path: Path) -> None:
        """``atspm.csv``, whole or not at all."""
        text = io.StringIO()
        out = csv.DictWriter(text, FIELDS, lineterminator="\n")
        out.writeheader()
        out.writerows({**row, "TimeStamp": row["TimeStamp"].isoformat(sep=" ")} for row in self.rows)
        write_whole(path, text.getvalue())


def detector_config(configs: Mapping[int, IntersectionConfig]) -> list[tuple[int, int, int, str]]:
    """``(DeviceId, Phase, Parameter, Function)`` of every vehicle detector: presence and arrival detector of its
    phase."""
    return [(device, phase, detector, function) for device, cfg in configs.items()
            for detector, phase in sorted(cfg.detectors.items()) if phase for function in ("Presence", "Advance")]


def measures(rows: Iterable[tuple[datetime, int, int, int]], configs: Mapping[int, IntersectionConfig]) -> Measures:
    """The measures of hi-res rows in the ATSPM layout (:func:`hils.protocol.hires.rows`) of controllers with these
    configs."""
    try:
        import pandas as pd
        from atspm import SignalDataProcessor
    except ImportError:
        return Measures(missing=f"the atspm package is not installed ({INSTALL})")
    raw = pd.DataFrame(list(rows), columns=["TimeStamp", "DeviceId", "EventId", "Parameter"])
    detectors = pd.DataFrame(detector_config(configs), columns=["DeviceId", "Phase", "Parameter", "Function"])
    aggregations = [
        {"name": "actuations", "params": {}},
        {"name": "arrival_on_green", "params": {"latency_offset_seconds": 0}},
        {"name": "split_failures", "params": SPLIT_FAILURE},
        {"name": "terminations", "params": {}},
    ]
    with SignalDataProcessor(raw_data=raw, detector_config=detectors, bin_size=BIN_MINUTES, verbose=0,
                             aggregations=aggregations) as processor:
        processor.load()
        processor.aggregate()
        tables = {a["name"]: processor.conn.query(f"SELECT * FROM {a['name']}").df() for a in aggregations}
    return Measures(tuple(_rows(tables, detectors)))


def _rows(tables: Mapping[str, Any], detectors: Any) -> list[dict[str, Any]]:
    """One row per (bin, device, phase) out of the package's tables."""
    out: dict[tuple[Any, int, int], dict[str, Any]] = {}

    def row(ts: Any, device: Any, phase: Any) -> dict[str, Any]:
        key = (ts.to_pydatetime(), int(device), int(phase))
        return out.setdefault(key, {"TimeStamp": key[0], "DeviceId": key[1], "Phase": key[2], "split_failures": 0,
                                    "green_occupancy": None, "red_occupancy": None, "arrivals": 0,
                                    "arrivals_on_green": 0, "percent_on_green": None, "actuations": 0,
                                    "gap_outs": 0, "max_outs": 0, "force_offs": 0})

    for r in tables["split_failures"].itertuples():
        cell = row(r.TimeStamp, r.DeviceId, r.Phase)
        cell["split_failures"] = int(r.Split_Failure)
        cell["green_occupancy"] = round(float(r.Green_Occupancy), 4)
        cell["red_occupancy"] = round(float(r.Red_Occupancy), 4)
    # The package's arrival_on_green leaves out the bins without an arrival on green; every detector being an
    # arrival detector, a phase's arrivals are its actuations.
    for r in tables["arrival_on_green"].itertuples():
        row(r.TimeStamp, r.DeviceId, r.Phase)["arrivals_on_green"] = round(float(r.Percent_AOG) *
                                                                           int(r.Total_Actuations))
    phase_of = {(int(d.DeviceId), int(d.Parameter)): int(d.Phase) for d in detectors.itertuples()}
    for r in tables["actuations"].itertuples():
        phase = phase_of.get((int(r.DeviceId), int(r.Detector)))
        if phase is not None:
            row(r.TimeStamp, r.DeviceId, phase)["actuations"] += int(r.Total)
    for r in tables["terminations"].itertuples():
        row(r.TimeStamp, r.DeviceId, r.Phase)[_TERMINATIONS[r.PerformanceMeasure]] += int(r.Total)
    for cell in out.values():
        cell["arrivals"] = cell["actuations"]
        cell["percent_on_green"] = _share(cell["arrivals_on_green"], cell["arrivals"])
    return [out[k] for k in sorted(out)]


def _share(part: int, whole: int) -> float | None:
    return round(100 * part / whole, 1) if whole else None


def _mean(values: Iterable[float]) -> float | None:
    values = list(values)
    return round(sum(values) / len(values), 4) if values else None
