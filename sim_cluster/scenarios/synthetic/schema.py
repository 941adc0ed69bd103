"""The synthetic scenario kind: its TOML schema, read into a :class:`WorldConfig`.

Synthetic schema (metres, degrees, pixels; see the presets for commented examples)::

    name = "my-scene"          # optional, defaults to the file name
    seed = 0                   # optional (default 0); load_scenario(seed=...) overrides
    frames = 600               # load_scenario(frames=...) overrides
    fps = 25.0                 # every camera's frame rate (frames are synchronised)

    [source]                   # optional
    kind = "synthetic"

    [area]                     # the walkable ground rectangle
    xmin = 0.0  xmax = 10.0  ymin = 0.0  ymax = 10.0

    [[cameras]]                # one table per camera; ids are 0.. in file order
    image_size = [360, 288]    # width, height in pixels
    position = [x, y, z]       # camera centre (z = height above the ground, > 0)
    look_at = [x, y, z]        # what the optical axis points at; or yaw_deg + pitch_deg
    # yaw_deg = 45.0           # heading on the ground, counter-clockwise from +x
    # pitch_deg = 20.0         # tilt below the horizon, in [-90, 90]
    # roll_deg = 0.0           # rotation about the optical axis
    fov_deg = 60.0             # horizontal field of view; or focal_px
    # principal_point = [180.0, 144.0]   # default: the image centre
    # ... or instead of the pose: homography = [[..], [..], [..]] (image -> ground),
    #     pixel_scale = 1.0, projection = [[4 numbers] x 3] (optional, ground xyz -> image)

    [people]     concurrent, initial, speed_mps, width_m, height_m, stay_s, entry_gap_s,
                 turn_rate_dps, pause_probability, pause_s, spawn_margin_m, waypoint_margin_m,
                 personal_space_m                   (see world.PeopleParams; ranges [lo, hi])
    [detector]   miss_rate, occlusion_miss_threshold, false_positives_per_frame, box_noise_px,
                 min_box_height_px, fp_person_height_m, fp_height_frac  (detector_model.DetectorParams)
    [appearance] dim and either the weights identity, view, noise, shared or the expected
                 distances same_camera_distance, cross_camera_distance, different_person_distance;
                 the re-id quality rank1 (or mean_ap; cross-camera, 1 = perfect, the default)
                 with quality_people (the gallery it is stated for, default 20), or decay
    [truth]      min_visible                         (world module docstring)

    [layout]                   # optional, instead of [area] and [[cameras]]: a generated
    kind = "corridor"          # corridor | grid of N cameras with people_per_camera people each
    cameras = 16               # (layout module; presets corridor and grid, names corridor-<N>)

    [calibration_error]        # optional: known registration errors (calibration module)
    shift_m = [[dx, dy], ...]  # per camera (file order): the believed ground map's shift, metres
    rotation_deg = [r, ...]    # per camera: its rotation about the camera's reference point
    [calibration_error.bump]   # optional: the true camera moves mid-run
    camera = 2                 # which camera
    frame = 300                # from this frame on
    shift_m = [dx, dy]         # it sees at p what it saw at B(p): B = this shift ...
    rotation_deg = 1.0         # ... and rotation about its reference point

Every error is a :class:`~sim_cluster.scenarios.files.ScenarioError` naming the file and the
field, e.g. ``terrace-sim.toml: cameras[2].fov_deg must be in (0, 180), got 200``. Unknown
fields are errors (a typo must not silently fall back to a default). ``[detector]`` and
``[appearance]`` are read the same way by the other kinds that simulate detections (EPFL).
"""
from __future__ import annotations

from dataclasses import MISSING, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.geometry import Camera, GeometryError
from edge_node.settings import Table
from sim_cluster.scenarios.data import ScenarioStream
from sim_cluster.scenarios.files import ScenarioError, scenario_table
from sim_cluster.scenarios.synthetic.appearance import (QUALITY_PEOPLE, AppearanceError,
                                                        AppearanceParams)
