"""libsumo, imported with its caution on stdout kept off it.

libsumo prints a caution on stdout when it is imported beside a pyarrow other than the one it was built with
(the atspm extra brings pyarrow). Scripts read what hils prints there, so the caution is logged at debug level
instead. Whatever in the project uses libsumo imports it from here (``from hils.sim.quiet_libsumo import libsumo``):
the first import decides, and later ones are Python's cached module.
"""

from __future__ import annotations

import io
import logging
from contextlib import redirect_stdout

with redirect_stdout(io.StringIO()) as _import_note:
    import libsumo
if _import_note.getvalue().strip():
    logging.getLogger(__name__).debug("libsumo on import: %s", " ".join(_import_note.getvalue().split()))

__all__ = ["libsumo"]
