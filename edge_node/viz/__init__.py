"""Live view of a camera network in Rerun (``edge_node/viz/rerun_log.py``).

Importing this package never imports Rerun: ``make_sink("off")`` returns a no-op sink, and
``rerun`` is imported only when a sink that really logs is created.
"""
from edge_node.viz.rerun_log import (APP_ID, NullSink, SinkError, VizSpec, VizSpecError,
                                     disagreement, fov_polygon, ground_points, make_sink,
                                     node_colour, open_node_sink, parse_spec, track_colour,
                                     track_label)

__all__ = ["APP_ID", "NullSink", "SinkError", "VizSpec", "VizSpecError", "disagreement",
           "fov_polygon", "ground_points", "make_sink", "node_colour", "open_node_sink",
           "parse_spec", "track_colour", "track_label"]
