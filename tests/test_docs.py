"""The documentation: every generated table matches its data file, no other table carries a
measured figure, the user docs name no issue numbers or commit hashes outside a table's
provenance line, the README stays short and shows the two commands, and the site builds with
``mkdocs build --strict`` (no broken link or reference) with the CLI reference of every
subcommand."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sim_cluster.experiments import report

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RESULTS = DOCS / "results"
HASH = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
ISSUE = re.compile(r"\bissues? \d+|#\d{2,}\b", re.I)
FIGURE = re.compile(r"(?<![\w.])\d+\.\d{2,}(?![\w.])")  # 0.936, 12.34: a measured figure


def _user_pages() -> list[Path]:
    return [ROOT / "README.md"] + report.pages(DOCS)


def test_every_generated_block_matches_its_data_file():
    stale, unknown = report.update(DOCS, RESULTS, check=True)
    assert unknown == []
    assert stale == [], f"run sim_cluster report: {stale}"
    names = {m.group("name") for p in report.pages(DOCS) for m in report.BLOCK.finditer(p.read_text())}
    # every registered table is on some page, so a data file cannot be rendered nowhere
    assert names == set(report.TABLES), set(report.TABLES) ^ names


def test_a_changed_data_file_makes_its_tables_stale(tmp_path):
    docs = tmp_path / "docs"
    shutil.copytree(DOCS, docs, ignore=shutil.ignore_patterns("*.png", "results.csv"))
    summary = json.loads((docs / "results/summary.json").read_text())
    cell = summary["cells"]["terrace-gt"]["complete"]["dkf+lda+dtm"]["ground_mota"]
    cell["mean"] += 0.01
    (docs / "results/summary.json").write_text(json.dumps(summary))
    stale, _ = report.update(docs, docs / "results", check=True)
    assert stale == ["evaluation.md: ablation-terrace-gt"]
    report.update(docs, docs / "results", check=False)  # re-rendering makes it true again
    assert report.update(docs, docs / "results", check=True) == ([], [])
    assert f"{cell['mean']:.3f} /" in (docs / "evaluation.md").read_text()


def test_no_table_outside_a_generated_block_carries_a_measured_figure():
    bad = []
    for page in _user_pages():
        text = report.BLOCK.sub("", page.read_text())
        for n, line in enumerate(text.splitlines(), 1):
            if line.startswith("|") and FIGURE.search(line):
                bad.append(f"{page.name}: {line[:100]}")
    assert bad == []


def test_user_docs_name_no_issue_numbers_or_commit_hashes():
    bad = []
    for page in _user_pages():
        for n, line in enumerate(page.read_text().splitlines(), 1):
            if line.startswith("*Data: "):  # a table's provenance: its commit belongs there
                continue
            if ISSUE.search(line) or HASH.search(line):
                bad.append(f"{page.name}:{n}: {line.strip()[:100]}")
    assert bad == []


def test_the_readme_is_an_entry_point():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    assert "make run" in text and "make test" in text
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (ROOT / link).is_file(), link


@pytest.mark.integration
def test_the_site_builds_strictly_with_the_cli_reference(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                          str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    cli = (tmp_path / "site/cli/index.html").read_text()
    from edge_node.cli import _parser as edge_parser  # noqa: PLC0415 (the CLI's own parsers)
    from sim_cluster.cli import build_parser
    for prog, parser in (("sim_cluster", build_parser()), ("edge_node", edge_parser())):
        sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        for name in sub.choices:
            assert f"{prog} {name}" in cli, f"{prog} {name} missing from the CLI reference"
    api = (tmp_path / "site/api/index.html").read_text()
    for name in ("CameraNode", "TrackerConfig", "Detection", "FrameMessage", "SsdliteDetector"):
        assert name in api
