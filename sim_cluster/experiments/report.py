"""``sim_cluster report``: every results and benchmark table of the docs, rendered from the data
files the commands write (``docs/results/``). (The CLI reference is rendered from the argparse
parsers by the docs build itself: ``docs/hooks/cli_reference.py``.)

A generated part of a docs page is a block::

    <!-- report:NAME -->
    ... (written by sim_cluster report; edit the template, not the text) ...
    <!-- /report -->

``sim_cluster report`` rewrites every block of every page under ``docs/`` from its template and
data; ``sim_cluster report --check`` changes nothing and exits 1 naming each block whose text
differs from what its data gives (the test suite runs it). Under each table a line names the
data file, the command that writes it, the commit of the code it was measured on and the
machine (from the file's ``meta.provenance``, or for files that predate it from
``docs/results/provenance.json``).

Adding a table: a command writes a JSON file under ``docs/results/`` (with
``meta.provenance = sim_cluster.experiments.provenance.provenance()``), a function here turns it
into Markdown, registered with ``@table("NAME", "path/under/results.json")``, and a page gets a
``<!-- report:NAME -->`` block.
"""
from __future__ import annotations

import csv
import json
import math
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BLOCK = re.compile(r"(<!-- report:(?P<name>[\w.@-]+) -->\n)(?P<body>.*?)(<!-- /report -->)", re.S)


class Table:
    def __init__(self, name: str, source: str | None, fn: Callable[..., str]):
        self.name, self.source, self.fn = name, source, fn


TABLES: dict[str, Table] = {}


def table(name: str, source: str | None = None):
    """Register ``fn(data) -> markdown`` as block ``name``, fed the file ``source`` (relative to
    the results folder; ``.json`` parsed, ``.csv`` as a list of dicts, else text)."""
    def wrap(fn):
        TABLES[name] = Table(name, source, fn)
        return fn
    return wrap


