"""Compact encoding of ``FrameMessage`` in one pass, with full validation on both sides.

What goes on the wire is the paper's per-frame message (Casao et al., ICRA 2021, Section III-D):
for every active tracker ``(ID_i, x_bar_i, u_i, U_i, ell_i)``, plus the appearance model (the
gallery descriptors) only for a tracker that is new to the sender, plus merge announcements.

Layout, schema version 3: a msgpack header with every tracker's numbers in one binary block::

    message    = [version, network, sender, frame, sent_at, n, widths, merges, appearances, block]
    merge      = [loser_camera, loser_counter, winner_camera, winner_counter, winner_born]
    appearance = [row, m, D]                 # rows strictly increasing, row < n
    block      = bin, little-endian, sections back to back:
        camera  (n)  counter (n)  born (n)  ell (n)      unsigned ints of 1, 2, 4 or 8 bytes
        measured     ceil(n / 8) bytes, bit i (LSB first) set when row i carries u, U
        x_bar        (n, 6) float32
        scale        (m,) float32                        s, per measured row
        measurement  (m, 10 + 4) float16                 tril(L / s) row-major, then w
        per appearance entry: (m_j,) float32 scales, then (m_j, D_j) int8 descriptors

``n`` is the number of trackers and ``m`` the number of set bits. ``widths`` holds each integer
column's byte width as a 2-bit code (``2**code`` bytes), camera in bits 0-1, counter 2-3, born
4-5, ell 6-7; the encoder picks the narrowest width that holds the column's largest value, and
the decoder accepts only that. ``version``, ``sender``, ``frame``, ``n``, the ids, ``born``,
``ell``, ``m`` and ``D`` are non-negative integers (at most ``2**63 - 1``); ``sent_at`` is a
float64; ``network`` a UTF-8 string that is a valid key chunk (see ``protocol.keys``).

What a measurement carries (eq. 2): ``H`` picks ``(x, y, w, h)``, so ``u = H^T R^-1 z`` and
``U = H^T R^-1 H`` are zero outside their first 4 rows and columns (13 of the 27 numbers of
``u, triu(U)`` always zero). The wire sends the 14 that are not, in a form that is exact in
structure and whose float16 rounding is bounded in units of the measurement's own noise:

* ``R^-1 = U_zz = L L^T`` (Cholesky): ``s`` = the largest diagonal element of ``L`` (float32)
  and the 10 numbers of ``tril(L / s)`` (float16, each within a relative 2**-11, or 2**-25
  absolute below float16's normal range). The receiver's ``U~ = L~ L~^T``, ``L~ = s tril~``,
  is positive definite by construction; its standard deviations are those sent to about 0.05 %.
* ``w = L~^T (z - H x_bar)``, ``z = U_zz^-1 u_z``: the innovation against the sent ``x_bar``,
  whitened by the factor the receiver rebuilds (float16). The receiver's
  ``z~ = H x_bar + L~^-T w~`` then misses ``z`` by ``e`` with ``e^T U~ e = |w~ - w|^2 <=
  2**-22 |w|^2``: **the error, in standard deviations of the measurement noise, is at most
  2**-11 (0.05 %) of the innovation's own length in those units** (an innovation of 10 sigma
  arrives within 0.005 sigma). ``u~ = U~ z~ = U~ H x_bar + L~ w~``.

A tracker whose ``u`` and ``U`` are all zero (no local measurement this frame) sends ``x_bar``
alone. A ``u, U`` outside that form (information on velocity, ``U_zz`` not positive definite)
is not a camera measurement and is refused (``"malformed"``); an innovation beyond float16's
range (65504 standard deviations) is ``"non_finite"``.

Descriptors travel as int8 with a float32 scale each (``a ~ q * s``, ``s = max |a| / 127``):
a cosine distance moves by 2e-4 (median) to 1.6e-3 (largest seen) against float64, and re-id
rank-1 on the synthetic appearance model is unchanged (tests/test_protocol.py measures both).

The decoder reads each section with one ``numpy.frombuffer`` and validates every rule over the
whole block at once (finite numbers, positive factors, widths, unique ids), so its cost hardly
grows per tracker. Versions 1 and 2 are refused with reason ``"version"``.

Measured sizes (tests/test_protocol.py): per tracker 4-6 bytes of ids, birth frame and ``ell``
(1 byte each below 256, 2 below 65536), 1 bit of the measured mask, 24 bytes of ``x_bar``,
and 32 bytes with a measurement: 60-62 bytes with a measurement, 28-30 without (version 2:
136-138 and 28-30); 1039 bytes per new tracker's 2 x 512 appearance (version 2: 2054); about
31 bytes of message header. The paper reports 0.78 kB per tracker and 16.38 kB per appearance.

Quantisation: ``encode`` rounds ``x_bar`` to float32 and the rest as above. ``decode`` returns
read-only float64 arrays holding exactly what the wire values give, and keeps those wire
values with the block, so ``decode(encode(m)) == quantize(m)`` and ``encode(decode(b)) == b``
byte for byte for the tracker block (the msgpack header is not checked for its canonical
form: a peer may pack a small int wider or ``sent_at`` as float32, and ``encode(decode(b))`` is
then shorter than ``b``).

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
    VELOCITY_PLACES,
    FrameMessage,
    Merge,
    TrackerBlock,
)

__all__ = ["DEFAULT_LIMITS", "MAX_WIRE_INT", "Limits", "appearance_bytes", "decode", "encode", "quantize"]

_N = STATE_DIM
_Z = 4  # the measured part of the state, (x, y, w, h): rows and columns of U that can be non-zero
_TRIL = np.tril_indices(_Z)  # a Cholesky factor's lower triangle, row-major: 10 numbers
_N_TRIL = len(_TRIL[0])
_TRIL_FLAT = _TRIL[0] * _Z + _TRIL[1]  # its places in the flattened 4 x 4 factor
_DIAG = np.array([i * (i + 1) // 2 + i for i in range(_Z)])  # the diagonal's places in it
# each element of a 4 x 4 factor, row-major: its place in the triangle, or _N_TRIL (a zero)
_SQUARE = np.array([i * (i + 1) // 2 + k if k <= i else _N_TRIL for i in range(_Z) for k in range(_Z)])
_N_INFO = _N_TRIL + _Z  # float16 numbers of a measured row: tril(L / s), then w
_F32 = np.dtype("<f4")
_F16 = np.dtype("<f2")
_I8 = np.dtype("i1")
_INT_DTYPES = (np.dtype("<u1"), np.dtype("<u2"), np.dtype("<u4"), np.dtype("<i8"))
_COLUMNS = ("camera", "counter", "born", "ell")
_MESSAGE_LEN = 10
_F32_MAX = float(np.finfo(np.float32).max)
_F16_LIMIT = 65520.0  # the smallest magnitude float16 rounds to inf
_Q8 = 127  # descriptors travel as int8 in [-127, 127] times a per-descriptor scale


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


def _width_codes(maxes: list[int]) -> int:
    """The ``widths`` byte of four columns whose largest values (``>= 0``) are ``maxes``: for
    each, the narrowest width that holds it, as a 2-bit code."""
    code = 0
    for shift, v in zip((0, 2, 4, 6), maxes):
        code |= (0 if v <= 0xFF else 1 if v <= 0xFFFF else 2 if v <= 0xFFFF_FFFF else 3) << shift
    return code


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


@dataclass(frozen=True)
class _Wire:
    """A block's values exactly as they travel (validated). Decoded blocks keep theirs, so a
    relayed or re-encoded message gives the same bytes without recomputing the factors."""

    widths: int
    ints: np.ndarray  # (4, n) int64: camera, counter, born, ell
    x_bar: np.ndarray  # (n, 6) float32
    measured: np.ndarray  # (n,) bool
    scale: np.ndarray  # (m,) float32: s, the largest diagonal element of L
    info: np.ndarray  # (m, 14) float16: tril(L / s) row-major, then w = (s L~)^T (z - H x_bar)
    appearance: tuple[tuple[int, np.ndarray, np.ndarray], ...]  # (row, (m_j,) float32, (m_j, D) int8)


def _factor(scale: np.ndarray, tril: np.ndarray) -> np.ndarray:
    """``L = s * tril`` as (m, 4, 4) float64 lower-triangular matrices (products exact: 11 by
    24 significant bits), ``tril`` given as float64: the products in a row with a zero after
    them, read out in the matrix's order."""
    t = np.zeros((len(scale), _N_TRIL + 1))
    np.multiply(tril, scale.astype(np.float64)[:, None], out=t[:, :_N_TRIL])
    return t.take(_SQUARE, axis=1).reshape(-1, _Z, _Z)


