"""The scenario commands: ``sim_cluster scenarios`` (list the presets), ``export-detections``
(a scenario as a det-files folder), ``import-detections`` (another tool's detection files as a
det-files folder), ``check-scale`` (units_per_metre against the people in the data) and
``render`` (a synthetic scenario's camera videos)."""
from __future__ import annotations

from pathlib import Path

from edge_node.formats.detfile import DetFilesError
from sim_cluster.scenarios.detfiles import export_detections
from sim_cluster.scenarios.files import LAYOUT_PRESETS, list_presets
from sim_cluster.scenarios.loader import import_options, load_scenario, scenario_from_args
from sim_cluster.scenarios.scale import scenario_scale
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


def import_detections(args) -> int:
    """``sim_cluster import-detections SOURCE --out DIR``: the folder's notes, then the det-files
    folder (calibration.json, every camera's det.txt / .npy / gt.txt, gt_ground.csv) that
    ``run``, ``up`` and camera processes read."""
    src = Path(args.source)
    if not src.is_dir():
        raise DetFilesError(f"{src}: not a folder (import-detections reads a folder of detection "
                            "files; sim_cluster run --help lists the layouts)")
    data = load_scenario(src, frames=args.frames, options=import_options(args))
    for note in data.notes:
        print(note)
    warning = scenario_scale(data).warning()
    if warning:
        print(f"{data.name}: {warning}")
    path = export_detections(data, Path(args.out), descriptor_dtype="float32")
    print(f"wrote {data.num_cameras} cameras x {data.frames} frames to {args.out} "
          f"(replay: sim_cluster run --scenario {path})")
    return 0


def check_scale(args) -> int:
    """``sim_cluster check-scale``: the estimate, per camera and from walking speed, and a
    WARNING line when the declared units_per_metre disagrees by more than 20 %."""
    data = scenario_from_args(args)
    for line in scenario_scale(data).lines(data.name):
        print(line)
    return 0


def render(args) -> int:
    info = render_scenario(args.scenario, Path(args.out), seed=args.seed, frames=args.frames,
                           fmt="png" if args.png else "avi", noise=args.noise)
    for c, v in info["cameras"].items():
        print(f"camera {c}: {v['frames']} (background {v['background']})")
    return 0
