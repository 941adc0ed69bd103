"""mkdocs hook: the CLI reference (docs/cli.md) rendered from the argparse parsers at build time,
so it cannot fall behind the code. ``<!-- cli:sim_cluster -->`` and ``<!-- cli:edge_node -->``
in a page become the ``--help`` of the program and of each of its subcommands;
``<!-- cli:tracker -->`` the tracker's parameters, section by section, with their defaults,
rules and meanings (``edge_node/core/config.py``, where each is declared once)."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:  # the checkout's code, whatever is installed
    sys.path.insert(0, str(ROOT))

WIDTH = "100"


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices.items())
    return []


def reference(parser: argparse.ArgumentParser) -> str:
    """The program's ``--help``, then a section per subcommand with its ``--help``."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        parts = [f"```text\n{parser.format_help().rstrip()}\n```"]
        for name, sub in _subparsers(parser):
            parts.append(f"### {parser.prog} {name}\n\n```text\n{sub.format_help().rstrip()}\n```")
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n\n".join(parts)


def _toml(v) -> str:
    """A default as a TOML file writes it."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "(none)"
    if isinstance(v, tuple):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def parameters() -> str:
    """The configuration tree as one table per section: name, default, rule, meaning."""
    from dataclasses import fields
    from edge_node.core.config import SECTIONS
    parts = []
    for name, cls in SECTIONS.items():
        doc = " ".join((cls.__doc__ or "").split()).split(": ", 1)[-1]
        rows = ["| parameter | default | rule | meaning |", "| --- | --- | --- | --- |"]
        for f in fields(cls):
            rule = f.metadata["rule"]
            meaning = f.metadata.get("doc", "").replace("|", "\\|")
            rows.append(f"| `{f.name}` | `{_toml(f.default)}` | {rule.describe()} | {meaning} |")
        parts.append(f"### [tracker.{name}]\n\n{doc}\n\n" + "\n".join(rows))
    return "\n\n".join(parts)


def parsers() -> dict[str, argparse.ArgumentParser]:
    from edge_node.cli import _parser
    from sim_cluster.cli import build_parser
    return {"sim_cluster": build_parser(), "edge_node": _parser()}


def on_page_markdown(markdown: str, page, config, files) -> str:
    if "<!-- cli:" not in markdown:
        return markdown
    for name, parser in parsers().items():
        markdown = markdown.replace(f"<!-- cli:{name} -->", reference(parser))
    if "<!-- cli:tracker -->" in markdown:
        markdown = markdown.replace("<!-- cli:tracker -->", parameters())
    return markdown
