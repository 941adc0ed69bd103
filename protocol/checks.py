"""Scalar and array rules of the wire contract, shared by the message types and the codec.

Each helper returns the normalised value or raises ``ProtocolError`` with the reason a peer
would give: ``"malformed"`` for wrong types, shapes and ranges, ``"non_finite"`` for NaN/inf.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from protocol.errors import ProtocolError

MAX_WIRE_INT = 2**63 - 1
"""Largest integer (ids, counters, frames, ell) the wire carries; fits a signed 64-bit integer."""

TrackerId = tuple[int, int]


def err(reason: str, detail: str) -> ProtocolError:
    return ProtocolError(reason, detail)


def as_int(v: Any, what: str) -> int:
    """A non-negative int up to ``MAX_WIRE_INT`` (numpy ints accepted, bools rejected)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise err("malformed", f"{what} must be an int, got {type(v).__name__}")
    v = int(v)
    if not 0 <= v <= MAX_WIRE_INT:
        raise err("malformed", f"{what} out of range: {v}")
    return v


def as_id(tid: Any, what: str) -> TrackerId:
    """A ``(camera, counter)`` tuple of two ``as_int`` values."""
    if not isinstance(tid, tuple) or len(tid) != 2:
        raise err("malformed", f"{what} must be a (camera, counter) tuple, got {tid!r:.80}")
    return (as_int(tid[0], f"{what} camera"), as_int(tid[1], f"{what} counter"))


def as_float_array(a: Any, shape: tuple[int, ...] | None, what: str, *, finite: bool = True) -> np.ndarray:
    """``a`` as a float64 array of real numbers (of ``shape`` if given; finite if ``finite``)."""
    try:
        arr = np.asarray(a)
    except Exception:  # noqa: BLE001 - ragged / unconvertible input
        raise err("malformed", f"{what} is not a numeric array") from None
    if arr.dtype.kind not in "fiu":
        raise err("malformed", f"{what} must be real numbers, got dtype {arr.dtype}")
    if shape is not None and arr.shape != shape:
        raise err("malformed", f"{what} must have shape {shape}, got {arr.shape}")
    arr = arr.astype(np.float64)
    if finite and not np.isfinite(arr).all():
        raise err("non_finite", f"{what} has NaN or inf")
    return arr


def as_appearance(a: Any, what: str) -> np.ndarray:
    """An ``(n, D)`` float64 descriptor array with ``n, D >= 1`` (finiteness is the codec's)."""
    arr = as_float_array(a, None, what, finite=False)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise err("malformed", f"{what} must be (n, D) with n, D >= 1, got {arr.shape}")
    return arr