from sim_cluster.scenarios.synthetic.calibration import CalibrationBump, CalibrationOffsets
from sim_cluster.scenarios.synthetic.detector_model import DetectorParams, DetectorParamsError
from sim_cluster.scenarios.synthetic.layout import KINDS as LAYOUT_KINDS
from sim_cluster.scenarios.synthetic.layout import LayoutParams, layout_cameras, layout_stream
from sim_cluster.scenarios.synthetic.pose import camera_from_pose, look_at_angles
from sim_cluster.scenarios.synthetic.world import PeopleParams, WorldConfig, WorldError, stream

CAMERA_KEYS = ("image_size", "homography", "pixel_scale", "projection", "position", "look_at",
               "yaw_deg", "pitch_deg", "roll_deg", "fov_deg", "focal_px", "principal_point")


# -- cameras ----------------------------------------------------------------------------------


def _camera(t: Table, cid: int, fps: float) -> Camera:
    t.declare(*CAMERA_KEYS)  # a homography and a pose exclude each other; both are known
    size = t.raw("image_size")
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise t.error("image_size", f"must be [width, height] positive integers, got {size!r}")
    image_size = (size[0], size[1])
    try:
        if t.has("homography"):
            for k in ("position", "look_at", "yaw_deg", "pitch_deg", "fov_deg", "focal_px"):
                if t.has(k):
                    raise t.error(k, "cannot be combined with homography (give a pose or a homography)")
            G = t.matrix("homography", 3, 3)
            scale = t.number("pixel_scale", 1.0, lo=0.0, lo_open=True)
            P = t.matrix("projection", 3, 4) if t.has("projection") else None
            cam = Camera(id=cid, image_size=image_size, G=G, P=P, pixel_scale=scale, fps=fps)
        else:
            pos = t.vector("position", 3)
            if pos[2] <= 0:
                raise t.error("position", f"height (z) must be > 0, got {pos[2]:g}")
            if t.has("look_at"):
                if t.has("yaw_deg") or t.has("pitch_deg"):
                    raise t.error("look_at", "cannot be combined with yaw_deg/pitch_deg")
                target = t.vector("look_at", 3)
                if np.allclose(target, pos):
                    raise t.error("look_at", "must differ from position")
                yaw, pitch = look_at_angles(pos, target)
            elif t.has("yaw_deg") or t.has("pitch_deg"):
                yaw = t.number("yaw_deg", lo=-360.0, hi=360.0)
                pitch = t.number("pitch_deg", lo=-90.0, hi=90.0)
            else:
                raise t.error(None, "needs look_at, yaw_deg + pitch_deg, or a homography")
            roll = t.number("roll_deg", 0.0, lo=-180.0, hi=180.0)
            if t.has("fov_deg") == t.has("focal_px"):
                raise t.error(None, "needs exactly one of fov_deg and focal_px")
            fov = (t.number("fov_deg", lo=0.0, hi=180.0, lo_open=True, hi_open=True)
                   if t.has("fov_deg") else None)
            focal = t.number("focal_px", lo=0.0, lo_open=True) if t.has("focal_px") else None
            pp = t.vector("principal_point", 2) if t.has("principal_point") else None
            cam = camera_from_pose(cid, image_size, pos, yaw, pitch, roll, focal_px=focal,
                                   fov_deg=fov, principal_point=None if pp is None else tuple(pp),
                                   fps=fps)
    except GeometryError as e:
        raise t.error(None, str(e)) from None
    t.finish()
    return cam


# -- the synthetic kind -----------------------------------------------------------------------


def _dataclass_from(t: Table, cls: type, spans: dict[str, dict], numbers: dict[str, dict],
                    ints: dict[str, dict]) -> Any:
    kwargs: dict[str, Any] = {}
    for f in fields(cls):  # every field read (its default when absent): all known to finish()
        default = f.default if f.default is not MISSING else f.default_factory()
        if f.name in spans:
            kwargs[f.name] = t.span(f.name, default, **spans[f.name])
        elif f.name in ints:
            kwargs[f.name] = t.integer(f.name, default, **ints[f.name])
        elif f.name in numbers:
            kwargs[f.name] = t.number(f.name, default, **numbers[f.name])
    t.finish()
    return cls(**kwargs)


def parse_synthetic(raw: dict, path: Path, seed: int, frames: int | None = None) -> WorldConfig:
    """Validate a synthetic scenario's TOML (already parsed) into a :class:`WorldConfig`."""
    return parse_world(raw, path, seed, frames)[0]


