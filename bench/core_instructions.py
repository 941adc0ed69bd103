"""Instructions the tracker core executes per node-frame: ``sim_cluster bench``'s workload,
counted by valgrind instead of timed, so that two versions of the core compare exactly.

    .venv/bin/python bench/core_instructions.py [--targets 20] [--frames 30] [--neighbours 4]
                                                [--only edge_node.core.screen:Screen.messages]
                                                [--codec] [--split]

CPU time on the shared 2-core machines of the README moves by 30 % and more from one run to
the next (other machines' load), which hides a change of a few per cent however many runs are
alternated. The number of instructions does not move: the core is deterministic. The script
runs itself under ``valgrind --tool=callgrind`` (Debian package ``valgrind``; not installed by
the project; about two minutes for the defaults) with collection switched on only inside
``functools.reduce``, through which it calls every node's ``prepare`` and ``update`` of the
measured frames (``bench_targets``' ``wrap``; the same frames its core figure uses). Imports,
the simulated world, the codec and the frames before the measured ones are not counted.

``--only module:qualname`` counts one function of the core instead (each call inside the
measured frames, with everything it calls): where the instructions go. ``--codec`` counts the
codec instead: every node's message of the measured frames encoded once (from its block, as a
node sends it) and decoded once per neighbour, the node-frame of ``sim_cluster bench``'s codec
line (1 encode + 4 decodes).

``--cameras N [--scope S] [--layout corridor|grid]`` counts ``sim_cluster bench --cameras``'s
workload instead: every node's ``prepare`` + ``update`` on the generated ``<layout>-<N>``
network (6.25 people per camera, the layout's neighbour graph), the first third of the frames
not counted. It prints the mean over the counted node-frames (the scale sweep's CPU column is a
median of noisy timings) and the trackers a node held on average, so that the issue's ratio
"per-node cost at 64 cameras over 4" can be given without the machine's noise.

``--calls`` also counts the NumPy calls per node-frame: calls from CPython's interpreter into
NumPy's shared objects (a ufunc or an operator on arrays, a NumPy function or array method
implemented in C, each counted once however much NumPy does inside), read from callgrind's
call graph.

``--split`` also says whose code executes them: CPython's interpreter, NumPy's dispatch (argument
parsing, array creation, type resolution, iterators), NumPy's inner loops (the elementwise
arithmetic, copies and casts themselves), BLAS and LAPACK (OpenBLAS), the C library
(``malloc``, ``memset``, ``memcpy``) and the rest: by the shared object and function
``callgrind_annotate`` (valgrind's) names for each instruction. What a compiled kernel would
keep of the core is about the inner loops and BLAS; the rest is the price of calling them from
Python one small array at a time.

Prints the instructions per node-frame (millions). Instructions are not time (a cache miss
costs more than an add), but the core's time is spread over hundreds of small numpy calls
whose cost is their instructions: on this machine 15 M instructions per node-frame at 20
targets were 3 ms of CPU time.
"""
import argparse
import collections
import functools
import importlib
import os
import re
import shutil
import subprocess
import sys
import tempfile

_CHILD = "DMTT_CORE_INSTRUCTIONS_CHILD"

# this checkout's code, not the installed one: an old checkout's copy of this script (``git
# worktree add``) counts the old code (the project's editable install points at one checkout)
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


# NumPy's inner loops: the typed elementwise kernels (``DOUBLE_add``...), copies and casts, sorts;
# not the per-element ``_setitem`` / ``_getitem`` of Python objects (conversion, not arithmetic)
_KERNEL = re.compile(r"((C?DOUBLE|C?FLOAT|C?LONGDOUBLE|HALF|BOOL|U?BYTE|U?SHORT|U?INT|U?LONG|U?LONGLONG)_"
                     r"(?!setitem|getitem)|_aligned|_contig|_strided|_cast|npyv|simd|.*sort)")
_ANNOTATE_LINE = re.compile(r"\s*([\d,]+)\s+\([\s\d.]+%\)\s+(.*?):(.+?)(?:\s+\[(.*)\])?\s*$")
SPLIT = ("Python interpreter", "NumPy dispatch", "NumPy inner loops", "BLAS / LAPACK", "C library", "other")


