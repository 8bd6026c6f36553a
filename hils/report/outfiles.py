"""Where a command's outputs go, and that they are written whole or not at all.

A command writes to the folder its user names (``--out``), or else to a new folder of its own,
``reports/runs/<time>-<command>/`` under the current folder (:func:`fresh_folder`; a clone's git ignores
``reports/runs/``): running it from a clone's root never writes over the published reports beside it.

A full disk or a file size limit can stop a write halfway: a summary.json that is not JSON, or a
picture cut off, would pass for a result. :func:`write_whole` removes what it could not finish and
names the file in the error it raises.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

from hils.protocol.errors import UserError

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


def write_whole(path: Path, text: str) -> None:
    """Write ``text`` to ``path``; on failure remove the part written and raise the OSError naming ``path``."""
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        with contextlib.suppress(OSError):
            path.unlink(missing_ok=True)
        if exc.filename is None:
            exc.filename = str(path)
        raise
