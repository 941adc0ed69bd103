"""The dependency rules of the three packages, read from the source with ``ast`` (nothing runs).

* ``protocol`` imports nothing of ours: it is the wire contract both sides build on.
* ``edge_node`` never imports ``sim_cluster``: a camera box runs without the simulator.
* ``edge_node/core`` imports neither Zenoh, Rerun, torch nor OpenCV, and nothing of ``edge_node``
  outside the core but ``edge_node.geometry`` (``protocol`` it may): the tracker is pure.
* No import circles among module-level imports (importing ``a.b.c`` also runs the package
  ``a.b``'s ``__init__``, and ``from a.b import c`` names ``a.b``: both count as edges).
* Nobody imports a ``cli`` module: the command lines are argparse over library modules.
* Imports inside functions are for heavy dependencies only (torch, OpenCV, Rerun, matplotlib,
  or one of our modules that imports them at module level; and SciPy, which the core needs
  from its first assignment on but which is two thirds of a camera process's import time, so
  ``edge_node run`` loads it while it waits for its network), each with a comment on its line
  or the line above saying why.

Every failure names ``file:line``, the rule and the import. The last tests run the checker on a
small fake tree that breaks each rule once, so a checker that finds nothing is caught too.
"""
from __future__ import annotations

import ast
import io
import subprocess
import sys
import tokenize
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
OURS = ("protocol", "edge_node", "sim_cluster")
CORE_BANNED = ("zenoh", "rerun", "torch", "cv2")
HEAVY = ("torch", "torchvision", "cv2", "onnxruntime", "rerun", "rerun_cli", "matplotlib",
         "scipy")
CLI_MODULES = ("sim_cluster.cli", "edge_node.cli")

RULES = ("protocol", "edge_node", "core", "circle", "cli", "inner")


@dataclass(frozen=True)
class Import:
    module: str  # the importing module
    path: str  # its file, relative to the root
    line: int
    end_line: int
    names: tuple[str, ...]  # every dotted name the statement may import
    imported: tuple[str, ...]  # what it binds: modules, or the module holding a name
    text: str  # the statement as written
    inner: bool  # inside a function (runs when called, not at import)


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _names(node: ast.AST, module: str, is_package: bool) -> tuple[str, ...]:
    """``import a.b`` -> ``a.b``; ``from a import b, c`` -> ``a``, ``a.b``, ``a.c`` (``b`` may be
    a module or a name in ``a``; relative imports resolved against ``module``)."""
    if isinstance(node, ast.Import):
        return tuple(a.name for a in node.names)
    assert isinstance(node, ast.ImportFrom)
    if node.level:
        base = module.split(".")
        if not is_package:
            base = base[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    return (target, *(f"{target}.{a.name}" for a in node.names))


def _imports(root: Path, path: Path) -> list[Import]:
    source = path.read_text(encoding="utf-8")
    tree = ast.parse(source, str(path))
    module = _module_name(root, path)
    rel = str(path.relative_to(root))
    lines = source.splitlines()
    out: list[Import] = []

    def visit(node: ast.AST, inner: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                text = " ".join(x.strip() for x in lines[child.lineno - 1:child.end_lineno])
                names = _names(child, module, path.name == "__init__.py")
                imported = names if isinstance(child, ast.Import) else names[1:]
                out.append(Import(module, rel, child.lineno, child.end_lineno or child.lineno,
                                  names, imported, text, inner))
            visit(child, inner or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                     ast.Lambda)))

    visit(tree, False)
    return out


def _comment_lines(path: Path) -> tuple[set[int], set[int]]:
    """Lines holding a comment, and lines that are only a comment."""
    tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
    comments = [t for t in tokens if t.type == tokenize.COMMENT]
    return ({t.start[0] for t in comments},
            {t.start[0] for t in comments if not t.line[:t.start[1]].strip()})


