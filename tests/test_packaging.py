"""The wheel is the product: ``python -m build`` makes it without a warning from the project's
metadata, and installed in a fresh venv outside the source tree it runs ``sim_cluster up
--frames 50`` (presets, the detector model and the entry points come from the wheel alone).

To keep minutes of dependency installs out of the suite the venv sees this interpreter's
site-packages through a ``.pth`` path line (a path line only: the ``.pth`` files there, the
editable install of this checkout among them, are not processed); the project's own code comes
from the wheel, which the test checks."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("protocol", "edge_node", "sim_cluster", "pyproject.toml", "README.md", "LICENSE")

pytestmark = [pytest.mark.integration, pytest.mark.slow]


#: no PYTHONPATH: nothing of the checkout may leak into the venv (pip would take a dmtt there for
#: the wheel's and skip the install)
ENV = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "DMTT_DATA")}


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    kw.setdefault("env", ENV)
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)


def test_the_wheel_runs_a_cluster_outside_the_source_tree(tmp_path):
    pytest.importorskip("build")
    src = tmp_path / "src"
    src.mkdir()
    for name in SOURCES:  # build from a copy: the checkout stays clean
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(p, src / name)
    dist = tmp_path / "dist"
    b = _run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", dist, src],
             timeout=600)
    assert b.returncode == 0, b.stdout[-2000:] + b.stderr[-2000:]
    out = b.stdout + b.stderr
    for warning in ("SetuptoolsDeprecationWarning", "License classifiers are deprecated",
                    "project.license` as a TOML table is deprecated"):
        assert warning not in out, out[-3000:]
    wheel, = dist.glob("dmtt-*.whl")

    venv = tmp_path / "venv"
    assert _run([sys.executable, "-m", "venv", "--without-pip", venv], timeout=120).returncode == 0
    py = venv / "bin" / "python"
    site = Path(_run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"])
                .stdout.strip())
    pip = _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index",
                "--quiet", wheel], timeout=300)
    assert pip.returncode == 0, pip.stderr[-2000:]
    assert (site / "edge_node" / "perception" / "models" / "ssdlite_person.onnx").is_file()
    # the dependencies, seen only after the install (pip would take this checkout's editable
    # install there for the wheel's and skip it)
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_dmtt_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")

    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = ENV
    where = _run([py, "-c", "import edge_node, sim_cluster, protocol; "
                  "print(edge_node.__file__, sim_cluster.__file__, protocol.__file__)"],
                 cwd=cwd, env=env, timeout=120)
    assert where.returncode == 0, where.stderr
    for f in where.stdout.split():
        assert Path(f).is_relative_to(site), f  # from the wheel, not the checkout
        assert not Path(f).is_relative_to(ROOT)
    if _run([py, "-c", "import cv2"], env=env).returncode == 0:  # the vision extra is there
        det = _run([py, "-c", "from edge_node.perception.detectors import SsdliteDetector as S; "
                    "d = S(backend='opencv'); print(d.path)"], cwd=cwd, env=env, timeout=120)
        assert det.returncode == 0 and Path(det.stdout.strip()).is_relative_to(site), det.stderr

    up = _run([venv / "bin" / "sim_cluster", "up", "--frames", "50", "--out", "run", "--quiet"],
              cwd=cwd, env=env, timeout=600)
    assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-2000:]
    summary = json.loads((cwd / "run" / "summary.json").read_text())
    assert summary["scenario"] == "terrace-sim" and summary["frames"] == 50
    assert summary["metrics"]["ground"]["median"]["mota"] > 0.5
