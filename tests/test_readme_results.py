"""The docs' headline Results tables are the committed ``docs/results/summary.json``.

``sim_cluster ablation`` writes ``summary.json``; ``sim_cluster report`` renders the ablation
tables of ``docs/evaluation.md`` from it. This test does not trust the renderer: it reads every
cell back from the markdown and compares it with the summary's mean rounded to the printed
precision, so a table edited by hand, or a summary re-run without re-rendering the page, fails
here naming the cell. (``tests/test_docs.py`` checks every generated block of every page.)"""
from __future__ import annotations

import json
import re
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "evaluation.md"

#: a table's column header -> (configuration, view); cells are "MOTA / IDF1" of that view
COLUMNS = {
    "dkf": ("dkf", "ground"),
    "dkf+lda": ("dkf+lda", "ground"),
    "dkf+lda+dtm ground": ("dkf+lda+dtm", "ground"),
    ":noreg ground": ("dkf+lda+dtm:noreg", "ground"),
    "dkf+dtm ground": ("dkf+dtm", "ground"),
    "dkf+dtm (no re-id) ground": ("dkf+dtm", "ground"),
    "dkf+lda+dtm image": ("dkf+lda+dtm", "image"),
    ":noreg image": ("dkf+lda+dtm:noreg", "image"),
    "dkf+dtm image": ("dkf+dtm", "image"),
}
HEADLINE = ("terrace-gt", "campus-gt", "terrace-sim", "lab-sim", "campus-sim")


def _number(text: str) -> float:
    return float(text.strip().strip("*").replace("\u2212", "-"))


def page_tables(text: str) -> dict[str, list[list[str]]]:
    """``{scenario: rows}`` of each ``<!-- report:ablation-<scenario> -->`` block's table
    (header row first, separator dropped)."""
    tables = {}
    for name in HEADLINE:
        start = text.index(f"<!-- report:ablation-{name} -->")
        lines = text[start:].splitlines()
        first = next(i for i, line in enumerate(lines) if line.startswith("|"))
        rows = []
        for line in lines[first:]:
            if not line.startswith("|"):
                break
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                rows.append(cells)
        tables[name] = rows
    return tables


def mismatches(tables: dict[str, list[list[str]]], summary: dict) -> tuple[list[str], int]:
    """The cells whose printed figure is not the summary's mean at three decimals, and how many
    figures were compared."""
    bad, checked = [], 0
    for scenario, rows in tables.items():
        header, body = rows[0], rows[1:]
        assert header[0] == "topology" and body, (scenario, header)
        for row in body:
            topology = row[0]
            for head, cell in zip(header[1:], row[1:]):
                config, view = COLUMNS[head]
                got = summary["cells"][scenario][topology][config]
                for part, metric in zip(cell.split("/"), ("mota", "idf1")):
                    want = got[f"{view}_{metric}"]["mean"]
                    checked += 1
                    if abs(_number(part) - round(want, 3)) > 1.5e-3:
                        bad.append(f"{scenario} {topology} '{head}' {metric}: docs "
                                   f"{part.strip()}, summary.json {want:.4f}")
    return bad, checked


def _summary() -> dict:
    return json.loads((ROOT / "docs/results/summary.json").read_text())


def test_the_docs_headline_tables_are_the_committed_summary():
    bad, checked = mismatches(page_tables(PAGE.read_text()), _summary())
    assert bad == []
    assert checked >= 200  # five tables of 4-5 topologies x 6-7 columns x 2 figures


def test_the_check_finds_a_changed_cell():
    text = PAGE.read_text()
    row = page_tables(text)["terrace-gt"][1]
    mota = row[1].split("/")[0].strip().strip("*")
    bumped = text.replace(f"| {row[0]} | {row[1]} |",
                          f"| {row[0]} | {row[1].replace(mota, f'{_number(mota) + 0.01:.3f}')} |", 1)
    bad, _ = mismatches(page_tables(bumped), _summary())
    assert len(bad) == 1 and bad[0].startswith(f"terrace-gt {row[0]} 'dkf+lda+dtm ground' mota")
