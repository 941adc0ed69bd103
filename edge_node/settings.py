"""Settings files: the one validating TOML reader of the project.

Camera configs (``edge_node/runtime/config.py``), fault plans (``edge_node/faults.py``),
scenarios (``sim_cluster/scenarios``) and tracker parameter files are all read with
:func:`read_toml` and :class:`Table`. Every error names the file and the field, e.g.
``cam0.toml: zenoh.listen[0] must be an endpoint ...`` or
``terrace-sim.toml: cameras[2].fov_deg must be in (0, 180), got 200``; each kind of file raises
its own subclass of :class:`SettingsError` (``NodeConfigError``, ``FaultPlanError``,
``ScenarioError``), given to the reader as ``error``.

Unknown fields are errors, because a typo must not silently fall back to a default. A reader
reads (or :meth:`Table.declare`\\ s) every field it knows before :meth:`Table.finish`, so the
error for a misspelt field lists every known one.

The tracker core's parameter dataclasses (``TrackerConfig``, ``TriggerConfig``) declare their
own rules (``edge_node/core/params.py``); :meth:`Table.built` builds one and turns its
``ConfigError`` into this file's error naming the field. This module lives in ``edge_node``, not
in the core: camera processes read their files with it, the core reads no files.
"""
from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from edge_node.core.params import ConfigError
from edge_node.formats.text import read_text
from protocol.errors import DmttError

T = TypeVar("T")

_REQUIRED = object()


class SettingsError(DmttError, ValueError):
    """A settings file that cannot be used; ``file`` and ``field`` say where (``field`` is None
    when the error is about the whole file or a whole table)."""

    def __init__(self, file: str, field: str | None, message: str):
        self.file = file
        self.field = field
        self.message = message
        super().__init__(f"{file}: {field} {message}" if field else f"{file}: {message}")