# -- formatting ---------------------------------------------------------------------------------
def f3(x) -> str:
    """Three decimals, a real minus sign for negatives (as the tables always printed them)."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    s = f"{x:.3f}"
    return s.replace("-", "\u2212") if s.startswith("-") else s


def pair(cell: dict, view: str) -> str:
    return f"{f3(cell[f'{view}_mota']['mean'])} / {f3(cell[f'{view}_idf1']['mean'])}"


def md(header: list[str], rows: list[list[str]], align: list[str] | None = None) -> str:
    align = align or ["---"] * len(header)
    out = ["| " + " | ".join(header) + " |", "| " + " | ".join(align) + " |"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _load(results: Path, source: str):
    path = results / source
    if source.endswith(".json"):
        return json.loads(path.read_text())
    if source.endswith(".csv"):
        with path.open(newline="") as f:
            return list(csv.DictReader(f))
    return path.read_text()


def provenance_line(results: Path, source: str, data) -> str:
    prov = None
    if isinstance(data, dict):
        prov = (data.get("meta") or {}).get("provenance")
    if prov is None:
        side = results / "provenance.json"
        if side.is_file():
            prov = json.loads(side.read_text()).get(source)
    link = f"`docs/results/{source}`"
    if not prov:
        return f"*Data: {link}.*"
    parts = [f"*Data: {link}"]
    if prov.get("command"):
        parts.append(f"written by `{prov['command']}`")
    if prov.get("commit"):
        parts.append(f"code of commit `{prov['commit']}`")
    if prov.get("machine"):
        parts.append(f"machine: {prov['machine']}")
    if prov.get("load") is not None:
        parts.append(f"load average {prov['load']}")
    return "; ".join(parts) + ".*"


def render(name: str, results: Path | None = None) -> str:
    results = results or ROOT / "docs" / "results"
    t = TABLES[name]
    data = _load(results, t.source)
    return t.fn(data).rstrip() + "\n\n" + provenance_line(results, t.source, data) + "\n"


# -- the ablation (summary.json) ----------------------------------------------------------------
#: a table's column header -> (configuration, view)
ABLATION_COLUMNS = {
    "dkf": ("dkf", "ground"),
    "dkf+lda": ("dkf+lda", "ground"),
    "dkf+lda+dtm ground": ("dkf+lda+dtm", "ground"),
    ":noreg ground": ("dkf+lda+dtm:noreg", "ground"),
    "dkf+dtm ground": ("dkf+dtm", "ground"),
    "dkf+lda+dtm image": ("dkf+lda+dtm", "image"),
    ":noreg image": ("dkf+lda+dtm:noreg", "image"),
    "dkf+dtm image": ("dkf+dtm", "image"),
}
GT_COLUMNS = ["dkf+lda+dtm ground", ":noreg ground", "dkf+dtm ground", "dkf+lda+dtm image",
              ":noreg image", "dkf+dtm image"]
SIM_COLUMNS = ["dkf", "dkf+lda", "dkf+lda+dtm ground", ":noreg ground", "dkf+dtm ground",
               "dkf+lda+dtm image", ":noreg image"]


def _topologies(summary: dict, scenario: str) -> list[str]:
    meta = summary["meta"]["scenarios"].get(scenario, {})
    topos = [t for t in summary["meta"]["topologies"] if t in summary["cells"][scenario]]
    if meta.get("ring_is_complete"):
        topos = [t for t in topos if t != "ring"]
    return topos


def ablation_table(summary: dict, scenario: str, columns: list[str]) -> str:
    rows = []
    for topo in _topologies(summary, scenario):
        cells = summary["cells"][scenario][topo]
        rows.append([topo] + [pair(cells[ABLATION_COLUMNS[c][0]], ABLATION_COLUMNS[c][1])
                              for c in columns])
    return md(["topology"] + columns, rows)


for _scn, _cols in (("terrace-gt", GT_COLUMNS), ("campus-gt", GT_COLUMNS),
                    ("terrace-sim", SIM_COLUMNS), ("lab-sim", SIM_COLUMNS),
                    ("campus-sim", SIM_COLUMNS)):
    table(f"ablation-{_scn}", "summary.json")(
        lambda s, _scn=_scn, _cols=_cols: ablation_table(s, _scn, _cols))


@table("ablation-ratios", "summary.json")
def ablation_ratios(s: dict) -> str:
    """Distributed over centralized ground MOTA, the complete method, per scenario."""
    topos = ["complete", "ring", "chain", "disconnected"]
    rows = []
    for scn, by in s["ratios_by_config"].items():
        r = by.get("dkf+lda+dtm", {})
        rows.append([scn] + [("= complete" if t == "ring" and s["meta"]["scenarios"][scn].get(
            "ring_is_complete") else f3(r[t]["ground_mota"]["mean"]) if t in r else "-")
            for t in topos])
    return md(["scenario"] + topos, rows, ["---"] + ["---:"] * len(topos))


# -- the whole Terrace sequence -----------------------------------------------------------------
@table("terrace-full", "terrace-full/summary.json")
def terrace_full(s: dict) -> str:
    rows = []
    for topo in _topologies(s, "terrace-full"):
        c = s["cells"]["terrace-full"][topo]
        a, b = c["dkf+lda+dtm"], c["dkf+dtm"]
        rows.append([topo, pair(a, "ground"), pair(a, "image"), pair(b, "ground"), pair(b, "image"),
                     f"{a['ground_track_ids']['mean']:.0f} / {b['ground_track_ids']['mean']:.0f}"])
    return md(["topology", "with descriptors: ground MOTA / IDF1", "image MOTA / IDF1",
               "without descriptors (`dkf+dtm`): ground", "image", "track ids (with / without)"],
              rows)


# -- each camera's own view (own_view.json) ----------------------------------------------------
@table("own-view", "views/own_view.json")
def own_view(s: dict) -> str:
    rows = []
    for cell, c in s["cells"].items():
        scenario, topology = cell.split("/", 1)
        b, a = c["before"], c["after"]
        seeds = sorted(b["seeds"], key=int)
        per = ", ".join(f"{f3(b['seeds'][k]['image'])} -> {f3(a['seeds'][k]['image'])}" for k in seeds)
        rows.append([scenario, topology, f"{f3(b['image_mota'])} -> {f3(a['image_mota'])}",
                     f"{f3(b['ground_mota'])} -> {f3(a['ground_mota'])}", per])
    seeds = ", ".join(str(k) for k in s["meta"]["seeds"])
    return md(["scenario", "topology", "image MOTA, before -> after", "ground MOTA",
               f"image MOTA per seed ({seeds})"], rows)


# -- re-id quality ------------------------------------------------------------------------------
@table("reid-sweep", "reid/summary.json")
def reid_sweep(s: dict) -> str:
    """A column per group (scenario/topology; a scenario alone in files of one topology):
    ground MOTA / IDF1 and, beside each level, its IDF1 minus that of no descriptors."""
    groups = list(s["cells"])
    header = ["stated rank-1"] + [f"{g}: ground MOTA / IDF1 (vs none)" for g in groups]
    rows = []
    for level in s["meta"]["levels"]:
        label = {"1": "1 (perfect)", "none": "none (`dkf+dtm`)"}.get(level, level)
        row = [label]
        for g in groups:
            c = s["cells"][g].get(level)
            if c is None:
                row.append("–")
                continue
            none = s["cells"][g].get("none", {}).get("ground_idf1")
            delta = ("" if level == "none" or none is None
                     else f" ({c['ground_idf1']['mean'] - none['mean']:+.3f})")
            row.append(pair(c, "ground") + delta)
        rows.append(row)
    return md(header, rows)


# -- bandwidth ----------------------------------------------------------------------------------
def _bw(rows: list[dict]) -> dict:
    out: dict = {}
    for r in rows:
        scn = r["scenario"]
        late = r["late"] == "True"
        key = "sync" if r["mode"] == "sync" else (("late" if late else "async"), float(r["gain"]))
        out.setdefault(scn, {})[key] = r
    return out


@table("bandwidth", "bandwidth/bandwidth.csv")
def bandwidth(rows: list[dict]) -> str:
    out = []
    for scn, by in _bw(rows).items():
        s, a = by["sync"], by[("async", 1.0)]
        l0, l1 = by.get(("late", 0.0)), by.get(("late", 1.0))
        f = lambda r, k: f3(float(r[k]))  # noqa: E731
        out.append([scn, f"{float(s['bytes_per_frame']):.0f}",
                    f"{float(a['bytes_per_frame']):.0f} ({float(a['bytes_ratio']):.2f})",
                    f"{f(s, 'ground_mota')} / {f(s, 'ground_idf1')} → "
                    f"{f(a, 'ground_mota')} / {f(a, 'ground_idf1')}",
                    f"{f(s, 'image_mota')} → {f(a, 'image_mota')}",
                    f"{f(l0, 'mota_ratio') if l0 else '-'} / {f(l1, 'mota_ratio') if l1 else '-'}"])
    return md(["preset", "sync B/frame", "gain 1: B/frame (ratio to sync)",
               "ground MOTA / IDF1 sync → gain 1", "image MOTA sync → gain 1",
               "1-4 frames late: ground MOTA / sync, gain 0 / 1"], out,
              ["---", "---:", "---:", "---", "---", "---"])


@table("bandwidth-paper", "bandwidth/bandwidth.csv")
def bandwidth_paper(rows: list[dict]) -> str:
    by = _bw(rows)
    per = {s: float(b["sync"]["bytes_per_tracker_frame"]) for s, b in by.items()}
    app = [float(b["sync"]["appearance_bytes_per_new_tracker"]) for b in by.values()]
    def frame(s):
        return (f"{s} {float(by[s]['sync']['bytes_per_frame']) / 1000:.2f} kB sync, "
                f"{float(by[s][('async', 1.0)]['bytes_per_frame']) / 1000:.2f} kB async at gain 1")
    terrace = [s for s in ("terrace-gt", "terrace-sim") if s in by]
    return md(["", "paper", "measured (sync, ring, dkf+lda+dtm, seed 0)"], [
        ["per tracker per frame", "0.78 kB",
         ", ".join(f"{s} {per[s]:.0f} B" for s in terrace)],
        ["per new tracker's appearance (two 512-d descriptors)", "16.38 kB",
         f"{min(app):.0f}-{max(app):.0f} B (int8)"],
        ["per frame, whole network, Terrace", "28.23 kB (upper bound)",
         "; ".join(frame(s) for s in terrace)],
    ], ["---", "---:", "---"])


# -- scale ----------------------------------------------------------------------------------------
@table("scale", "scale/scale.csv")
def scale(rows: list[dict]) -> str:
    out = []
    for r in sorted(rows, key=lambda r: (int(r["cameras"]), int(r["scope"]))):
        g = lambda k: float(r[k])  # noqa: E731
        out.append([r["cameras"], r["scope"], f"{g('people_per_frame'):.0f}",
                    f"{g('cpu_ms_median'):.2f} / {g('cpu_ms_p90'):.2f}",
                    f"{g('trackers_median'):.0f} / {g('trackers_max'):.0f}",
                    f"{g('bytes_per_node_frame'):.0f}",
                    f"{f3(g('mota'))} / {f3(g('idf1'))}",
                    f"{f3(g('mota_region'))} / {f3(g('idf1_region'))}",
                    f"{r['long_walkers']}; {g('id_kept'):.3f} / {g('ids_per_walk'):.2f}; "
                    f"{g('id_kept_region'):.3f} / {g('ids_per_walk_region'):.2f}",
                    f"{g('frames_per_s'):.3g}"])
    return md(["cameras", "scope", "people in view", "CPU ms (median / p90)",
               "trackers per node (median / max)", "bytes per node-frame",
               "MOTA / IDF1 global", "MOTA / IDF1 regional",
               "long walkers; id kept / ids per walk, global; regional", "frames/s"], out,
              ["---:", "---:", "---:", "---:", "---:", "---:", "---", "---", "---", "---:"])


@table("scale-ratio", "scale/scale.csv")
def scale_ratio(rows: list[dict]) -> str:
    cpu = {(int(r["cameras"]), int(r["scope"])): float(r["cpu_ms_median"]) for r in rows}
    out = []
    for scope in sorted({s for _, s in cpu}):
        cams = sorted(c for c, s in cpu if s == scope)
        lo = cams[0]
        out.append([str(scope)] + [f"{cpu[(c, scope)] / cpu[(lo, scope)]:.2f}x" for c in cams[1:]])
    cams = sorted({c for c, _ in cpu})
    return md(["scope"] + [f"{c} / {cams[0]} cameras" for c in cams[1:]], out,
              ["---:"] + ["---:"] * (len(cams) - 1))


# -- the tracker core and the codec (sim_cluster bench --json) -----------------------------------
@table("core-bench", "bench/core.json")
def core_bench(d: dict) -> str:
    m = d["meta"]
    rows = []
    for r in d["rows"]:
        runs = r["core_ms_runs"]
        codec = r["codec_node_frame_us_runs"]
        rows.append([str(r["targets"]), f"{r['trackers_per_node']:.0f}",
                     f"{r['core_ms_median']:.2f} ({runs[0]:.2f}-{runs[-1]:.2f})",
                     f"{r['core_ms_p90']:.2f}",
                     f"{r['codec_node_frame_block_us']:.0f} ({codec[0]:.0f}-{codec[-1]:.0f})",
                     f"{r['codec_encode_block_us']:.0f} / {r['codec_decode_us']:.0f}",
                     f"{r['codec_bytes']:.0f}", f"{r['bytes_per_tracker']:.1f}",
                     f"{r['appearance_bytes_per_new_tracker']:.0f}"])
    return md(["targets", "trackers per node", "core ms per node-frame (median of runs; range)",
               "p90 ms", f"codec µs per node-frame (1 encode + {m['neighbours']} decodes)",
               "encode / decode µs", "bytes per message", "bytes per tracker",
               "bytes per appearance"], rows, ["---:"] * 9) + (
        f"\n\n{m['frames']} frames, {m['neighbours']} neighbours, {m['repeats']} runs; CPU time of "
        "the process (`time.process_time`).")


# -- the zombie probes (sim_cluster probe KIND --out docs/results/probe) -----------------------------
PROBE_GOALS = {
    "freeze": "frozen node within one frame of its neighbours within 2 s of SIGCONT; neighbours at "
              ">= 0.95 of camera rate",
    "disk-full": "every node `degraded` within 2 s, tracking and sending on; no unreadable row, no "
                 "(frame, id) row twice",
    "restarts": "every track file reads whole; no (frame, id) row twice",
    "flood": "honest nodes at camera rate, resident memory within +10 %, every node still sending, "
             "honest people's tracks as in the run without the flood (same ids in every frame, "
             "positions within 0.25 m)",
    "boot": "nodes not bordering the absent camera start within 1 s, its neighbour within 5 s",
}


def probe_table(d: dict) -> str:
    rows = d["rows"]
    keys = [k for k in rows[0] if k != "pass"]
    body = md([k.replace("_", " ") for k in keys] + ["goal met"],
              [[("-" if r[k] is None else str(r[k])) for k in keys] + ["yes" if r["pass"] else "no"]
               for r in rows])
    return f"Goal: {PROBE_GOALS[d['kind']]}.\n\n{body}"


for _kind in PROBE_GOALS:
    table(f"probe-{_kind}", f"probe/probe_{_kind}.json")(probe_table)


# -- faults -----------------------------------------------------------------------------------------
@table("faults", "fault_report.md")
def faults(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if line.startswith("|"))


# -- a faulty neighbour (trust-report) ------------------------------------------------------------
def trust_rows(summary: list[dict]) -> str:
    """``sim_cluster trust-report``'s summary as a markdown table (it prints the same)."""
    def f(x, fmt="{:.3f}"):
        return "-" if x is None else fmt.format(x)
    lines = ["| scenario | faulty kind | trust role | ground MOTA (x fault-free) | ground IDF1 "
             "(x fault-free) | settled: node 0 and its neighbours 2 s on (x fault-free) "
             "| far tracks > 1 s | frames to quarantine (worst) | ids kept | "
             "honest nodes quarantined |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for s in summary:
        kind = s["kind"] if s["kind"] != "none" else (
            "none (async, late and lost messages)" if s["late"] else "none")
        q = f(s["quarantine_frames"], "{}")
        if s["unquarantined"]:
            q = f"never at {s['unquarantined']} of the neighbours' runs" if q == "-" else q
        lines.append(
            f"| {s['scenario']} | {kind} | {'on' if s['trust'] else 'off'} "
            f"| {f(s['mota'])} ({f(s['mota_ratio'])}x) | {f(s['idf1'])} ({f(s['idf1_ratio'])}x) "
            f"| {f(s.get('settled_ratio'))}{'x' if s.get('settled_ratio') is not None else ''} "
            f"| {s['far']} | {q if s['kind'] != 'none' else '-'} | {f(s['kept_ids'], '{:.2f}')} "
            f"| {s['honest_quarantined']} |")
    return "\n".join(lines)


def trust_table(d: dict, omit: tuple[str, ...] = ()) -> str:
    meta = d["meta"]
    return (f"Node 0 of a ring faulty from a third of the run to two thirds; honest nodes only; "
            f"medians over seeds {', '.join(map(str, meta['seeds']))} ({meta['config']}); "
            "ratios against the fault-free sync run of the same seed; settled: ground MOTA "
            "of node 0 and its neighbours from 2 s after the fault starts and 2 s after it "
            "ends; far tracks: the most "
            "episodes of a seed; frames to quarantine and ids kept: the worst neighbour and "
            "seed.\n\n" + trust_rows([s for s in d["summary"] if s["kind"] not in omit]))


table("trust", "trust/trust.json")(trust_table)
#: negative evidence with the fixed limit of 10 frames, when it was an option (report_unseen
#: without unseen_runs), with the tracker config the runs were given
table("trust-unseen", "trust-unseen/trust.json")(trust_table)
#: the bumped camera without its re-lock (registration R7, reg_relock): runs of code whose
#: default had it off
table("trust-norelock", "trust-norelock/trust.json")(
    lambda d: trust_table(d, omit=tuple({s["kind"] for s in d["summary"]} - {"none", "bumped"})))


# -- detectors --------------------------------------------------------------------------------------
DETECTOR_LABELS = {"mog2": "MOG2 (empty-scene start, camera geometry)",
                   "ssdlite": "ssdlite, score >= 0.3",
                   "ssdlite@0.1": "ssdlite, score >= 0.1",
                   "ssdlite tiles 2x2": "ssdlite, 2 x 2 tiles + whole frame, score >= 0.3"}


def render_detectors(d: dict) -> str:
    scenarios = list(d["scenarios"])
    names = list(next(iter(d["scenarios"].values()))["variants"])
    header = ["detector"] + [f"{s}: recall / precision" for s in scenarios] + ["ms / frame (default threads)"]
    rows = []
    for n in names:
        row = [DETECTOR_LABELS.get(n, n)]
        ms = []
        for s in scenarios:
            v = d["scenarios"][s]["variants"][n]
            row.append(f"{v['recall']:.3f} / {v['precision']:.3f}")
            ms.append(v["ms_per_frame"])
        row.append(f"{sum(ms) / len(ms):.0f}")
        rows.append(row)
    people = ", ".join(f"{s} {d['scenarios'][s]['variants'][names[0]]['people']}"
                       for s in scenarios)
    return (md(header, rows, ["---"] + ["---:"] * (len(header) - 1)) +
            f"\n\nVisible people scored: {people} (every {d['meta']['stride']}th frame from "
            f"frame {d['meta']['warmup']} of {d['meta']['frames']}, every camera; IoU >= "
            f"{d['meta']['iou']}; ssdlite backend: {d['meta']['backends'].get('ssdlite', '?')}). "
            "Recall counts the visible people found; precision the detections on anyone in the "
            "image, a half-hidden person included.")


def render_detector_backends(d: dict) -> str:
    b = d["backends"]
    rows = [[name, b.get(f"{name}_version", "") if name != "opencv" else b.get("opencv_version", ""),
             f"{b[name]['ms_median']:.1f} ({b[name]['ms_min']:.1f}-{b[name]['ms_max']:.1f})"]
            for name in ("opencv", "onnxruntime") if name in b]
    text = md(["backend", "version", "ms / frame, one thread (median, range over rounds)"], rows,
              ["---", "---", "---:"])
    if "ratio_opencv_to_onnxruntime" in b:
        text += (f"\n\nOpenCV DNN / onnxruntime: **{b['ratio_opencv_to_onnxruntime']:.2f}x** the "
                 f"time, timed alternately in one run; largest difference between their boxes "
                 f"{b['largest_difference_px']:.2g} px.")
    return text


table("detectors", "perception/detectors.json")(render_detectors)
table("detector-backends", "perception/detectors.json")(render_detector_backends)


# -- rewriting the pages ------------------------------------------------------------------------------
def pages(docs: Path) -> list[Path]:
    return sorted(p for p in docs.rglob("*.md") if "results" not in p.relative_to(docs).parts[:1])


def update(docs: Path, results: Path, check: bool) -> tuple[list[str], list[str]]:
    """``(stale blocks, unknown blocks)``; rewrites the pages unless ``check``."""
    stale, unknown = [], []
    for page in pages(docs):
        text = page.read_text()

        def sub(m):
            name = m.group("name")
            if name not in TABLES:
                unknown.append(f"{page.relative_to(docs)}: {name}")
                return m.group(0)
            body = render(name, results)
            if body != m.group("body"):
                stale.append(f"{page.relative_to(docs)}: {name}")
            return m.group(1) + body + m.group(4)

        new = BLOCK.sub(sub, text)
        if new != text and not check:
            page.write_text(new)
    return stale, unknown


def main(args) -> int:
    docs = Path(args.docs)
    results = Path(args.results) if args.results else docs / "results"
    stale, unknown = update(docs, results, args.check)
    for u in unknown:
        print(f"sim_cluster report: unknown block {u} (known: {', '.join(sorted(TABLES))})",
              file=sys.stderr)
    if args.check:
        for s in stale:
            print(f"stale: {s} (its data file says otherwise; run sim_cluster report)")
        if not stale and not unknown:
            print(f"every generated block of {docs} matches its data")
        return 1 if stale or unknown else 0
    print(f"rewrote {len(stale)} block(s) of {docs}" + (": " + ", ".join(stale) if stale else ""))
    return 1 if unknown else 0
