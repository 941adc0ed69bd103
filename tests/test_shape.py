"""The core's shape (issue: the tracker as roles over one state table): ``CameraNode`` only
composes roles; no role imports another; no role holds the whole configuration; every role has
a fake in ``tests/fakes.py`` and a node runs with it in the role's place."""
import ast
from pathlib import Path

import numpy as np
import pytest

from edge_node.core import CameraNode, Components, Detection, TrackerConfig, assemble
from edge_node.core.config import SECTION_OF, SECTIONS, Slice
from fakes import FakeViews, box_at, fake_roles, topdown_camera

CORE = Path(__file__).resolve().parent.parent / "edge_node" / "core"
#: role -> its module (the node's attribute is the role's name; views: ``own_views``)
ROLES = {"predictor": "predictor", "measurer": "measurer", "associator": "associator",
         "initiators": "initiator", "lifecycle": "lifecycle", "inbound": "inbound",
         "trust": "trust", "updater": "updater", "registrar": "registrar", "outbound": "outbound",
         "reporter": "reporter", "own_views": "views"}


def test_the_node_only_composes():
    """``node.py`` under 150 lines, without NumPy, and ``prepare`` / ``update`` a call per role."""
    text = (CORE / "node.py").read_text()
    assert len(text.splitlines()) <= 150
    tree = ast.parse(text)
    imported = {a.name for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
                for a in n.names} | {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {"numpy", "np"} & imported and "np." not in text
    node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "CameraNode")
    methods = [f.name for f in node.body if isinstance(f, ast.FunctionDef)]
    assert len(methods) <= 8, methods


def test_no_role_imports_another_role():
    modules = set(ROLES.values())
    bad = []
    for mod in sorted(modules):
        tree = ast.parse((CORE / f"{mod}.py").read_text())
        for n in ast.walk(tree):
            names = ([n.module] if isinstance(n, ast.ImportFrom) and n.module else []) + \
                ([a.name for a in n.names] if isinstance(n, ast.Import) else [])
            for name in names:
                other = name.rsplit(".", 1)[-1]
                if name.startswith("edge_node.core.") and other in modules - {mod}:
                    bad.append(f"{mod} imports {other}")
    assert bad == []


def _held(obj, seen=None) -> list:
    """Every object ``obj`` refers to through its attributes, one level into containers."""
    out = []
    for v in (vars(obj).values() if hasattr(obj, "__dict__") else ()):
        out.append(v)
        if isinstance(v, dict):
            out += list(v.values())
        elif isinstance(v, (list, tuple)):
            out += list(v)
    return out


def test_no_role_holds_the_whole_configuration():
    """Each role (and each part a role is built from) holds its slice, never the tree."""
    node = CameraNode(topdown_camera(0), (1,), TrackerConfig(), "t")
    parts = [getattr(node, r) for r in ROLES] + [node.associate, node.manager, node.book,
                                                  node.memory, node.screen]
    parts += list(node.initiators.values()) + list(node.registrations.values())
    for p in parts:
        for q in [p, *_held(p)]:
            assert not isinstance(q, TrackerConfig), f"{type(p).__name__} holds the configuration"
    slices = [q for p in parts for q in _held(p) if isinstance(q, Slice)]
    assert len({type(s) for s in slices}) >= 8  # the roles read their own slices


def test_every_parameter_is_declared_once_in_one_section():
    names = [f for s in SECTIONS.values() for f in s.__dataclass_fields__]
    assert len(names) == len(set(names)) == len(SECTION_OF)
    cfg = TrackerConfig(tau=2.5, kappa=9, view_rate=0.5)
    assert cfg.associator.tau == cfg.tau == 2.5 and cfg.manager.kappa == 9
    assert TrackerConfig.from_dict({"associator": {"tau": 2.5}, "kappa": 9, "view_rate": 0.5}) == cfg


def _walk(node, frames=12):
    out = []
    for k in range(frames):
        node.prepare(k, [Detection(box_at(2.0 + 0.02 * k, 3.0), None)])
        out.append(node.update([]))
    return out


@pytest.mark.parametrize("role", list(ROLES))
def test_a_node_runs_with_a_fake_in_each_role(role):
    """A fake in the role's place is called every frame, and the node still tracks the one
    person (one track) where the fake keeps the role's promise."""
    cfg = TrackerConfig(registration=False, use_appearance=False)
    node = CameraNode(topdown_camera(0), (), cfg, "t",
                      components=Components(**{**vars(assemble(cfg)), "views": FakeViews})
                      if role == "own_views" else None)
    fake = node.own_views if role == "own_views" else fake_roles(node)[role]
    if role != "own_views":
        setattr(node, role, fake)
    out = _walk(node)
    fakes = fake.values() if isinstance(fake, dict) else [fake]
    assert all(f.calls >= 12 for f in fakes)
    if role not in ("outbound",):
        assert len(out[-1]) == 1 and np.allclose(out[-1][0].x[:2], [2.22, 3.0], atol=0.15)
