"""``sim_cluster bandwidth-sweep``: bytes against accuracy as the event trigger's ``gain`` varies
(issue 16 item 3; the paper's headline trade-off, Sec. III-D and IV).

    sim_cluster bandwidth-sweep [--scenarios terrace-sim,terrace-gt,campus-sim,ring8-sim]
        [--topology ring] [--gains 0,0.1,1,...] [--late 0,1] [--frames N] [--jobs N] --out DIR

Per scenario, in process (``run_once``), configuration dkf+lda+dtm, one seed:

* ``sync`` once: every camera sends every tracker every frame; the reference point;
* ``async`` at each ``--gains`` value (``TriggerConfig.gain``, nats: withheld measurement
  information goes out once its KL divergence exceeds it; 0 sends every measurement;
  ``edge_node/core/trigger.py``), the other trigger settings at their defaults;
* ``async`` with every message on every link 1-4 frames late (fault plan delay 1 + jitter 0..3,
  seeded) at each ``--late`` gain.

A row per run: bytes per frame (the whole network: every directed link), bytes per tracker
entry, bytes of a new tracker's appearance, the bytes ratio to sync, ground and image MOTA /
IDF1 (median over nodes, ``sim_cluster/evaluation``) and their ratios to sync. The per-scenario
summary names the largest gain whose ground MOTA is within 2% of sync (ratio >= 0.98) and its
bytes ratio, against the issue's goals: bytes ratio <= 0.5 there, and ground MOTA with late
messages >= 0.95 x sync.

Outputs in ``--out``: ``bandwidth.csv`` (a row per run), ``bandwidth.md`` (a table per scenario
and the summary), ``bandwidth.png`` (a panel per scenario: ground MOTA and IDF1 against bytes per
frame, sync marked). Runs execute in a process pool with ``--jobs`` > 1; rows are in plan order
whatever the completion order, so the files do not depend on ``--jobs``.
"""
from __future__ import annotations

import functools
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from edge_node.core.config import CONFIG_NAMES, TrackerConfig
from edge_node.core.trigger import TriggerConfig
from edge_node.faults import FaultPlan
from sim_cluster.experiments import ablation
from sim_cluster.experiments.ablation import PAPER, AblationError, _hms, _md_table, parse_list, probe
from sim_cluster.experiments.run import run_once
from sim_cluster.network import topology as topo
from sim_cluster.network.inprocess import CENTRALIZED
from sim_cluster.scenarios.loader import load_scenario

DEFAULT_SCENARIOS = ("terrace-sim", "terrace-gt", "campus-sim", "ring8-sim")
DEFAULT_GAINS = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
#: The gain the README recommends; ``--late`` runs at 0 and at this by default.
RECOMMENDED_GAIN = 1.0
DEFAULT_LATE = (0.0, RECOMMENDED_GAIN)
CONFIG = "dkf+lda+dtm"
#: Every message on every link 1-4 frames late (as tests/test_network.py's async acceptance)
LATE_PLAN = {"seed": 1, "link": [{"delay": 1, "jitter": 3}]}
LATE_TEXT = "every message 1-4 frames late"
MOTA_TOLERANCE = 0.02  # "ground MOTA within 2% of sync"
GOAL_BYTES_RATIO = 0.5
GOAL_LATE_MOTA_RATIO = 0.95

_TRIGGER = TriggerConfig()
CSV_COLS = ("scenario", "topology", "config", "seed", "frames", "nodes", "mode", "gain", "late",
            "bytes_per_frame", "bytes_per_tracker_frame", "appearance_bytes_per_new_tracker",
            "messages", "bytes_ratio", "ground_mota", "ground_idf1", "image_mota", "image_idf1",
            "mota_ratio", "idf1_ratio")


class BandwidthError(AblationError):
    """A bad argument of ``bandwidth-sweep`` (the CLI turns it into exit status 2)."""


@dataclass(frozen=True)
class Task:
    """One run: ``gain`` is None for sync; ``late``: every message 1-4 frames late."""

    index: int
    scenario: str
    mode: str
    gain: float | None
    late: bool
    topology: str = "ring"
    config: str = CONFIG
    seed: int = 0
    frames: int | None = None
    data_root: str | None = None


