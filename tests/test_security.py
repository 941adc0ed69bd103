"""Transport security on loopback with the deploy/ examples: certificates from
deploy/tls/make-certs.sh, Zenoh mutual TLS (deploy/zenoh/peer-mtls.json5) and access control by
certificate common name (deploy/zenoh/peer-acl.json5).

* Two nodes with certificates from the network's CA talk over tls/ endpoints.
* A peer with a certificate from another CA (even with a box's name), or with none, cannot
  connect: its puts never arrive and the node's counters do not move.
* With access control, a peer holding a valid certificate of the same CA but a common name
  that is not one of the network's boxes connects, yet cannot publish on the network's keys
  (nor announce a liveliness token there); without access control the same peer can. A box of
  the network may publish only as itself (its own links, its own token).
* Two real ``edge_node run`` processes run a few frames under mTLS + access control.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from protocol import codec
from protocol.keys import alive_key, link_key
from protocol.messages import FrameMessage, TrackerInfo

REPO = Path(__file__).resolve().parents[1]
DEPLOY = REPO / "deploy"
MAKE_CERTS = DEPLOY / "tls" / "make-certs.sh"
from tests.loopback import ep, free_port, wait_for  # noqa: E402

NET = "terrace"  # the network deploy/zenoh/peer-acl.json5 is written for (boxes cam0..cam3)

pytestmark = [pytest.mark.integration, pytest.mark.skipif(
    shutil.which("openssl") is None,
    reason="the openssl command is not installed: deploy/tls/make-certs.sh needs it to make the "
           "test CA and certificates")]



def tls(port: int) -> str:
    return ep(port, "tls")



def _msg(sender: int, frame: int) -> bytes:
    t = TrackerInfo((sender, 0), np.arange(6.0), np.zeros(6), np.zeros((6, 6)), 0)
    return codec.encode(FrameMessage(NET, sender, frame, (t,), sent_at=time.time()))


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> tuple[Path, Path]:
    """The network's CA with boxes cam0, cam1, cam2 and a certified outsider "intruder"; and a
    rogue CA that issued its own "cam1"."""
    base = tmp_path_factory.mktemp("tls")
    good, rogue = base / "net", base / "rogue"
    for out, ca, names in ((good, "dmtt-test-ca", ["cam0", "cam1", "cam2", "intruder"]),
                           (rogue, "rogue-ca", ["cam1"])):
        r = subprocess.run(["sh", str(MAKE_CERTS), str(out), *names], capture_output=True,
                           text=True, env=dict(os.environ, CA_CN=ca), timeout=60)
        assert r.returncode == 0, r.stderr
        assert all((out / f"{n}.pem").exists() and (out / f"{n}.key").exists() for n in names)
    return good, rogue


def peer_config(tmp: Path, template: str, tls_dir: Path, name: str,
                ca_dir: Path | None = None) -> Path:
    """A deploy/zenoh example made concrete: this box's certificate and key (and the CA it
    trusts, from ``ca_dir``, default ``tls_dir``), no listen endpoint of its own (the camera
    config or the test gives one on loopback)."""
    text = (DEPLOY / "zenoh" / template).read_text()
    for old, new in (("/etc/dmtt/tls/ca.pem", (ca_dir or tls_dir) / "ca.pem"),
                     ("/etc/dmtt/tls/box.pem", tls_dir / f"{name}.pem"),
                     ("/etc/dmtt/tls/box.key", tls_dir / f"{name}.key"),
                     ('listen: { endpoints: ["tls/0.0.0.0:7447"] }', "listen: { endpoints: [] }")):
        assert str(old) in text, (template, old)
        text = text.replace(str(old), str(new))
    path = tmp / f"{template.split('.')[0]}-{tls_dir.name}-{name}.json5"
    path.write_text(text)
    return path


@pytest.fixture
def closing():
    """Transports and sessions opened by a test; closed at the end, newest first."""
    opened: list = []
    try:
        yield opened
    finally:
        for o in reversed(opened):
            try:
                o.close()
            except Exception:  # noqa: BLE001 - close the rest regardless
                pass


def _pair(tmp, closing, template, tls_dir):
    from edge_node.runtime.transport import ZenohTransport

    p0, p1 = free_port(), free_port()
    a = ZenohTransport(NET, 0, [1], [tls(p0)], [tls(p1)],
                       config_file=peer_config(tmp, template, tls_dir, "cam0"))
    closing.append(a)
    b = ZenohTransport(NET, 1, [0], [tls(p1)], [tls(p0)],
                       config_file=peer_config(tmp, template, tls_dir, "cam1"))
    closing.append(b)
    a.wait_ready(10.0)
    b.wait_ready(10.0)
    return a, b, p0


def _talk(a, b) -> None:
    """One frame each way over the secured link."""
    a.publish(_msg(0, 0))
    b.publish(_msg(1, 0))
    assert list(b.collect(0, 5.0)) == [0]
    assert list(a.collect(0, 5.0)) == [1]


def _outsider(closing, port: int, config: Path | None):
    import zenoh

    from edge_node.runtime.transport import zenoh_config

    s = zenoh.open(zenoh_config([], [tls(port)], config_file=config))
    closing.append(s)
    return s


def _inject(session, keys=(link_key(NET, 1, 0), link_key(NET, 9, 0)), n: int = 20) -> None:
    """Put valid-looking messages (node 1's, frames 1..n; a stranger's) on node 0's inbox."""
    import zenoh

    for key in keys:
        pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        sender = int(key.split("/")[3])
        for f in range(1, n + 1):
            pub.put(_msg(sender, f))


