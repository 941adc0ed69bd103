"""Small readers shared by the ``[perception.<kind>]`` tables of detectors and re-id backends
(each kind parses its own table; :mod:`edge_node.perception.settings` calls them)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any


def file_option(t, key: str, base: Path, what: str, required: bool = False) -> str | None:
    """``key`` of table ``t`` as an existing file (relative to ``base``), or ``None``."""
    p = t.path(key, base, None)
    if p is None:
        if required:
            raise t.error(key, f"is required ({what})")
        return None
    if not p.is_file():
        raise t.error(key, f"names a file that does not exist: {p} ({what})")
    return str(p)


def pair_option(t, key: str, integer: bool) -> list | None:
    """``key`` as two positive (integer) numbers, or ``None`` when absent."""
    if not t.has(key):
        t.raw(key, None)
        return None
    v = t.raw(key)
    ok = isinstance(v, list) and len(v) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0
        and (not integer or isinstance(x, int)) and math.isfinite(x) for x in v)
    if not ok:
        raise t.error(key, f"must be two positive {'integers' if integer else 'numbers'}, got {v!r}")
    return list(v)


def drop_none(d: dict[str, Any]) -> dict[str, Any]:
    """The keys a table set (readers give ``None`` for absent ones)."""
    return {k: v for k, v in d.items() if v is not None}