def parse_gains(text: str | Sequence[float], what: str = "--gains",
                allow_empty: bool = False) -> list[float]:
    """Comma-separated non-negative numbers, sorted, duplicates dropped (``none`` or empty:
    no gains, where ``allow_empty``)."""
    if isinstance(text, str):
        parts = [p.strip() for p in text.split(",") if p.strip()]
        if allow_empty and (not parts or parts == ["none"]):
            return []
    else:
        parts = list(text)
    out: set[float] = set()
    for p in parts:
        try:
            v = float(p)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or v < 0:
            raise BandwidthError(f"bad {what} {text!r}: expected non-negative numbers like "
                                 "0,0.1,1" + (" (or none)" if allow_empty else ""))
        out.add(v)
    if not out and not allow_empty:
        raise BandwidthError(f"no {what} given")
    return sorted(out)


def plan(scenarios: Sequence[str], gains: Sequence[float], late: Sequence[float] = DEFAULT_LATE,
         *, topology: str = "ring", config: str = CONFIG, seed: int = 0,
         frames: int | None = None,
         data_root: Mapping[str, str | None] | str | None = None) -> list[Task]:
    """Per scenario: sync, async at each gain, async with late messages at each ``late`` gain."""
    tasks: list[Task] = []
    for sc in scenarios:
        root = data_root.get(sc) if isinstance(data_root, Mapping) else data_root
        runs = ([("sync", None, False)] + [("async", g, False) for g in gains]
                + [("async", g, True) for g in late])
        for mode, g, lt in runs:
            tasks.append(Task(len(tasks), sc, mode, g, lt, topology, config, seed, frames, root))
    return tasks


@functools.lru_cache(maxsize=1)
def _load(scenario: str, seed: int, frames: int | None, data_root: str | None):
    """The scenario, once per worker process (a scenario's runs are adjacent in the plan)."""
    return load_scenario(scenario, seed=seed, frames=frames, data_root=data_root)


def summarise(task: Task, summary: Mapping) -> dict:
    """A row (without the ratios to sync) from ``run_once``'s summary."""
    med = {v: summary.get("metrics", {}).get(v, {}).get("median", {}) for v in ("ground", "image")}
    bw = summary["bandwidth"]
    return {
        "scenario": task.scenario, "topology": task.topology, "config": task.config,
        "seed": task.seed, "frames": summary["frames"], "nodes": summary["nodes"],
        "mode": task.mode, "gain": task.gain, "late": task.late,
        "bytes_per_frame": bw["bytes_per_frame"],
        "bytes_per_tracker_frame": bw["bytes_per_tracker_frame"] or None,
        "appearance_bytes_per_new_tracker": bw["appearance_bytes_per_new_tracker"] or None,
        "messages": bw["messages"],
        "ground_mota": med["ground"].get("mota"), "ground_idf1": med["ground"].get("idf1"),
        "image_mota": med["image"].get("mota"), "image_idf1": med["image"].get("idf1"),
    }


def run_task(task: Task) -> dict:
    """Run one task; returns its row (ratios to sync added later, by :func:`with_ratios`)."""
    data = _load(task.scenario, task.seed, task.frames, task.data_root)
    cfg = TrackerConfig.for_ablation(task.config)
    kw: dict[str, Any] = {"mode": task.mode}
    if task.mode == "async":
        kw["trigger"] = TriggerConfig(gain=task.gain)
    if task.late:
        kw["faults"] = FaultPlan.from_dict(LATE_PLAN)
    _, summary = run_once(data, task.topology, cfg, **kw)
    return summarise(task, summary)


def label(t: Task) -> str:
    if t.mode == "sync":
        return f"{t.scenario} sync"
    return f"{t.scenario} async gain {t.gain:g}" + (" late" if t.late else "")


def execute(tasks: Sequence[Task], jobs: int = 1, progress: bool = True) -> list[dict | None]:
    """Run ``tasks`` (a process pool when ``jobs > 1``); rows in task order, ``None`` for a run
    that raised (reported with one line on stderr). The ablation's loop, with this sweep's runs."""
    return ablation.execute(tasks, jobs, progress, run=run_task, label=label, name="bandwidth-sweep")


def _ratio(a, b) -> float | None:
    if a is None or b is None or not b:
        return None
    return a / b


