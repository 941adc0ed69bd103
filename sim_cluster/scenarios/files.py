"""Scenario files: the presets shipped with the package, a name or path resolved to a file, the
file read, and the error every scenario kind raises (naming the file and the field).

A scenario is a TOML file; ``[source] kind`` selects how it becomes a
:class:`~sim_cluster.scenarios.data.ScenarioData` (:mod:`sim_cluster.scenarios.loader`). Every
kind reads its tables with the shared reader (``edge_node/settings.py``) through
:func:`scenario_table`, so errors look alike, e.g.
``terrace-sim.toml: cameras[2].fov_deg must be in (0, 180), got 200``. Unknown fields are errors
(a typo must not silently fall back to a default).
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from edge_node.settings import SettingsError, Table, read_toml

PRESET_DIR = Path(__file__).resolve().parent / "presets"


class ScenarioError(SettingsError):
    """A scenario that cannot be loaded; the message names the file and the field."""


def scenario_table(raw: Any, file: str) -> Table:
    """The top table of a scenario file: the shared reader raising :class:`ScenarioError`."""
    return Table(raw, file, error=ScenarioError)


def list_presets() -> list[str]:
    """Names of the scenario presets shipped with the package."""
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A preset name -> ``presets/<name>.toml``; anything path-like -> that file."""
    s = str(name_or_path)
    p = Path(s)
    if p.suffix == ".toml" or "/" in s or "\\" in s or p.exists():
        if not p.is_file():
            raise ScenarioError(p.name or s, None, f"no such scenario file: {s}")
        return p
    preset = PRESET_DIR / f"{s}.toml"
    param = parametric_layout(s)
    if param is not None:
        return PRESET_DIR / f"{param[0]}.toml"
    if not preset.is_file():
        raise ScenarioError(s, None, f"unknown scenario preset (presets: {', '.join(list_presets())}; "
                            "and corridor-<N>, grid-<N>)")
    return preset


#: ``corridor-64``, ``grid-256``: a layout preset with its number of cameras
LAYOUT_PRESETS = ("corridor", "grid")  # presets that take a camera count: corridor-<N>, grid-<N>
_PARAMETRIC = re.compile(rf"({'|'.join(LAYOUT_PRESETS)})-(\d+)")


def parametric_layout(name: str | Path) -> tuple[str, int] | None:
    """``(preset, cameras)`` of a parametric layout name (``corridor-64`` -> the ``corridor``
    preset with 64 cameras), or None when ``name`` is not one (or is a file or a preset)."""
    m = _PARAMETRIC.fullmatch(str(name))
    if m is None or Path(str(name)).exists() or (PRESET_DIR / f"{name}.toml").is_file():
        return None
    return m.group(1), int(m.group(2))


def read_scenario_toml(path: Path) -> dict:
    """Parse a scenario file, turning I/O and syntax errors into :class:`ScenarioError`."""
    return read_toml(path, ScenarioError, what="scenario file", invalid="invalid TOML")