def parse_world(raw: dict, path: Path, seed: int, frames: int | None = None
                ) -> tuple[WorldConfig, LayoutParams | None]:
    """:func:`parse_synthetic`, and the scenario's generated layout when it has a ``[layout]``
    (which then makes its area, cameras and number of people)."""
    file = path.name
    top = scenario_table(raw, file)
    src = top.table("source")
    src.string("kind", "synthetic")
    src.finish()
    name = top.string("name", path.stem)
    top.string("description", "")
    top.integer("seed", 0, lo=0)  # validated; the resolved seed is passed in
    n_frames = top.integer("frames", None, lo=1)
    if frames is not None:
        n_frames = frames
    elif n_frames is None:
        raise top.error("frames", "is required (or pass frames=...)")
    fps = top.number("fps", 25.0, lo=0.0, lo_open=True)

    lt = top.optional_table("layout")
    layout = None if lt is None else layout_from_table(lt)
    if layout is not None:
        for key in ("area", "cameras", "calibration_error"):
            if top.has(key):
                raise top.error(key, "cannot be combined with [layout] (the layout makes the "
                                "area and the cameras, and its cameras are exact)")
        try:
            cameras = layout_cameras(layout, fps)
        except WorldError as e:
            raise lt.error(None, str(e)) from None
        xmin, xmax, ymin, ymax = layout.area
    else:
        a = top.table("area")
        xmin, xmax = a.number("xmin"), a.number("xmax")
        ymin, ymax = a.number("ymin"), a.number("ymax")
        if xmax <= xmin:
            raise a.error("xmax", f"must be > xmin ({xmin:g}), got {xmax:g}")
        if ymax <= ymin:
            raise a.error("ymax", f"must be > ymin ({ymin:g}), got {ymax:g}")
        a.finish()
        cameras = [_camera(t, i, fps) for i, t in enumerate(top.tables("cameras"))]

    pt = top.table("people")
    if layout is not None:
        for key in ("concurrent", "initial"):
            if pt.has(key):
                raise pt.error(key, "is set by [layout] people_per_camera")
        pt = Table({**pt.data, "concurrent": layout.people, "initial": layout.people}, file,
                   "people", ScenarioError)
    pos = {"lo": 0.0, "lo_open": True}
    try:
        people = _dataclass_from(
            pt, PeopleParams,
            spans={"speed_mps": pos, "width_m": pos, "height_m": pos, "stay_s": {"lo": 0.0},
                   "pause_s": {"lo": 0.0}},
            numbers={"entry_gap_s": {"lo": 0.0}, "turn_rate_dps": pos,
                     "pause_probability": {"lo": 0.0, "hi": 1.0}, "spawn_margin_m": {"lo": 0.0},
                     "waypoint_margin_m": {"lo": 0.0}, "personal_space_m": {"lo": 0.0}},
            ints={"concurrent": {"lo": 0, "hi": 100_000}, "initial": {"lo": 0, "hi": 100_000}},
        )
    except WorldError as e:
        raise pt.error(None, str(e)) from None

    detector = detector_params_from_table(top.table("detector"))
    appearance = appearance_params_from_table(top.table("appearance"))

    tt = top.table("truth")
    min_visible = tt.number("min_visible", 0.1, lo=0.0, hi=1.0)
    tt.finish()
    ct = top.optional_table("calibration_error")
    calibration = None if ct is None else calibration_error_from_table(ct, len(cameras))
    top.finish()
    try:
        return WorldConfig(name=name, area=(xmin, xmax, ymin, ymax), cameras=cameras,
                           frames=n_frames, fps=fps, seed=seed, people=people, detector=detector,
                           appearance=appearance, min_visible=min_visible,
                           calibration=calibration), layout
    except WorldError as e:
        raise ScenarioError(file, None, str(e)) from None


_MAX_ROTATION_DEG = 45.0  # a registration error, not a different camera


def _shift(t: Table, label: str, v: object) -> tuple[float, float]:
    if not isinstance(v, list) or len(v) != 2:
        raise t.error(label, f"must be [dx, dy] in metres, got {v!r}")
    return (t.check_number(f"{label}[0]", v[0]), t.check_number(f"{label}[1]", v[1]))


