"""What ``--rerun save`` costs a real cluster: frames/s of ``sim_cluster up`` with and without.

    .venv/bin/python bench/rerun_cost.py [--frames 300] [--repeats 3] [--out runs/rerun-cost]

4-node chain, terrace-sim seed 0, sync mode, no pacing; the two settings alternate
(off, save, off, save, ...) so that a change in machine load hits both. Per run:

``loop fps``  frames / the slowest node's loop time (its status ``updated_at`` at exit minus
              ``started_at`` minus its start-up barrier ``startup_s``): the rate the cluster
              sustains in lock-step, Rerun logging and the final flush included;
``command s`` wall time of the whole ``sim_cluster up`` (process start-up with Rerun's import,
              the run, evaluation, and for ``save`` logging the world and merging the files);
``cpu ms``    CPU time of the launcher and all its processes (user + system, from
              ``getrusage(RUSAGE_CHILDREN)``) per node and frame.

Medians over the repeats are printed and written to ``<out>/rerun_cost.json``.
"""
import argparse
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent


def one(out: Path, frames: int, rerun: list[str]) -> dict:
    t0 = time.time()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "terrace-sim", "--topology",
                        "chain", "--frames", str(frames), "--mode", "sync", "--sync-timeout", "30",
                        "--out", str(out), "--quiet", "--rerun", *rerun],
                       capture_output=True, text=True)
    wall = time.time() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if r.returncode != 0:
        raise SystemExit(r.stdout + r.stderr)
    loops = []
    for i in range(4):
        st = json.loads((out / "nodes" / f"status_node{i}.json").read_text())
        c = json.loads((out / "nodes" / f"counters_node{i}.json").read_text())
        assert c["frames_done"] == frames, c
        loops.append(st["updated_at"] - st["started_at"] - (c.get("startup_s") or 0.0))
    return {"loop_fps": frames / max(loops), "command_s": wall,
            "cpu_ms_per_node_frame": cpu / (4 * frames) * 1e3}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="runs/rerun-cost")
    a = ap.parse_args()
    out = Path(a.out)
    runs = {"off": [], "save": []}
    for rep in range(a.repeats):
        for name in ("off", "save"):
            spec = ["off"] if name == "off" else ["save", str(out / "cost.rrd")]
            runs[name].append(one(out / name, a.frames, spec))
            x = runs[name][-1]
            print(f"run {rep + 1} {name:>4}: {x['loop_fps']:.1f} frames/s, command "
                  f"{x['command_s']:.1f} s, cpu {x['cpu_ms_per_node_frame']:.1f} ms per node-frame",
                  flush=True)
    metrics = ("loop_fps", "command_s", "cpu_ms_per_node_frame")
    med = {k: {m: statistics.median(r[m] for r in v) for m in metrics} for k, v in runs.items()}
    res = {"frames": a.frames, "repeats": a.repeats, "runs": runs, "median": med,
           "rrd_bytes": (out / "cost.rrd").stat().st_size}
    (out / "rerun_cost.json").write_text(json.dumps(res, indent=2))
    print(f"median frames/s: off {med['off']['loop_fps']:.1f}, save {med['save']['loop_fps']:.1f} "
          f"({100 * (med['save']['loop_fps'] / med['off']['loop_fps'] - 1):+.0f}%); command: off "
          f"{med['off']['command_s']:.1f} s, save {med['save']['command_s']:.1f} s; cpu per "
          f"node-frame: off {med['off']['cpu_ms_per_node_frame']:.1f} ms, save "
          f"{med['save']['cpu_ms_per_node_frame']:.1f} ms; recording {res['rrd_bytes'] / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
