"""The wire contract between camera nodes: message types, codec, key expressions.

Depends on nothing else of ours (numpy and msgpack only), so any implementation that
speaks these bytes can join a network.
"""
from protocol.codec import DEFAULT_LIMITS, MAX_WIRE_INT, Limits, decode, encode, quantize
from protocol.errors import DmttError, ProtocolError
from protocol.keys import (
    MAX_NETWORK_LEN,
    MAX_NODE_ID,
    alive_key,
    alive_pattern,
    all_links_key,
    inbox_key,
    is_valid_network,
    is_valid_node,
    link_key,
    parse_alive_key,
    parse_link_key,
)
from protocol.messages import (
    MAX_DESCRIPTORS,
    SCHEMA_VERSION,
    STATE_DIM,
    FrameMessage,
    Merge,
    TrackerBlock,
    TrackerId,
    TrackerInfo,
)

__all__ = [
    "DmttError",
    "DEFAULT_LIMITS",
    "MAX_DESCRIPTORS",
    "MAX_NETWORK_LEN",
    "MAX_NODE_ID",
    "MAX_WIRE_INT",
    "SCHEMA_VERSION",
    "STATE_DIM",
    "FrameMessage",
    "Limits",
    "Merge",
    "ProtocolError",
    "TrackerBlock",
    "TrackerId",
    "TrackerInfo",
    "alive_key",
    "alive_pattern",
    "all_links_key",
    "decode",
    "encode",
    "inbox_key",
    "is_valid_network",
    "is_valid_node",
    "link_key",
    "parse_alive_key",
    "parse_link_key",
    "quantize",
]
