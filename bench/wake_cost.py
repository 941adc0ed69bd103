"""What waking up costs a camera process: one numpy call timed back to back and right after the
thread slept, as a node sleeps each frame for its neighbours' messages and its pacing.

    .venv/bin/python bench/wake_cost.py [--sleep-ms 35] [--calls 60] [--n 40]

Each call works on ``n`` stacked 4x4 information matrices (a frame's neighbour entries, what
``Screen.informations`` checks). Prints, per call, the median wall time over ``calls`` calls
made back to back ("warm") and over as many calls each made right after ``time.sleep``
("after sleep"), and the difference: the cost of a wake-up that lands on whatever runs first.
On the 2-core virtual machines of the README's tables the difference is 50-120 us for every
call alike, so it is not the call's own work (README, "A real cluster").
"""
import argparse
import statistics
import time

import numpy as np


def median_us(call, calls: int, sleep_s: float) -> float:
    times = []
    for _ in range(calls):
        if sleep_s:
            time.sleep(sleep_s)
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sleep-ms", type=float, default=35.0, help="how long the thread sleeps")
    ap.add_argument("--calls", type=int, default=60)
    ap.add_argument("--n", type=int, default=40, help="stacked 4x4 matrices per call")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    A = rng.normal(size=(args.n, 4, 4))
    U = A @ A.transpose(0, 2, 1) + np.eye(4)
    u = rng.normal(size=(args.n, 4))
    calls = {
        "eigh": lambda: np.linalg.eigh(U),
        "cholesky": lambda: np.linalg.cholesky(U),
        "inv": lambda: np.linalg.inv(U),
        "solve": lambda: np.linalg.solve(U, u[..., None]),
        "einsum": lambda: np.einsum("nij,nj->ni", U, u),
        "matmul": lambda: U @ U,
    }
    print(f"{'call':10s} {'warm us':>9s} {'after sleep us':>15s} {'difference':>11s}")
    for name, call in calls.items():
        warm = median_us(call, args.calls, 0.0)
        cold = median_us(call, args.calls, args.sleep_ms / 1000.0)
        print(f"{name:10s} {warm:9.1f} {cold:15.1f} {cold - warm:11.1f}")


if __name__ == "__main__":
    main()
