"""The controllers' own record of a run, kept in its folder: hi-res logs, ATSPM measures and charts.

After a run, :func:`gather` takes each controller's hi-res event log (:mod:`hils.protocol.hires`): in virtual time
from the in-process emulator (:meth:`hils.Testbed.hires`), which also wrote it through to the run's journal as it
went (:mod:`hils.shell.hiresjournal`); at the wall clock over a MaxTime event-log endpoint when the run names one
(``hils emulator serve --http`` offers it; so does an Intelight MaxTime), collected within bounds
(:mod:`hils.shell.asclog`); otherwise the controller keeps its log and the run says where to collect it. It
computes the ATSPM measures (:mod:`hils.report.atspm`). :meth:`Record.write_small` then writes ``atspm.csv`` and
the Purdue coordination diagram and split monitor of each controller (:mod:`hils.report.atspm_charts`), and
:meth:`Record.write_log`, last, the largest file: the logs in the ATSPM layout (``hires.parquet``, or ``hires.csv``
without pyarrow), one ``DeviceId`` per intersection in the run's order, which replaces the journal. What it did
goes into the run's summary under ``record``; whatever failed (a log that could not be collected, a file that
could not be written) is one line there, and the rest is still kept.
"""

from __future__ import annotations

import contextlib
import logging
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from functools import partial
from typing import Any

from hils.protocol import hires
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import Event
from hils.report import atspm, atspm_charts, plots
from hils.report.outfiles import Outputs, write_whole
from hils.shell import asclog as asclog_mod
from hils.shell.hiresjournal import HiresJournal

log = logging.getLogger(__name__)

#: Where a run at the wall clock finds its controller's log when it does not collect it (summary and event log).
KEPT_BY_CONTROLLER = ("the controller keeps its own hi-res log: collect it from the controller for the run's window "
                      f"(MaxTime: GET http://CONTROLLER{hires.ASCLOG_PATH}?since=MM-DD-YYYY HH:MM:SS.0; others: the "
                      "vendor's tool), or give hils run --asclog http://HOST:PORT")


@dataclass
class Record:
    """A run's record: its summary section (updated as files are written), the logs by traffic light and their
    measures."""

    section: dict[str, Any]
    logs: dict[str, list[Event]]
    devices: dict[str, int]
    configs: Mapping[str, IntersectionConfig]
    measured: atspm.Measures | None = None
    journal: HiresJournal | None = None

    def write_small(self, files: Outputs, *, several: bool) -> None:
        """``atspm.csv``, and each controller's charts (in its own folder when the run has several)."""
        measures = self.section.get("atspm", {})
        path = files.folder / "atspm.csv"
        if "file" in measures and not files.write(path.name, partial(self.measured.write, path)):
            del measures["file"]
        for tls, events in self.logs.items():
            folder = files.folder / tls if several else files.folder
            title = plots.named(tls if several else None, self.configs[tls])
            for name, chart in atspm_charts.CHARTS.items():
                files.write(f"{tls}/{name}" if several else name,
                            partial(chart, events, self.configs[tls], folder / name, title))

    def write_log(self, files: Outputs) -> None:
        """The logs in the ATSPM layout, in one file; the journal, whole, stands in for it when it cannot be
        written (removed with :meth:`drop_journal` once the summary names the file that replaces it)."""
        if not self.logs:
            return
        name = hires.file_name()
        by_device = {self.devices[tls]: events for tls, events in self.logs.items()}
        if files.write(name, lambda: write_whole(files.folder / name, hires.encode(by_device))):
            self.section["file"] = name
            if name.endswith(".csv"):
                self.section["format_note"] = ("CSV: pyarrow is not installed (pip install 'hils[atspm]' for "
                                               "hires.parquet)")
            return
        journal = self.journal
        if journal is not None and journal.failure is None:
            self.section["file"] = journal.path.name
            self.section["format_note"] = (f"{name} could not be written: the log stays in the run's journal, "
                                           f"{journal.path.name} (CSV, ATSPM layout, rows in the order logged)")
        elif journal is not None:
            self.section["format_note"] = (f"{name} could not be written, and the journal stopped: {journal.failure}; "
                                           f"{journal.path.name} keeps those")

    @property
    def journal_kept(self) -> str | None:
        """The journal's name when it stays in the run folder: the record's file could not be written, and it
        holds the log, whole or its first events."""
        journal = self.journal
        if journal is None or self.section.get("file") not in (None, journal.path.name):
            return None
        return journal.path.name

    def drop_journal(self) -> None:
        """Remove the journal once the record's file replaces it (a journal that stopped early included)."""
        if self.journal is not None and self.journal_kept is None:
            with contextlib.suppress(OSError):
                self.journal.path.unlink(missing_ok=True)