def calibration_error_from_table(t: Table, n_cameras: int) -> CalibrationOffsets:
    """``CalibrationOffsets`` from a ``[calibration_error]`` table: ``shift_m`` (one ``[dx, dy]``
    per camera, metres) and ``rotation_deg`` (one per camera), each defaulting to zeros, and an
    optional ``[calibration_error.bump]`` (``camera``, ``frame``, ``shift_m``, ``rotation_deg``)."""
    rot = {"lo": -_MAX_ROTATION_DEG, "hi": _MAX_ROTATION_DEG}
    shifts: list[tuple[float, float]] = [(0.0, 0.0)] * n_cameras
    if t.has("shift_m"):
        v = t.raw("shift_m")
        if not isinstance(v, list) or len(v) != n_cameras:
            raise t.error("shift_m", f"must list one [dx, dy] per camera ({n_cameras}), got {v!r}")
        shifts = [_shift(t, f"shift_m[{i}]", s) for i, s in enumerate(v)]
    rotations: list[float] = [0.0] * n_cameras
    if t.has("rotation_deg"):
        v = t.raw("rotation_deg")
        if not isinstance(v, list) or len(v) != n_cameras:
            raise t.error("rotation_deg", f"must list one angle per camera ({n_cameras}), got {v!r}")
        rotations = [t.check_number(f"rotation_deg[{i}]", r, **rot) for i, r in enumerate(v)]
    t.declare("shift_m", "rotation_deg")
    bump = None
    bt = t.optional_table("bump")
    if bt is not None:
        camera = bt.integer("camera", lo=0, hi=n_cameras - 1)
        frame = bt.integer("frame", lo=0)
        shift = _shift(bt, "shift_m", bt.raw("shift_m")) if bt.has("shift_m") else (0.0, 0.0)
        bt.declare("shift_m")
        rotation = bt.number("rotation_deg", 0.0, **rot)
        bt.finish()
        bump = CalibrationBump(camera=camera, frame=frame, shift=shift, rotation_deg=rotation)
    t.finish()
    return CalibrationOffsets(shifts=tuple(shifts), rotations_deg=tuple(rotations), bump=bump)


def appearance_params_from_table(t: Table) -> AppearanceParams:
    """``AppearanceParams`` from an ``[appearance]`` table: ``dim`` and either the weights
    (``identity``, ``view``, ``noise``, ``shared``, ``decay``) or the expected distances
    (``same_camera_distance``, ``cross_camera_distance``, ``different_person_distance``); and
    optionally a re-id quality instead of ``decay``: ``rank1`` or ``mean_ap`` (cross-camera, in
    (0, 1]; 1 is the default, perfect re-id) measured with ``quality_people`` people (default
    ``appearance.QUALITY_PEOPLE``; ``AppearanceParams.from_quality``)."""
    dim = t.integer("dim", 512, lo=2, hi=65536)
    weights = ("identity", "view", "noise", "shared")
    dists = ("same_camera_distance", "cross_camera_distance", "different_person_distance")
    quality = ("rank1", "mean_ap")
    t.declare(*weights, *dists, "decay", *quality, "quality_people")  # one set or the other
    has_w = [k for k in weights if t.has(k)]
    has_d = [k for k in dists if t.has(k)]
    has_q = [k for k in quality if t.has(k)]
    try:
        if has_w and has_d:
            raise t.error(has_d[0], f"cannot be combined with {has_w[0]} (give weights or distances)")
        if len(has_q) > 1:
            raise t.error(has_q[1], f"cannot be combined with {has_q[0]} (give one re-id quality)")
        if has_q and t.has("decay"):
            raise t.error("decay", f"cannot be combined with {has_q[0]} (the quality sets it)")
        if t.has("quality_people") and not has_q:
            raise t.error("quality_people", "applies to rank1 or mean_ap, and neither is given")
        decay = t.number("decay", 0.0, lo=0.0)
        if has_d:
            d = AppearanceParams.from_distances()
            ref = d.expected_distances()
            same = t.number("same_camera_distance", ref["same_camera"], lo=0.0, hi=1.0)
            cross = t.number("cross_camera_distance", ref["cross_camera"], lo=0.0, hi=1.0)
            diff = t.number("different_person_distance", ref["different_person"], lo=0.0, hi=1.0)
            params = AppearanceParams.from_distances(same, cross, diff, dim=dim)
            params = replace(params, decay=decay)
        else:
            dflt = AppearanceParams()
            kw = {k: t.number(k, getattr(dflt, k), lo=0.0) for k in weights}
            params = AppearanceParams(dim=dim, decay=decay, **kw)
        if has_q:
            key = has_q[0]
            target = t.number(key, lo=0.0, hi=1.0, lo_open=True)
            people = t.integer("quality_people", QUALITY_PEOPLE, lo=2, hi=10000)
            try:
                params = AppearanceParams.from_quality(**{key: target}, base=params, people=people)
            except AppearanceError as e:
                raise t.error(key, str(e)) from None
    except AppearanceError as e:
        raise t.error(None, str(e)) from None
    t.finish()
    return params


