"""``edge_node router``: a Zenoh router that joins sites (docs/deploy.md, "More than one site").

Within a site, camera boxes peer directly (one Zenoh connection per logical link, multicast and
gossip off). Sites are joined through routers: every box of a site also connects to its site's
router, and the routers connect to each other (over a WAN, a VPN, TLS). The routers forward the
per-link keys (``dmtt/<net>/link/<src>/<dst>``), the liveliness tokens and the id check between
sites, so a neighbour in the other site is a neighbour like any other; nothing in the camera
configs changes but one more ``connect`` endpoint.

This is the Python binding of Zenoh (``eclipse-zenoh``, already a dependency) opened in router
mode: the stand-alone ``zenohd`` binary does not install from the package registries these
machines reach, and a router needs nothing the binding lacks. A Zenoh JSON5 config
(``--config``, e.g. ``deploy/examples/two-site/router-a.json5``) sets everything, TLS included;
``--listen`` / ``--connect`` add endpoints. Runs until SIGINT or SIGTERM.
"""
from __future__ import annotations

import json
import signal
import threading
from collections.abc import Sequence

import zenoh

from edge_node.runtime.transport import TransportError


def router_config(config_file: str | None, listen: Sequence[str], connect: Sequence[str]
                  ) -> "zenoh.Config":
    try:
        conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
        conf.insert_json5("mode", '"router"')
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if not config_file:
            conf.insert_json5("scouting/multicast/enabled", "false")
        # as for the nodes (edge_node.runtime.transport): Zenoh's same-host shared memory keeps
        # every restarted sender's pool mapped for the receiver's life (eclipse-zenoh/zenoh#2787)
        conf.insert_json5("transport/shared_memory/enabled", "false")
    except zenoh.ZError as e:
        raise TransportError(f"bad router configuration: {str(e).split(' at /')[0]}") from None
    return conf


def run_router(config_file: str | None, listen: Sequence[str], connect: Sequence[str],
               stop: threading.Event | None = None) -> int:
    """Open the router and serve until ``stop`` is set (or SIGINT / SIGTERM)."""
    stop = stop or threading.Event()
    conf = router_config(config_file, listen, connect)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as e:
        raise TransportError(f"cannot open the router: {str(e).split(' at /')[0]}") from None
    old = {}
    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            old[s] = signal.signal(s, lambda *_: stop.set())
    try:
        while not stop.wait(0.5):
            pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        session.close()
    return 0
