"""Where a command's outputs go, and that they are written whole or not at all, one by one, each failure named.

A command writes to the folder its user names (``--out``), or else to a new folder of its own,
``reports/runs/<time>-<command>/`` under the current folder (:func:`fresh_folder`; a clone's git ignores
``reports/runs/``): running it from a clone's root never writes over the published reports beside it.

A full disk or a file size limit can stop a write halfway: a summary.json that is not JSON, or a
picture cut off, would pass for a result. :func:`write_whole` writes a file beside its place and moves it
there once whole, so the place holds the whole new file or what it held before (never half of either); the
error it raises names the file and the reason. :class:`Outputs` writes a run folder's files in the order given
(small ones first: the summary before the pictures, the pictures before the hi-res log) and goes on past a
file that cannot be written, keeping its name and why.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path

from hils.protocol.errors import UserError

log = logging.getLogger(__name__)

#: Where a command writes when its user names no folder (relative to the current folder).
RUNS = Path("reports/runs")


def fresh_folder(command: str) -> Path:
    """A new folder ``reports/runs/<YYYYmmdd-HHMMSS>-<command>`` that no other command uses (``-2``, ``-3``... beside
    one that started in the same second), made."""
    base = RUNS / f"{time.strftime('%Y%m%d-%H%M%S')}-{command}"
    for n in range(1, 1000):
        candidate = base if n == 1 else base.with_name(f"{base.name}-{n}")
        try:
            candidate.mkdir(parents=True, exist_ok=False)
        except FileExistsError:
            continue  # another command started in the same second: take the next name
        except OSError as exc:
            raise UserError(f"cannot create the output folder {candidate}: {exc.strerror}") from None
        return candidate
    raise UserError(f"no free output folder name beside {base}")


def given_folder(path: Path) -> Path:
    """The folder a user named for a command's outputs, made (with its parents) if it does not exist."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create the output folder {path}: {exc.strerror}") from None
    return path



def write_whole(path: Path, data: str | bytes) -> None:
    """Write ``data`` to ``path`` whole (text as UTF-8; its folder made if need be); on failure leave ``path`` as it
    was and raise the OSError naming ``path``."""
    body = memoryview(data.encode() if isinstance(data, str) else data)
    part = path.with_name(f".{path.name}.part")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        try:
            while body:
                body = body[os.write(fd, body):]
        finally:
            os.close(fd)
        os.replace(part, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            part.unlink(missing_ok=True)
        exc.filename = str(path)
        raise


class Outputs:
    """The files of a run folder, written one at a time: one that cannot be written is named with why, and the
    others are still written. With ``raise_errors`` (``hils run -v``) an error that is not the disk's is raised, for
    its traceback."""

    def __init__(self, folder: Path, *, raise_errors: bool = False) -> None:
        self.folder = folder
        self.raise_errors = raise_errors
        self.written: list[str] = []  # names in the folder, in the order written
        self.failed: dict[str, str] = {}  # name -> why it could not be written

    def write(self, name: str, make: Callable[[], object]) -> bool:
        """``make()`` writes the file ``name`` (relative to the folder); True when it did. ``make`` returning False
        means it had nothing to write (no file, no failure)."""
        try:
            made = make()
        except OSError as exc:
            self.failed[name] = exc.strerror or str(exc)
            return False
        except Exception as exc:  # a picture's bug must not cost the summary or the record
            if self.raise_errors:
                raise
            log.debug("writing %s", name, exc_info=True)
            self.failed[name] = f"{type(exc).__name__}: {exc} (hils -v run ... gives its traceback)"
            return False
        self.failed.pop(name, None)  # written now (summary.json is written twice)
        if made is False:
            return False
        if name not in self.written:
            self.written.append(name)
        return True

    def lines(self) -> list[str]:
        """One line per file that could not be written: its name and why."""
        return [f"{name}: {why}" for name, why in self.failed.items()]
