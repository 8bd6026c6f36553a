"""A run's output files are written whole or not at all.

A full disk or a file size limit can stop a write halfway: a summary.json that is not JSON, or a
picture cut off, would pass for a result. :func:`write_whole` removes what it could not finish and
names the file in the error it raises.
"""

from __future__ import annotations

import contextlib
from pathlib import Path


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