def split(annotate: str) -> dict[str, int]:
    """Instructions by whose code runs them (``SPLIT``), from ``callgrind_annotate
    --inclusive=no --auto=no``'s listing (``Ir file:function [object]`` per line). Code inlined
    from a header is listed without its object; its source file tells: CPython's tree, or
    glibc's (a relative ``./`` path)."""
    out: collections.Counter[str] = collections.Counter({k: 0 for k in SPLIT})
    for line in annotate.splitlines():
        m = _ANNOTATE_LINE.match(line)
        if m is None:
            continue
        n, src, fn = int(m.group(1).replace(",", "")), m.group(2), m.group(3)
        obj = os.path.basename(m.group(4)) if m.group(4) else ""
        if not obj:  # inlined: by the source file
            obj = ("libpython" if re.search(r"/Python-\d|/Include/", src)
                   else "libc.so" if src.startswith("./") else "")
        if "libpython" in obj or re.fullmatch(r"python3(\.\d+)?", obj):
            out["Python interpreter"] += n
        elif "blas" in obj or "lapack" in obj:  # OpenBLAS carries LAPACK too
            out["BLAS / LAPACK"] += n
        elif "_multiarray_umath" in obj or "_umath_linalg" in obj:
            out["NumPy inner loops" if _KERNEL.match(fn) else "NumPy dispatch"] += n
        elif obj.startswith(("libc.so", "libm.so")):
            out["C library"] += n
        else:
            out["other"] += n
    return dict(out)


def _counted(call):
    """``call()`` inside ``functools.reduce``: what valgrind counts."""
    return functools.reduce(lambda _, f: f(), [call], None)


def _through_reduce(k: int, call, warm: int):
    """Run ``call`` counted from frame ``warm`` on."""
    return call() if k < warm else _counted(call)


def _only(target: str, warm: int):
    """Count calls of ``target`` (``module:qualname``) in the measured frames alone; returns
    the benchmark's ``wrap``, which tells which frames those are."""
    module, _, qualname = target.partition(":")
    owner = importlib.import_module(module)
    *path, name = qualname.split(".")
    for part in path:
        owner = getattr(owner, part)
    fn = getattr(owner, name)
    measuring = [False]

    @functools.wraps(fn)
    def counted(*a, **kw):
        return _counted(functools.partial(fn, *a, **kw)) if measuring[0] else fn(*a, **kw)

    setattr(owner, name, counted)

    def wrap(k, call):
        measuring[0] = k >= warm
        return call()
    return wrap


def _codec(args, warm: int) -> None:
    """The benchmark's run uncounted, then its measured frames' messages through the codec,
    counted: one encode per message and one decode per neighbour."""
    from protocol import FrameMessage, codec
    from sim_cluster.experiments.bench import bench_targets
    sent: list[FrameMessage] = []

    def keep(k, call):
        out = call()
        if k >= warm and isinstance(out, FrameMessage):
            sent.append(out)
        return out
    bench_targets(args.targets, args.neighbours, args.frames, codec_line=False, wrap=keep)
    for m in sent:
        payload = _counted(functools.partial(codec.encode, m))
        for _ in range(args.neighbours):
            _counted(functools.partial(codec.decode, payload))


def _scale(args, warm: int) -> int:
    """The scale sweep's run of ``<layout>-<cameras>`` (scope ``args.scope``), every node's
    ``prepare`` + ``update`` of the frames from ``warm`` on counted; returns the node-frames
    counted (and prints the trackers held)."""
    from edge_node.core.config import TrackerConfig
    from edge_node.core.node import CameraNode
    from sim_cluster.network.inprocess import run_network
    from sim_cluster.scenarios.loader import open_scenario
    data = open_scenario(f"{args.layout}-{args.cameras}", seed=0, frames=args.frames)
    counted, held = [0], [0]
    prepare, update = CameraNode.prepare, CameraNode.update

    def counted_prepare(node, k, dets):
        counted[0] += k >= warm
        return _through_reduce(k, functools.partial(prepare, node, k, dets), warm)

    def counted_update(node, *a, **kw):
        k = node._frame
        out = _through_reduce(k, functools.partial(update, node, *a, **kw), warm)
        held[0] += len(node.trackers) if k >= warm else 0
        return out

    CameraNode.prepare, CameraNode.update = counted_prepare, counted_update
    try:
        run_network(data, data.neighbours, TrackerConfig(scope_hops=args.scope), topology_name="layout")
    finally:
        CameraNode.prepare, CameraNode.update = prepare, update
    print(f"trackers held per node-frame {held[0] / max(counted[0], 1):.1f}")
    return counted[0]