def _ancestors(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def check(root: Path) -> dict[str, list[str]]:
    """Every violation of every rule under ``root`` (which holds the three packages), by rule."""
    files = {_module_name(root, p): p for pkg in OURS if (root / pkg).is_dir()
             for p in sorted((root / pkg).rglob("*.py"))}
    imports = {m: _imports(root, p) for m, p in files.items()}
    bad: dict[str, list[str]] = {r: [] for r in RULES}

    def ours(name: str) -> str | None:
        """The module of ours that ``name`` is (or lives in), if any."""
        parts = name.split(".")
        for k in range(len(parts), 0, -1):
            if ".".join(parts[:k]) in files:
                return ".".join(parts[:k])
        return None

    def where(imp: Import) -> str:
        return f"{imp.path}:{imp.line}: {imp.text}"

    # -- edges of module-level imports, and which of our modules are heavy to import
    edges: dict[str, dict[str, Import]] = defaultdict(dict)
    heavy_roots: dict[str, bool] = {}
    for m, imps in imports.items():
        for imp in imps:
            if imp.inner:
                continue
            # ``from a.b import c`` depends on a.b itself too: from inside a.b's own package, a
            # name a.b's __init__ has not defined yet (the __init__ importing this module) fails
            targets = {t for t in (ours(n) for n in imp.names) if t and t != m}
            for t in list(targets):  # importing a.b.c runs a.b's __init__ first
                targets.update(a for a in _ancestors(t) if a in files and a not in _ancestors(m))
            for t in targets - {m}:
                edges[m].setdefault(t, imp)
            if any(n.split(".")[0] in HEAVY for n in imp.names):
                heavy_roots[m] = True

    heavy: dict[str, bool] = {}

    def is_heavy(m: str, seen: frozenset = frozenset()) -> bool:
        if m not in heavy:
            heavy[m] = heavy_roots.get(m, False) or any(
                is_heavy(t, seen | {m}) for t in edges[m] if t not in seen | {m})
        return heavy[m]

    comments = {m: _comment_lines(p) for m, p in files.items()}
    for m, imps in imports.items():
        for imp in imps:
            roots = {n.split(".")[0] for n in imp.names}
            targets = [t for t in (ours(n) for n in imp.imported) if t]
            if m.split(".")[0] == "protocol" and roots & {"edge_node", "sim_cluster"}:
                bad["protocol"].append(f"{where(imp)} (protocol imports nothing of ours)")
            if m.split(".")[0] == "edge_node" and "sim_cluster" in roots:
                bad["edge_node"].append(f"{where(imp)} (edge_node never imports sim_cluster)")
            if m == "edge_node.core" or m.startswith("edge_node.core."):
                if roots & set(CORE_BANNED):
                    bad["core"].append(f"{where(imp)} (the core imports no "
                                       f"{'/'.join(sorted(roots & set(CORE_BANNED)))})")
                outside = [n for n in imp.names if n.startswith("edge_node.")
                           and not n.startswith(("edge_node.core", "edge_node.geometry"))]
                if outside:
                    bad["core"].append(f"{where(imp)} (the core imports {outside[0]}: only "
                                       "edge_node.core, edge_node.geometry and protocol)")
            clis = [c for c in CLI_MODULES if any(n == c or n.startswith(c + ".") for n in imp.names)]
            if clis:
                bad["cli"].append(f"{where(imp)} (nobody imports {clis[0]})")
            if imp.inner:
                third = roots - set(OURS) - {"__future__"}
                ok = (all(r in HEAVY for r in third)
                      and all(is_heavy(t) for t in {t for t in targets if t != m})
                      and (third or targets))
                if not ok:
                    bad["inner"].append(f"{where(imp)} (inside a function: only heavy optional "
                                        "dependencies import there; move it to the top)")
                elif not (any(k in comments[m][0] for k in range(imp.line, imp.end_line + 1))
                          or imp.line - 1 in comments[m][1]):
                    bad["inner"].append(f"{where(imp)} (a heavy import inside a function needs "
                                        "a comment saying why, on its line or the line above)")

    # -- circles (Tarjan's strongly connected components)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    sccs: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in sorted(files):
        if v not in index:
            strong(v)
    for comp in sccs:
        links = [f"{edges[a][b].path}:{edges[a][b].line}: {a} -> {b}"
                 for a in comp for b in sorted(edges[a]) if b in comp]
        bad["circle"].append("import circle " + " <-> ".join(comp) + ": " + "; ".join(links))
    return bad


@pytest.fixture(scope="module")
def found() -> dict[str, list[str]]:
    return check(ROOT)


@pytest.mark.parametrize("rule", RULES)
def test_dependency_rule_holds(found, rule):
    assert not found[rule], f"{len(found[rule])} violation(s) of rule {rule!r}:\n" + "\n".join(found[rule])


def test_checker_reads_the_real_tree(found):
    """The checker saw the packages (a wrong root would find no violations, vacuously)."""
    mods = {_module_name(ROOT, p) for pkg in OURS for p in (ROOT / pkg).rglob("*.py")}
    assert {"protocol.codec", "edge_node.core.node", "sim_cluster.cli"} <= mods
    assert any(i.inner for i in _imports(ROOT, ROOT / "edge_node/perception/reid.py"))


# -- the test of the test: a fake tree that breaks each rule once ---------------------------------
FAKE = {
    "protocol/__init__.py": "",
    "protocol/codec.py": "import json\nfrom edge_node.geometry import Camera\n",
    "edge_node/__init__.py": "",
    "edge_node/geometry.py": "import numpy as np\n",
    "edge_node/cli.py": "import argparse\n",
    "edge_node/runtime/__init__.py": "",
    "edge_node/runtime/loop.py": "from edge_node.core import node\n",
    "edge_node/runtime/sources.py": "import os\nfrom sim_cluster.scenarios import loader\n",
    "edge_node/core/__init__.py": "",
    "edge_node/core/node.py": ("from edge_node.geometry import Camera\nfrom protocol import codec\n"
                               "import zenoh\nfrom edge_node.runtime.loop import run\n"),
    "edge_node/perception/__init__.py": "",
    "edge_node/perception/osnet.py": "import torch\n",
    "edge_node/perception/reid.py": ("def extract():\n"
                                     "    # torch only when OSNet is configured\n"
                                     "    from edge_node.perception import osnet\n"
                                     "    import cv2  # OpenCV is optional\n"
                                     "    import torch\n"),
    "sim_cluster/__init__.py": "from sim_cluster import cli\n",
    "sim_cluster/cli.py": "import argparse\nfrom sim_cluster.a import f\n",
    "sim_cluster/a.py": "from .b import g\n\n\ndef f():\n    import json\n    return json\n",
    "sim_cluster/b.py": "import sim_cluster.a\n\n\ndef g():\n    pass\n",
    "sim_cluster/pkg/__init__.py": "from sim_cluster.pkg.mod import h\n",
    "sim_cluster/pkg/mod.py": "def h():\n    pass\n",
    "sim_cluster/pkg/user.py": "from sim_cluster.pkg.mod import h\n",
    "sim_cluster/pkg/back.py": "from sim_cluster.pkg import mod\n",
    "sim_cluster/pkg2/__init__.py": "from sim_cluster.pkg2.node import Node\n",
    "sim_cluster/pkg2/node.py": "from sim_cluster.pkg2 import helper\n\n\nclass Node:\n    pass\n",
    "sim_cluster/pkg2/helper.py": "X = 1\n",
}


@pytest.fixture(scope="module")
def fake(tmp_path_factory) -> dict[str, list[str]]:
    root = tmp_path_factory.mktemp("tree")
    for rel, text in FAKE.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return check(root)


def test_checker_finds_protocol_importing_ours(fake):
    assert fake["protocol"] == ["protocol/codec.py:2: from edge_node.geometry import Camera "
                                "(protocol imports nothing of ours)"]


def test_checker_finds_edge_node_importing_sim_cluster(fake):
    assert len(fake["edge_node"]) == 1
    assert fake["edge_node"][0].startswith("edge_node/runtime/sources.py:2: from "
                                           "sim_cluster.scenarios import loader")


def test_checker_finds_core_importing_zenoh_and_the_runtime(fake):
    got = fake["core"]
    assert len(got) == 2, got  # geometry and protocol are allowed
    assert got[0].startswith("edge_node/core/node.py:3: import zenoh (the core imports no zenoh")
    assert got[1].startswith("edge_node/core/node.py:4: from edge_node.runtime.loop import run "
                             "(the core imports edge_node.runtime.loop")


def test_checker_finds_circles_with_their_lines(fake):
    got = fake["circle"]
    # a <-> b; the core <-> runtime through loop; pkg2's __init__ importing its node, which
    # imports from pkg2. Not circles: sim_cluster's __init__ importing cli, which imports a,
    # whose package is sim_cluster itself (a parent package is initialised before its modules),
    # and pkg's __init__ importing pkg.mod, which imports nothing back.
    assert any(c.startswith("import circle sim_cluster.a <-> sim_cluster.b: ") and
               "sim_cluster/a.py:1: sim_cluster.a -> sim_cluster.b" in c and
               "sim_cluster/b.py:1: sim_cluster.b -> sim_cluster.a" in c for c in got), got
    assert any("edge_node.core.node" in c and "edge_node.runtime.loop" in c for c in got), got
    assert any(c.startswith("import circle sim_cluster.pkg2 <-> sim_cluster.pkg2.node: ") and
               "sim_cluster/pkg2/node.py:1: sim_cluster.pkg2.node -> sim_cluster.pkg2" in c
               for c in got), got
    assert not any("sim_cluster.pkg " in c or "sim_cluster.pkg." in c for c in got), got
    assert len(got) == 3, got


def test_checker_finds_imports_of_a_cli(fake):
    assert fake["cli"] == ["sim_cluster/__init__.py:1: from sim_cluster import cli "
                           "(nobody imports sim_cluster.cli)"]


def test_checker_finds_inner_imports_that_are_light_or_unexplained(fake):
    got = fake["inner"]
    assert len(got) == 2, got  # osnet (torch, comment above) and cv2 (comment) pass
    assert got[0].startswith("edge_node/perception/reid.py:5: import torch (a heavy import "
                             "inside a function needs a comment")
    assert got[1].startswith("sim_cluster/a.py:5: import json (inside a function: only heavy")


def test_a_camera_process_imports_no_scipy_before_it_needs_it():
    """Start-up time: ``edge_node``'s command line and core import without SciPy (the run
    command loads it in the background while it waits for its network)."""
    code = ("import sys, edge_node.cli, edge_node.core.node; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'torch', 'cv2')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
