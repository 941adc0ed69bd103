"""``[source] kind = "scenario"``: a camera process that replays one camera of a simulated
scenario (developer convenience; what ``sim_cluster up`` configures its nodes with).

A plug-in of ``edge_node``'s sources (entry-point group ``dmtt.sources``, declared in
pyproject.toml; the interface is in ``edge_node/runtime/sources.py``): edge_node looks the kind
up by name and never imports the simulator. The scenario is regenerated in the process from its
file and seed, a chunk at a time as the node asks for frames (``ScenarioStream``), so the node
sees exactly the detections of the in-process run and holds one chunk of them. ``[source]``
fields::

    kind = "scenario"
    scenario = "terrace-sim"   # preset name or path (relative to the camera config)
    seed = 0                   # optional: the scenario's own by default
    frames = 200               # optional: the scenario's own by default
    data_root = "..."          # optional: for dataset scenarios (EPFL)
    camera = 0                 # which camera of the scenario        [the node id]
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from edge_node.runtime.sources import Source, SourceError
from edge_node.settings import Table
from sim_cluster.scenarios.loader import open_scenario


def parse(t: Table, base: Path) -> dict[str, Any]:
    """The ``[source]`` fields of this kind (``t.finish()`` is the caller's)."""
    name = t.string("scenario")
    if not name:
        raise t.error("scenario", "must be a preset name or a path")
    if "/" in name or name.endswith(".toml"):
        p = Path(name).expanduser()
        name = str(p if p.is_absolute() else base / p)
    return {"scenario": name, "seed": t.integer("seed", None, lo=0),
            "frames": t.integer("frames", None, lo=1),
            "data_root": t.path("data_root", base, None)}


def open(options: dict[str, Any], camera: int, node: int) -> Source:  # noqa: A001 - the plug-in API
    """Camera ``camera`` of the scenario, as node ``node`` (its camera id). A scenario that
    cannot be loaded or has no such camera is a ``SourceError`` naming the field."""
    try:
        data = open_scenario(options["scenario"], seed=options.get("seed"),
                             frames=options.get("frames"), data_root=options.get("data_root"))
    except (ValueError, OSError) as e:
        raise SourceError(f"source.scenario: {e}") from None
    if camera >= data.num_cameras:
        raise SourceError(f"source.camera is {camera}, but scenario {data.name} has "
                          f"{data.num_cameras} cameras (0..{data.num_cameras - 1})")
    cam = replace(data.cameras[camera], id=node)
    read = data.camera(camera)
    # the first chunk now, at start-up, before the node joins the network: made at frame 0 it
    # held the node's first message back while its neighbours, past the start-up barrier, waited
    # (on a busy machine long enough to time out on frame 0)
    read(0)
    return Source(cam, data.frames, data.fps, data.units_per_metre, read,
                  f"scenario {data.name} seed {data.seed} camera {camera}")
