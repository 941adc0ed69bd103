"""Compact encoding of ``FrameMessage`` in one pass, with full validation on both sides.

What goes on the wire is the paper's per-frame message (Casao et al., ICRA 2021, Section III-D):
for every active tracker ``(ID_i, x_bar_i, u_i, U_i, ell_i)``, plus the appearance model (the
gallery descriptors) only for a tracker that is new to the sender, plus merge announcements.

Layout, schema version 2: a msgpack header with every tracker's numbers in one binary block::

    message    = [version, network, sender, frame, sent_at, n, widths, merges, appearances, block]
    merge      = [loser_camera, loser_counter, winner_camera, winner_counter, winner_born]
    appearance = [row, m, D]                 # rows strictly increasing, row < n
    block      = bin, little-endian, sections back to back:
        camera  (n)  counter (n)  born (n)  ell (n)      unsigned ints of 1, 2, 4 or 8 bytes
        measured     ceil(n / 8) bytes, bit i (LSB first) set when row i carries u, U
        x_bar        (n, 6) float32
        u, triu(U)   (m, 6 + 21) float32, the measured rows in row order (row-major upper triangle)
        descriptors  (m_j, D_j) float16 per appearance entry, in order, row-major

``n`` is the number of trackers and ``m`` the number of set bits. ``widths`` holds each integer
column's byte width as a 2-bit code (``2**code`` bytes), camera in bits 0-1, counter 2-3, born
4-5, ell 6-7; the encoder picks the narrowest width that holds the column's largest value, and
the decoder accepts only that, so the tracker block has exactly one encoding (the msgpack
header is not checked for its canonical form: a peer may pack a small int wider or
``sent_at`` as float32, and ``encode(decode(b))`` is then shorter than ``b``). ``version``,
``sender``, ``frame``, ``n``, the ids, ``born``, ``ell``, ``m`` and ``D`` are non-negative
integers (at most ``2**63 - 1``); ``sent_at`` is a float64; ``network`` a UTF-8 string that is
a valid key chunk (see ``protocol.keys``). A tracker whose ``u`` and ``U`` are all zero (no local
measurement this frame) sends ``x_bar`` alone: 24 instead of 132 bytes of numbers.

The decoder reads each section with one ``numpy.frombuffer`` and validates every rule over the
whole block at once (finite numbers, widths, unique ids), so its cost hardly grows per tracker.
Version 1 (one msgpack array per tracker) is refused with reason ``"version"``.

Measured sizes (tests/test_protocol.py): per tracker 4-6 bytes of ids, birth frame and ``ell``
(1 byte each below 256, 2 below 65536), 1 bit of the measured mask, 24 bytes of ``x_bar``
and 108 of ``u, U`` when measured: 136-138 bytes with a measurement, 28-30 without (version 1:
139-143 and 31-35); 2054 bytes per new tracker's 2 x 512 appearance; about 31 bytes of message
header. The paper reports 0.78 kB per tracker and 16.38 kB per appearance.

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

import math
from collections.abc import Collection
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from typing import Any

import msgpack
import numpy as np

from protocol.checks import MAX_WIRE_INT, as_int, err
from protocol.errors import ProtocolError
from protocol.keys import MAX_NETWORK_LEN, is_valid_network
from protocol.messages import (
    MAX_DESCRIPTORS,
    SCHEMA_VERSION,
    STATE_DIM,
    FrameMessage,
    Merge,
    TrackerBlock,
)

__all__ = ["DEFAULT_LIMITS", "MAX_WIRE_INT", "Limits", "appearance_bytes", "decode", "encode", "quantize"]

_N = STATE_DIM
_TRIU = np.triu_indices(_N)
_TRIU_FLAT = _TRIU[0] * _N + _TRIU[1]  # the upper triangle's places in a row-major (6, 6)
_N_TRIU = len(_TRIU_FLAT)  # 21
_N_INFO = _N + _N_TRIU  # u, triu(U): 27 numbers of a measured row
# a row's (u, triu U) -> U flattened, symmetric: U[i, j] = triu[min(i, j), max(i, j)]
_tri_pos = {(int(i), int(j)): k for k, (i, j) in enumerate(zip(*_TRIU))}
_SYM = np.array([_N + _tri_pos[min(i, j), max(i, j)] for i in range(_N) for j in range(_N)])
_F32 = np.dtype("<f4")
_F16 = np.dtype("<f2")
_INT_DTYPES = (np.dtype("<u1"), np.dtype("<u2"), np.dtype("<u4"), np.dtype("<i8"))
_INT_LIMITS = (0xFF, 0xFFFF, 0xFFFF_FFFF)  # largest value of width codes 0, 1, 2
_COLUMNS = ("camera", "counter", "born", "ell")
_MESSAGE_LEN = 10


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
        """Longest binary field: the tracker block, at most the whole message."""
        return self.max_bytes

    @property
    def max_array_len(self) -> int:
        """Longest msgpack array: the merge or appearance list, or the message itself."""
        return max(self.max_trackers, self.max_merges, _MESSAGE_LEN)


DEFAULT_LIMITS = Limits()


# ----------------------------------------------------------------------------------------------
# Shared helpers: the same quantisation serves encode, decode and quantize.


def _width_code(v: int) -> int:
    """The narrowest integer width (as a 2-bit code) that holds ``v >= 0``."""
    return 0 if v <= 0xFF else 1 if v <= 0xFFFF else 2 if v <= 0xFFFF_FFFF else 3


@lru_cache(maxsize=256)
def _widths(widths: int) -> tuple[tuple[np.dtype, ...], int]:
    """Column dtypes of a ``widths`` byte and the bytes of one row's four integers."""
    dts = tuple(_INT_DTYPES[(widths >> (2 * k)) & 3] for k in range(4))
    return dts, sum(d.itemsize for d in dts)


