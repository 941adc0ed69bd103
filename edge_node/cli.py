"""``edge_node``: run one camera of the network as its own process.

    edge_node run   --config cam0.toml [--frames N] [--mode sync|async] [--log-level INFO]
                    [--rerun off|spawn|connect ADDR|save FILE.rrd|serve] [--recording-id ID]
    edge_node check --config cam0.toml       # validate, open the source as run does (no Zenoh),
                                             # print the resolved config (JSON)
    edge_node calibrate --points pairs.csv [--image-size W H] [--ransac PX]
                                             # image-to-ground homography from >= 4 point pairs

Exit codes: 0 done (or stopped by SIGINT / SIGTERM), 1 internal error, 2 bad command line /
config / source files, 4 Zenoh could not start, 5 the node id is already alive on the
network; 3, a start-up barrier timeout, is no longer fatal (``edge_node/runtime/loop.py``).
Errors are one line on stderr.
"""
from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
import threading
from dataclasses import replace

from edge_node.perception import calibrate
from edge_node.runtime import loop, router
from edge_node.runtime.config import NodeConfigError, load_node_config
from edge_node.runtime.preflight import preflight
from edge_node.runtime.sources import SourceError
from edge_node.runtime.transport import DuplicateNodeError, TransportError
from edge_node.viz import VizSpecError, parse_spec
from protocol.errors import DmttError

PROG = "edge_node"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit 2
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="One camera node of the distributed tracker.")
    sub = p.add_subparsers(dest="command", metavar="{run,check,calibrate,router}",
                           parser_class=_Parser)
    sub.required = True
    r = sub.add_parser("run", help="run this camera's tracker and exchange messages over Zenoh")
    r.add_argument("--config", required=True, help="camera config TOML file")
    r.add_argument("--frames", type=int, default=None, help="process at most N frames")
    r.add_argument("--mode", choices=("sync", "async"), default=None,
                   help="override [runtime] mode")
    r.add_argument("--join", action="store_true",
                   help="join a running network (after a restart): start at the neighbours' "
                        "frame; they resync this node with their trackers")
    r.add_argument("--rerun", nargs="+", default=None, metavar="MODE",
                   help="live view in Rerun, overrides [viz] rerun: off | spawn | connect [ADDR] "
                        "| save FILE.rrd | serve [PORT]")
    r.add_argument("--recording-id", default=None,
                   help="Rerun recording shared by the network's nodes (default dmtt-<network>)")
    r.add_argument("--log-level", default="INFO",
                   choices=("DEBUG", "INFO", "WARNING", "ERROR", "debug", "info", "warning", "error"))
    c = sub.add_parser("check", help="validate the config and print it resolved")
    c.add_argument("--config", required=True, help="camera config TOML file")
    k = sub.add_parser("calibrate", help="fit the image-to-ground homography to point pairs "
                       "(prints a [camera] table and the reprojection errors)")
    k.add_argument("--points", required=True,
                   help="file of u, v, x, y lines: pixel (u, v) shows ground point (x, y)")
    k.add_argument("--image-size", type=int, nargs=2, metavar=("W", "H"), default=None,
                   help="the image size, written into the [camera] table")
    k.add_argument("--ransac", type=float, default=None, metavar="PX",
                   help="robust fit: pairs off by more than PX pixels are left out")
    ro = sub.add_parser("router", help="a Zenoh router joining sites (runs until Ctrl-C)")
    ro.add_argument("--config", default=None, help="Zenoh JSON5 config of the router")
    ro.add_argument("--listen", nargs="*", default=[], metavar="EP", help="endpoints to listen on")
    ro.add_argument("--connect", nargs="*", default=[], metavar="EP",
                    help="endpoints to connect to (the other sites' routers)")
    return p


def _router(args) -> int:
    try:
        return router.run_router(args.config, args.listen, args.connect)
    except TransportError as e:
        return _fail(str(e), loop.EXIT_TRANSPORT)


def _calibrate(args) -> int:
    try:
        img, gnd = calibrate.read_pairs(args.points)
        cal = calibrate.fit_homography(img, gnd, ransac_px=args.ransac)
    except DmttError as e:
        return _fail(str(e))
    print(calibrate.report(cal, tuple(args.image_size) if args.image_size else None))
    return 0


def _fail(message: str, code: int = 2) -> int:
    sys.stderr.write(f"{PROG}: error: {message}\n")
    return code


def _check(args) -> int:
    """Validate the config and open its source as ``run`` does before Zenoh (``preflight``),
    then print the config with what the source resolved."""
    try:
        cfg = load_node_config(args.config)
        ready = preflight(cfg)
    except DmttError as e:
        return _fail(str(e))
    ready.close()
    src = ready.source
    d = cfg.to_dict()
    d["resolved"] = {"frames": src.frames, "fps": src.fps, "units_per_metre": src.units_per_metre,
                     "camera_image_size": list(src.camera.image_size),
                     "first_counter": ready.first_counter}
    print(json.dumps(d, indent=1))
    return 0


def _run(args, warming: threading.Thread | None = None) -> int:
    logging.basicConfig(level=args.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if args.frames is not None and args.frames < 1:
        return _fail(f"--frames must be >= 1, got {args.frames}")
    try:
        cfg = load_node_config(args.config)
    except NodeConfigError as e:
        return _fail(str(e))
    if args.rerun is not None or args.recording_id is not None:
        try:
            spec = parse_spec(args.rerun) if args.rerun is not None else None
        except VizSpecError as e:
            return _fail(f"--rerun {e}")
        viz = replace(cfg.viz, **({"rerun": str(spec)} if spec else {}),
                      **({"recording_id": args.recording_id} if args.recording_id else {}))
        cfg = replace(cfg, viz=viz)
    try:
        report = loop.run_node(cfg, frames=args.frames, mode=args.mode, join=args.join,
                               freeze_gc=True,
                               before_network=warming.join if warming is not None else None)
    except (NodeConfigError, SourceError) as e:
        return _fail(str(e), loop.EXIT_USAGE)
    except DuplicateNodeError as e:
        return _fail(str(e), loop.EXIT_DUPLICATE)
    except TransportError as e:
        return _fail(str(e), loop.EXIT_TRANSPORT)
    except KeyboardInterrupt:
        return _fail("interrupted", 130)
    except Exception as e:  # noqa: BLE001 - log the traceback, one line on stderr
        logging.getLogger("edge_node").exception("internal error")
        return _fail(f"internal error: {type(e).__name__}: {e}", loop.EXIT_FAILURE)
    return report.exit_code


def warm_up(modules: tuple[str, ...] = ("scipy.optimize",)) -> threading.Thread:
    """Import the heavy libraries the first frame needs in the background, while the process
    reads its config and opens its source (start-up time is spawn to frame 0; the core imports
    them on first use). ``run`` waits for it before it opens Zenoh: a node whose neighbours
    already wait for its frame 0 must not still be importing (on a busy machine that took
    seconds, and the neighbours timed out)."""
    t = threading.Thread(target=lambda: [importlib.import_module(m) for m in modules],
                         name="warm-up", daemon=True)
    t.start()
    return t


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    warming = warm_up() if args.command == "run" else None
    if args.command == "check":
        return _check(args)
    if args.command == "calibrate":
        return _calibrate(args)
    if args.command == "router":
        return _router(args)
    return _run(args, warming)


if __name__ == "__main__":
    sys.exit(main())
