"""Human-readable tables of a run's summary."""
from __future__ import annotations

import statistics


def _f(v, fmt="{:.3f}") -> str:
    return "-" if v is None else fmt.format(v)


def _mt(m: dict) -> str:
    """``MT/PT/ML`` of one metrics dict (``-`` when absent: a summary written before them)."""
    if m.get("mostly_tracked") is None:
        return "-"
    return "/".join(f"{m.get(n) or 0:g}" for n in ("mostly_tracked", "partially_tracked",
                                                     "mostly_lost"))


def run_table(summary: dict) -> str:
    """Per node: track ids issued, ground and image MOTA / IDF1, ground identity counts (track
    ids per person matched, fragmentations, mostly tracked / partially / mostly lost people),
    bytes sent per frame."""
    m = summary.get("metrics", {})
    g, im = m.get("ground", {}), m.get("image", {})
    bw = summary["bandwidth"]
    sent: dict[str, float] = {}
    for link, b in bw["per_link"].items():
        src = link.split("->")[0]
        sent[src] = sent.get(src, 0.0) + b
    people = next((v.get("num_unique_objects") for v in g.get("per_node", {}).values()), None)
    lines = [f"{summary['scenario']}  topology={summary['topology']}  config={summary['config']}  "
             f"seed={summary['seed']}  frames={summary['frames']}"
             + (f"  people={people}" if people is not None else ""),
             f"{'node':>4} {'ids':>5} {'gMOTA':>7} {'gIDF1':>7} {'gMOTP[m]':>9} {'ids/pers':>8} "
             f"{'FM':>5} {'MT/PT/ML':>9} {'iMOTA':>7} {'iIDF1':>7} {'sent B/frame':>12}"]
    for node, nids in summary["tracks"]["ids_per_node"].items():
        gn = g.get("per_node", {}).get(node, {})
        inn = im.get("per_node", {}).get(node, {})
        lines.append(f"{node:>4} {nids:>5} {_f(gn.get('mota')):>7} {_f(gn.get('idf1')):>7} "
                     f"{_f(gn.get('motp_m')):>9} {_f(gn.get('ids_per_person'), '{:.2f}'):>8} "
                     f"{_f(gn.get('num_fragmentations'), '{:.0f}'):>5} {_mt(gn):>9} "
                     f"{_f(inn.get('mota')):>7} {_f(inn.get('idf1')):>7} "
                     f"{_f(sent.get(node), '{:.0f}'):>12}")
    gm, imm = g.get("median", {}), im.get("median", {})
    if gm or imm:
        lines.append(f"{'med':>4} {'':>5} {_f(gm.get('mota')):>7} {_f(gm.get('idf1')):>7} "
                     f"{_f(gm.get('motp_m')):>9} {_f(gm.get('ids_per_person'), '{:.2f}'):>8} "
                     f"{_f(gm.get('num_fragmentations'), '{:g}'):>5} {_mt(gm):>9} "
                     f"{_f(imm.get('mota')):>7} {_f(imm.get('idf1')):>7}")
    if people is not None:
        lines.append("ids: track ids reported; ids/pers: track ids matched per person (ground); "
                     "FM: fragmentations;\nMT/PT/ML: people tracked in >= 80 %, 20-80 %, < 20 % "
                     "of their frames (ground)")
    lines.append(f"bandwidth: {bw['bytes_per_frame'] / 1000:.2f} kB/frame network-wide, "
                 f"{bw['bytes_per_tracker_frame']:.0f} B per tracker per frame, "
                 f"{bw['appearance_bytes_per_new_tracker']:.0f} B per new tracker's appearance")
    return "\n".join(lines)


def latency_line(summary: dict) -> str:
    """The one-hop latency of a cluster run (``summary["processes"][node]["latency"]``, written
    by ``edge_node.runtime.output.latency_summary``): the median of the node medians, and the
    nodes without a sample (no neighbour, or none that sent): ``-`` when no node has one."""
    medians, without = [], []
    for node, proc in summary.get("processes", {}).items():
        m = (proc.get("latency") or {}).get("median_ms")
        if m is None:
            without.append(node)
        else:
            medians.append(m)
    none = (f" (no samples: node{'s' if len(without) > 1 else ''} {', '.join(without)})"
            if without else "")
    if not medians:
        return f"one-hop latency: -{none}"
    return f"one-hop latency: median of node medians {statistics.median(medians):.2f} ms{none}"
