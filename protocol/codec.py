"""Compact msgpack encoding of ``FrameMessage`` with full validation on both sides.

What goes on the wire is the paper's per-frame message (Casao et al., ICRA 2021, Section III-D):
for every active tracker ``(ID_i, x_bar_i, u_i, U_i, ell_i)``, plus the appearance model (the
gallery descriptors) only for a tracker that is new to the sender, plus merge announcements.

Layout (msgpack, positional arrays, no keys)::

    message = [version, network, sender, frame, sent_at, trackers, merges]
    tracker = [camera, counter, born, ell, nums]                 # no appearance
            | [camera, counter, born, ell, nums, appearance]
    nums    = bin: little-endian float32 x_bar (6)                      # u = 0, U = 0
            | bin: little-endian float32 x_bar (6), u (6), triu(U) (21)  # row-major upper triangle
    appearance = [n, D, bin: little-endian float16, n * D values, row-major]
    merge   = [loser_camera, loser_counter, winner_camera, winner_counter, winner_born]

``version``, ``sender``, ``frame``, ``camera``, ``counter``, ``born``, ``ell``, ``n`` and ``D`` are
non-negative integers (at most ``2**63 - 1``); ``sent_at`` is a float64; ``network`` a UTF-8
string that is a valid key chunk (see ``protocol.keys``). A tracker whose ``u`` and ``U`` are all
zero (no local measurement this frame) is sent as ``x_bar`` alone: 24 instead of 132 bytes.

Measured sizes (tests/test_protocol.py): 138 bytes per tracker with a measurement (tracker
counter >= 128), 30 bytes without; 2056 bytes per new tracker's 2 x 512 appearance; about 27
bytes of message header. The paper reports 0.78 kB per tracker and 16.38 kB per appearance.

Quantisation: ``encode`` rounds ``x_bar``, ``u`` and ``U`` to float32 and descriptors to float16;
only the upper triangle of ``U`` is sent (``U`` is assumed symmetric) and ``decode`` rebuilds it
symmetric. ``decode`` returns read-only float64 arrays holding exactly the quantised values, so
``decode(encode(m)) == quantize(m)`` and ``encode(decode(encode(m))) == encode(m)`` byte for byte;
on an already quantised message the round trip is the identity.

``decode`` is the trust boundary: whatever bytes it is given, it either returns a valid
``FrameMessage`` or raises ``ProtocolError`` (never any other exception), with the reason tag
saying why. ``encode`` validates the same rules, so a node never sends what a peer would reject.
"""
from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, fields, replace
from typing import Any

import msgpack
import numpy as np

from protocol.errors import ProtocolError
from protocol.keys import MAX_NETWORK_LEN, is_valid_network
from protocol.messages import (
    MAX_DESCRIPTORS,
    SCHEMA_VERSION,
    STATE_DIM,
    FrameMessage,
    Merge,
    TrackerId,
    TrackerInfo,
)

MAX_WIRE_INT = 2**63 - 1
"""Largest integer (ids, counters, frames, ell) the wire carries; fits a signed 64-bit integer."""

_N = STATE_DIM
_TRIU = np.triu_indices(_N)
_TRIU_T = (_TRIU[1], _TRIU[0])
_N_TRIU = len(_TRIU[0])  # 21
_NUMS_SHORT = _N  # x_bar only
_NUMS_FULL = 2 * _N + _N_TRIU  # x_bar, u, triu(U): 33
_F32 = np.dtype("<f4")
_F16 = np.dtype("<f2")
_MESSAGE_LEN = 7


@dataclass(frozen=True)
class Limits:
    """Bounds a decoder enforces (and an encoder respects) before trusting a message.

    Exceeding a bound raises ``ProtocolError("oversize", ...)``. All bounds are positive ints.
    """

    max_bytes: int = 1 << 20  # whole encoded message
    max_trackers: int = 4096  # trackers in one message
    max_merges: int = 4096  # merge announcements in one message
    max_descriptors: int = MAX_DESCRIPTORS  # descriptors (rows) in one tracker's appearance
    max_descriptor_dim: int = 4096  # descriptor length D
    max_network_len: int = MAX_NETWORK_LEN  # network name, bytes of UTF-8

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
                raise ValueError(f"Limits.{f.name} must be a positive int, got {v!r}")

    @property
    def max_bin_len(self) -> int:
        """Longest binary field: one tracker's appearance, or its numbers."""
        return max(4 * _NUMS_FULL, 2 * self.max_descriptors * self.max_descriptor_dim)

    @property
    def max_array_len(self) -> int:
        """Longest msgpack array: the tracker list, the merge list or the message itself."""
        return max(self.max_trackers, self.max_merges, _MESSAGE_LEN)