def child(args) -> None:
    """The benchmark's run, under valgrind."""
    from sim_cluster.experiments.bench import bench_targets, warm_frames
    warm = warm_frames(args.frames)
    if args.cameras:
        print(f"node-frames {_scale(args, warm)}")
        return
    if args.codec:
        _codec(args, warm)
    else:
        wrap = _only(args.only, warm) if args.only else functools.partial(_through_reduce, warm=warm)
        bench_targets(args.targets, args.neighbours, args.frames, codec_line=False, wrap=wrap)
    print(f"node-frames {(args.frames - warm) * (args.neighbours + 1)}")


#: NumPy entry points that are not a call the core asks for: freeing, attribute reads, scalar
#: conversions (the interpreter calls them around every expression)
_NOT_CALLS = re.compile(r"(dealloc|_get$|_get'|long_|float_|bool_arrtype_nonzero|array_length|"
                        r"gentype_|_richcompare|array_bool|array_index|array_int|array_float)")


#: the entries that run a ufunc: a ufunc called by name, or an operator or comparison on arrays
_UFUNC = re.compile(r"^(ufunc_\w+|array_(add|subtract|multiply|true_divide|floor_divide|power|"
                    r"negative|positive|absolute|matrix_multiply|remainder|divmod|and|or|xor|"
                    r"invert|lshift|rshift|inplace_\w+|richcompare))('\d+)?$")


def numpy_calls(path: str) -> tuple[int, int]:
    """Calls from the interpreter (libpython or the python binary) into NumPy's shared objects,
    counted from a callgrind output file's call graph (its ``ob=`` / ``cob=`` / ``cfn=`` /
    ``calls=`` lines; a name is given once with an id and referred to by the id after): every
    ufunc or operator on arrays, NumPy function and array method or subscript, each once
    however much NumPy does inside; not freeing, attribute reads and scalar conversions
    (``_NOT_CALLS``). Returns ``(calls, ufunc calls)`` (``_UFUNC``: those that run a ufunc)."""
    objects: dict[str, str] = {}  # callgrind's name compression: "(id) name", then "(id)"
    functions: dict[str, str] = {}

    def named(names: dict[str, str], spec: str) -> str:
        spec = spec.strip()
        if spec.startswith("("):
            key, _, name = spec.partition(")")
            if name.strip():
                names[key] = name.strip()
            return names.get(key, "")
        return spec

    ob = cob = cfn = ""
    total = ufuncs = 0
    with open(path, errors="replace") as f:
        for line in f:
            if line.startswith("ob="):
                ob = named(objects, line[3:])
            elif line.startswith("cob="):
                cob = named(objects, line[4:])
            elif line.startswith("cfn="):
                cfn = named(functions, line[4:])
            elif line.startswith("fn="):
                named(functions, line[3:])
                cob = ""
            elif line.startswith("calls="):
                caller = ob.rsplit("/", 1)[-1]
                if caller.startswith(("python", "libpython")) and "numpy" in (cob or ob):
                    n = int(line[6:].split()[0])
                    if _UFUNC.match(cfn):
                        ufuncs += n
                    if not _NOT_CALLS.search(cfn) or _UFUNC.match(cfn):
                        total += n
                cob = ""
    return total, ufuncs


