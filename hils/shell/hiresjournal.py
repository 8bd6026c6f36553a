"""The run's hi-res journal: its controllers' events in the ATSPM layout, on disk as each tick logs them.

A controller the run holds in process (the emulator in virtual time) logs its hi-res events in memory, and the
run keeps them in ``hires.parquet`` when it ends (:mod:`hils.report.record`). A run that never ends that way
(SIGKILL, the OOM killer) would lose them all: so each tick's events are also appended to the
journal, ``hires.journal.csv`` in the run folder, written through as the event log is
(:class:`hils.shell.appendfile.AppendFile`: one ``write(2)`` per tick with events, whole or not at all). It is
the CSV form of the ATSPM layout (:func:`hils.protocol.hires.csv_rows`: ``TimeStamp, DeviceId, EventId,
Parameter``), which pandas, the ``atspm`` package and ``hils replay`` read as it is, finished or not; rows are
in the order the controllers logged them (each controller's in time order). Once the run's record is written,
the journal is removed; it stays when the record could not be written.

A journal that stops taking rows (a full disk) stops the journal alone: the run's events are still whole in
memory for the record at its end, and :attr:`HiresJournal.failure` says what happened.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

from hils.protocol.hires import CSV_HEADER, Event, csv_rows
from hils.shell.appendfile import AppendFile

log = logging.getLogger(__name__)

#: The journal's name in the run folder.
NAME = "hires.journal.csv"


class HiresJournal:
    """The append-only hi-res log of a run's controllers, one ``DeviceId`` each (raises OSError when the file
    cannot be created)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = AppendFile(path)
        self._file.append(CSV_HEADER.encode())
        self.events = 0  # rows in the file

    @property
    def failure(self) -> str | None:
        """Why the journal stopped taking rows, in a few words (None while it takes them)."""
        exc = self._file.failure
        return None if exc is None else f"{exc.strerror or exc} (it keeps its first {self.events} events, whole)"

    def device(self, number: int) -> Callable[[Sequence[Event]], None]:
        """What a controller hands its events to as it logs them, as ``DeviceId`` ``number``."""
        def append(events: Sequence[Event]) -> None:
            if not self._file.open or not events:
                return
            if self._file.append(csv_rows((e.time, number, e.code, e.parameter) for e in events).encode()):
                self.events += len(events)
            else:
                log.warning("the hi-res journal %s stopped: %s; the run's record is kept in memory until its end",
                            self.path, self.failure)

        return append

    def close(self) -> None:
        self._file.close()
