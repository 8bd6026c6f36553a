"""JSON that every reader can load: no NaN or infinity, ever.

Python's json writes ``NaN`` and ``Infinity``, which are not JSON (jq, JavaScript and most
JSON libraries refuse them). Every JSON file the project writes goes through :func:`dumps`:
a float that is not finite becomes null, and when the document is an object its ``notes``
list says which fields are null and why, so a reader never mistakes a missing figure for a
zero.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from typing import Any

NON_FINITE_NOTE = "null: not a finite number (a statistic over no values, or a division by zero)"


def dumps(doc: Any, *, indent: int | None = 2) -> str:
    """``doc`` as JSON text with every non-finite float written as null and noted."""
    nulls: list[str] = []
    clean = _clean(doc, "", nulls)
    if nulls and isinstance(clean, dict):
        clean["notes"] = [*clean.get("notes", []), *(f"{path}: {NON_FINITE_NOTE}" for path in nulls)]
    return json.dumps(clean, indent=indent, allow_nan=False)


def _clean(value: Any, path: str, nulls: list[str]) -> Any:
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        nulls.append(path or "(document)")
        return None
    if isinstance(value, bool | int | str) or value is None:
        return value
    if is_dataclass(value) and not isinstance(value, type):
        value = asdict(value)
    if isinstance(value, Mapping):
        return {str(k): _clean(v, f"{path}.{k}" if path else str(k), nulls) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        items = sorted(value) if isinstance(value, set | frozenset) else value
        return [_clean(v, f"{path}[{i}]", nulls) for i, v in enumerate(items)]
    if hasattr(value, "item"):  # numpy scalars
        return _clean(value.item(), path, nulls)
    return str(value)
