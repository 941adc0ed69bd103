"""``sim_cluster bench``'s hook for counting the core's instructions (``bench_targets``' ``wrap``)
and ``bench/core_instructions.py``'s wrappers: what valgrind counts is every node's ``prepare``
and ``update`` of the measured frames (or, with ``--codec``, their messages' encodes and
decodes), and nothing in the tracking changes for being counted."""
from __future__ import annotations

import argparse
import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from sim_cluster.experiments.bench import bench_targets, warm_frames

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "core_instructions.py"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("core_instructions", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _reduce_calls(monkeypatch) -> list[int]:
    """Count ``functools.reduce`` calls (the region valgrind counts) from here on."""
    calls = []
    real = functools.reduce

    def reduce(*a):
        calls.append(1)
        return real(*a)
    monkeypatch.setattr(functools, "reduce", reduce)
    return calls


def test_wrap_runs_every_prepare_and_update_of_every_frame():
    seen = []

    def wrap(k, call):
        seen.append((k, call.func.__name__))
        return call()

    plain = bench_targets(3, neighbours=1, frames=9, codec_line=False)
    wrapped = bench_targets(3, neighbours=1, frames=9, codec_line=False, wrap=wrap)
    # two nodes: per frame two prepares, then two updates
    assert seen == [(k, name) for k in range(9) for name in ("prepare",) * 2 + ("update",) * 2]
    assert wrapped["trackers_per_node"] == plain["trackers_per_node"] == 3
    assert not any(key.startswith("codec_") and key != "codec_ms_median" for key in wrapped)
    assert warm_frames(9) == 3


def test_the_tool_counts_the_measured_frames_only(tool, monkeypatch):
    calls = _reduce_calls(monkeypatch)
    wrap = functools.partial(tool._through_reduce, warm=warm_frames(9))
    bench_targets(3, neighbours=1, frames=9, codec_line=False, wrap=wrap)
    assert len(calls) == (9 - 3) * 2 * 2  # frames 3..8, two nodes, prepare and update


def test_only_counts_one_function_in_the_measured_frames(tool, monkeypatch):
    from edge_node.core.screen import Screen
    real = Screen.messages
    runs = []

    def messages(self, msgs, book):
        runs.append(1)
        return real(self, msgs, book)
    monkeypatch.setattr(Screen, "messages", messages)
    calls = _reduce_calls(monkeypatch)
    wrap = tool._only("edge_node.core.screen:Screen.messages", warm=warm_frames(9))
    try:
        bench_targets(3, neighbours=1, frames=9, codec_line=False, wrap=wrap)
    finally:
        monkeypatch.undo()
    assert len(runs) == 9 * 2  # every update screens its messages once
    assert len(calls) == (9 - 3) * 2  # counted in the measured frames alone


def test_codec_counts_one_encode_and_a_decode_per_neighbour(tool, monkeypatch):
    """``--codec``: every node's message of the measured frames is encoded once and decoded
    once per neighbour inside the counted region, and nothing else is counted."""
    from protocol import codec
    real_encode, real_decode = codec.encode, codec.decode
    counted: list[str] = []
    inside = [False]
    real_reduce = functools.reduce

    def reduce(*a):
        inside[0] = True
        try:
            return real_reduce(*a)
        finally:
            inside[0] = False
    monkeypatch.setattr(functools, "reduce", reduce)

    def encode(m, **kw):
        counted.append("encode" if inside[0] else "uncounted encode")
        return real_encode(m, **kw)

    def decode(b, **kw):
        counted.append("decode" if inside[0] else "uncounted decode")
        return real_decode(b, **kw)
    monkeypatch.setattr(codec, "encode", encode)
    monkeypatch.setattr(codec, "decode", decode)
    args = argparse.Namespace(targets=3, neighbours=2, frames=9, codec=True, only=None)
    try:
        tool._codec(args, warm=warm_frames(9))
    finally:
        monkeypatch.undo()
    measured = (9 - warm_frames(9)) * 3  # node-frames of the measured frames
    assert counted.count("encode") == measured
    assert counted.count("decode") == 2 * measured
    # the benchmark's own run before it counts nothing
    assert counted.count("uncounted encode") > 0 and "uncounted decode" in counted


def test_cameras_counts_every_nodes_prepare_and_update_of_the_measured_frames(tool, monkeypatch, capsys):
    """``--cameras N``: the scale sweep's network of N cameras, every live node's ``prepare``
    and ``update`` counted from the warm frames on, and the node's methods restored after."""
    from edge_node.core.node import CameraNode
    real = CameraNode.prepare, CameraNode.update
    calls = _reduce_calls(monkeypatch)
    args = argparse.Namespace(cameras=4, scope=1, layout="corridor", frames=9)
    try:
        counted = tool._scale(args, warm=warm_frames(9))
    finally:
        monkeypatch.undo()
    assert counted == 4 * (9 - warm_frames(9))
    assert len(calls) == 2 * counted
    assert (CameraNode.prepare, CameraNode.update) == real
    assert "trackers held per node-frame" in capsys.readouterr().out


def test_split_names_whose_code_runs_each_instruction(tool):
    """``--split``: ``callgrind_annotate``'s self costs summed by object, NumPy's own split into
    its inner loops (typed kernels, copies, casts) and the rest; lines it cannot read (headers,
    totals) are skipped. The listing below is in callgrind_annotate's format, the sums by hand."""
    numpy = "/v/site-packages/numpy/_core/_multiarray_umath.cpython-311-x86_64-linux-gnu.so"
    listing = f"""--------------------------------------------------------------------------------
912,478,370 (100.0%)  PROGRAM TOTALS
Ir                    file:function
110,000 (12.07%)  /tmp/Python-3.11.7/Python/ceval.c:_PyEval_EvalFrameDefault'2 [/root/lib/libpython3.11.so.1.0]
 26,000 ( 2.87%)  ???:ufunc_generic_fastcall [{numpy}]
  7,000 ( 0.77%)  ???:DOUBLE_add_X86_V3 [{numpy}]
  5,000 ( 0.66%)  ???:_aligned_strided_to_contig_size8_srcstride0 [{numpy}]
  1,500 ( 0.17%)  ???:LONG_setitem [{numpy}]
    900 ( 0.10%)  ???:LONGLONG_multiply [{numpy}]
  8,000 ( 0.91%)  ???:dtrsm_kernel_LT_HASWELL [/v/numpy.libs/libscipy_openblas64_-32a4b2a6.so]
    300 ( 0.01%)  ???:npy_clear_floatstatus_barrier [/v/numpy/linalg/_umath_linalg.cpython-311-x86_64-linux-gnu.so]
 14,000 ( 1.55%)  ./string/memset-vec-unaligned-erms.S:__memset_avx2_unaligned_erms [/usr/lib/x86_64-linux-gnu/libc.so.6]
     20 ( 0.00%)  ???:sqrt [/usr/lib/x86_64-linux-gnu/libm.so.6]
     70 ( 0.00%)  ???:solve [/v/scipy/optimize/_lsap.cpython-311-x86_64-linux-gnu.so]
     10 ( 0.00%)  ???:PyLong_FromLong [/usr/bin/python3.11]
  2,000 ( 0.33%)  /tmp/Python-3.11.7/./Include/object.h:_PyEval_EvalFrameDefault'2
    600 ( 0.07%)  ./malloc/./malloc/malloc.c:_int_malloc
      5 ( 0.00%)  /somewhere/else.c:mystery
"""
    assert tool.split(listing) == {"Python interpreter": 112_010, "NumPy dispatch": 27_800,
                                   "NumPy inner loops": 12_900, "BLAS / LAPACK": 8_000,
                                   "C library": 14_620, "other": 75}


def test_track_hash_is_the_same_in_another_shell_and_moves_with_the_tracks(tmp_path, monkeypatch):
    """``bench/track_hash.py`` fingerprints every track of the benchmark runs: a second
    process with another hash seed prints the in-process hash (the core is deterministic), and
    one track's number changed by an ulp changes it."""
    import os
    import subprocess
    import sys

    import numpy as np

    script = SCRIPT.with_name("track_hash.py")
    spec = importlib.util.spec_from_file_location("track_hash", script)
    th = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(th)
    here = th.track_hash([3], 12)
    env = dict(os.environ, PYTHONHASHSEED="12345")
    out = subprocess.run([sys.executable, str(script), "--targets", "3", "--frames", "12"],
                         capture_output=True, text=True, env=env, cwd=tmp_path, check=True)
    assert out.stdout.strip() == here
    assert len(here) == 64 and here != th.track_hash([3], 11)

    from edge_node.core.node import CameraNode
    real = CameraNode.update

    def nudged(self, *a, **kw):  # one node's first track, x moved by one ulp at frame 7
        tracks = real(self, *a, **kw)
        if self.id == 0 and self.frame == 7 and tracks:
            t = tracks[0]
            object.__setattr__(t, "x", np.nextafter(t.x, np.inf))
        return tracks
    monkeypatch.setattr(CameraNode, "update", nudged)
    assert th.track_hash([3], 12) != here


def test_compiled_kernel_benchmark_replays_the_cores_own_calls(tmp_path, monkeypatch):
    """``bench/compiled_kernel.py`` times eq. 4 on the calls the core made: the arguments it
    saves, replayed through ``dkf.corrects``, give what the core got from those calls."""
    from edge_node.core import dkf

    spec = importlib.util.spec_from_file_location(
        "compiled_kernel", SCRIPT.parent / "compiled_kernel.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    real, results = dkf.corrects, []

    def outer(*a, **kw):
        out = real(*a, **kw)
        results.append(tuple(o.copy() for o in out))
        return out
    monkeypatch.setattr(dkf, "corrects", outer)
    n = module.capture(5, tmp_path / "calls.npz", keep=12)
    assert dkf.corrects is outer  # put back
    calls = module._load(tmp_path / "calls.npz")
    assert n == len(calls) == 12 and len(results) > 12
    for c, (x_hat, M) in zip(calls, results[-12:]):
        assert len(c[0]) == 5  # the bench holds its 5 targets
        x2, M2 = real(*c[:6], degree=c[6], bound=c[7])
        assert np.array_equal(x2, x_hat) and np.array_equal(M2, M)
