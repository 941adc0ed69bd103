"""Real network separation (issue 14, item 5): one Linux network namespace per camera ("host"),
joined by veth links with private addresses that exist only inside those namespaces. A link is
taken down mid-run and brought back, so it is Zenoh's own link loss and reconnection that the
nodes live through, not the in-app fault layer. Root only; skipped, with the reason, where the
kernel or the user cannot make namespaces."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.loopback import export_scenario

REPO = Path(__file__).resolve().parents[1]
FPS, FRAMES = 25.0, 300
# chain 0 - 1 - 2; link (a, b) gets 10.213.<n>.1 on a's side and .2 on b's side
LINKS = {(0, 1): 1, (1, 2): 2}
PORT = 7447


def sh(*cmd: str) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=20)


def netns_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "needs root (network namespaces)"
    probe = f"dmtt-probe-{os.getpid()}"
    r = sh("ip", "netns", "add", probe)
    if r.returncode != 0:
        return f"cannot make a network namespace: {r.stderr.strip()}"
    sh("ip", "netns", "del", probe)
    return None


class Hosts:
    """Three namespaces joined by two veth links; removed on exit."""

    def __init__(self, tag: str):
        self.ns = {i: f"dmtt{tag}-{i}" for i in range(3)}
        self.dev = {}  # (node, link) -> device name in that node's namespace
        for i, ns in self.ns.items():
            self._ok("ip", "netns", "add", ns)
            self._ok("ip", "-n", ns, "link", "set", "lo", "up")
        for (a, b), n in LINKS.items():
            da, db = f"v{a}{b}a", f"v{a}{b}b"
            self._ok("ip", "link", "add", da, "netns", self.ns[a], "type", "veth",
                     "peer", "name", db, "netns", self.ns[b])
            for node, dev, host in ((a, da, 1), (b, db, 2)):
                self._ok("ip", "-n", self.ns[node], "addr", "add", f"10.213.{n}.{host}/30",
                         "dev", dev)
                self._ok("ip", "-n", self.ns[node], "link", "set", dev, "up")
                self.dev[(node, (a, b))] = dev

    @staticmethod
    def _ok(*cmd: str) -> None:
        r = sh(*cmd)
        assert r.returncode == 0, (cmd, r.stderr)

    @staticmethod
    def addr(link: tuple[int, int], node: int) -> str:
        return f"tcp/10.213.{LINKS[link]}.{1 if node == link[0] else 2}:{PORT}"

    def link(self, link: tuple[int, int], up: bool) -> None:
        for node in link:
            self._ok("ip", "-n", self.ns[node], "link", "set", self.dev[(node, link)],
                     "up" if up else "down")

    def close(self) -> None:
        for ns in self.ns.values():
            sh("ip", "netns", "del", ns)


def node_config(path: Path, node: int, export: Path, out: Path) -> Path:
    links = [l for l in LINKS if node in l]
    neighbours = sorted(a if b == node else b for a, b in links)
    listen = [Hosts.addr(l, node) for l in links]
    connect = [Hosts.addr(l, a if b == node else b) for l in links for a, b in [l]]
    path.write_text("\n".join([
        f"node = {node}", 'network = "ns"', f"neighbours = {neighbours}",
        "[zenoh]", f"listen = {json.dumps(listen)}", f"connect = {json.dumps(connect)}",
        "lease_ms = 1000",
        "[runtime]", "startup_timeout_s = 20", "sync_timeout_s = 1.0", f"fps = {FPS}",
        f"frames = {FRAMES}",
        "[source]", 'kind = "det-file"', f'path = "{export}"', f"camera = {node}",
        "[output]", f'dir = "{out}"', "status_interval_s = 0.05", ""]))
    return path


@pytest.mark.integration
@pytest.mark.slow  # three nodes in network namespaces, a 3 s link cut, watched recovering
def test_nodes_on_separate_hosts_live_through_a_link_cut_by_the_kernel(tmp_path):
    """Chain 0 - 1 - 2, each node in its own namespace. The veth link 1 - 2 goes down for 3 s
    mid-run: Zenoh loses the link (lease 1 s), node 1 stops waiting for node 2, both go on;
    when the link comes back Zenoh reconnects by itself and messages flow again, and the nodes
    that fell behind skip ahead to the network's front-runner. Every node runs to the last
    frame and exits 0."""
    why = netns_unavailable()
    if why:
        pytest.skip(why)
    export = export_scenario(tmp_path / "export", FRAMES)
    out = tmp_path / "out"
    hosts = Hosts(str(os.getpid()))
    procs = {}
    try:
        env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
        for i in range(3):
            cfg = node_config(tmp_path / f"cam{i}.toml", i, export, out)
            procs[i] = subprocess.Popen(
                ["ip", "netns", "exec", hosts.ns[i], sys.executable, "-m", "edge_node.cli", "run",
                 "--config", str(cfg), "--log-level", "WARNING"],
                cwd=str(REPO), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

        def frame(i):
            try:
                return json.loads((out / f"status_node{i}.json").read_text()).get("frame") or 0
            except (OSError, ValueError):
                return 0
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline and min(frame(i) for i in range(3)) < 60:
            time.sleep(0.05)
        cut_at = frame(1)
        assert cut_at >= 60, "the nodes never got going across the namespaces"
        hosts.link((1, 2), up=False)
        time.sleep(3.0)
        hosts.link((1, 2), up=True)
        healed_at = frame(1)
        for i, p in procs.items():
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, (i, err)
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
        hosts.close()
    c = {i: json.loads((out / f"counters_node{i}.json").read_text()) for i in range(3)}
    # every node ran to the end (the frames a node spent waiting on the cut link, one sync
    # timeout and the 1 s lease, it skips to catch up with the network's front-runner; how many
    # depends on the machine keeping camera rate: README, "Running on real camera boxes")
    for i in range(3):
        s = json.loads((out / f"status_node{i}.json").read_text())
        assert s["frame"] == FRAMES - 1 and s["phase"] == "finished", (i, s["frame"])
    # the cut was seen: frames of node 2 missing at node 1 while the link was down ...
    got = c[1]["received_per_link"]["2->1"]
    assert got < FRAMES - 0.5 * (healed_at - cut_at)
    # ... and the link came back by itself: node 2's messages reached node 1 after it
    tracks = (out / "tracks_node1.csv").read_text().splitlines()[1:]
    assert got > cut_at + 0.5 * (FRAMES - healed_at), (got, cut_at, healed_at)
    # the other link never broke: node 0 got node 1's message of every frame node 1 ran
    assert c[0]["received_per_link"]["1->0"] >= c[1]["frames_done"] - 2
    assert len(tracks) > 0
    # nothing left behind: the namespaces are gone
    assert not any(ns in sh("ip", "netns", "list").stdout for ns in hosts.ns.values())
