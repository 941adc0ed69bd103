"""Declared parameters: each field of a config dataclass carries its own rule, one check for all.

A config (``TrackerConfig``, ``TriggerConfig``) declares its fields with :func:`number`,
:func:`integer`, :func:`boolean` or :func:`pair`; ``check(self)`` in ``__post_init__`` applies
the rules and raises :class:`ConfigError` naming the field. The TOML reader
(``edge_node.settings``) builds these dataclasses from files and adds the file name; the rules
are written once, here, beside the fields.
"""
from __future__ import annotations

import math
from dataclasses import Field, dataclass, field, fields
from typing import Any

from protocol.errors import DmttError


class ConfigError(DmttError, ValueError):
    """A parameter that is out of range, of the wrong type or unknown.

    ``field`` is the parameter's name as written in a file (``tracker.tau``), or ``None`` when
    the error is about the whole table; the message names it too.
    """

    def __init__(self, field: str | None, message: str):
        self.field = field
        self.message = message
        super().__init__(f"{field} {message}" if field else message)


@dataclass(frozen=True)
class Rule:
    kind: str  # "number" | "integer" | "boolean" | "pair"
    lo: float | None = None
    lo_open: bool = False
    hi: float | None = None
    optional: bool = False  # None is allowed

    def problem(self, v: Any) -> str | None:
        """What is wrong with ``v``, or ``None``."""
        if v is None and self.optional:
            return None
        if self.kind == "boolean":
            return None if isinstance(v, bool) else f"must be true or false, got {v!r}"
        if self.kind == "pair":
            if not (isinstance(v, (tuple, list)) and len(v) == 2):
                return f"must be two numbers, got {v!r}"
            bad = [self._number(x) for x in v]
            return next((b for b in bad if b), None)
        if self.kind == "integer" and (isinstance(v, bool) or not isinstance(v, int)):
            return f"must be {self.describe()}, got {v!r}"
        return self._number(v)

    def _number(self, v: Any) -> str | None:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return f"must be {self.describe()}, got {v!r}"
        if not math.isfinite(v):
            return f"must be finite, got {v!r}"
        low = self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo)
        high = self.hi is not None and v > self.hi
        return f"must be {self.describe()}, got {v!r}" if (low or high) else None

    def _range(self) -> str:
        if self.lo is None and self.hi is None:
            return ""
        if self.lo is not None and self.hi is not None:
            return f" in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"
        if self.lo is not None:
            return f" {'>' if self.lo_open else '>='} {self.lo:g}"
        return f" <= {self.hi:g}"

    def describe(self) -> str:
        """``a positive number``, ``an integer >= 1``, ... (what the error messages say)."""
        if self.kind == "number" and self.lo == 0 and self.hi is None:
            return "a positive number" if self.lo_open else "a non-negative number"
        return {"integer": "an integer", "boolean": "true or false"}.get(self.kind, "a number") \
            + self._range()


def _declare(default: Any, rule: Rule, doc: str) -> Any:
    return field(default=default, metadata={"rule": rule, "doc": doc})


def number(default: float | None, *, lo: float | None = None, lo_open: bool = False,
           hi: float | None = None, optional: bool = False, doc: str = "") -> Any:
    """A real parameter in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    return _declare(default, Rule("number", lo, lo_open, hi, optional), doc)


def positive(default: float, doc: str = "") -> Any:
    return number(default, lo=0.0, lo_open=True, doc=doc)


def nonnegative(default: float, doc: str = "") -> Any:
    return number(default, lo=0.0, doc=doc)


def integer(default: int, *, lo: int | None = None, hi: int | None = None, doc: str = "") -> Any:
    return _declare(default, Rule("integer", lo, False, hi), doc)


def boolean(default: bool, doc: str = "") -> Any:
    return _declare(default, Rule("boolean"), doc)


def pair(default: tuple[float, float] | None, *, lo: float | None = None, lo_open: bool = False,
         optional: bool = False, doc: str = "") -> Any:
    """Two numbers, each in the range (e.g. ``(sigma_xy, sigma_wh)``); ``None`` if optional."""
    return _declare(default, Rule("pair", lo, lo_open, None, optional), doc)


def declared(cls: type) -> list[Field]:
    """The fields of ``cls`` that carry a rule (the parameters a file may set)."""
    return [f for f in fields(cls) if "rule" in f.metadata]


def check(obj: Any, section: str) -> None:
    """Apply every field's rule to ``obj``; the first failure raises ``ConfigError`` naming
    ``section.field``."""
    for f in declared(type(obj)):
        problem = f.metadata["rule"].problem(getattr(obj, f.name))
        if problem:
            raise ConfigError(f"{section}.{f.name}", problem)


def build(cls: type, values: dict, section: str) -> Any:
    """``cls(**values)`` for a dataclass with declared fields; unknown names raise
    ``ConfigError`` listing every known one (a misspelt field is named with what it could be)."""
    known = [f.name for f in fields(cls) if f.init]
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ConfigError(None, f"{section}: unknown parameter(s) {', '.join(unknown)} "
                          f"(known: {', '.join(known)})")
    values = dict(values)
    for f in declared(cls):  # lists from TOML become the tuples the dataclass holds
        if f.metadata["rule"].kind == "pair" and isinstance(values.get(f.name), list):
            values[f.name] = tuple(values[f.name])
    return cls(**values)