def read_toml(path: str | Path, error: type[SettingsError] = SettingsError, *,
              file: str | None = None, what: str = "settings file",
              invalid: str = "not valid TOML") -> dict:
    """Parse a TOML file; a missing, unreadable or malformed file raises ``error`` naming it
    (as ``file``, default the file's name). ``what`` names the kind of file when it is missing,
    ``invalid`` starts the message for bad TOML; bytes that are not UTF-8 name the line and the
    byte offset (``cam0.toml: line 1: not UTF-8 text: byte 0xff at offset 0 ...``)."""
    path = Path(path)
    file = path.name if file is None else file
    try:
        text = read_text(path, lambda e: error(file, None, f"line {e.line}: {e.problem}"))
    except FileNotFoundError:
        raise error(file, None, f"{what} not found: {path}") from None
    except OSError as e:
        raise error(file, None, f"cannot read {path}: {e.strerror or e}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(file, None, f"{invalid} ({e})") from None


class Table:
    """Typed, range-checked access to one TOML table; errors name ``file`` and ``where.key``.

    Every accessor marks its key as known; :meth:`finish` rejects the keys nobody read.
    """

    def __init__(self, data: Any, file: str, where: str = "",
                 error: type[SettingsError] = SettingsError):
        if not isinstance(data, dict):
            raise error(file, where or None, f"must be a table, got {type(data).__name__}")
        self.data = data
        self.file = file
        self.where = where
        self.error_type = error
        self._used: set[str] = set()

    # -- naming and errors -----------------------------------------------------------------
    def name(self, key: str) -> str:
        return f"{self.where}.{key}" if self.where else key

    def error(self, key: str | None, message: str) -> SettingsError:
        """An error about ``key`` of this table, or about the whole table when ``key`` is None."""
        if key:
            return self.error_type(self.file, self.name(key), message)
        return self.error_type(self.file, None, f"{self.where}: {message}" if self.where else message)

    def built(self, make: Callable[[], T], keys: Mapping[str, str] | None = None) -> T:
        """``make()``, a core parameter dataclass built from this table's values (through
        ``edge_node.core.params.build``: ``TrackerConfig.from_dict``, ``for_ablation`` ...);
        its ``ConfigError`` becomes this file's error. ``keys`` maps a dataclass field to the
        key this table spells it with (``{"drift": "drift_m"}``); without it the error keeps
        the field as the core names it (``tracker.tau``)."""
        try:
            return make()
        except ConfigError as e:
            if e.field is None:
                raise self.error_type(self.file, None, e.message) from None
            if keys is None:
                raise self.error_type(self.file, e.field, e.message) from None
            name = e.field.rsplit(".", 1)[-1]
            raise self.error(keys.get(name, name), e.message) from None

    # -- raw access ------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        return key in self.data

    def declare(self, *keys: str) -> None:
        """Mark ``keys`` as known without reading them (fields of another branch: a camera
        given by a homography knows the pose fields too, to list them when one is misspelt)."""
        self._used.update(keys)

    def raw(self, key: str, default: Any = _REQUIRED) -> Any:
        self._used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise self.error(key, "is required")
            return default
        return self.data[key]

    def _absent(self, key: str, default: Any) -> bool:
        """Whether ``key`` is missing and has a default (then it is marked known)."""
        if not self.has(key) and default is not _REQUIRED:
            self._used.add(key)
            return True
        return False

    # -- scalars ---------------------------------------------------------------------------
    def check_number(self, label: str, v: Any, lo: float | None = None, hi: float | None = None,
                     lo_open: bool = False, hi_open: bool = False) -> float:
        """``v`` as a finite float within the bounds; errors name ``label``."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(label, f"must be a number, got {v!r}")
        if not math.isfinite(v):
            raise self.error(label, f"must be finite, got {v!r}")
        bad = (lo is not None and (v <= lo if lo_open else v < lo)) or (
            hi is not None and (v >= hi if hi_open else v > hi))
        if bad:
            if lo is not None and hi is not None:
                rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
                raise self.error(label, f"must be in {rng}, got {v!r}")
            if lo is not None:
                raise self.error(label, f"must be {'>' if lo_open else '>='} {lo:g}, got {v!r}")
            raise self.error(label, f"must be {'<' if hi_open else '<='} {hi:g}, got {v!r}")
        return float(v)

    def number(self, key: str, default: Any = _REQUIRED, *, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, hi_open: bool = False) -> float:
        if self._absent(key, default):
            return default
        return self.check_number(key, self.raw(key), lo, hi, lo_open, hi_open)

    def probability(self, key: str, default: Any = _REQUIRED) -> float:
        if self._absent(key, default):
            return default
        v = self.raw(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
            raise self.error(key, f"must be a probability in [0, 1], got {v!r}")
        return float(v)

    def integer(self, key: str, default: Any = _REQUIRED, *, lo: int | None = None,
                hi: int | None = None) -> int:
        if self._absent(key, default):
            return default
        v = self.raw(key)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            if hi is None:
                raise self.error(key, f"must be >= {lo}, got {v!r}")
            if lo is None:
                raise self.error(key, f"must be <= {hi}, got {v!r}")
            raise self.error(key, f"must be in [{lo}, {hi}], got {v!r}")
        return v

    def _typed(self, key: str, default: Any, kind: type, what: str) -> Any:
        """The value of ``key`` if it is a ``kind`` (``default`` when absent)."""
        if self._absent(key, default):
            return default
        v = self.raw(key)
        if not isinstance(v, kind):
            raise self.error(key, f"must be {what}, got {v!r}")
        return v

    def boolean(self, key: str, default: Any = _REQUIRED) -> bool:
        return self._typed(key, default, bool, "true or false")

    def string(self, key: str, default: Any = _REQUIRED, *,
               choices: tuple[str, ...] | None = None) -> str:
        v = self._typed(key, default, str, "a string")
        if v is not default and choices is not None and v not in choices:
            raise self.error(key, f"must be one of {', '.join(repr(c) for c in choices)}, got {v!r}")
        return v

    def path(self, key: str, base: Path, default: Any = _REQUIRED) -> Path:
        """A non-empty path; a relative one is relative to ``base`` (the file's folder)."""
        if self._absent(key, default):
            return default
        v = self.string(key)
        if not v:
            raise self.error(key, "must be a non-empty path")
        p = Path(v).expanduser()
        return p if p.is_absolute() else (base / p)

    # -- lists -----------------------------------------------------------------------------
    def list(self, key: str, default: Any = _REQUIRED) -> list:
        return self._typed(key, default, list, "a list")

    def vector(self, key: str, n: int, default: Any = _REQUIRED, *, lo: float | None = None,
               lo_open: bool = False) -> np.ndarray:
        if self._absent(key, default):
            return default
        v = self.raw(key)
        if not isinstance(v, list) or len(v) != n:
            raise self.error(key, f"must be a list of {n} numbers, got {v!r}")
        return np.array([self.check_number(f"{key}[{i}]", x, lo, None, lo_open)
                         for i, x in enumerate(v)])

    def span(self, key: str, default: Any = _REQUIRED, *, lo: float = 0.0, lo_open: bool = False,
             hi: float | None = None) -> tuple[float, float]:
        """A range ``[lo, hi]`` (or a single number meaning ``[x, x]``), ``lo <= hi``."""
        if self._absent(key, default):
            return default
        v = self.raw(key)
        if not isinstance(v, list):
            x = self.check_number(key, v, lo, hi, lo_open)
            return (x, x)
        if len(v) != 2:
            raise self.error(key, f"must be a number or a range [lo, hi], got {v!r}")
        a = self.check_number(f"{key}[0]", v[0], lo, hi, lo_open)
        b = self.check_number(f"{key}[1]", v[1], lo, hi, lo_open)
        if a > b:
            raise self.error(key, f"must have lo <= hi, got {v!r}")
        return (a, b)

    def matrix(self, key: str, rows: int, cols: int) -> np.ndarray:
        v = self.raw(key)
        ok = isinstance(v, list) and len(v) == rows and all(
            isinstance(r, list) and len(r) == cols for r in v)
        if not ok:
            raise self.error(key, f"must be a {rows}x{cols} list of lists of numbers, got {v!r}")
        return np.array([[self.check_number(f"{key}[{i}][{j}]", x) for j, x in enumerate(r)]
                         for i, r in enumerate(v)])

    # -- sub-tables ------------------------------------------------------------------------
    def table(self, key: str, *, required: bool = False) -> "Table":
        """The sub-table ``[where.key]``: an empty one when absent (an error if ``required``)."""
        if required and not self.has(key):
            self._used.add(key)
            raise self.error(key, "is required (a [table])")
        return Table(self.raw(key, {}), self.file, self.name(key), self.error_type)

    def optional_table(self, key: str) -> "Table | None":
        """The sub-table ``[where.key]``, or ``None`` when the file has none."""
        self._used.add(key)
        return self.table(key) if self.has(key) else None

    def tables(self, key: str, *, required: bool = True) -> list["Table"]:
        """An array of tables ``[[where.key]]`` (non-empty when ``required``; else may be absent)."""
        v = self.raw(key, _REQUIRED if required else [])
        if not isinstance(v, list) or (required and not v):
            raise self.error(key, "must be a non-empty array of tables ([[...]])" if required
                             else "must be an array of tables ([[...]])")
        return [Table(t, self.file, f"{self.name(key)}[{i}]", self.error_type)
                for i, t in enumerate(v)]

    def finish(self) -> None:
        """Reject the keys nobody read, listing every known one."""
        unknown = sorted(set(self.data) - self._used)
        if unknown:
            raise self.error(unknown[0], f"is not a known field (known: {', '.join(sorted(self._used))})")