_known_networks: set[str] = set()  # names is_valid_network accepted (a pure check, so cached)


def _network_ok(network: Any) -> bool:
    if network in _known_networks if type(network) is str else False:
        return True
    if not is_valid_network(network):
        return False
    if len(_known_networks) >= 256:
        _known_networks.clear()
    _known_networks.add(network)
    return True


def _assemble(ints: np.ndarray, floats: np.ndarray, measured: np.ndarray | None, m: int,
              appearance: tuple[tuple[int, np.ndarray], ...]) -> TrackerBlock:
    """The block of validated wire values: ``ints`` (4, n) int64, ``floats`` float64 holding
    ``x_bar`` (n, 6) then the measured rows' ``u, triu(U)`` (m, 27), ``measured`` the rows
    (``None`` when ``m`` is 0 or ``n``)."""
    n = ints.shape[1]
    ints.setflags(write=False)
    floats.setflags(write=False)
    x_bar = floats[: _N * n].reshape(n, _N)
    if m == n:
        info = floats[_N * n :].reshape(n, _N_INFO)
    else:
        info = np.zeros((n, _N_INFO))
        if m:
            info[measured] = floats[_N * n :].reshape(m, _N_INFO)
        info.setflags(write=False)
    U = info.take(_SYM, axis=1).reshape(n, _N, _N)
    U.setflags(write=False)
    return TrackerBlock._trusted(ints[0], ints[1], ints[2], ints[3], x_bar, info[:, :_N], U, appearance)


def _first(bad: np.ndarray) -> int:
    """The first row a (n,) or (n, ...) boolean array flags."""
    return int(np.flatnonzero(bad.reshape(len(bad), -1).any(axis=1))[0])


# ----------------------------------------------------------------------------------------------
# Encode side


def _checked_header(msg: Any, limits: Limits) -> tuple[str, int, int, float, tuple[Merge, ...]]:
    """Check a FrameMessage's header against the wire rules; return it normalised."""
    if not isinstance(msg, FrameMessage):
        raise err("malformed", f"expected a FrameMessage, got {type(msg).__name__}")
    version = msg.version
    if isinstance(version, (bool, np.bool_)) or not isinstance(version, (int, np.integer)) \
            or version != SCHEMA_VERSION:
        raise err("version", f"cannot encode schema version {msg.version!r:.40} (we speak {SCHEMA_VERSION})")
    network = msg.network
    if (isinstance(network, str) and network.isprintable()
            and len(network.encode("utf-8")) > limits.max_network_len):
        raise err("oversize", "network name too long")
    if not _network_ok(network):
        raise err("malformed", f"invalid network name {network!r:.80}")
    sender = as_int(msg.sender, "sender")
    frame = as_int(msg.frame, "frame")
    sent_at = msg.sent_at
    if type(sent_at) is not float:
        if isinstance(sent_at, (bool, np.bool_)) or not isinstance(sent_at, (int, float, np.integer,
                                                                              np.floating)):
            raise err("malformed", f"sent_at must be a float, got {type(sent_at).__name__}")
        try:
            sent_at = float(sent_at)
        except OverflowError:  # an int beyond float range
            raise err("non_finite", "sent_at overflows float64") from None
    if not math.isfinite(sent_at):
        raise err("non_finite", "sent_at is NaN or inf")
    if sent_at < 0:
        raise err("malformed", "sent_at is negative")
    if not isinstance(msg.merges, (tuple, list)):
        raise err("malformed", "merges must be a sequence")
    if len(msg.merges) > limits.max_merges:
        raise err("oversize", f"{len(msg.merges)} merges > {limits.max_merges}")
    merges = []
    for mg in msg.merges:
        if not isinstance(mg, Merge):
            raise err("malformed", f"merge must be a Merge, got {type(mg).__name__}")
        loser, winner = _as_id(mg.loser, "merge loser"), _as_id(mg.winner, "merge winner")
        winner_born = as_int(mg.winner_born, "merge winner_born")
        if loser == winner:
            raise err("malformed", f"merge of {loser} into itself")
        merges.append(Merge(loser, winner, winner_born))
    return network, sender, frame, sent_at, tuple(merges)