def _information(w: _Wire, x_bar: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """Eq. 2's ``u, U`` (n, 6) and (n, 6, 6) from the wire (``x_bar`` its float64 values):
    ``U = L L^T`` and ``u = U z = L (L^T H x_bar + w)`` (from ``z = H x_bar + L^-T w``); zero
    for unmeasured rows. ``L @ L^T`` of one array with its own transpose is BLAS's ``syrk`` in
    NumPy's matmul, which computes one triangle and copies it: ``U`` is exactly symmetric.
    Also the factor they were built from (``TrackerBlock.measurement_factor``, with the
    measured mask): ``L`` and ``v = L^T H x_bar + w`` (so ``u_z = L v``)."""
    n, m = len(w.measured), len(w.scale)
    u, U = np.zeros((n, _N)), np.zeros((n, _N, _N))
    if not m:
        return u, U, (np.zeros((0, _Z, _Z)), np.zeros((0, _Z)))
    info = w.info.astype(np.float64)
    L = _factor(w.scale, info[:, :_N_TRIL])
    rows = slice(None) if m == n else w.measured.nonzero()[0]
    U[rows, :_Z, :_Z] = L @ L.transpose(0, 2, 1)
    xz = x_bar[:, None, :_Z] if m == n else x_bar[:, :_Z].take(rows, axis=0)[:, None]  # (take: cheaper)
    v = (xz @ L)[:, 0]  # (L^T H x_bar)^T
    v += info[:, _N_TRIL:]
    u[rows, :_Z] = (L @ v[:, :, None])[:, :, 0]
    return u, U, (L, v)


def _assemble(w: _Wire) -> TrackerBlock:
    """The block a peer reads from wire values ``w`` (read-only float64), keeping ``w`` and the
    measurements' factor."""
    x_bar = w.x_bar.astype(np.float64)
    u, U, (L, v) = _information(w, x_bar)
    for a in (w.ints, x_bar, u, U, w.measured, L, v):
        a.setflags(write=False)
    apps = tuple((row, _readonly(q.astype(np.float64) * s.astype(np.float64)[:, None]))
                 for row, s, q in w.appearance)
    block = TrackerBlock._trusted(w.ints[0], w.ints[1], w.ints[2], w.ints[3], x_bar, u, U, apps)
    block.__dict__["_wire"] = w
    block.__dict__["_factor"] = (w.measured, L, v)
    return block


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


def _checked_block(msg: FrameMessage, limits: Limits) -> _Wire:
    """Validate the message's trackers over the whole block at once; quantise them."""
    if msg._infos is not None and not isinstance(msg._infos, (tuple, list)):
        raise err("malformed", "trackers must be a sequence")
    n = len(msg._block) if msg._block is not None else len(msg._infos)  # type: ignore[arg-type]
    if n > limits.max_trackers:
        raise err("oversize", f"{n} trackers > {limits.max_trackers}")
    b = msg.block
    cached = b.__dict__.get("_wire")
    if cached is not None:  # decoded (or quantised) here: its wire values are known and valid
        for row, _, q in cached.appearance:
            if q.shape[0] > limits.max_descriptors or q.shape[1] > limits.max_descriptor_dim:
                raise err("oversize", f"appearance of {_row_id(cached.ints, row)} has shape {q.shape}")
        return cached
    ints = np.empty((4, n), np.int64)
    for k, name in enumerate(_COLUMNS):
        ints[k] = getattr(b, name)
    with np.errstate(over="ignore", invalid="ignore"):
        x_bar = b.x_bar.astype(_F32)
        finite = math.isfinite(x_bar.sum(dtype=np.float64)) and math.isfinite(b.u.sum()) \
            and math.isfinite(b.U.sum())
    if not n:
        return _Wire(0, ints, x_bar, np.zeros(0, bool), np.zeros(0, _F32), np.zeros((0, _N_INFO), _F16), ())
    if ints.min() < 0:
        i = _first((ints < 0).T)
        raise err("malformed", f"id, born or ell of row {i} is negative: {ints[:, i].tolist()}")
    if not finite:
        bad = ~np.isfinite(x_bar).all(axis=1) | ~np.isfinite(b.u).all(axis=1) \
            | ~np.isfinite(b.U).reshape(n, -1).all(axis=1)
        where = f"row {_row_id(ints, _first(bad))}" if bad.any() else "the block (sums beyond float64)"
        raise err("non_finite", f"x_bar, u or U of {where} has NaN or inf (or overflows float32)")
    maxes = ints.max(axis=1).tolist()
    widths = _width_codes(maxes)
    if len(set(zip(ints[0].tolist(), ints[1].tolist()))) != n:
        raise err("malformed", "duplicate tracker ids")
    measured = b.U.reshape(n, -1).any(axis=1) | b.u.any(axis=1)
    rows = measured.nonzero()[0]
    if len(rows) == n:  # every row measured: no gathering
        scale, info = _measurement_wire(b.u, b.U, x_bar, ints[:2])
    else:
        scale, info = _measurement_wire(b.u.take(rows, axis=0), b.U.take(rows, axis=0),
                                        x_bar.take(rows, axis=0), ints[:2].take(rows, axis=1))
    apps = []
    for row, a in b.appearance:
        if a.shape[0] > limits.max_descriptors or a.shape[1] > limits.max_descriptor_dim:
            raise err("oversize", f"appearance of {_row_id(ints, row)} has shape {a.shape}")
        apps.append((row, *_descriptor_wire(a, _row_id(ints, row))))
    return _Wire(widths, ints, x_bar, measured, scale, info, tuple(apps))


def _measurement_wire(u: np.ndarray, U: np.ndarray, x_bar: np.ndarray, ids: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The measured rows' information on the wire: ``s`` (float32) and ``tril(L / s), w``
    (float16), where ``U_zz = L L^T`` (Cholesky, ``U_zz`` the (x, y, w, h) block) and ``w`` is
    the innovation ``z - H x_bar`` whitened by the quantised factor, ``z = U_zz^-1 u_z``.
    ``ids`` (2, m) names the rows in errors."""
    m = len(u)
    if not m:
        return np.zeros(0, _F32), np.zeros((0, _N_INFO), _F16)
    if U.reshape(m, _N * _N).take(VELOCITY_PLACES, axis=1).any() or u[:, _Z:].any():
        beyond = U[:, _Z:].reshape(m, -1).any(axis=1) | U[:, :_Z, _Z:].reshape(m, -1).any(axis=1) \
            | u[:, _Z:].any(axis=1)
        raise err("malformed", f"u, U of {_row_id(ids, _first(beyond))} carry velocity information: a "
                               "measurement informs (x, y, w, h) only")
    U4 = U[:, :_Z, :_Z]
    try:
        L = np.linalg.cholesky(U4)
    except np.linalg.LinAlgError:
        bad = next(i for i in range(m) if not _positive_definite(U4[i]))
        raise err("malformed", f"U of {_row_id(ids, bad)} is not positive definite on (x, y, w, h)") from None
    flat = L.reshape(m, _Z * _Z)
    peak = flat[:, :: _Z + 1].max(axis=1)  # the diagonal
    if not peak.max() <= _F32_MAX:
        raise err("non_finite", f"U of {_row_id(ids, _first(~(peak <= _F32_MAX)))} overflows float32")
    scale = peak.astype(_F32)
    if not scale.min() > 0:
        raise err("malformed", f"U of {_row_id(ids, _first(~(scale > 0)))} is below float32's range")
    tril = (flat.take(_TRIL_FLAT, axis=1) / scale.astype(np.float64)[:, None]).astype(_F16)  # <= 1
    if not tril.take(_DIAG, axis=1).min() > 0:
        bad = _first(~(tril[:, _DIAG] > 0))
        raise err("malformed", f"U of {_row_id(ids, bad)} is too ill-conditioned for float16 factors")
    z = np.linalg.solve(U4, u[:, :_Z, None])[..., 0]
    L_sent = _factor(scale, tril.astype(np.float64))  # the factor the receiver rebuilds
    w = ((z - x_bar[:, :_Z])[:, None, :] @ L_sent)[:, 0]  # L~^T (z - H x_bar)
    if not np.abs(w).max() < _F16_LIMIT:  # beyond it float16 rounds to inf (NaN fails too)
        raise err("non_finite", f"the innovation of {_row_id(ids, _first(~(np.abs(w) < _F16_LIMIT)))} is "
                                "beyond float16 (65504 standard deviations)")
    return scale, np.concatenate((tril, w.astype(_F16)), axis=1)


def _positive_definite(M: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return False
    return True


def _descriptor_wire(a: np.ndarray, tid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors ``a`` (m, D) as int8 ``q`` in [-127, 127] and a float32 scale per descriptor
    (``a ~ q * s``, ``s = max |a| / 127``)."""
    peak = np.abs(a).max(axis=1) / _Q8
    if not peak.max() <= _F32_MAX:  # NaN fails too
        raise err("non_finite", f"appearance of {tid} has NaN or inf (or overflows float32)")
    scale = peak.astype(_F32)
    s = scale.astype(np.float64)[:, None]
    if s.min() > 0:
        q = np.rint(a / s).clip(-_Q8, _Q8).astype(_I8)
    else:  # a descriptor of zeros (or below float32's range) travels as zeros
        q = np.zeros(a.shape, _I8)
        nz = scale > 0
        q[nz] = np.rint(a[nz] / s[nz]).clip(-_Q8, _Q8)
    return scale, q


def _row_id(ints: np.ndarray, i: int) -> tuple[int, int]:
    return (int(ints[0, i]), int(ints[1, i]))


# ----------------------------------------------------------------------------------------------
# Public API


def encode(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> bytes:
    """Validate ``msg`` and pack it compactly (see the module docstring for the layout).

    Rounds ``x_bar`` to float32, sends the measurement as a float16 factor and whitened
    innovation and descriptors as int8 (module docstring). Raises ``ProtocolError``:
    ``"non_finite"`` for NaN/inf (also after the rounding), ``"oversize"`` beyond ``limits``, ``"version"`` for a version other
    than ``SCHEMA_VERSION``, ``"malformed"`` for anything else a peer would reject.
    """
    network, sender, frame, sent_at, merges = _checked_header(msg, limits)
    w = _checked_block(msg, limits)
    dts, _ = _widths(w.widths)
    parts = [w.ints[k].astype(dts[k]).tobytes() for k in range(4)]
    parts.append(np.packbits(w.measured, bitorder="little").tobytes())
    parts += [w.x_bar.tobytes(), w.scale.tobytes(), w.info.tobytes()]
    for _, scale, q in w.appearance:
        parts += [scale.tobytes(), q.tobytes()]
    n = w.ints.shape[1]
    data = msgpack.packb(
        [SCHEMA_VERSION, network, sender, frame, sent_at, n, w.widths,
         [[mg.loser[0], mg.loser[1], mg.winner[0], mg.winner[1], mg.winner_born] for mg in merges],
         [[row, q.shape[0], q.shape[1]] for row, _, q in w.appearance], b"".join(parts)],
        use_bin_type=True,
    )
    if len(data) > limits.max_bytes:
        raise err("oversize", f"{len(data)} bytes > {limits.max_bytes}")
    return data


def encoded_size(msg: FrameMessage, *, limits: Limits = DEFAULT_LIMITS) -> int:
    """``len(encode(msg))`` for a message ``encode`` accepts, without quantising it: the
    block's layout (rows, integer widths, measured rows, descriptor shapes) fixes its length.
    For counters (the bytes an event-triggered node did not send); a few microseconds where
    ``encode`` takes tens."""
    network, sender, frame, sent_at, merges = _checked_header(msg, limits)
    b = msg.block
    n = len(b)
    widths, m = 0, 0
    if n:
        widths = _width_codes([int(getattr(b, name).max()) for name in _COLUMNS])
        m = int(np.count_nonzero(b.U.reshape(n, -1).any(axis=1) | b.u.any(axis=1)))
    apps = [[row, a.shape[0], a.shape[1]] for row, a in b.appearance]
    blob = (n * _widths(widths)[1] + ((n + 7) >> 3) + 4 * _N * n + (4 + 2 * _N_INFO) * m
            + sum(c * (4 + d) for _, c, d in apps))
    head = msgpack.packb(
        [SCHEMA_VERSION, network, sender, frame, sent_at, n, widths,
         [[mg.loser[0], mg.loser[1], mg.winner[0], mg.winner[1], mg.winner_born] for mg in merges],
         apps, b""], use_bin_type=True)
    return len(head) - 2 + (2 if blob < 0x100 else 3 if blob < 0x10000 else 5) + blob


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
    needs the actual encoding. Useful in simulation to model the wire's rounding.
    """
    network, sender, frame, sent_at, merges = _checked_header(msg, limits)
    block = _assemble(_checked_block(msg, limits))
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
    expected = at + 4 * _N * n + (4 + 2 * _N_INFO) * m + sum(c * (4 + d) for _, c, d in apps)
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
    if _width_codes(maxes) != widths:
        raise err("malformed", f"widths {widths:#04x} are not the narrowest for {maxes}")
    floats = np.frombuffer(blob, _F32, _N * n + m, at)  # x_bar, then the scales
    x_bar, scale = floats[: _N * n].reshape(n, _N), floats[_N * n :]
    at += 4 * (_N * n + m)
    info = np.frombuffer(blob, _F16, _N_INFO * m, at).reshape(m, _N_INFO)
    at += 2 * _N_INFO * m
    measured = np.ones(n, bool) if m == n else _bits(mask, n)
    # isfinite reads NaN (signalling ones too) without casting them, so without a warning
    if (np.count_nonzero(np.isfinite(floats)) != floats.size
            or np.count_nonzero(np.isfinite(info)) != info.size):
        bad_x = ~np.isfinite(x_bar).all(axis=1)
        bad_info = ~(np.isfinite(info).all(axis=1) & np.isfinite(scale))
        row = _first(bad_x) if bad_x.any() else int(np.flatnonzero(measured)[_first(bad_info)])
        raise err("non_finite", f"x_bar or measurement of {_row_id(ints, row)} has NaN or inf")
    if len(set(zip(ints[0].tolist(), ints[1].tolist()))) != n:
        raise err("malformed", "duplicate tracker ids")
    if m and not (scale.min() > 0 and info.take(_DIAG, axis=1).min() > 0):
        row = int(np.flatnonzero(measured)[_first(~((scale > 0) & (info[:, _DIAG] > 0).all(axis=1)))])
        raise err("malformed", f"measurement of {_row_id(ints, row)} has a factor that is not positive")
    appearance = []
    for row, c, d in apps:
        s = np.frombuffer(blob, _F32, c, at)
        q = np.frombuffer(blob, _I8, c * d, at + 4 * c).reshape(c, d)
        scales = s.tolist()
        if not all(0.0 <= v <= _F32_MAX for v in scales):  # NaN fails both comparisons
            raise err("non_finite" if not all(math.isfinite(v) for v in scales) else "malformed",
                      f"appearance of {_row_id(ints, row)} has a scale that is NaN, inf or negative")
        if q.min() == -_Q8 - 1:
            raise err("malformed", f"appearance of {_row_id(ints, row)} has -128 (int8 range is +-127)")
        appearance.append((row, s, q))
        at += c * (4 + d)
    return _assemble(_Wire(widths, ints, x_bar, measured, scale, info, tuple(appearance)))


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
