"""A log file that grows by whole records, each on disk (in the OS) before the run goes on.

The run's event log (:mod:`hils.shell.events`) and its controllers' hi-res journal (:mod:`hils.shell.hiresjournal`)
are written through this way, so a run that dies, SIGKILL and the OOM killer included, keeps every record
written before it: the file is opened unbuffered and each record is one ``write(2)``, which the kernel has
taken whole when it returns (a short write is finished by the next). A record the file cannot take whole
(a full disk, a file size limit) is cut back out, so the file always ends with its last whole record, and the
file takes no more: :attr:`AppendFile.failure` says why.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import IO

log = logging.getLogger(__name__)


class AppendFile:
    """An append-only file of whole records (opening it raises the OSError of a file that cannot be created)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file: IO[bytes] | None = path.open("wb", buffering=0)
        self.size = 0  # bytes of whole records in the file
        self.records = 0  # whole records in the file
        #: Why the file stopped taking records (None while it takes them).
        self.failure: OSError | None = None

    @property
    def open(self) -> bool:
        """Whether the file still takes records."""
        return self._file is not None

    def append(self, record: bytes) -> bool:
        """Write ``record`` whole (a short write is finished); False when the file does not take it (then
        :attr:`failure` says why, and the file ends with the records before it)."""
        if self._file is None:
            return False
        view = memoryview(record)
        try:
            while view:
                n = self._file.write(view)
                if not n:
                    raise OSError(0, "the file took no bytes")
                view = view[n:]
        except OSError as exc:
            self._stop(exc)
            return False
        self.size += len(record)
        self.records += 1
        return True

    def _stop(self, exc: OSError) -> None:
        file, self._file = self._file, None
        try:
            os.ftruncate(file.fileno(), self.size)  # never half a record: the file ends with the last whole one
        except OSError:
            log.warning("could not cut %s back to its last whole record", self.path)
        finally:
            file.close()
        self.failure = exc

    def close(self) -> None:
        if self._file is not None:
            try:
                self._file.close()
            finally:
                self._file = None
