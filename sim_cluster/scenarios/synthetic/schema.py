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
                 distances same_camera_distance, cross_camera_distance, different_person_distance
    [truth]      min_visible                         (world module docstring)

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

from dataclasses import MISSING, fields
import math
from pathlib import Path
from typing import Any

import numpy as np

from edge_node.geometry import Camera, GeometryError
from edge_node.settings import Table
from sim_cluster.scenarios.data import ScenarioStream
from sim_cluster.scenarios.files import ScenarioError, scenario_table
from sim_cluster.scenarios.synthetic.appearance import AppearanceError, AppearanceParams
from sim_cluster.scenarios.synthetic.calibration import CalibrationBump, CalibrationError
from sim_cluster.scenarios.synthetic.detector_model import DetectorParams, DetectorParamsError
from sim_cluster.scenarios.synthetic.world import PeopleParams, WorldConfig, WorldError, stream

CAMERA_KEYS = ("image_size", "homography", "pixel_scale", "projection", "position", "look_at",
               "yaw_deg", "pitch_deg", "roll_deg", "fov_deg", "focal_px", "principal_point")


# -- cameras ----------------------------------------------------------------------------------


def look_at_angles(position: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """``(yaw_deg, pitch_deg)`` of an optical axis from ``position`` towards ``target`` (xyz)."""
    d = np.asarray(target, float) - np.asarray(position, float)
    horiz = math.hypot(d[0], d[1])
    yaw = math.degrees(math.atan2(d[1], d[0])) if horiz > 1e-12 else 0.0
    pitch = math.degrees(math.atan2(-d[2], horiz))
    return yaw, pitch


def camera_from_pose(
    id: int,
    image_size: tuple[int, int],
    position: np.ndarray,
    yaw_deg: float,
    pitch_deg: float,
    roll_deg: float = 0.0,
    *,
    focal_px: float | None = None,
    fov_deg: float | None = None,
    principal_point: tuple[float, float] | None = None,
    fps: float = 25.0,
) -> Camera:
    """A pinhole camera: ``P = K [R | -R C]``, ``G = inv(K [r1 r2 -R C])`` (ground z = 0).

    World axes: x, y on the ground, z up. Camera axes: x right, y down, z forward. ``yaw`` is
    the optical axis' heading counter-clockwise from +x, ``pitch`` its tilt below the horizon,
    ``roll`` a rotation about it. Give ``focal_px`` or the horizontal ``fov_deg``.
    """
    W, H = image_size
    if (focal_px is None) == (fov_deg is None):
        raise GeometryError(f"camera {id}: give exactly one of focal_px and fov_deg")
    f = focal_px if focal_px is not None else (W / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    cx, cy = principal_point if principal_point is not None else (W / 2.0, H / 2.0)
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    fwd = np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)])
    right = np.array([math.sin(y), -math.cos(y), 0.0])
    down = np.cross(fwd, right)
    right, down = math.cos(r) * right + math.sin(r) * down, -math.sin(r) * right + math.cos(r) * down
    R = np.stack([right, down, fwd])
    C = np.asarray(position, float)
    t = -R @ C
    P = K @ np.hstack([R, t[:, None]])
    Hg = K @ np.stack([R[:, 0], R[:, 1], t], axis=1)  # ground (x, y, 1) -> pixels
    if abs(np.linalg.det(Hg)) < 1e-12 * max(1.0, np.abs(Hg).max()) ** 3:
        raise GeometryError(f"camera {id}: the ground plane is seen edge-on (camera at height 0?)")
    G = np.linalg.inv(Hg)
    G = G / np.abs(G).max()
    return Camera(id=id, image_size=(int(W), int(H)), G=G, P=P, pixel_scale=1.0, fps=fps)


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
    pos = {"lo": 0.0, "lo_open": True}
    try:
        people = _dataclass_from(
            pt, PeopleParams,
            spans={"speed_mps": pos, "width_m": pos, "height_m": pos, "stay_s": {"lo": 0.0},
                   "pause_s": {"lo": 0.0}},
            numbers={"entry_gap_s": {"lo": 0.0}, "turn_rate_dps": pos,
                     "pause_probability": {"lo": 0.0, "hi": 1.0}, "spawn_margin_m": {"lo": 0.0},
                     "waypoint_margin_m": {"lo": 0.0}, "personal_space_m": {"lo": 0.0}},
            ints={"concurrent": {"lo": 0, "hi": 1000}, "initial": {"lo": 0, "hi": 1000}},
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
                           calibration=calibration)
    except WorldError as e:
        raise ScenarioError(file, None, str(e)) from None


_MAX_ROTATION_DEG = 45.0  # a registration error, not a different camera


def _shift(t: Table, label: str, v: object) -> tuple[float, float]:
    if not isinstance(v, list) or len(v) != 2:
        raise t.error(label, f"must be [dx, dy] in metres, got {v!r}")
    return (t.check_number(f"{label}[0]", v[0]), t.check_number(f"{label}[1]", v[1]))


def calibration_error_from_table(t: Table, n_cameras: int) -> CalibrationError:
    """``CalibrationError`` from a ``[calibration_error]`` table: ``shift_m`` (one ``[dx, dy]``
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
    return CalibrationError(shifts=tuple(shifts), rotations_deg=tuple(rotations), bump=bump)


def appearance_params_from_table(t: Table) -> AppearanceParams:
    """``AppearanceParams`` from an ``[appearance]`` table: ``dim`` and either the weights
    (``identity``, ``view``, ``noise``, ``shared``) or the expected distances
    (``same_camera_distance``, ``cross_camera_distance``, ``different_person_distance``)."""
    dim = t.integer("dim", 512, lo=2, hi=65536)
    weights = ("identity", "view", "noise", "shared")
    dists = ("same_camera_distance", "cross_camera_distance", "different_person_distance")
    t.declare(*weights, *dists)  # one set or the other; both are known
    has_w = [k for k in weights if t.has(k)]
    has_d = [k for k in dists if t.has(k)]
    try:
        if has_w and has_d:
            raise t.error(has_d[0], f"cannot be combined with {has_w[0]} (give weights or distances)")
        if has_d:
            d = AppearanceParams.from_distances()
            ref = d.expected_distances()
            same = t.number("same_camera_distance", ref["same_camera"], lo=0.0, hi=1.0)
            cross = t.number("cross_camera_distance", ref["cross_camera"], lo=0.0, hi=1.0)
            diff = t.number("different_person_distance", ref["different_person"], lo=0.0, hi=1.0)
            params = AppearanceParams.from_distances(same, cross, diff, dim=dim)
        else:
            dflt = AppearanceParams()
            kw = {k: t.number(k, getattr(dflt, k), lo=0.0) for k in weights}
            params = AppearanceParams(dim=dim, **kw)
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


def load_synthetic(raw: dict, path: Path, seed: int, frames: int | None) -> ScenarioStream:
    """The scenario loader of kind ``synthetic`` (``SCENARIO_KINDS["synthetic"]``): the world,
    frames on demand."""
    return stream(parse_synthetic(raw, path, seed, frames))
