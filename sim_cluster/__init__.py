"""Many cameras: scenarios, topologies, the in-process network, evaluation, and the CLI."""
