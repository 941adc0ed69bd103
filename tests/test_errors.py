"""One root for the project's errors (``protocol/errors.py``): every exception class the
project defines derives from ``DmttError``, so the command lines catch the root once and a new
error needs no list to be added to (``sim_cluster/cli.py`` listed 15 classes by hand and had
missed three). Read from the source, so a module with a heavy optional dependency counts too."""
from __future__ import annotations

import ast
from pathlib import Path

from protocol.errors import DmttError, ProtocolError

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("protocol", "edge_node", "sim_cluster")
BUILTIN = {"Exception", "ValueError", "RuntimeError", "OSError", "FileNotFoundError", "KeyError",
           "TypeError", "LookupError", "IOError", "EnvironmentError", "ArithmeticError"}


def _classes():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if isinstance(node, ast.ClassDef):
                    names = [b.id if isinstance(b, ast.Name) else getattr(b, "attr", "")
                             for b in node.bases]
                    yield path.relative_to(ROOT), node, names


def test_every_exception_class_derives_from_the_root():
    bad, seen = [], 0
    for path, node, bases in _classes():
        if set(bases) & BUILTIN:
            seen += 1
            if "DmttError" not in bases and node.name != "DmttError":
                bad.append(f"{path}:{node.lineno}: class {node.name}({', '.join(bases)})")
    assert seen >= 20  # the scan sees the project's error classes
    assert not bad, "derive from protocol.errors.DmttError:\n" + "\n".join(bad)


def test_a_class_named_like_an_error_is_an_exception():
    """``CalibrationError`` was a dataclass of calibration offsets: a name that lies."""
    bad = [f"{p}:{n.lineno}: {n.name}" for p, n, bases in _classes()
           if n.name.endswith("Error") and not bases]
    assert not bad, bad


def test_the_command_lines_catch_the_root():
    from sim_cluster import cli

    assert DmttError in cli.INPUT_ERRORS
    assert issubclass(ProtocolError, ValueError)  # still what a ValueError handler expects


def test_every_protocol_reason_is_raised_somewhere():
    """A reason tag that no code raises is a counter that can never move (``stale`` was)."""
    text = "\n".join(p.read_text(encoding="utf-8") for pkg in PACKAGES
                     for p in (ROOT / pkg).rglob("*.py") if p.name != "errors.py")
    never = [r for r in ProtocolError.REASONS
             if f'ProtocolError("{r}"' not in text and f"ProtocolError('{r}'" not in text
             and f'"{r}"' not in text]
    assert not never, never