def with_ratios(rows: Sequence[Mapping]) -> list[dict]:
    """Each row with ``bytes_ratio``, ``mota_ratio`` (ground) and ``idf1_ratio`` (ground) to its
    scenario's sync run (None without one)."""
    sync = {r["scenario"]: r for r in rows if r["mode"] == "sync"}
    out = []
    for r in rows:
        s = sync.get(r["scenario"], {})
        out.append({**r, "bytes_ratio": _ratio(r["bytes_per_frame"], s.get("bytes_per_frame")),
                    "mota_ratio": _ratio(r["ground_mota"], s.get("ground_mota")),
                    "idf1_ratio": _ratio(r["ground_idf1"], s.get("ground_idf1"))})
    return out


def summary(rows: Sequence[Mapping], tolerance: float = MOTA_TOLERANCE) -> dict[str, dict]:
    """Per scenario: the sync row, the largest on-time gain whose ground MOTA is within
    ``tolerance`` of sync (``best``, None when none is), the gains below it that are not
    (``failing_below``), and the late runs by gain."""
    out: dict[str, dict] = {}
    for sc in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == sc]
        sync = next((r for r in mine if r["mode"] == "sync"), None)
        on_time = sorted((r for r in mine if r["mode"] == "async" and not r["late"]),
                         key=lambda r: r["gain"])
        ok = [r for r in on_time if r["mota_ratio"] is not None
              and r["mota_ratio"] >= 1.0 - tolerance]
        best = ok[-1] if ok else None
        failing = [r["gain"] for r in on_time if best is not None and r["gain"] < best["gain"]
                   and r not in ok]
        out[sc] = {"sync": sync, "best": best, "failing_below": failing,
                   "late": {r["gain"]: r for r in mine if r["late"]}}
    return out


# -- outputs ------------------------------------------------------------------------------------------
def write_csv(path: Path, rows: Sequence[Mapping]) -> None:
    ablation.write_csv(path, rows, CSV_COLS)


def _f(v, fmt: str = "{:.3f}") -> str:
    return "–" if v is None else fmt.format(v)


def _gain(r: Mapping) -> str:
    return "–" if r["gain"] is None else f"{r['gain']:g}"


def _what(r: Mapping) -> str:
    return "sync" if r["mode"] == "sync" else ("async, late" if r["late"] else "async")


SUMMARY_HEADER = ("scenario", "sync B/frame", "gain (largest within 2%)", "bytes ratio",
                  "MOTA sync → async", "IDF1 sync → async", "late MOTA ratio (gain)")


def summary_rows(summ: Mapping[str, Mapping]) -> list[list[str]]:
    rows = []
    for sc, s in summ.items():
        sync, best = s["sync"], s["best"]
        late = ", ".join(f"{_f(r['mota_ratio'])} ({g:g})" for g, r in sorted(s["late"].items()))
        if sync is None:
            rows.append([sc, "–", "–", "–", "–", "–", late or "–"])
            continue
        if best is None:
            rows.append([sc, f"{sync['bytes_per_frame']:.0f}", "none", "–",
                         f"{_f(sync['ground_mota'])} → –", f"{_f(sync['ground_idf1'])} → –",
                         late or "–"])
            continue
        rows.append([sc, f"{sync['bytes_per_frame']:.0f}", f"{best['gain']:g}",
                     _f(best["bytes_ratio"]),
                     f"{_f(sync['ground_mota'])} → {_f(best['ground_mota'])}",
                     f"{_f(sync['ground_idf1'])} → {_f(best['ground_idf1'])}", late or "–"])
    return rows


def summary_text(summ: Mapping[str, Mapping]) -> str:
    """The summary as aligned plain text (what the command prints)."""
    rows = [list(SUMMARY_HEADER)] + summary_rows(summ)
    width = [max(len(r[i]) for r in rows) for i in range(len(SUMMARY_HEADER))]
    return "\n".join("  ".join(v.ljust(w) if i == 0 else v.rjust(w)
                               for i, (v, w) in enumerate(zip(r, width))) for r in rows)


