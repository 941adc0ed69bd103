"""What a compiled kernel would buy the core, measured on one step: eq. 4 (``dkf.corrects``)
for a frame's trackers, NumPy's as the core runs it against the same arithmetic in explicit
loops compiled by numba.

The project keeps heavy dependencies out of the tracker core (numba brings LLVM), and the core
is pure NumPy; whether to take a compiler for speed is a maintainer's decision (issue 15,
README "Benchmarks"). This gives that decision numbers instead of an estimate: the step's CPU
time both ways, what numba costs a process at start (its import; the first call compiling,
and the first call of a restarted process loading the compiled code from numba's cache), and
how far the compiled numbers are from NumPy's (LAPACK's LU against the same algorithm in
loops: another order of operations, so the last bits differ).

The arguments are those of ``sim_cluster bench``'s workload (``--targets`` people, four
neighbours, 90 frames; the last 200 calls). Run it with the project's interpreter; the timing
runs in an interpreter that has numba (``--numba-python``; numba is not a dependency)::

    python -m venv /tmp/nb && /tmp/nb/bin/pip install numba numpy==<the project's>
    python bench/compiled_kernel.py --numba-python /tmp/nb/bin/python [--targets 20]

(about a minute: the compilation takes 5-10 s.)
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CHILD = "COMPILED_KERNEL_CHILD"

if os.environ.get(CHILD):  # the timing process: numba at module level, so that its cache works
    _t0 = time.perf_counter()
    import numba
    IMPORT_S = time.perf_counter() - _t0

    @numba.njit(cache=True)
    def corrects_compiled(x_bar, P, y, S, diff, upm, degree, bound):  # pragma: no cover
        """``dkf.corrects`` in loops, no allocation per tracker: ``M = (I + P S)^-1 P`` by
        Gaussian elimination with partial pivoting (LAPACK ``gesv``'s algorithm, unblocked),
        symmetrised; ``x_hat = x_bar + M (y - S x_bar) + gamma M_m diff`` with
        ``consensus_gamma``'s rule (the Frobenius bound, the largest eigenvalue only where it
        may bind)."""
        n = x_bar.shape[0]
        x_hat = np.empty_like(x_bar)
        M_out = np.empty_like(P)
        A = np.empty((6, 6))
        X = np.empty((6, 6))
        r = np.empty(6)
        u2 = upm * upm
        for t in range(n):
            for i in range(6):  # A = I + P S, X = P
                for j in range(6):
                    s = 0.0
                    for k in range(6):
                        s += P[t, i, k] * S[t, k, j]
                    A[i, j] = s + (1.0 if i == j else 0.0)
                    X[i, j] = P[t, i, j]
            for k in range(6):  # A X = P, eliminating with the largest pivot of the column
                p = k
                m = abs(A[k, k])
                for i in range(k + 1, 6):
                    if abs(A[i, k]) > m:
                        m = abs(A[i, k])
                        p = i
                if p != k:
                    for j in range(6):
                        tmp = A[k, j]
                        A[k, j] = A[p, j]
                        A[p, j] = tmp
                        tmp = X[k, j]
                        X[k, j] = X[p, j]
                        X[p, j] = tmp
                for i in range(k + 1, 6):
                    f = A[i, k] / A[k, k]
                    for j in range(k + 1, 6):
                        A[i, j] -= f * A[k, j]
                    for j in range(6):
                        X[i, j] -= f * X[k, j]
            for k in range(5, -1, -1):  # back substitution
                for j in range(6):
                    s = X[k, j]
                    for i in range(k + 1, 6):
                        s -= A[k, i] * X[i, j]
                    X[k, j] = s / A[k, k]
            M = M_out[t]
            for i in range(6):
                for j in range(6):
                    M[i, j] = 0.5 * (X[i, j] + X[j, i])
            for i in range(6):  # r = y - S x_bar
                s = 0.0
                for k in range(6):
                    s += S[t, i, k] * x_bar[t, k]
                r[i] = y[t, i] - s
            pull = False
            for j in range(6):
                if diff[t, j] != 0.0:
                    pull = True
            g = 0.0
            if pull:
                fro = 0.0
                for i in range(6):
                    for j in range(6):
                        fro += (M[i, j] / u2) ** 2
                fro = np.sqrt(fro)
                g = 1.0 / (1.0 + fro)
                d = max(degree[t], 1)
                if d * g * fro > bound:
                    step = d * g * np.linalg.eigvalsh(M / u2)[-1]
                    if step > bound:
                        g = g * bound / step
            for i in range(6):
                s = 0.0
                c = 0.0
                for k in range(6):
                    s += M[i, k] * r[k]
                    c += (M[i, k] / u2) * diff[t, k]
                x_hat[t, i] = x_bar[t, i] + s + g * c
        return x_hat, M_out


def capture(targets: int, path: Path, keep: int = 200) -> int:
    """The last ``keep`` calls' arguments of ``dkf.corrects`` in ``sim_cluster bench``'s
    workload, saved to ``path`` (npz); returns how many calls were kept."""
    from edge_node.core import dkf
    from sim_cluster.experiments.bench import bench_targets

    calls: list[tuple] = []
    original = dkf.corrects

    def recording(x_bar, P, y, S, diff, units_per_metre=1.0, *, degree, bound=dkf.CONSENSUS_BOUND):
        calls.append((x_bar.copy(), P.copy(), y.copy(), S.copy(), diff.copy(), float(units_per_metre),
                      np.asarray(degree, np.int64).copy(), float(bound)))
        del calls[:-keep]
        return original(x_bar, P, y, S, diff, units_per_metre, degree=degree, bound=bound)

    dkf.corrects = recording
    try:
        bench_targets(targets, 4, 90, codec_line=False)
    finally:
        dkf.corrects = original
    arrays = {f"{name}{i}": a for i, call in enumerate(calls)
              for name, a in zip(("x_bar", "P", "y", "S", "diff", "upm", "degree", "bound"), call)}
    np.savez(path, n=len(calls), **arrays)
    return len(calls)


def _load(path: Path) -> list[tuple]:
    data = np.load(path)
    return [(data[f"x_bar{i}"], data[f"P{i}"], data[f"y{i}"], data[f"S{i}"], data[f"diff{i}"],
             float(data[f"upm{i}"]), data[f"degree{i}"], float(data[f"bound{i}"]))
            for i in range(int(data["n"]))]


def child(path: Path, rounds: int) -> dict:  # pragma: no cover - needs numba
    """In the numba interpreter: first call's time, the numbers' agreement, then both
    versions timed alternately (CPU time per call, median over ``rounds`` passes)."""
    from edge_node.core import dkf

    calls = _load(path)
    t0 = time.perf_counter()
    corrects_compiled(*calls[0])
    first_call = time.perf_counter() - t0
    diff, same = 0.0, 0
    for c in calls:
        x1, M1 = dkf.corrects(*c[:6], degree=c[6], bound=c[7])
        x2, M2 = corrects_compiled(*c)
        diff = max(diff, float(np.abs(x1 - x2).max()), float(np.abs(M1 - M2).max()))
        same += bool(np.array_equal(x1, x2) and np.array_equal(M1, M2))
    numpy_us, compiled_us = [], []
    for _ in range(rounds):
        t = time.process_time()
        for c in calls:
            dkf.corrects(*c[:6], degree=c[6], bound=c[7])
        numpy_us.append((time.process_time() - t) / len(calls) * 1e6)
        t = time.process_time()
        for c in calls:
            corrects_compiled(*c)
        compiled_us.append((time.process_time() - t) / len(calls) * 1e6)
    return {"import_s": IMPORT_S, "first_call_s": first_call, "max_abs_diff": diff,
            "bit_identical_calls": same, "calls": len(calls),
            "trackers_per_call": float(np.mean([len(c[0]) for c in calls])),
            "numpy_us": float(np.median(numpy_us)), "compiled_us": float(np.median(compiled_us)),
            "numba": numba.__version__}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--numba-python", default=sys.executable,
                    help="an interpreter that has numba (default: this one)")
    ap.add_argument("--rounds", type=int, default=15, help="timed passes over the calls")
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:  # pragma: no cover - runs in the numba interpreter
        print(json.dumps(child(args.child, args.rounds)))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "calls.npz"
        n = capture(args.targets, path)
        env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(Path(tmp) / "cache"),
                   OPENBLAS_NUM_THREADS="1", **{CHILD: "1"})
        runs = []
        for label in ("empty cache (compiles)", "cache of the run before (a restarted process)"):
            out = subprocess.run([args.numba_python, __file__, "--child", str(path),
                                  "--rounds", str(args.rounds)],
                                 env=env, capture_output=True, text=True)
            if out.returncode:
                print(out.stderr[-2000:], file=sys.stderr)
                return 1
            runs.append((label, json.loads(out.stdout.strip().splitlines()[-1])))
    r = runs[-1][1]
    print(f"eq. 4 (dkf.corrects), {args.targets} targets, 4 neighbours: {n} calls of "
          f"{r['trackers_per_call']:.1f} trackers (numba {r['numba']})")
    for label, run in runs:
        print(f"  {label}: import numba {run['import_s'] * 1e3:.0f} ms, first call "
              f"{run['first_call_s'] * 1e3:.0f} ms; CPU per call: NumPy {run['numpy_us']:.1f} us, "
              f"compiled {run['compiled_us']:.1f} us ({run['numpy_us'] / run['compiled_us']:.1f}x)")
    print(f"  numbers: {r['bit_identical_calls']} of {r['calls']} calls bit for bit equal, "
          f"largest difference {r['max_abs_diff']:.2g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