DEFAULT_LIMITS = Limits()


# ----------------------------------------------------------------------------------------------
# Shared helpers: the same quantisation serves encode, decode and quantize.


def _err(reason: str, detail: str) -> ProtocolError:
    return ProtocolError(reason, detail)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _arrays_from_wire(
    nums: np.ndarray, app: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """float32 numbers (6 or 33) and float16 ``(n, D)`` descriptors -> read-only float64 arrays."""
    v = nums.astype(np.float64)
    x_bar = _readonly(v[:_N].copy())
    if len(v) == _NUMS_SHORT:
        u = np.zeros(_N)
        U = np.zeros((_N, _N))
    else:
        u = v[_N : 2 * _N].copy()
        tri = v[2 * _N :]
        U = np.zeros((_N, _N))
        U[_TRIU] = tri
        U[_TRIU_T] = tri
    appearance = None if app is None else _readonly(app.astype(np.float64))
    return x_bar, _readonly(u), _readonly(U), appearance


def _as_int(v: Any, what: str) -> int:
    """Encode side: a non-negative int (numpy ints accepted, bools rejected)."""
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
        raise _err("malformed", f"{what} must be an int, got {type(v).__name__}")
    v = int(v)
    if not 0 <= v <= MAX_WIRE_INT:
        raise _err("malformed", f"{what} out of range: {v}")
    return v


def _as_id(tid: Any, what: str) -> TrackerId:
    if not isinstance(tid, tuple) or len(tid) != 2:
        raise _err("malformed", f"{what} must be a (camera, counter) tuple, got {tid!r:.80}")
    return (_as_int(tid[0], f"{what} camera"), _as_int(tid[1], f"{what} counter"))


def _as_float_array(a: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    try:
        arr = np.asarray(a)
    except Exception:  # noqa: BLE001 - ragged / unconvertible input
        raise _err("malformed", f"{what} is not a numeric array") from None
    if arr.dtype.kind not in "fiu":
        raise _err("malformed", f"{what} must be real numbers, got dtype {arr.dtype}")
    if shape is not None and arr.shape != shape:
        raise _err("malformed", f"{what} must have shape {shape}, got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise _err("non_finite", f"{what} has NaN or inf")
    return arr


_WireTracker = tuple[TrackerId, int, int, np.ndarray, np.ndarray | None]


def _tracker_to_wire(t: Any, limits: Limits) -> _WireTracker:
    """Validate one TrackerInfo; return id, born, ell, float32 numbers, float16 descriptors."""
    if not isinstance(t, TrackerInfo):
        raise _err("malformed", f"tracker must be a TrackerInfo, got {type(t).__name__}")
    tid = _as_id(t.id, "tracker id")
    ell = _as_int(t.ell, f"ell of {tid}")
    born = _as_int(t.born, f"born of {tid}")
    x_bar = _as_float_array(t.x_bar, (_N,), f"x_bar of {tid}")
    u = _as_float_array(t.u, (_N,), f"u of {tid}")
    U = _as_float_array(t.U, (_N, _N), f"U of {tid}")
    with np.errstate(over="ignore"):
        nums = np.concatenate([x_bar, u, U[_TRIU]]).astype(_F32)
    if not np.isfinite(nums).all():
        raise _err("non_finite", f"x_bar, u or U of {tid} overflows float32")
    if not nums[_N:].any():  # no measurement information: send x_bar only
        nums = nums[:_N]
    app = None
    if t.appearance is not None:
        a = _as_float_array(t.appearance, None, f"appearance of {tid}")
        if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
            raise _err("malformed", f"appearance of {tid} must be (n, D) with n, D >= 1, got {a.shape}")
        if a.shape[0] > limits.max_descriptors or a.shape[1] > limits.max_descriptor_dim:
            raise _err("oversize", f"appearance of {tid} has shape {a.shape}")
        with np.errstate(over="ignore"):
            app = a.astype(_F16)
        if not np.isfinite(app).all():
            raise _err("non_finite", f"appearance of {tid} overflows float16")
    return tid, born, ell, nums, app


def _validated(msg: Any, limits: Limits) -> tuple[FrameMessage, list[_WireTracker]]:
    """Check a FrameMessage against the wire rules; return it with normalised header fields."""
    if not isinstance(msg, FrameMessage):
        raise _err("malformed", f"expected a FrameMessage, got {type(msg).__name__}")
    version = msg.version
    if isinstance(version, (bool, np.bool_)) or not isinstance(version, (int, np.integer)) \
            or version != SCHEMA_VERSION:
        raise _err("version", f"cannot encode schema version {msg.version!r}")
    network = msg.network
    if (isinstance(network, str) and network.isprintable()
            and len(network.encode("utf-8")) > limits.max_network_len):
        raise _err("oversize", "network name too long")
    if not is_valid_network(network):
        raise _err("malformed", f"invalid network name {network!r:.80}")
    sender = _as_int(msg.sender, "sender")
    frame = _as_int(msg.frame, "frame")
    sent_at = msg.sent_at
    if isinstance(sent_at, (bool, np.bool_)) or not isinstance(sent_at, (int, float, np.integer,
                                                                          np.floating)):
        raise _err("malformed", f"sent_at must be a float, got {type(sent_at).__name__}")
    try:
        sent_at = float(sent_at)
    except OverflowError:  # an int beyond float range
        raise _err("non_finite", "sent_at overflows float64") from None
    if not np.isfinite(sent_at):
        raise _err("non_finite", "sent_at is NaN or inf")
    if sent_at < 0:
        raise _err("malformed", "sent_at is negative")
    if not isinstance(msg.trackers, (tuple, list)) or not isinstance(msg.merges, (tuple, list)):
        raise _err("malformed", "trackers and merges must be sequences")
    if len(msg.trackers) > limits.max_trackers:
        raise _err("oversize", f"{len(msg.trackers)} trackers > {limits.max_trackers}")
    if len(msg.merges) > limits.max_merges:
        raise _err("oversize", f"{len(msg.merges)} merges > {limits.max_merges}")
    wire = [_tracker_to_wire(t, limits) for t in msg.trackers]
    if len({w[0] for w in wire}) != len(wire):
        raise _err("malformed", "duplicate tracker ids")
    merges = []
    for m in msg.merges:
        if not isinstance(m, Merge):
            raise _err("malformed", f"merge must be a Merge, got {type(m).__name__}")
        loser, winner = _as_id(m.loser, "merge loser"), _as_id(m.winner, "merge winner")
        winner_born = _as_int(m.winner_born, "merge winner_born")
        if loser == winner:
            raise _err("malformed", f"merge of {loser} into itself")
        merges.append(Merge(loser, winner, winner_born))
    header = FrameMessage(network=network, sender=sender, frame=frame, merges=tuple(merges),
                          sent_at=sent_at, version=SCHEMA_VERSION)
    return header, wire


# ----------------------------------------------------------------------------------------------
# Public API


def encode(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> bytes:
    """Validate ``msg`` and pack it compactly (see the module docstring for the layout).

    Rounds ``x_bar``, ``u``, ``U`` to float32 and descriptors to float16; sends only the upper
    triangle of ``U``. Raises ``ProtocolError``: ``"non_finite"`` for NaN/inf (also after the
    float32/float16 rounding), ``"oversize"`` beyond ``limits``, ``"version"`` for a version other
    than ``SCHEMA_VERSION``, ``"malformed"`` for anything else a peer would reject.
    """
    header, wire = _validated(msg, limits)
    trackers = []
    for (cam, cnt), born, ell, nums, app in wire:
        t: list[Any] = [cam, cnt, born, ell, nums.tobytes()]
        if app is not None:
            t.append([app.shape[0], app.shape[1], app.tobytes()])
        trackers.append(t)
    merges = [[m.loser[0], m.loser[1], m.winner[0], m.winner[1], m.winner_born]
              for m in header.merges]
    data = msgpack.packb(
        [SCHEMA_VERSION, header.network, header.sender, header.frame, header.sent_at, trackers, merges],
        use_bin_type=True,
    )
    if len(data) > limits.max_bytes:
        raise _err("oversize", f"{len(data)} bytes > {limits.max_bytes}")
    return data


def appearance_bytes(msg: FrameMessage, payload: bytes | None = None) -> int:
    """Bytes the appearance fields add to ``msg``'s encoding (0 without appearance): the
    measured cost of sharing new trackers' descriptors (``payload`` = ``encode(msg)`` if known)."""
    if not any(t.appearance is not None for t in msg.trackers):
        return 0
    payload = encode(msg) if payload is None else payload
    bare = replace(msg, trackers=tuple(replace(t, appearance=None) for t in msg.trackers))
    return len(payload) - len(encode(bare))


def quantize(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> FrameMessage:
    """``msg`` exactly as a peer will see it after ``decode(encode(msg))``, without packing bytes.

    Validates like ``encode`` (same ``ProtocolError``s) except the ``max_bytes`` bound, which
    needs the actual encoding. Useful in simulation to model the wire's float32/float16 rounding.
    """
    header, wire = _validated(msg, limits)
    trackers = []
    for tid, born, ell, nums, app in wire:
        x_bar, u, U, appearance = _arrays_from_wire(nums, app)
        trackers.append(TrackerInfo(tid, x_bar, u, U, ell, appearance, born))
    return FrameMessage(network=header.network, sender=header.sender, frame=header.frame,
                        trackers=tuple(trackers), merges=header.merges, sent_at=header.sent_at,
                        version=SCHEMA_VERSION)


_LIMIT_ERRORS = {"max_array_len": "oversize", "max_str_len": "oversize", "max_bin_len": "oversize"}


def _wire_int(v: Any, what: str) -> int:
    if type(v) is not int or not 0 <= v <= MAX_WIRE_INT:  # bool is not int here
        raise _err("malformed", f"{what} must be an int in [0, 2**63), got {v!r:.40}")
    return v


def _wire_list(v: Any, lengths: tuple[int, ...], what: str) -> list[Any]:
    if type(v) is not list or len(v) not in lengths:
        raise _err("malformed", f"{what} must be an array of length {' or '.join(map(str, lengths))}")
    return v


def _decode_tracker(t: Any, i: int, limits: Limits) -> TrackerInfo:
    t = _wire_list(t, (5, 6), f"tracker {i}")
    tid = (_wire_int(t[0], f"tracker {i} camera"), _wire_int(t[1], f"tracker {i} counter"))
    born = _wire_int(t[2], f"born of {tid}")
    ell = _wire_int(t[3], f"ell of {tid}")
    raw = t[4]
    if type(raw) is not bytes or len(raw) not in (4 * _NUMS_SHORT, 4 * _NUMS_FULL):
        raise _err("malformed", f"numbers of {tid} must be {4 * _NUMS_SHORT} or {4 * _NUMS_FULL} bytes")
    nums = np.frombuffer(raw, dtype=_F32)
    if not np.isfinite(nums).all():
        raise _err("non_finite", f"x_bar, u or U of {tid} has NaN or inf")
    app = None
    if len(t) == 6:
        a = _wire_list(t[5], (3,), f"appearance of {tid}")
        n, d = _wire_int(a[0], f"descriptor count of {tid}"), _wire_int(a[1], f"descriptor dim of {tid}")
        if n < 1 or d < 1:
            raise _err("malformed", f"appearance of {tid} has shape ({n}, {d})")
        if n > limits.max_descriptors or d > limits.max_descriptor_dim:
            raise _err("oversize", f"appearance of {tid} has shape ({n}, {d})")
        if type(a[2]) is not bytes or len(a[2]) != 2 * n * d:
            raise _err("malformed", f"appearance of {tid} must be {2 * n * d} bytes of float16")
        app = np.frombuffer(a[2], dtype=_F16).reshape(n, d)
        if not np.isfinite(app).all():
            raise _err("non_finite", f"appearance of {tid} has NaN or inf")
    x_bar, u, U, appearance = _arrays_from_wire(nums, app)
    return TrackerInfo(tid, x_bar, u, U, ell, appearance, born)


def _decode_obj(
    obj: Any,
    limits: Limits,
    expect_network: str | None,
    expect_sender: int | None,
    allowed_senders: Collection[int] | None,
) -> FrameMessage:
    if type(obj) is not list or not obj or type(obj[0]) is not int:
        raise _err("malformed", "not a message: expected an array starting with the schema version")
    if obj[0] != SCHEMA_VERSION:
        raise _err("version", f"schema version {obj[0]} (we speak {SCHEMA_VERSION})")
    version, network, sender, frame, sent_at, trackers, merges = _wire_list(obj, (_MESSAGE_LEN,), "message")
    if type(network) is not str or not is_valid_network(network):
        raise _err("malformed", f"invalid network name {network!r:.80}")
    if expect_network is not None and network != expect_network:
        raise _err("unknown_network", f"message for network {network!r}, expected {expect_network!r}")
    sender = _wire_int(sender, "sender")
    if expect_sender is not None and allowed_senders is not None and expect_sender not in allowed_senders:
        raise _err("unknown_sender", f"link source {expect_sender} is not a configured neighbour")
    if expect_sender is not None and sender != expect_sender:
        raise _err("forged_source", f"payload sender {sender} on the link of {expect_sender}")
    if allowed_senders is not None and sender not in allowed_senders:
        raise _err("unknown_sender", f"sender {sender} is not a configured neighbour")
    frame = _wire_int(frame, "frame")
    if type(sent_at) is not float:
        raise _err("malformed", f"sent_at must be a float, got {type(sent_at).__name__}")
    if not np.isfinite(sent_at):
        raise _err("non_finite", "sent_at is NaN or inf")
    if sent_at < 0:
        raise _err("malformed", "sent_at is negative")
    if type(trackers) is not list or type(merges) is not list:
        raise _err("malformed", "trackers and merges must be arrays")
    if len(trackers) > limits.max_trackers:
        raise _err("oversize", f"{len(trackers)} trackers > {limits.max_trackers}")
    if len(merges) > limits.max_merges:
        raise _err("oversize", f"{len(merges)} merges > {limits.max_merges}")
    infos = tuple(_decode_tracker(t, i, limits) for i, t in enumerate(trackers))
    if len({t.id for t in infos}) != len(infos):
        raise _err("malformed", "duplicate tracker ids")
    out_merges = []
    for i, m in enumerate(merges):
        m = _wire_list(m, (5,), f"merge {i}")
        loser = (_wire_int(m[0], f"merge {i}"), _wire_int(m[1], f"merge {i}"))
        winner = (_wire_int(m[2], f"merge {i}"), _wire_int(m[3], f"merge {i}"))
        if loser == winner:
            raise _err("malformed", f"merge of {loser} into itself")
        out_merges.append(Merge(loser, winner, _wire_int(m[4], f"merge {i} winner_born")))
    return FrameMessage(network=network, sender=sender, frame=frame, trackers=infos,
                        merges=tuple(out_merges), sent_at=sent_at, version=version)


def _peek_version(data: bytes) -> int | None:
    """The leading version of a message we cannot parse (a future layout may not parse at all)."""
    try:
        unpacker = msgpack.Unpacker(max_buffer_size=max(len(data), 1), max_str_len=0, max_bin_len=0,
                                    max_array_len=0, max_map_len=0, max_ext_len=0)
        unpacker.feed(data)
        if unpacker.read_array_header() < 1:
            return None
        version = unpacker.unpack()
    except Exception:  # noqa: BLE001 - not even the header parses
        return None
    return version if type(version) is int else None


def decode(
    data: bytes,
    *,
    limits: Limits = DEFAULT_LIMITS,
    expect_network: str | None = None,
    expect_sender: int | None = None,
    allowed_senders: Collection[int] | None = None,
) -> FrameMessage:
    """Parse and validate one message; raise ``ProtocolError`` (and nothing else) if unacceptable.

    ``expect_network``: the network this node belongs to (else ``"unknown_network"``).
    ``expect_sender``: the source node named by the key expression the bytes arrived on; the
    payload's sender must equal it (else ``"forged_source"``).
    ``allowed_senders``: the configured neighbours; the sender, and ``expect_sender`` when
    given, must be among them (else ``"unknown_sender"``).
    Other reasons: ``"malformed"`` (not msgpack, trailing bytes, wrong structure, types, shapes,
    negative or bool integers, duplicate tracker ids, self-merges), ``"version"``,
    ``"non_finite"`` (NaN/inf in any number, descriptors and ``sent_at`` included),
    ``"oversize"`` (beyond ``limits``).
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise _err("malformed", f"expected bytes, got {type(data).__name__}")
    if isinstance(data, memoryview):
        try:
            data = data.tobytes()
        except Exception:  # noqa: BLE001 - e.g. a released buffer
            raise _err("malformed", "unreadable buffer") from None
    if len(data) > limits.max_bytes:
        raise _err("oversize", f"{len(data)} bytes > {limits.max_bytes}")
    try:
        obj = msgpack.unpackb(
            data,
            raw=False,
            use_list=True,
            strict_map_key=True,
            max_str_len=limits.max_network_len,
            max_bin_len=limits.max_bin_len,
            max_array_len=limits.max_array_len,
            max_map_len=0,
            max_ext_len=0,
        )
    except Exception as e:  # noqa: BLE001 - msgpack raises many types for bad input
        version = _peek_version(data)
        if version is not None and version != SCHEMA_VERSION:
            raise _err("version", f"schema version {version} (we speak {SCHEMA_VERSION})") from None
        text = str(e)
        for limit, reason in _LIMIT_ERRORS.items():
            if limit in text:
                raise _err(reason, f"msgpack: {text[:120]}") from None
        raise _err("malformed", f"not a msgpack message: {type(e).__name__}: {text[:120]}") from None
    try:
        return _decode_obj(obj, limits, expect_network, expect_sender, allowed_senders)
    except ProtocolError:
        raise
    except Exception as e:  # noqa: BLE001 - safety net: nothing a peer sends may escape as another type
        raise _err("malformed", f"internal: {type(e).__name__}: {str(e)[:120]}") from None