def markdown(rows: Sequence[Mapping], summ: Mapping[str, Mapping], meta: Mapping) -> str:
    lines = ["# Bandwidth against accuracy: the event trigger's gain (issue 16)", ""]
    lines.append(
        f"Topology {meta['topology']}, configuration {meta['config']}, seed {meta['seed']}, "
        f"frames: {meta['frames'] or 'each scenario’s default'}; in process. `gain` is the "
        "trigger's threshold in nats (`edge_node/core/trigger.py`): withheld measurement "
        "information goes out once its KL divergence exceeds it; 0 sends every measurement. The "
        f"other trigger settings are the defaults (heartbeat every {_TRIGGER.heartbeat_frames} "
        f"frames, drift {_TRIGGER.drift:g} m): they still send when the gain would not. "
        f"Late: {LATE_TEXT} on every link (delay 1 + jitter 0-3, seeded). Bytes are what the "
        "codec produced, on every directed link (a message to each neighbour); B/tracker is per "
        "tracker entry on one link, appearance excluded. MOTA / IDF1: median over nodes; ground "
        "within 1 m, image IoU >= 0.5. Ratios are to the scenario's sync run.")
    lines.append("")
    if meta.get("command"):
        lines.append(f"Reproduce with `{meta['command']}`.")
        lines.append("")
    for sc, reason in meta.get("skipped", {}).items():
        lines.append(f"- **{sc} skipped**: {reason}")
    if meta.get("failed"):
        lines.append(f"- **{len(meta['failed'])} run(s) failed** and are left out: "
                     + "; ".join(meta["failed"][:10]))
    if meta.get("skipped") or meta.get("failed"):
        lines.append("")
    lines.append("## Summary")
    lines.append("")
    lines += _md_table(SUMMARY_HEADER, summary_rows(summ))
    lines.append("")
    lines.append(f"Goals (issue 16): bytes ratio <= {GOAL_BYTES_RATIO} at ground MOTA within "
                 f"{MOTA_TOLERANCE:.0%} of sync; with {LATE_TEXT}, async ground MOTA >= "
                 f"{GOAL_LATE_MOTA_RATIO} x sync.")
    lines.append("")
    for sc, s in summ.items():
        best = s["best"]
        if best is None:
            lines.append(f"- {sc}: no gain keeps ground MOTA within {MOTA_TOLERANCE:.0%} of sync.")
        else:
            met = best["bytes_ratio"] is not None and best["bytes_ratio"] <= GOAL_BYTES_RATIO
            note = (f" (but gain(s) {', '.join(f'{g:g}' for g in s['failing_below'])} below it "
                    "are not)" if s["failing_below"] else "")
            lines.append(f"- {sc}: largest gain within {MOTA_TOLERANCE:.0%} of sync MOTA: "
                         f"{best['gain']:g}{note}, bytes {_f(best['bytes_ratio'])} of sync "
                         f"({'meets' if met else 'misses'} the <= {GOAL_BYTES_RATIO} goal).")
        for g, r in sorted(s["late"].items()):
            met = r["mota_ratio"] is not None and r["mota_ratio"] >= GOAL_LATE_MOTA_RATIO
            lines.append(f"  Late, gain {g:g}: ground MOTA {_f(r['mota_ratio'])} of sync "
                         f"({'meets' if met else 'misses'} >= {GOAL_LATE_MOTA_RATIO}), bytes "
                         f"{_f(r['bytes_ratio'])} of sync.")
    lines.append("")
    for sc in summ:
        mine = [r for r in rows if r["scenario"] == sc]
        r0 = mine[0]
        lines.append(f"## {sc}")
        lines.append("")
        lines.append(f"{r0['nodes']} cameras, {r0['frames']} frames.")
        lines.append("")
        lines += _md_table(
            ["run", "gain", "B/frame", "B/tracker", "bytes ratio", "ground MOTA", "ground IDF1",
             "image MOTA", "image IDF1", "MOTA ratio"],
            [[_what(r), _gain(r), f"{r['bytes_per_frame']:.0f}",
              _f(r["bytes_per_tracker_frame"], "{:.1f}"), _f(r["bytes_ratio"]),
              _f(r["ground_mota"]), _f(r["ground_idf1"]), _f(r["image_mota"]),
              _f(r["image_idf1"]), _f(r["mota_ratio"])] for r in mine])
        lines.append("")
    lines.append(
        f"Paper (Sec. III-D, IV; analytic): {PAPER['kB_per_tracker_frame']} kB per tracker per "
        f"frame, {PAPER['kB_per_appearance_exchange']} kB per new tracker's appearance, "
        f"{PAPER['distributed_kB_per_frame_terrace']} kB per frame for the whole network on "
        "Terrace (upper bound).")
    lines.append("")
    return "\n".join(lines)