def detector_params_from_table(t: Table) -> DetectorParams:
    """``DetectorParams`` from a ``[detector]`` table (every field optional, range-checked)."""
    unit = {"lo": 0.0, "hi": 1.0}
    try:
        return _dataclass_from(
            t, DetectorParams,
            spans={"fp_person_height_m": {"lo": 0.0, "lo_open": True},
                   "fp_height_frac": {"lo": 0.0, "lo_open": True, "hi": 1.0}},
            numbers={"miss_rate": unit, "occlusion_miss_threshold": unit,
                     "false_positives_per_frame": {"lo": 0.0}, "box_noise_px": {"lo": 0.0},
                     "min_box_height_px": {"lo": 0.0}},
            ints={},
        )
    except DetectorParamsError as e:
        raise t.error(None, str(e)) from None


def layout_from_table(t: Table) -> LayoutParams:
    """``LayoutParams`` from a ``[layout]`` table (:mod:`~sim_cluster.scenarios.synthetic.layout`):
    ``kind`` (corridor | grid), ``cameras``, ``rows`` (grid), ``cell_m``, ``height_m``,
    ``back_m``, ``fov_deg``, ``image_size``, ``people_per_camera``, ``trip_m``, ``leg_m``,
    ``heading_jitter_deg``."""
    d = LayoutParams()
    pos = {"lo": 0.0, "lo_open": True}
    kind = t.string("kind", d.kind, choices=LAYOUT_KINDS)
    cameras = t.integer("cameras", d.cameras, lo=1, hi=4096)
    rows = t.integer("rows", None, lo=1)
    if rows is not None and kind != "grid":
        raise t.error("rows", "is for a grid (a corridor is one row)")
    size = t.raw("image_size", list(d.image_size))
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise t.error("image_size", f"must be [width, height] positive integers, got {size!r}")
    try:
        params = LayoutParams(
            kind=kind, cameras=cameras, rows=rows, cell_m=t.number("cell_m", d.cell_m, **pos),
            height_m=t.number("height_m", d.height_m, **pos),
            back_m=t.number("back_m", d.back_m, lo=0.0),
            fov_deg=t.number("fov_deg", d.fov_deg, lo=0.0, hi=180.0, lo_open=True, hi_open=True),
            image_size=(size[0], size[1]),
            people_per_camera=t.number("people_per_camera", d.people_per_camera, lo=0.0),
            trip_m=t.span("trip_m", d.trip_m, **pos), leg_m=t.span("leg_m", d.leg_m, **pos),
            heading_jitter_deg=t.number("heading_jitter_deg", d.heading_jitter_deg, lo=0.0,
                                        hi=180.0))
    except WorldError as e:
        raise t.error(None, str(e)) from None
    t.finish()
    return params


def load_synthetic(raw: dict, path: Path, seed: int, frames: int | None) -> ScenarioStream:
    """The scenario loader of kind ``synthetic`` (``SCENARIO_KINDS["synthetic"]``): the world,
    frames on demand (a generated layout's world when the scenario has a ``[layout]``)."""
    config, layout = parse_world(raw, path, seed, frames)
    if layout is not None:
        return layout_stream(config, layout)
    return stream(config)
