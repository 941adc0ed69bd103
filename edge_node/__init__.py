"""One camera of the network: the pure tracker core, its geometry, and (later) the process runtime."""
