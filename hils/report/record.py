"""The controllers' own record of a run, kept in its folder: hi-res logs, ATSPM measures and charts.

After a run, :func:`keep` collects each controller's hi-res event log (:mod:`hils.protocol.hires`): in virtual time
from the in-process emulator (:meth:`hils.Testbed.hires`); at the wall clock over a MaxTime event-log
endpoint when the run names one (``hils emulator serve --http`` offers it; so does an Intelight MaxTime);
otherwise the controller keeps its log and the run says where to collect it. It writes them in the ATSPM
layout (``hires.parquet``, or ``hires.csv`` without pyarrow), one ``DeviceId`` per intersection in the run's
order, computes the ATSPM measures (:mod:`hils.report.atspm`, ``atspm.csv``) and draws the Purdue coordination
diagram and split monitor of each controller (:mod:`hils.report.atspm_charts`). What it did goes into the run's
summary under ``record``.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from pathlib import Path
from typing import Any

from hils.protocol import hires
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import Event
from hils.report import atspm, atspm_charts, plots

#: Where a run at the wall clock finds its controller's log when it does not collect it (summary and event log).
KEPT_BY_CONTROLLER = ("the controller keeps its own hi-res log: collect it from the controller for the run's window "
                      f"(MaxTime: GET http://CONTROLLER{hires.ASCLOG_PATH}?since=MM-DD-YYYY HH:MM:SS.0; others: the "
                      "vendor's tool), or give hils run --asclog http://HOST:PORT")


def keep(logs: Mapping[str, list[Event]], configs: Mapping[str, IntersectionConfig], folder: Path, *,
         several: bool, asclog: str | None = None, since: datetime | None = None) -> tuple[dict[str, Any], list[str]]:
    """Keep the record of a run whose controllers are ``configs`` (by traffic light, in the run's order) in
    ``folder``: the logs the run holds, or the one collected from ``asclog`` (``http://HOST:PORT``, one controller,
    from ``since``). Returns the summary's ``record`` section and the names of the files written."""
    devices = {tls: n for n, tls in enumerate(configs, start=1)}
    section: dict[str, Any] = {"devices": {str(n): tls for tls, n in devices.items()}}
    logs = dict(logs)
    if not logs and asclog is not None:
        (tls,) = configs
        try:
            logs = {tls: hires.collect(asclog, since)}
            section["collected_from"] = hires.asclog_url(asclog, since)
        except (OSError, hires.AsclogError) as exc:
            section["missing"] = f"could not collect the controller's log from {asclog}: {exc}"
            return section, []
    if not logs:
        section["missing"] = KEPT_BY_CONTROLLER
        return section, []
    by_device = {devices[tls]: events for tls, events in logs.items()}
    path = hires.write(by_device, folder)
    written = [path.name]
    section["file"] = path.name
    section["events"] = {str(devices[tls]): len(events) for tls, events in logs.items()}
    if path.suffix == ".csv":
        section["format_note"] = "CSV: pyarrow is not installed (pip install 'hils[atspm]' for hires.parquet)"
    measured = atspm.measures(hires.rows(by_device), {devices[tls]: configs[tls] for tls in logs})
    if measured.missing:
        section["atspm"] = {"missing": measured.missing}
    else:
        measured.write(folder / "atspm.csv")
        written.append("atspm.csv")
        totals = measured.totals()
        section["atspm"] = {"bin_minutes": atspm.BIN_MINUTES, "file": "atspm.csv", **measured.run_figures(),
                            "per_phase": {str(d): {str(p): t for p, t in phases.items()}
                                          for d, phases in totals.items()}}
    folders = {tls: folder / tls if several else folder for tls in logs}
    for f in folders.values():
        f.mkdir(exist_ok=True)
    charts = atspm_charts.draw(logs, configs, folders,
                               {tls: plots.named(tls if several else None, configs[tls]) for tls in logs})
    written += [str(p.relative_to(folder)) for p in charts]
    if not any(atspm_charts.chose_its_splits(events) for events in logs.values()):
        section["charts"] = atspm_charts.NOTHING_TO_DRAW
    return section, written


def describe(section: Mapping[str, Any]) -> list[str]:
    """The console's lines about a run's record."""
    if "file" not in section:
        return [f"Hi-res log: {section.get('missing', 'none')}"]
    count = sum(section["events"].values())
    lines = [f"Hi-res log: {count} events in {section['file']} (ATSPM layout, DeviceId "
             + ", ".join(f"{n} = {tls}" for n, tls in section["devices"].items()) + ")"]
    if "format_note" in section:
        lines.append(f"  {section['format_note']}")
    if "charts" in section:
        lines.append(f"  {section['charts']}")
    measured = section.get("atspm", {})
    if "missing" in measured:
        lines.append(f"ATSPM measures: not computed, {measured['missing']}")
        return lines
    aog = measured["percent_on_green"]
    if measured["split_failures"] is None:
        detectors = atspm.NO_DETECTORS
    else:
        detectors = (f"{measured['split_failures']} split failures, {'-' if aog is None else f'{aog:.1f} %'} of "
                     "arrivals on green (stop-bar detectors)")
    lines.append(f"ATSPM ({measured['bin_minutes']}-minute bins in atspm.csv): {detectors}; {measured['gap_outs']} "
                 f"gap-outs, {measured['max_outs']} max-outs, {measured['force_offs']} force-offs")
    for device, phases in measured["per_phase"].items():
        name = section["devices"][device]
        rows = ", ".join(f"{p}: {t['split_failures']} SF, {t['gap_outs']}/{t['max_outs']}/{t['force_offs']}"
                         for p, t in phases.items())
        lines.append(f"  {name} per phase (split failures, gap/max/force-off): {rows}")
    return lines