def _still(a, before: dict, settle: float = 0.8) -> None:
    time.sleep(settle)  # time enough for delivery: a hop takes well under a millisecond here
    c = a.counters()
    assert c["messages_received"] == before["messages_received"]
    assert c["bytes_received"] == before["bytes_received"]
    assert c["rejected"] == before["rejected"]


def test_mtls_nodes_talk_and_peers_without_a_valid_certificate_cannot_connect(
        tmp_path, certs, closing):
    good, rogue = certs
    a, b, p0 = _pair(tmp_path, closing, "peer-mtls.json5", good)
    _talk(a, b)
    before = a.counters()
    assert before["messages_received"] == 1
    no_cert = tmp_path / "no-cert.json5"  # trusts the CA, presents no certificate of its own
    no_cert.write_text(json.dumps({"transport": {"link": {"tls": {
        "root_ca_certificate": str(good / "ca.pem"), "enable_mtls": False}}}}))
    outsiders = {
        # trusts the network's (public) CA certificate, presents a "cam1" issued by its own CA
        "another CA's cam1": peer_config(tmp_path, "peer-mtls.json5", rogue, "cam1", good),
        "no client certificate": no_cert,
    }
    for what, config in outsiders.items():
        s = _outsider(closing, p0, config)
        _inject(s)
        assert not list(s.info.peers_zid()), f"{what}: connected"
        _still(a, before)
        assert not list(s.info.peers_zid()), f"{what}: connected"
    assert a.alive_nodes() == {1}  # nobody else even announced liveliness
    a.publish(_msg(0, 1))
    assert list(b.collect(1, 5.0)) == [0]  # the link between the boxes is unaffected


def test_acl_lets_only_the_networks_boxes_publish(tmp_path, certs, closing):
    import zenoh

    good, _ = certs
    a, b, p0 = _pair(tmp_path, closing, "peer-acl.json5", good)
    _talk(a, b)  # the barrier passed and messages flow: the ACL allows what a node needs
    before = a.counters()
    intruder_cfg = peer_config(tmp_path, "peer-mtls.json5", good, "intruder")
    s = _outsider(closing, p0, intruder_cfg)
    assert wait_for(lambda: list(s.info.peers_zid())), "the intruder's certificate is valid"
    token = s.liveliness().declare_token(alive_key(NET, 5))  # noqa: F841 - held while checked
    _inject(s)  # forged as node 1, and as stranger 9
    _still(a, before)
    assert a.alive_nodes() == {1}  # the intruder's liveliness token was denied too
    assert list(s.info.peers_zid())  # still connected: it is the ACL that keeps it out

    # a box of the network (cam2) may publish only as itself: not as node 1 or node 3
    box = _outsider(closing, p0, peer_config(tmp_path, "peer-acl.json5", good, "cam2"))
    assert wait_for(lambda: list(box.info.peers_zid()))
    token2 = box.liveliness().declare_token(alive_key(NET, 3))  # noqa: F841 - held while checked
    _inject(box, keys=(link_key(NET, 1, 0), link_key(NET, 3, 0)))
    _still(a, before)
    assert a.alive_nodes() == {1}
    # as itself it gets through Zenoh, and node 0 rejects it: 2 is not its neighbour
    _inject(box, keys=(link_key(NET, 2, 0),), n=5)
    assert wait_for(lambda: a.counters()["rejected"] == {"unknown_sender": 5})
    assert a.counters()["messages_received"] == before["messages_received"]

    # control: the same intruder against a node with mTLS only does get its messages in
    from edge_node.runtime.transport import ZenohTransport

    p2 = free_port()
    c = ZenohTransport(NET, 0, [1], [tls(p2)], [],
                       config_file=peer_config(tmp_path, "peer-mtls.json5", good, "cam0"))
    closing.append(c)
    s2 = _outsider(closing, p2, intruder_cfg)
    pub = s2.declare_publisher(link_key(NET, 1, 0),
                               congestion_control=zenoh.CongestionControl.BLOCK)
    assert wait_for(lambda: pub.matching_status.matching)
    pub.put(_msg(1, 0))
    assert wait_for(lambda: c.counters()["messages_received"] == 1)


def test_two_processes_run_under_mtls_and_acl(tmp_path, certs):
    from sim_cluster.scenarios.detfiles import export_detections
    from sim_cluster.scenarios.loader import load_scenario

    frames = 8
    good, _ = certs
    export = tmp_path / "det"
    export_detections(load_scenario("terrace-sim", frames=frames), export)
    out = tmp_path / "out"
    ports = {0: free_port(), 1: free_port()}
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
    procs = []
    try:
        for n in (0, 1):
            cfg = tmp_path / f"cam{n}.toml"
            cfg.write_text("\n".join([
                f"node = {n}", f'network = "{NET}"', f"neighbours = [{1 - n}]",
                "[zenoh]", f'listen = ["{tls(ports[n])}"]', f'connect = ["{tls(ports[1 - n])}"]',
                f'config_file = "{peer_config(tmp_path, "peer-acl.json5", good, f"cam{n}")}"',
                "[runtime]", "startup_timeout_s = 20", "sync_timeout_s = 5",
                "[source]", 'kind = "det-file"', f'path = "{export}"',
                "[output]", f'dir = "{out}"', ""]))
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "edge_node.cli", "run", "--config", str(cfg),
                 "--log-level", "WARNING"], cwd=str(REPO), env=env, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True))
        for p in procs:
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, err
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
    for n in (0, 1):
        c = json.loads((out / f"counters_node{n}.json").read_text())
        assert c["frames_done"] == frames and c["messages_received"] == frames
        assert c["rejected"] == {} and c["timeouts"] == {}
