"""The scenario commands: ``sim_cluster scenarios`` (list the presets), ``export-detections``
(a scenario as a det-files folder) and ``render`` (a synthetic scenario's camera videos)."""
from __future__ import annotations

from pathlib import Path

from sim_cluster.scenarios.detfiles import export_detections
from sim_cluster.scenarios.files import LAYOUT_PRESETS, list_presets
from sim_cluster.scenarios.loader import scenario_from_args
from sim_cluster.scenarios.synthetic.render import render_scenario


def scenarios(args) -> int:
    for name in list_presets():
        print(f"{name}  (also {name}-<N>: N cameras)" if name in LAYOUT_PRESETS else name)
    return 0


def export(args) -> int:
    data = scenario_from_args(args)
    if getattr(args, "no_descriptors", False):
        data = data.without_descriptors()
    path = export_detections(data, Path(args.out),
                             descriptor_dtype="float32" if args.float32 else "float16")
    print(f"wrote {data.num_cameras} cameras x {data.frames} frames to {args.out} "
          f"(replay: sim_cluster run --scenario {path})")
    return 0


def render(args) -> int:
    info = render_scenario(args.scenario, Path(args.out), seed=args.seed, frames=args.frames,
                           fmt="png" if args.png else "avi", noise=args.noise)
    for c, v in info["cameras"].items():
        print(f"camera {c}: {v['frames']} (background {v['background']})")
    return 0
