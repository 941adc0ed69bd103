"""Zenoh key expressions of the wire: one key per directed neighbour link, one liveliness token per node.

Layout (docs/concepts.md, "How it is built")::

    dmtt/<network>/link/<src>/<dst>    one FrameMessage per frame from node src to node dst
    dmtt/<network>/alive/<node>        liveliness token of a running node
    dmtt/<network>/peers/<node>        queryable: the nodes <node> sees alive (id check at start)

``<network>`` is one key chunk (non-empty; no ``/``, ``*``, ``$``, ``?``, ``#`` or whitespace;
printable; at most ``MAX_NETWORK_LEN`` bytes in UTF-8). Node ids are non-negative integers written
in canonical decimal (no sign, no leading zeros). Every builder and parser raises
``ProtocolError("key", ...)`` on bad input, so a node can feed any received key to a parser.
"""
from __future__ import annotations

import re

from protocol.errors import ProtocolError

KEY_ROOT = "dmtt"
LINK = "link"
ALIVE = "alive"
PEERS = "peers"
MAX_NETWORK_LEN = 64  # bytes of UTF-8
MAX_NODE_ID = 2**63 - 1  # fits a signed 64-bit integer everywhere

_FORBIDDEN = frozenset("/*$?#")
_NODE_RE = re.compile(r"0|[1-9][0-9]{0,18}")


def is_valid_network(name: object) -> bool:
    """True when ``name`` can be used as the ``<network>`` chunk of a key expression."""
    return (
        isinstance(name, str)
        and 0 < len(name) <= MAX_NETWORK_LEN
        and name.isprintable()  # also rules out lone surrogates, so encode() below cannot fail
        and not any(c in _FORBIDDEN or c.isspace() for c in name)
        and len(name.encode("utf-8")) <= MAX_NETWORK_LEN
    )


def is_valid_node(node: object) -> bool:
    """True when ``node`` is a node id: a non-negative ``int`` (not ``bool``) up to ``MAX_NODE_ID``."""
    return isinstance(node, int) and not isinstance(node, bool) and 0 <= node <= MAX_NODE_ID


def _network(name: object) -> str:
    if not is_valid_network(name):
        raise ProtocolError("key", f"invalid network name {name!r}")
    return name  # type: ignore[return-value]


def _node(node: object, what: str) -> int:
    # numpy integers are accepted and normalised; bools and everything else are rejected
    if not isinstance(node, bool) and hasattr(node, "__index__") and not isinstance(node, int):
        try:
            node = int(node.__index__())  # type: ignore[union-attr]
        except Exception:  # noqa: BLE001 - any failure is a bad key argument
            raise ProtocolError("key", f"invalid {what} node id {node!r}") from None
    if not is_valid_node(node):
        raise ProtocolError("key", f"invalid {what} node id {node!r}")
    return node  # type: ignore[return-value]


def link_key(network: str, src: int, dst: int) -> str:
    """Key on which node ``src`` publishes its per-frame message to neighbour ``dst``."""
    return f"{KEY_ROOT}/{_network(network)}/{LINK}/{_node(src, 'source')}/{_node(dst, 'destination')}"


def inbox_key(network: str, dst: int) -> str:
    """Subscription pattern matching every link into node ``dst``: ``dmtt/<network>/link/*/<dst>``."""
    return f"{KEY_ROOT}/{_network(network)}/{LINK}/*/{_node(dst, 'destination')}"


def all_links_key(network: str) -> str:
    """Pattern matching every link of the network (for monitors and bandwidth meters)."""
    return f"{KEY_ROOT}/{_network(network)}/{LINK}/**"


def alive_key(network: str, node: int) -> str:
    """Liveliness token key of ``node``."""
    return f"{KEY_ROOT}/{_network(network)}/{ALIVE}/{_node(node, 'alive')}"


def alive_pattern(network: str) -> str:
    """Pattern matching every node's liveliness token: ``dmtt/<network>/alive/*``."""
    return f"{KEY_ROOT}/{_network(network)}/{ALIVE}/*"


def peers_key(network: str, node: int) -> str:
    """Queryable of ``node`` that answers which nodes it sees alive."""
    return f"{KEY_ROOT}/{_network(network)}/{PEERS}/{_node(node, 'peers')}"


def peers_pattern(network: str) -> str:
    """Every node's ``peers`` queryable: ``dmtt/<network>/peers/*``."""
    return f"{KEY_ROOT}/{_network(network)}/{PEERS}/*"


def _chunks(key: object, n: int, kind: str) -> list[str]:
    if not isinstance(key, str):
        try:  # e.g. a zenoh KeyExpr
            key = str(key)
        except Exception:  # noqa: BLE001 - any failure is an unparsable key
            raise ProtocolError("key", f"key of type {type(key).__name__} is not a string") from None
    parts = key.split("/")
    if len(parts) != n or parts[0] != KEY_ROOT or parts[2] != kind:
        raise ProtocolError("key", f"not a {kind} key: {key[:200]!r}")
    _network(parts[1])
    return parts


def _parse_node(text: str, what: str) -> int:
    if not _NODE_RE.fullmatch(text):
        raise ProtocolError("key", f"invalid {what} node id {text[:40]!r}")
    value = int(text)
    if value > MAX_NODE_ID:
        raise ProtocolError("key", f"{what} node id {text!r} out of range")
    return value


def parse_link_key(key: object) -> tuple[str, int, int]:
    """``"dmtt/<network>/link/<src>/<dst>"`` -> ``(network, src, dst)``; exact inverse of ``link_key``.

    ``key`` is a ``str`` or anything whose ``str()`` is the key (e.g. a zenoh ``KeyExpr``).
    """
    parts = _chunks(key, 5, LINK)
    return parts[1], _parse_node(parts[3], "source"), _parse_node(parts[4], "destination")


def parse_alive_key(key: object) -> tuple[str, int]:
    """``"dmtt/<network>/alive/<node>"`` -> ``(network, node)``; exact inverse of ``alive_key``."""
    parts = _chunks(key, 4, ALIVE)
    return parts[1], _parse_node(parts[3], "alive")
