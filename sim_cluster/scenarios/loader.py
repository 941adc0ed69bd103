"""Loading a scenario: a preset name, a scenario file or a det-files folder -> ``ScenarioData``.

A scenario is a TOML file (:mod:`sim_cluster.scenarios.files`: presets, paths, errors).
``[source] kind`` selects how it becomes a :class:`~sim_cluster.scenarios.data.ScenarioData`:

``synthetic`` (the default)  the seeded world (:mod:`sim_cluster.scenarios.synthetic`)
``epfl-gt``                  EPFL ground truth replayed (:mod:`sim_cluster.scenarios.epfl`)
``det-files``                your own detections (:mod:`sim_cluster.scenarios.detfiles`)

A folder written by ``sim_cluster export-detections`` (or its ``calibration.json``) is a scenario
too, and so is a folder of another tool's MOTChallenge det files
(:mod:`edge_node.formats.layouts`); and ``corridor-<N>`` / ``grid-<N>`` name the ``corridor`` / ``grid`` layout presets with N
cameras (:mod:`sim_cluster.scenarios.synthetic.layout`). Same file + same seed gives identical detections. :func:`open_scenario` gives the
scenario as a :class:`~sim_cluster.scenarios.data.ScenarioStream` (frames on demand: what the
launcher and camera processes use), :func:`load_scenario` materialised (in-process runs).
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from edge_node.formats.layouts import ImportOptions
from sim_cluster.scenarios import detfiles, epfl
from sim_cluster.scenarios.data import ScenarioData, ScenarioStream
from sim_cluster.scenarios.detfiles import open_det_files
from sim_cluster.scenarios.files import (ScenarioError, parametric_layout, read_scenario_toml,
                                         resolve_scenario_path, scenario_table)
from sim_cluster.scenarios.synthetic.schema import load_synthetic

ScenarioLoader = Callable[[dict, Path, int, "int | None"], "ScenarioStream | ScenarioData"]

#: ``[source] kind`` -> loader ``(raw toml dict, file path, resolved seed, frames override or
#: None) -> ScenarioStream`` (or a ``ScenarioData``, wrapped). A loader validates its own fields
#: (``files.scenario_table``) and raises ``ScenarioError``.
SCENARIO_KINDS: dict[str, ScenarioLoader] = {
    "synthetic": load_synthetic,
    "epfl-gt": epfl.scenario_from_table,
    "det-files": detfiles.scenario_from_table,
}


#: Scenario kinds whose descriptors the synthetic appearance model makes (``[appearance]``)
SIMULATED_APPEARANCE = ("synthetic", "epfl-gt")


def load_scenario(name_or_path: str | Path, seed: int | None = None,
                  frames: int | None = None, data_root: str | Path | None = None,
                  options: ImportOptions | None = None,
                  rank1: float | None = None) -> ScenarioData:
    """Load a scenario by preset name or file path, every frame in memory (``open_scenario``'s
    arguments)."""
    return open_scenario(name_or_path, seed, frames, data_root, options, rank1).materialise()


def open_scenario(name_or_path: str | Path, seed: int | None = None,
                  frames: int | None = None, data_root: str | Path | None = None,
                  options: ImportOptions | None = None,
                  rank1: float | None = None) -> ScenarioStream:
    """Open a scenario by preset name or file path, frames on demand. ``seed`` / ``frames``
    override the file's; ``rank1`` its re-id quality (``[appearance] rank1``, replacing any
    ``rank1`` / ``mean_ap`` / ``decay`` of the file; scenarios that simulate descriptors only).

    Same file + same seed gives identical detections. A folder written by
    ``sim_cluster export-detections`` (or its ``calibration.json``) is a scenario too, and so is
    a folder of another tool's detection files (``edge_node.formats.layouts.LAYOUTS``), read
    with ``options`` (homographies, ground truth, units, frame rate, image size).
    """
    made = _open(name_or_path, seed, frames, data_root, options, rank1)
    return made if isinstance(made, ScenarioStream) else ScenarioStream.of(made)


def _open(name_or_path, seed, frames, data_root, options=None,
          rank1=None) -> ScenarioStream | ScenarioData:
    candidate = Path(str(name_or_path))
    if candidate.is_dir() or candidate.suffix == ".json":
        if rank1 is not None:
            raise ScenarioError(str(name_or_path), None, "a re-id quality (rank1) applies to "
                                "scenarios that simulate descriptors (synthetic, epfl-gt), not "
                                "to detection files: their descriptors are what they are")
        return open_det_files(candidate, frames=frames, seed=seed, options=options)
    if options is not None and options.given:
        raise ScenarioError(str(name_or_path), None,
                            f"{', '.join(options.given)} apply to a folder of detection files "
                            "without calibration.json (another tool's layout), not to a preset "
                            "or scenario file")
    path = resolve_scenario_path(name_or_path)
    raw = read_scenario_toml(path)
    param = parametric_layout(name_or_path)
    if param is not None:  # corridor-64: the corridor preset with 64 cameras
        raw["name"] = str(name_or_path)
        raw.setdefault("layout", {})["cameras"] = param[1]
    file = path.name
    top = scenario_table(raw, file)
    if seed is None:
        seed = top.integer("seed", 0, lo=0)
    elif isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ScenarioError(file, "seed", f"must be an integer >= 0, got {seed!r}")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, (int, np.integer))
                               or frames < 1):
        raise ScenarioError(file, "frames", f"must be an integer >= 1, got {frames!r}")
    src = top.table("source")
    kind = src.raw("kind", "synthetic")
    if kind not in SCENARIO_KINDS:
        raise src.error("kind", f"must be one of {sorted(SCENARIO_KINDS)}, got {kind!r}")
    if data_root is not None and kind == "epfl-gt":  # --data-root beats the file and $DMTT_DATA
        raw.setdefault("source", {})["data_root"] = str(Path(data_root).expanduser().resolve())
    if rank1 is not None:  # --reid-rank1 beats the file's quality
        if kind not in SIMULATED_APPEARANCE:
            raise src.error("kind", f"a re-id quality (rank1) applies to scenarios that simulate "
                            f"descriptors ({', '.join(SIMULATED_APPEARANCE)}), not {kind!r}")
        app = raw.setdefault("appearance", {})
        for key in ("rank1", "mean_ap", "decay"):
            app.pop(key, None)
        app["rank1"] = rank1
    return SCENARIO_KINDS[kind](raw, path, int(seed), None if frames is None else int(frames))


def scenario_from_args(args) -> ScenarioData:
    """The scenario of a command line: ``--scenario``, ``--seed``, ``--frames``, ``--data-root``."""
    return stream_from_args(args).materialise()


def stream_from_args(args) -> ScenarioStream:
    """:func:`scenario_from_args`, frames on demand (with ``--homographies`` and the other
    options of another tool's layout where the command has them)."""
    return open_scenario(args.scenario, seed=args.seed, frames=args.frames,
                         data_root=getattr(args, "data_root", None),
                         options=import_options(args), rank1=getattr(args, "reid_rank1", None))


def import_options(args) -> ImportOptions:
    """The options of another tool's layout on a command line (absent ones None)."""
    hom, gt = getattr(args, "homographies", None), getattr(args, "ground_truth", None)
    return ImportOptions(homographies=None if hom is None else Path(hom).expanduser(),
                         ground_truth=None if gt is None else Path(gt).expanduser(),
                         units_per_metre=getattr(args, "units_per_metre", None),
                         fps=getattr(args, "fps_override", None),
                         image_size=getattr(args, "image_size", None))