def main() -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--frames", type=int, default=30, help="frames of the run (a third are not counted)")
    ap.add_argument("--neighbours", type=int, default=4)
    ap.add_argument("--only", metavar="MODULE:QUALNAME",
                    help="count this function of the core alone, e.g. edge_node.core.screen:Screen.messages")
    ap.add_argument("--codec", action="store_true",
                    help="count the codec instead: 1 encode + one decode per neighbour per node-frame")
    ap.add_argument("--cameras", type=int, default=0,
                    help="count the scale sweep's run of <layout>-<N> instead (sim_cluster bench --cameras N)")
    ap.add_argument("--scope", type=int, default=1, help="--cameras: the tracker's scope_hops (default 1)")
    ap.add_argument("--layout", choices=("corridor", "grid"), default="corridor", help="--cameras: the layout")
    ap.add_argument("--calls", action="store_true",
                    help="also count the calls from the interpreter into NumPy per node-frame")
    ap.add_argument("--split", action="store_true",
                    help="also split the instructions by whose code runs them (interpreter, NumPy, BLAS, libc)")
    args = ap.parse_args()
    if args.codec and args.only:
        ap.error("--codec counts the codec; --only counts one function of the core")
    if args.cameras and (args.codec or args.only):
        ap.error("--cameras counts the scale sweep's nodes; it takes neither --codec nor --only")
    if os.environ.get(_CHILD):
        child(args)
        return 0
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        print("core_instructions: valgrind not found (Debian: apt-get install valgrind)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, **{_CHILD: "1", "PYTHONHASHSEED": "0", "OPENBLAS_NUM_THREADS": "1"})
        out = subprocess.run(
            [valgrind, "--tool=callgrind", "--collect-atstart=no", "--toggle-collect=functools_reduce",
             f"--callgrind-out-file={tmp}/callgrind.out", sys.executable, __file__, *sys.argv[1:]],
            env=env, capture_output=True, text=True)
        parts = None
        if out.returncode == 0 and args.split:
            annotate = subprocess.run(["callgrind_annotate", "--inclusive=no", "--threshold=100", "--auto=no",
                                       f"{tmp}/callgrind.out"], capture_output=True, text=True)
            parts = split(annotate.stdout) if annotate.returncode == 0 else None
            if parts is None:
                print("core_instructions: callgrind_annotate failed: " + annotate.stderr[-500:],
                      file=sys.stderr)
        calls = numpy_calls(f"{tmp}/callgrind.out") if out.returncode == 0 and args.calls else None
    if out.returncode != 0:
        print(out.stdout + out.stderr[-3000:], file=sys.stderr)
        return 1
    frames = next(int(line.split()[1]) for line in out.stdout.splitlines() if line.startswith("node-frames"))
    collected = next(int(line.split()[-1].replace(",", "")) for line in out.stderr.splitlines()
                     if "Collected" in line)
    what = (f"codec: 1 encode + {args.neighbours} decodes" if args.codec
            else args.only or "prepare + update")
    if args.cameras:
        held = next(line.split()[-1] for line in out.stdout.splitlines() if line.startswith("trackers held"))
        print(f"{args.layout}-{args.cameras}, scope {args.scope}: {collected / frames / 1e6:.3f} M "
              f"instructions per node-frame (prepare + update, mean of {frames} node-frames; "
              f"{held} trackers held per node-frame)")
    else:
        print(f"{args.targets} targets, {args.neighbours} neighbours: "
              f"{collected / frames / 1e6:.3f} M instructions per node-frame "
              f"({what}, {frames} node-frames)")
    if calls is not None:
        print(f"  NumPy calls          {calls[0] / frames:6.0f}    per node-frame (from the interpreter "
              f"into NumPy), {calls[1] / frames:.0f} of them ufuncs")
    if parts is not None:
        for name in SPLIT:
            print(f"  {name:<20} {parts[name] / frames / 1e6:6.3f} M  {parts[name] / max(collected, 1):6.1%}")
        if sum(parts.values()) != collected:
            print(f"  ({sum(parts.values()) / max(collected, 1):.1%} of the instructions named by "
                  "callgrind_annotate)")
    return 0 if not args.split or parts is not None else 1


if __name__ == "__main__":
    sys.exit(main())
