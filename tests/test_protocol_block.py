"""Schema 3: the tracker block, its two forms in a message, and whole-block validation."""
from __future__ import annotations

import dataclasses
import struct

import msgpack
import numpy as np
import pytest

from protocol import (
    SCHEMA_VERSION,
    FrameMessage,
    Merge,
    ProtocolError,
    TrackerBlock,
    TrackerInfo,
    decode,
    encode,
    quantize,
)


def infos(n: int, seed: int = 0, measured_every: int = 3) -> tuple[TrackerInfo, ...]:
    """``n`` trackers; every ``measured_every``-th has no measurement; rows 0 and 7 carry appearance."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        measured = i % measured_every != 1
        app = rng.normal(size=(2, 16)) if i in (0, 7) else None
        x_bar = rng.normal(size=6) * 20
        a = rng.normal(size=(4, 4)) * 0.3
        R = a @ a.T + 0.01 * np.eye(4)  # a camera's measurement noise (eq. 2: H picks x, y, w, h)
        u, U = np.zeros(6), np.zeros((6, 6))
        if measured:
            U[:4, :4] = np.linalg.inv(R)
            u[:4] = U[:4, :4] @ (x_bar[:4] + rng.normal(size=4) * 0.3)
        out.append(TrackerInfo((i % 5, 300 + 7 * i), x_bar, u, U, i % 4, app, 1000 + i))
    return tuple(out)


def message(n: int, **kw) -> FrameMessage:
    return FrameMessage("terrace", 2, 4321, infos(n, **kw), (Merge((1, 3), (0, 2), 5),), sent_at=1.7e9)


def block_of(ts: tuple[TrackerInfo, ...], **change) -> TrackerBlock:
    cols = dict(camera=[t.id[0] for t in ts], counter=[t.id[1] for t in ts],
                born=[t.born for t in ts], ell=[t.ell for t in ts],
                x_bar=np.array([t.x_bar for t in ts]).reshape(-1, 6),
                u=np.array([t.u for t in ts]).reshape(-1, 6),
                U=np.array([t.U for t in ts]).reshape(-1, 6, 6),
                appearance=tuple((i, t.appearance) for i, t in enumerate(ts) if t.appearance is not None))
    cols.update(change)
    return TrackerBlock(**cols)


# ------------------------------------------------------------------------------------------------
# Round trips at 0, 1 and 50 trackers, both forms


@pytest.mark.parametrize("n", [0, 1, 50])
def test_round_trip_both_forms(n: int) -> None:
    m = message(n)
    data = encode(m)
    q = quantize(m)
    got = decode(data)
    assert got == q and len(got.trackers) == n and len(got.block) == n
    assert encode(got) == data and encode(q) == data
    by_block = FrameMessage.from_block(m.network, m.sender, m.frame, block_of(m.trackers),
                                       m.merges, m.sent_at)
    assert by_block == m and m == by_block
    assert encode(by_block) == data
    assert decode(encode(got)) == got
    for t, u in zip(got.trackers, q.trackers):
        assert t == u and np.array_equal(t.U, t.U.T)


def test_block_arrays_are_read_only_float64_and_int64() -> None:
    b = decode(encode(message(20))).block
    for name in ("camera", "counter", "born", "ell"):
        a = getattr(b, name)
        assert a.dtype == np.int64 and a.shape == (20,) and not a.flags.writeable
    for name, shape in (("x_bar", (20, 6)), ("u", (20, 6)), ("U", (20, 6, 6))):
        a = getattr(b, name)
        assert a.dtype == np.float64 and a.shape == shape and not a.flags.writeable
    assert [row for row, _ in b.appearance] == [0, 7]
    assert all(a.dtype == np.float64 and not a.flags.writeable for _, a in b.appearance)
    mine = np.arange(6.0)
    built = block_of(infos(1), x_bar=mine[None])
    mine[0] = 99.0  # the block copied it
    assert built.x_bar[0, 0] == 0.0 and not built.x_bar.flags.writeable


def test_trackers_view_is_built_once_and_matches_the_block() -> None:
    got = decode(encode(message(12)))
    ts = got.trackers
    assert got.trackers is ts
    b = got.block
    for i, t in enumerate(ts):
        assert t.id == (b.camera[i], b.counter[i]) and t.born == b.born[i] and t.ell == b.ell[i]
        assert np.array_equal(t.U, b.U[i]) and type(t.ell) is int and type(t.id[0]) is int
    assert ts[7].appearance is dict(b.appearance)[7] and ts[1].appearance is None
    assert not ts[1].u.any() and not ts[1].U.any()  # the row without a measurement


def test_replace_keeps_its_meaning() -> None:
    got = decode(encode(message(6)))
    later = dataclasses.replace(got, sent_at=2.0e9)
    assert later.block is got.block and later.sent_at == 2.0e9 and later.frame == got.frame
    fewer = dataclasses.replace(got, trackers=got.trackers[:2])
    assert len(fewer.block) == 2 and fewer.trackers == got.trackers[:2]
    assert encode(fewer) == encode(FrameMessage("terrace", 2, 4321, got.trackers[:2], got.merges,
                                                sent_at=1.7e9))
    swapped = dataclasses.replace(fewer, block=got.block)
    assert swapped == got
    with pytest.raises(TypeError):
        FrameMessage("n", 0, 0, got.trackers, block=got.block)


def test_take_selects_rows_and_renumbers_their_appearance() -> None:
    ts = infos(12)  # rows 0 and 7 carry appearance
    b = block_of(ts)
    kept = [2, 5, 7, 11]
    sub = b.take(kept)
    assert sub == block_of(tuple(ts[i] for i in kept))  # row 7 is row 2 of the selection
    assert [r for r, _ in sub.appearance] == [2]
    assert sub.ids() == [ts[i].id for i in kept]
    assert b.take(range(12)) is b
    assert all(b.info(i) == ts[i] for i in range(12))
    assert not sub.x_bar.flags.writeable and not sub.camera.flags.writeable


def test_ids_are_the_rows_ids_in_a_new_list_each_time() -> None:
    ts = infos(12)
    for b in (block_of(ts), decode(encode(FrameMessage("n", 0, 3, ts))).block):
        first = b.ids()
        assert first == [t.id for t in ts]
        first.append((99, 99))  # the caller's list: the block's ids stay
        assert b.ids() == [t.id for t in ts] and b.ids() is not b.ids()


def test_equality_compares_rows() -> None:
    a, b = decode(encode(message(5))), decode(encode(message(5)))
    assert a == b
    assert a != decode(encode(message(5, seed=1)))
    assert a != dataclasses.replace(b, trackers=b.trackers[:4])
    assert a != dataclasses.replace(b, frame=4322)
    t = b.trackers[3]
    assert a != dataclasses.replace(b, trackers=b.trackers[:3] + (dataclasses.replace(t, ell=t.ell + 1),)
                                    + b.trackers[4:])
    assert FrameMessage("n", 0, 0) == FrameMessage("n", 0, 0, ())


def test_block_construction_checks_shapes_and_types() -> None:
    ts = infos(3)
    for change in (dict(x_bar=np.zeros((3, 5))), dict(U=np.zeros((3, 36))), dict(camera=[0, 1]),
                   dict(ell=[0.5, 1.0, 2.0]), dict(born=[True, False, True]),
                   dict(counter=np.array([2**64 - 1, 0, 1], np.uint64)),
                   dict(appearance=((5, np.ones((1, 4))),)), dict(appearance=((1, np.ones(4)),)),
                   dict(appearance=((1, np.ones((1, 4))), (0, np.ones((1, 4)))))):
        with pytest.raises(ProtocolError) as e:
            block_of(ts, **change)
        assert e.value.reason == "malformed", change


# ------------------------------------------------------------------------------------------------
# Version 1 is refused


def v1_bytes() -> bytes:
    """A message as schema 1 sent it: one msgpack array per tracker."""
    nums = struct.pack("<33f", *range(33))
    return msgpack.packb([1, "net", 1, 42, 1.7e9, [[1, 100, 0, 0, nums], [1, 101, 0, 2, nums[:24]]],
                          [[2, 5, 1, 100, 0]]], use_bin_type=True)


def test_version_1_bytes_are_refused_with_the_reason() -> None:
    with pytest.raises(ProtocolError) as e:
        decode(v1_bytes())
    assert e.value.reason == "version"
    assert "schema version 1" in str(e.value) and f"we speak {SCHEMA_VERSION}" in str(e.value)
    assert SCHEMA_VERSION == 3


def test_version_1_messages_are_not_encoded() -> None:
    with pytest.raises(ProtocolError) as e:
        encode(FrameMessage("n", 0, 0, version=1))
    assert e.value.reason == "version" and "1" in e.value.detail


# ------------------------------------------------------------------------------------------------
# Whole-block validation finds one bad row among many


def _refused(m: FrameMessage) -> ProtocolError:
    for fn in (encode, quantize):
        with pytest.raises(ProtocolError) as e:
            fn(m)
    return e.value


ONE_BAD_ROW = {
    "NaN in one U": (lambda ts: _set(ts, 37, U=_with(ts[37].U, (4, 2), np.nan)), "non_finite"),
    "inf in one U's lower triangle": (lambda ts: _set(ts, 12, U=_with(ts[12].U, (5, 0), np.inf)),
                                      "non_finite"),
    "NaN in one x_bar": (lambda ts: _set(ts, 49, x_bar=_with(ts[49].x_bar, (3,), np.nan)), "non_finite"),
    "one innovation beyond float16": (lambda ts: _set(ts, 20, u=_with(ts[20].u, (0,), 1e39)), "non_finite"),
    "one U with velocity information": (lambda ts: _set(ts, 21, U=_with(ts[21].U, (4, 4), 1.0)), "malformed"),
    "one U not positive definite": (lambda ts: _set(ts, 23, U=_with(ts[23].U, (0, 0), -1.0)), "malformed"),
    "negative ell in one row": (lambda ts: _set(ts, 33, ell=-1), "malformed"),
    "negative counter in one row": (lambda ts: _set(ts, 2, id=(0, -4)), "malformed"),
    "duplicate id in two rows": (lambda ts: _set(ts, 41, id=ts[9].id), "malformed"),
    "one appearance beyond float32": (lambda ts: _set(ts, 7, appearance=np.full((2, 16), 1e300)), "non_finite"),
    "one appearance too wide": (lambda ts: _set(ts, 44, appearance=np.ones((1, 5000))), "oversize"),
}


def _with(a: np.ndarray, at: tuple[int, ...], v: float) -> np.ndarray:
    a = np.array(a)
    a[at] = v
    return a


def _set(ts: tuple[TrackerInfo, ...], i: int, **change) -> tuple[TrackerInfo, ...]:
    return ts[:i] + (dataclasses.replace(ts[i], **change),) + ts[i + 1 :]


@pytest.mark.parametrize("name", sorted(ONE_BAD_ROW))
def test_one_bad_row_among_fifty_is_refused(name: str) -> None:
    edit, reason = ONE_BAD_ROW[name]
    ts = edit(infos(50))
    assert _refused(FrameMessage("n", 0, 0, ts)).reason == reason  # from TrackerInfo objects
    block = block_of(ts)
    assert _refused(FrameMessage.from_block("n", 0, 0, block)).reason == reason  # from arrays


def test_the_error_names_the_bad_row() -> None:
    ts = _set(infos(50), 37, U=_with(infos(50)[37].U, (4, 2), np.nan))
    assert str(ts[37].id) in _refused(FrameMessage("n", 0, 0, ts)).detail


def _decoded_block_edit(n: int, fn) -> bytes:
    obj = msgpack.unpackb(encode(message(n)), raw=False)
    obj[9] = fn(bytearray(obj[9]), obj)
    return msgpack.packb(obj, use_bin_type=True)


def _info_offsets(obj, row: int) -> tuple[int, int]:
    """Byte offsets of ``row``'s scale and of its float16 factor and innovation in a decoded
    message's block (``row`` measured)."""
    n, widths = obj[5], obj[6]
    ints = n * sum(1 << ((widths >> 2 * k) & 3) for k in range(4))
    mask = int.from_bytes(obj[9][ints : ints + (n + 7) // 8], "little")
    rank, m = bin(mask & ((1 << row) - 1)).count("1"), bin(mask).count("1")
    scales = ints + (n + 7) // 8 + 24 * n
    return scales + 4 * rank, scales + 4 * m + 28 * rank


def test_decode_finds_one_bad_row_among_fifty() -> None:
    def nan_in_the_factor_of_row_38(b: bytearray, obj) -> bytes:
        at = _info_offsets(obj, 38)[1] + 2 * 9  # the last of its 10 factor values
        b[at : at + 2] = np.array([np.nan], "<f2").tobytes()
        return bytes(b)

    with pytest.raises(ProtocolError) as e:
        decode(_decoded_block_edit(50, nan_in_the_factor_of_row_38))
    assert e.value.reason == "non_finite" and str(infos(50)[38].id) in e.value.detail

    def zero_scale_of_row_44(b: bytearray, obj) -> bytes:
        at = _info_offsets(obj, 44)[0]
        b[at : at + 4] = bytes(4)
        return bytes(b)

    with pytest.raises(ProtocolError) as e:
        decode(_decoded_block_edit(50, zero_scale_of_row_44))
    assert e.value.reason == "malformed" and str(infos(50)[44].id) in e.value.detail

    def counter_of_row_45_as_row_3(b: bytearray, obj) -> bytes:  # counters are u2 here: 300 + 7 i
        at = 50  # after the camera column
        b[at + 2 * 45 : at + 2 * 46] = b[at + 2 * 3 : at + 2 * 4]
        b[45] = b[3]  # and the same camera
        return bytes(b)

    with pytest.raises(ProtocolError) as e:
        decode(_decoded_block_edit(50, counter_of_row_45_as_row_3))
    assert e.value.reason == "malformed" and "duplicate" in e.value.detail


def test_wire_widths_follow_the_largest_value() -> None:
    ts = tuple(dataclasses.replace(t, born=0) for t in infos(4))
    for born, code in ((255, 0), (256, 1), (65535, 1), (65536, 2), (2**32 - 1, 2), (2**32, 3),
                       (2**63 - 1, 3)):
        m = FrameMessage("n", 0, 0, _set(ts, 2, born=born))
        obj = msgpack.unpackb(encode(m), raw=False)
        assert (obj[6] >> 4) & 3 == code, born
        assert decode(encode(m)).trackers[2].born == born