def _as_id(tid: Any, what: str) -> tuple[int, int]:
    if not isinstance(tid, tuple) or len(tid) != 2:
        raise err("malformed", f"{what} must be a (camera, counter) tuple, got {tid!r:.80}")
    return (as_int(tid[0], f"{what} camera"), as_int(tid[1], f"{what} counter"))


@dataclass(frozen=True)
class _Wire:
    """A block's validated wire values."""

    widths: int
    ints: np.ndarray  # (4, n) int64
    nums: np.ndarray  # (n, 33) float32: x_bar, u, triu(U)
    measured: np.ndarray  # (n,) bool
    m: int
    appearance: tuple[tuple[int, np.ndarray], ...]  # (row, float16 (m, D))


def _checked_block(msg: FrameMessage, limits: Limits) -> _Wire:
    """Validate the message's trackers over the whole block at once; quantise them."""
    if msg._infos is not None and not isinstance(msg._infos, (tuple, list)):
        raise err("malformed", "trackers must be a sequence")
    n = len(msg._block) if msg._block is not None else len(msg._infos)  # type: ignore[arg-type]
    if n > limits.max_trackers:
        raise err("oversize", f"{n} trackers > {limits.max_trackers}")
    b = msg.block
    ints = np.empty((4, n), np.int64)
    for k, name in enumerate(_COLUMNS):
        ints[k] = getattr(b, name)
    nums = np.empty((n, _N + _N_INFO), _F32)
    with np.errstate(over="ignore", invalid="ignore"):
        nums[:, :_N] = b.x_bar
        nums[:, _N : 2 * _N] = b.u
        nums[:, 2 * _N :] = b.U.reshape(n, _N * _N)[:, _TRIU_FLAT]
        # float32 values cannot overflow a float64 sum; U's is finite unless an entry is NaN or
        # inf (or beyond float32's range, which its upper triangle would overflow to anyway)
        finite = math.isfinite(nums.sum(dtype=np.float64)) and math.isfinite(b.U.sum())
    if not n:
        return _Wire(0, ints, nums, np.zeros(0, bool), 0, ())
    if ints.min() < 0:
        i = _first((ints < 0).T)
        raise err("malformed", f"id, born or ell of row {i} is negative: {ints[:, i].tolist()}")
    if not finite:
        bad = ~np.isfinite(nums).all(axis=1) | ~np.isfinite(b.U).reshape(n, -1).all(axis=1)
        where = f"row {_row_id(ints, _first(bad))}" if bad.any() else "the block (U sums beyond float64)"
        raise err("non_finite", f"x_bar, u or U of {where} has NaN or inf (or overflows float32)")
    maxes = ints.max(axis=1).tolist()
    widths = sum(_width_code(v) << (2 * k) for k, v in enumerate(maxes))
    if len(set(zip(ints[0].tolist(), ints[1].tolist()))) != n:
        raise err("malformed", "duplicate tracker ids")
    measured = nums[:, _N:].any(axis=1)
    apps = []
    for row, a in b.appearance:
        if a.shape[0] > limits.max_descriptors or a.shape[1] > limits.max_descriptor_dim:
            raise err("oversize", f"appearance of {_row_id(ints, row)} has shape {a.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            a16 = a.astype(_F16)
        if not np.isfinite(a16).all():
            raise err("non_finite", f"appearance of {_row_id(ints, row)} has NaN or inf "
                                    "(or overflows float16)")
        apps.append((row, a16))
    return _Wire(widths, ints, nums, measured, int(np.count_nonzero(measured)), tuple(apps))


def _row_id(ints: np.ndarray, i: int) -> tuple[int, int]:
    return (int(ints[0, i]), int(ints[1, i]))


# ----------------------------------------------------------------------------------------------
# Public API


def encode(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> bytes:
    """Validate ``msg`` and pack it compactly (see the module docstring for the layout).

    Rounds ``x_bar``, ``u``, ``U`` to float32 and descriptors to float16; sends only the upper
    triangle of ``U``. Raises ``ProtocolError``: ``"non_finite"`` for NaN/inf (also after the
    float32/float16 rounding), ``"oversize"`` beyond ``limits``, ``"version"`` for a version other
    than ``SCHEMA_VERSION``, ``"malformed"`` for anything else a peer would reject.
    """
    network, sender, frame, sent_at, merges = _checked_header(msg, limits)
    w = _checked_block(msg, limits)
    n = w.ints.shape[1]
    dts, _ = _widths(w.widths)
    parts = [w.ints[k].astype(dts[k]).tobytes() for k in range(4)]
    parts.append(np.packbits(w.measured, bitorder="little").tobytes())
    parts.append(w.nums[:, :_N].tobytes())
    parts.append((w.nums[:, _N:] if w.m == n else w.nums[w.measured, _N:]).tobytes())
    parts.extend(a.tobytes() for _, a in w.appearance)
    data = msgpack.packb(
        [SCHEMA_VERSION, network, sender, frame, sent_at, n, w.widths,
         [[mg.loser[0], mg.loser[1], mg.winner[0], mg.winner[1], mg.winner_born] for mg in merges],
         [[row, a.shape[0], a.shape[1]] for row, a in w.appearance], b"".join(parts)],
        use_bin_type=True,
    )
    if len(data) > limits.max_bytes:
        raise err("oversize", f"{len(data)} bytes > {limits.max_bytes}")
    return data


def appearance_bytes(msg: FrameMessage, payload: bytes | None = None) -> int:
    """Bytes the appearance fields add to ``msg``'s encoding (0 without appearance): the
    measured cost of sharing new trackers' descriptors (``payload`` = ``encode(msg)`` if known)."""
    if not msg.block.appearance:
        return 0
    payload = encode(msg) if payload is None else payload
    bare = replace(msg, block=replace(msg.block, appearance=()))
    return len(payload) - len(encode(bare))


def quantize(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> FrameMessage:
    """``msg`` exactly as a peer will see it after ``decode(encode(msg))``, without packing bytes.

    Validates like ``encode`` (same ``ProtocolError``s) except the ``max_bytes`` bound, which
    needs the actual encoding. Useful in simulation to model the wire's float32/float16 rounding.
    """
    network, sender, frame, sent_at, merges = _checked_header(msg, limits)
    w = _checked_block(msg, limits)
    n = w.ints.shape[1]
    info = w.nums[:, _N:] if w.m == n else w.nums[w.measured, _N:]
    floats = np.concatenate((w.nums[:, :_N].ravel(), info.ravel())).astype(np.float64)
    apps = tuple((row, _readonly(a.astype(np.float64))) for row, a in w.appearance)
    block = _assemble(w.ints, floats, w.measured if 0 < w.m < n else None, w.m, apps)
    return FrameMessage(network, sender, frame, merges=merges, sent_at=sent_at, block=block)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# ----------------------------------------------------------------------------------------------
# Decode side


_LIMIT_ERRORS = {"max_array_len": "oversize", "max_str_len": "oversize", "max_bin_len": "oversize"}


def _wire_int(v: Any, what: str) -> int:
    if type(v) is not int or not 0 <= v <= MAX_WIRE_INT:  # bool is not int here
        raise err("malformed", f"{what} must be an int in [0, 2**63), got {v!r:.40}")
    return v


def _wire_list(v: Any, lengths: tuple[int, ...], what: str) -> list[Any]:
    if type(v) is not list or len(v) not in lengths:
        raise err("malformed", f"{what} must be an array of length {' or '.join(map(str, lengths))}")
    return v


def _decode_appearances(apps: Any, n: int, limits: Limits) -> list[tuple[int, int, int]]:
    if type(apps) is not list:
        raise err("malformed", "appearances must be an array")
    if len(apps) > n:
        raise err("malformed", f"{len(apps)} appearances for {n} trackers")
    out = []
    last = -1
    for j, a in enumerate(apps):
        a = _wire_list(a, (3,), f"appearance {j}")
        row = _wire_int(a[0], f"appearance {j} row")
        cnt, dim = _wire_int(a[1], f"appearance {j} count"), _wire_int(a[2], f"appearance {j} dim")
        if not last < row < n:
            raise err("malformed", f"appearance {j}: row {row} out of order or beyond {n} rows")
        if cnt < 1 or dim < 1:
            raise err("malformed", f"appearance {j} has shape ({cnt}, {dim})")
        if cnt > limits.max_descriptors or dim > limits.max_descriptor_dim:
            raise err("oversize", f"appearance {j} has shape ({cnt}, {dim})")
        out.append((row, cnt, dim))
        last = row
    return out


def _decode_block(blob: Any, n: int, widths: Any, apps: list[tuple[int, int, int]]) -> TrackerBlock:
    """The tracker block of ``n`` rows: a few ``frombuffer`` and whole-block checks."""
    if type(blob) is not bytes:
        raise err("malformed", "the tracker block must be bin")
    if type(widths) is not int or not 0 <= widths <= 0xFF:
        raise err("malformed", f"widths must be an int in [0, 255], got {widths!r:.40}")
    dts, row_bytes = _widths(widths)
    at = n * row_bytes  # the measured mask
    nb = (n + 7) >> 3
    if len(blob) < at + nb:
        raise err("malformed", f"tracker block of {len(blob)} bytes is too short for {n} rows")
    mask = int.from_bytes(blob[at : at + nb], "little")
    if mask >> n:
        raise err("malformed", "measured mask has bits beyond the last row")
    m = mask.bit_count()
    at += nb
    n_floats = _N * n + _N_INFO * m
    expected = at + 4 * n_floats + 2 * sum(c * d for _, c, d in apps)
    if len(blob) != expected:
        raise err("malformed", f"tracker block of {len(blob)} bytes, expected {expected}")
    if n == 0:
        if widths:
            raise err("malformed", "widths of an empty block must be 0")
        return TrackerBlock.empty()
    ints = np.empty((4, n), np.int64)
    o = 0
    for k in range(4):
        ints[k] = np.frombuffer(blob, dts[k], n, o)
        o += n * dts[k].itemsize
    if widths >= 0xC0 or widths & 0x30 == 0x30 or widths & 0x0C == 0x0C or widths & 3 == 3:
        if ints.min() < 0:
            raise err("malformed", f"id, born or ell of row {_first((ints < 0).T)} exceeds 2**63 - 1")
    maxes = ints.max(axis=1).tolist()
    if sum(_width_code(v) << (2 * k) for k, v in enumerate(maxes)) != widths:
        raise err("malformed", f"widths {widths:#04x} are not the narrowest for {maxes}")
    with np.errstate(invalid="ignore"):  # a signalling NaN warns when cast; it is caught below
        floats = np.frombuffer(blob, _F32, n_floats, at).astype(np.float64)
    if not math.isfinite(floats.sum()):  # float32 values: the float64 sum cannot overflow
        bad = ~np.isfinite(floats)
        i = int(np.flatnonzero(bad)[0])
        row = i // _N if i < _N * n else int(np.flatnonzero(_bits(mask, n))[(i - _N * n) // _N_INFO])
        raise err("non_finite", f"x_bar, u or U of {_row_id(ints, row)} has NaN or inf")
    if len(set(zip(ints[0].tolist(), ints[1].tolist()))) != n:
        raise err("malformed", "duplicate tracker ids")
    measured = None
    if m:
        if np.count_nonzero(floats[_N * n :].reshape(m, _N_INFO).any(axis=1)) != m:
            raise err("malformed", "a row marked measured has u = 0 and U = 0")
        if m < n:
            measured = _bits(mask, n)
    at += 4 * n_floats
    appearance = []
    for row, c, d in apps:
        a = np.frombuffer(blob, _F16, c * d, at).reshape(c, d)
        if not np.isfinite(a).all():
            raise err("non_finite", f"appearance of {_row_id(ints, row)} has NaN or inf")
        appearance.append((row, _readonly(a.astype(np.float64))))
        at += 2 * c * d
    return _assemble(ints, floats, measured, m, tuple(appearance))


def _bits(mask: int, n: int) -> np.ndarray:
    """The rows set in ``mask`` as an (n,) bool array."""
    raw = np.frombuffer(mask.to_bytes((n + 7) >> 3, "little"), np.uint8)
    return np.unpackbits(raw, count=n, bitorder="little").view(bool)


def _decode_obj(
    obj: Any,
    limits: Limits,
    expect_network: str | None,
    expect_sender: int | None,
    allowed_senders: Collection[int] | None,
) -> FrameMessage:
    if type(obj) is not list or not obj or type(obj[0]) is not int:
        raise err("malformed", "not a message: expected an array starting with the schema version")
    if obj[0] != SCHEMA_VERSION:
        raise err("version", f"schema version {obj[0]} (we speak {SCHEMA_VERSION})")
    _, network, sender, frame, sent_at, n, widths, merges, apps, blob = _wire_list(
        obj, (_MESSAGE_LEN,), "message")
    if type(network) is not str or not _network_ok(network):
        raise err("malformed", f"invalid network name {network!r:.80}")
    if expect_network is not None and network != expect_network:
        raise err("unknown_network", f"message for network {network!r}, expected {expect_network!r}")
    sender = _wire_int(sender, "sender")
    if expect_sender is not None and allowed_senders is not None and expect_sender not in allowed_senders:
        raise err("unknown_sender", f"link source {expect_sender} is not a configured neighbour")
    if expect_sender is not None and sender != expect_sender:
        raise err("forged_source", f"payload sender {sender} on the link of {expect_sender}")
    if allowed_senders is not None and sender not in allowed_senders:
        raise err("unknown_sender", f"sender {sender} is not a configured neighbour")
    frame = _wire_int(frame, "frame")
    if type(sent_at) is not float:
        raise err("malformed", f"sent_at must be a float, got {type(sent_at).__name__}")
    if not math.isfinite(sent_at):
        raise err("non_finite", "sent_at is NaN or inf")
    if sent_at < 0:
        raise err("malformed", "sent_at is negative")
    n = _wire_int(n, "tracker count")
    if n > limits.max_trackers:
        raise err("oversize", f"{n} trackers > {limits.max_trackers}")
    if type(merges) is not list:
        raise err("malformed", "merges must be an array")
    if len(merges) > limits.max_merges:
        raise err("oversize", f"{len(merges)} merges > {limits.max_merges}")
    block = _decode_block(blob, n, widths, _decode_appearances(apps, n, limits))
    out_merges = []
    for i, mg in enumerate(merges):
        mg = _wire_list(mg, (5,), f"merge {i}")
        loser = (_wire_int(mg[0], f"merge {i}"), _wire_int(mg[1], f"merge {i}"))
        winner = (_wire_int(mg[2], f"merge {i}"), _wire_int(mg[3], f"merge {i}"))
        if loser == winner:
            raise err("malformed", f"merge of {loser} into itself")
        out_merges.append(Merge(loser, winner, _wire_int(mg[4], f"merge {i} winner_born")))
    return FrameMessage(network, sender, frame, merges=tuple(out_merges), sent_at=sent_at, block=block)


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
    Other reasons: ``"malformed"`` (not msgpack, trailing bytes, wrong structure, types, block
    length or widths, negative or bool integers, duplicate tracker ids, self-merges),
    ``"version"`` (any schema version but ``SCHEMA_VERSION``, 1 included), ``"non_finite"``
    (NaN/inf in any number, descriptors and ``sent_at`` included), ``"oversize"`` (beyond
    ``limits``).
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise err("malformed", f"expected bytes, got {type(data).__name__}")
    if isinstance(data, memoryview):
        try:
            data = data.tobytes()
        except Exception:  # noqa: BLE001 - e.g. a released buffer
            raise err("malformed", "unreadable buffer") from None
    if len(data) > limits.max_bytes:
        raise err("oversize", f"{len(data)} bytes > {limits.max_bytes}")
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
            raise err("version", f"schema version {version} (we speak {SCHEMA_VERSION})") from None
        text = str(e)
        for limit, reason in _LIMIT_ERRORS.items():
            if limit in text:
                raise err(reason, f"msgpack: {text[:120]}") from None
        raise err("malformed", f"not a msgpack message: {type(e).__name__}: {text[:120]}") from None
    try:
        return _decode_obj(obj, limits, expect_network, expect_sender, allowed_senders)
    except ProtocolError:
        raise
    except Exception as e:  # noqa: BLE001 - safety net: nothing a peer sends may escape as another type
        raise err("malformed", f"internal: {type(e).__name__}: {str(e)[:120]}") from None
