"""The camera process: TOML config, Zenoh transport, sync / async frame loops, output files.

Only this package (never ``edge_node.core``) touches the network, the clock and the disk.
``edge_node.runtime.config`` and ``edge_node.runtime.output`` import no Zenoh; the transport
imports it lazily, so ``edge_node check`` stays fast.
"""
