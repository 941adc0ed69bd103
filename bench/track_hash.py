"""A fingerprint of every track the core benchmark produces: whether two versions of the core
give the same tracks, bit for bit.

    .venv/bin/python bench/track_hash.py [--targets 5,20,50] [--frames 90]

Runs ``sim_cluster bench``'s workload (``bench_targets``: one node with 4 neighbours per
camera, seed 0) for each target count and hashes, after every node's every ``update``, each
track's id, frame, state ``x``, covariance ``P``, ``observed``, ``ell`` and image boxes (their
float64 bytes). Prints the SHA-256. A change meant to leave the tracker's numbers alone (a
faster way to compute the same thing) must print the same hash as the code before it; run the
old code from its own checkout (``git worktree add``). The core is deterministic (no clock, no
randomness, no dependence on hash seeds), so the hash is the same in any shell.
"""
import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from anywhere

from sim_cluster.experiments.bench import bench_targets  # noqa: E402


def track_hash(targets: list[int], frames: int) -> str:
    """SHA-256 (hex) of every track after every update of the benchmark runs."""
    h = hashlib.sha256()

    def wrap(k, call):
        out = call()
        if isinstance(out, list):  # update's tracks (prepare returns a message)
            for t in out:
                h.update(repr((t.id, t.frame, t.observed, t.ell)).encode())
                h.update(np.ascontiguousarray(t.x, float).tobytes())
                h.update(np.ascontiguousarray(t.P, float).tobytes())
                for cam, box in sorted((t.boxes or {}).items()):
                    h.update(repr(cam).encode())
                    h.update(np.ascontiguousarray(box, float).tobytes())
        return out

    for n in targets:
        bench_targets(n, 4, frames, codec_line=False, wrap=wrap)
    return h.hexdigest()


def main() -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--targets", default="5,20,50", help="comma-separated target counts")
    ap.add_argument("--frames", type=int, default=90)
    args = ap.parse_args()
    targets = [int(x) for x in args.targets.split(",") if x.strip()]
    print(track_hash(targets, args.frames))
    return 0


if __name__ == "__main__":
    sys.exit(main())