def plot(path: Path, rows: Sequence[Mapping], summ: Mapping[str, Mapping]) -> None:
    """``bandwidth.png``: a panel per scenario, x bytes per frame (kB; the top axis the ratio to
    sync), y ground MOTA and IDF1; async on time as lines (gains annotated), late as hollow
    markers, sync as stars; dotted: sync MOTA - 2% and half of sync's bytes (issue 16's goal)."""
    import matplotlib  # plotting only here

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # plotting only here (after choosing the headless backend)

    scenarios = list(summ)
    n = max(len(scenarios), 1)
    ncol = 2 if n > 1 else 1
    nrow = (n + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, squeeze=False, figsize=(6.2 * ncol, 4.4 * nrow))
    styles = (("ground_mota", "ground MOTA", "#08306b"), ("ground_idf1", "ground IDF1", "#e6550d"))
    for i, sc in enumerate(scenarios):
        ax = axes[i // ncol][i % ncol]
        mine = [r for r in rows if r["scenario"] == sc]
        on_time = sorted((r for r in mine if r["mode"] == "async" and not r["late"]),
                         key=lambda r: r["gain"])
        late = [r for r in mine if r["late"]]
        sync = summ[sc]["sync"]
        xmax = 1.08 * max(r["bytes_per_frame"] for r in mine) / 1e3
        for col, name, color in styles:
            pts = [(r["bytes_per_frame"] / 1e3, r[col]) for r in on_time if r[col] is not None]
            if pts:
                ax.plot(*zip(*pts), "o-", color=color, ms=4, lw=1.3, label=f"async: {name}")
            lp = [(r["bytes_per_frame"] / 1e3, r[col]) for r in late if r[col] is not None]
            if lp:
                ax.plot(*zip(*lp), "s", mfc="none", color=color, ms=7,
                        label=f"async, {LATE_TEXT}: {name}")
            if sync is not None and sync[col] is not None:
                ax.plot([sync["bytes_per_frame"] / 1e3], [sync[col]], "*", color=color, ms=14,
                        mec="black", mew=0.6, label=f"sync: {name}")
        if sync is not None and sync["ground_mota"] is not None:
            ax.axhline((1 - MOTA_TOLERANCE) * sync["ground_mota"], color="#08306b", lw=0.7,
                       ls=":", label=f"sync MOTA - {MOTA_TOLERANCE:.0%}")
        if sync is not None and sync["bytes_per_frame"]:
            sb = sync["bytes_per_frame"] / 1e3
            ax.axvline(GOAL_BYTES_RATIO * sb, color="grey", lw=0.7, ls=":",
                       label=f"{GOAL_BYTES_RATIO:g} x sync bytes")
            top = ax.secondary_xaxis("top", functions=(lambda x, sb=sb: x / sb,
                                                       lambda r, sb=sb: r * sb))
            top.set_xlabel("bytes / sync", fontsize=8)
            top.tick_params(labelsize=8)
        last_x, depth = None, 0  # labels of points close together go one line lower
        for r in on_time:
            if r["ground_mota"] is None:
                continue
            x = r["bytes_per_frame"] / 1e3
            depth = depth + 1 if last_x is not None and abs(x - last_x) < 0.05 * xmax else 0
            last_x = x
            ax.annotate(f"{r['gain']:g}", (x, r["ground_mota"]), textcoords="offset points",
                        xytext=(0, -11 - 8 * (depth % 3)), ha="center", fontsize=7,
                        color="#08306b")
        for r in late:
            if r["ground_mota"] is not None:
                x = r["bytes_per_frame"] / 1e3
                right = x > 0.75 * xmax  # near the right edge: the label on the left
                ax.annotate(f"late, gain {r['gain']:g}", (x, r["ground_mota"]),
                            textcoords="offset points", xytext=(-7 if right else 7, -3),
                            ha="right" if right else "left", fontsize=7, color="#555555")
        ax.set_xlim(0, xmax)
        ax.set_xlabel("kB per frame, whole network")
        ax.set_title(f"{sc} ({mine[0]['nodes']} cameras, {mine[0]['frames']} frames); "
                     "labels: gain (nats)", fontsize=9)
        ax.grid(alpha=0.3)
        ys = [r[c] for r in mine for c, _, _ in styles if r[c] is not None]
        if ys:
            ax.set_ylim(max(min(min(ys) - 0.03, 0.9), -1.0), 1.005)
    for j in range(len(scenarios), nrow * ncol):
        axes[j // ncol][j % ncol].axis("off")
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper center", ncol=4, frameon=False, fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.55 / (4.4 * nrow)))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out: Path, rows: Sequence[Mapping], summ: Mapping, meta: Mapping) -> list[Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "bandwidth.csv", out / "bandwidth.md", out / "bandwidth.png"]
    write_csv(paths[0], rows)
    paths[1].write_text(markdown(rows, summ, meta))
    plot(paths[2], rows, summ)
    return paths


def command(scenarios: Sequence[str], gains: Sequence[float], late: Sequence[float],
            args) -> str:
    """The command line that makes these outputs again (``--out`` and ``--jobs`` left out)."""
    parts = ["sim_cluster bandwidth-sweep", "--scenarios " + ",".join(scenarios)]
    if args.topology != "ring":
        parts.append(f"--topology {args.topology}")
    if args.config != CONFIG:
        parts.append(f"--config {args.config}")
    parts.append("--gains " + ",".join(f"{g:g}" for g in gains))
    parts.append("--late " + (",".join(f"{g:g}" for g in late) or "none"))
    if args.seed:
        parts.append(f"--seed {args.seed}")
    if args.frames:
        parts.append(f"--frames {args.frames}")
    return " ".join(parts)


# -- command ------------------------------------------------------------------------------------------
def main(args) -> int:
    """``sim_cluster bandwidth-sweep``; raises ``BandwidthError`` on a bad argument."""
    t0 = time.monotonic()
    scenarios = parse_list(args.scenarios, None, "scenario")
    gains = parse_gains(args.gains)
    late = parse_gains(args.late, "--late", allow_empty=True)
    if args.config not in CONFIG_NAMES:
        raise BandwidthError(f"unknown config {args.config!r}: choose from "
                             f"{', '.join(CONFIG_NAMES)}")
    data_root = None if args.data_root is None else str(Path(args.data_root).expanduser().resolve())
    quiet = args.quiet
    info, skipped = probe(scenarios, args.seed, data_root, name="bandwidth-sweep")
    runnable = [s for s in scenarios if s in info]
    if not runnable:
        raise BandwidthError("nothing to run: every scenario was skipped")
    if args.topology == CENTRALIZED:
        raise BandwidthError("--topology centralized has no links to send on: pick a network "
                             "topology")
    for s in runnable:  # a bad name or edge-list file: one line now, not a failure per run
        topo.build(args.topology, info[s]["cameras"])
    tasks = plan(runnable, gains, late, topology=args.topology, config=args.config,
                 seed=args.seed, frames=args.frames,
                 data_root={s: info[s]["data_root"] for s in runnable})
    if not quiet:
        print(f"bandwidth-sweep: {len(tasks)} runs ({len(runnable)} scenario(s) x (sync + "
              f"{len(gains)} gain(s) + {len(late)} late)) on {min(args.jobs, len(tasks))} "
              "process(es)", file=sys.stderr, flush=True)
    results = execute(tasks, args.jobs, progress=not quiet)
    failed = [label(t) for t, r in zip(tasks, results) if r is None]
    rows = with_ratios([r for r in results if r is not None])
    summ = summary(rows)
    meta = {"topology": args.topology, "config": args.config, "seed": args.seed,
            "frames": args.frames, "skipped": skipped, "failed": failed,
            "command": command(scenarios, gains, late, args)}
    paths = write_outputs(Path(args.out), rows, summ, meta)
    if rows:
        print(summary_text(summ))
    print(f"bandwidth-sweep: {len(rows)}/{len(tasks)} runs in {_hms(time.monotonic() - t0)}; "
          "wrote " + ", ".join(str(p) for p in paths))
    if failed:
        print(f"bandwidth-sweep: {len(failed)} run(s) failed (see above); they are left out",
              file=sys.stderr)
        return 1
    return 0