def gather(held: Mapping[str, list[Event]], configs: Mapping[str, IntersectionConfig], devices: Mapping[str, int],
           *, asclog: str | None = None, since: datetime | None = None,
           bounds: asclog_mod.Bounds | None = None, journal: HiresJournal | None = None) -> Record:
    """The record of a run whose controllers are ``configs`` (by traffic light, in the run's order, numbered
    ``devices``): the logs the run holds, or the one collected from ``asclog`` (``http://HOST:PORT``, one
    controller, from ``since``, within ``bounds``), with their ATSPM measures."""
    section: dict[str, Any] = {"devices": {str(n): tls for tls, n in devices.items()}}
    logs = dict(held)
    if not logs and asclog is not None:
        (tls,) = configs
        url = urllib.parse.unquote_plus(hires.asclog_url(asclog, since))  # as a reader reads it
        bounds = bounds or asclog_mod.Bounds()
        log.info("collecting the controller's hi-res log from %s (at most %g s and %g MB)", url, bounds.seconds,
                 bounds.max_bytes / 2**20)
        try:
            logs = {tls: asclog_mod.collect(asclog, since, bounds)}
            section["collected_from"] = hires.asclog_url(asclog, since)  # as a client asks for it again
        except asclog_mod.CollectError as exc:
            section["missing"] = f"could not collect the controller's log from {url}: {exc}"
    record = Record(section, logs, dict(devices), configs, journal=journal)
    if not logs:
        section.setdefault("missing", KEPT_BY_CONTROLLER)
        return record
    section["events"] = {str(devices[tls]): len(events) for tls, events in logs.items()}
    by_device = {devices[tls]: events for tls, events in logs.items()}
    try:
        record.measured = atspm.measures(hires.rows(by_device), {devices[tls]: configs[tls] for tls in logs})
    except Exception as exc:  # the atspm package on a log it cannot measure: the rest of the record is kept
        log.debug("ATSPM measures", exc_info=True)
        section["atspm"] = {"missing": f"the atspm package could not measure the log ({type(exc).__name__}: "
                                       f"{str(exc).splitlines()[0] if str(exc) else ''})"}
        return record
    if record.measured.missing:
        section["atspm"] = {"missing": record.measured.missing}
    else:
        totals = record.measured.totals()
        section["atspm"] = {"bin_minutes": atspm.BIN_MINUTES, "file": "atspm.csv", **record.measured.run_figures(),
                            "per_phase": {str(d): {str(p): t for p, t in phases.items()}
                                          for d, phases in totals.items()}}
    if not any(atspm_charts.chose_its_splits(events) for events in logs.values()):
        section["charts"] = atspm_charts.NOTHING_TO_DRAW
    return record


def describe(section: Mapping[str, Any]) -> list[str]:
    """The console's lines about a run's record."""
    if "events" not in section:
        return [f"Hi-res log: {section.get('missing', 'none')}"]
    count = sum(section["events"].values())
    kept = f"in {section['file']}" if "file" in section else "NOT kept"
    lines = [f"Hi-res log: {count} events {kept} (ATSPM layout, DeviceId "
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
