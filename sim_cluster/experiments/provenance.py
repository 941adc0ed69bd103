"""Where and on what code a measurement was taken: written into every data file the docs render
(``meta.provenance``), so a figure in the docs stands beside its machine and commit."""
from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys
from pathlib import Path


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _commit() -> str | None:
    """The commit of the code that runs (with ``+dirty`` when the work tree has changes), or
    ``None`` outside a git checkout (an installed wheel)."""
    root = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(["git", "-C", str(root), "rev-parse", "--short=7", "HEAD"],
                             capture_output=True, text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--",
                                "protocol", "edge_node", "sim_cluster"], capture_output=True,
                               text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return sha + ("+dirty" if dirty else "")


def machine() -> str:
    """One line: CPU model, cores, memory, OS, Python (the machine a timing belongs to)."""
    mem = ""
    try:
        kb = int(next(line.split()[1] for line in Path("/proc/meminfo").read_text().splitlines()
                      if line.startswith("MemTotal")))
        mem = f", {kb / 2**20:.0f} GiB"
    except (OSError, StopIteration, ValueError):
        pass
    return (f"{_cpu()}, {os.cpu_count()} cores{mem}; {platform.system()} {platform.release()}; "
            f"Python {platform.python_version()}")


def provenance(command: str | None = None) -> dict:
    """``{"commit", "machine", "date", "command", "load"}`` of a measurement taken now."""
    try:
        load = round(os.getloadavg()[0], 1)
    except OSError:
        load = None
    prog = Path(sys.argv[0])
    name = prog.parent.name if prog.name in ("cli.py", "__main__.py") else prog.name  # -m runs
    return {"commit": _commit(), "machine": machine(),
            "date": datetime.date.today().isoformat(),
            "command": command or " ".join([name] + sys.argv[1:]), "load": load}
