"""Shared bits of the experiment scripts: run metadata and atomic JSON reports."""

from __future__ import annotations

import json
import os
import platform
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def metadata(device: str, **extra) -> dict:
    """Who ran what: git sha, Warp and Python versions, device, core count, plus ``extra``."""
    git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return {"warp": __import__("warp").__version__, "python": platform.python_version(), "device": device,
            "cpus": os.cpu_count(), "git": git.stdout.strip(), **extra}


def write_report(path, report: dict) -> None:
    """Write ``report`` as JSON through a temporary file (never a half-written report)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2))
    os.replace(tmp, out)
    print(f"wrote {out}")
