"""Shared bits of the experiment scripts: run metadata, atomic JSON reports, the real robots' data and disks."""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# opencr-mujoco's training files of the real robots (v4_train.csv, v6_train.csv): not shipped here
HARDWARE_DATA = Path(os.environ.get("TDCR_HARDWARE_DATA", ROOT.parent / "shared" / "validation" / "ocm_ftdcr"))


# opencr-mujoco's links per segment (its data/sysid/v*_robot.json, links_per_segment): a spacer disk ends each
LINKS = {"v4": (10, 10, 10), "v6": (15, 15, 8)}


def with_disks(scene: dict, name: str) -> dict:
    """A scene dict of robot ``name`` in the disk model: a disk at the end of each link (sections
    end where tendons end), one RK4 step between two disks."""
    ends = sorted({t["length"] for t in scene["tendons"]})
    disks = [float(x) for a, b, c in zip([0.0, *ends[:-1]], ends, LINKS[name]) for x in np.linspace(a, b, c + 1)[1:]]
    return scene | {"robot": scene["robot"] | {"disks": disks},
                    "solver": scene.get("solver", {}) | {"model": "disks", "nodes": len(disks)}}


def metadata(device: str, **extra) -> dict:
    """Who ran what: git sha, Warp and Python versions, device, core count, plus ``extra``."""
    git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    return {"warp": __import__("warp").__version__, "python": platform.python_version(), "device": device,
            "cpus": os.cpu_count(), "git": git.stdout.strip(), **extra}


def add_hardware_data_argument(ap) -> None:
    ap.add_argument("--data", type=Path, default=HARDWARE_DATA, help="folder of v4_train.csv, v6_train.csv")


def no_hardware_data(data: Path, out) -> bool:
    """Whether the real robots' data are missing (then said, and a report saying so written)."""
    if data.exists():
        return False
    print(f"no data at {data}: nothing to do")
    write_report(out, {"meta": metadata("cpu"), "skipped": f"no data at {data}"})
    return True


def interleaved_times(cases: dict, repeats: int) -> tuple[dict, dict]:
    """Each case (name -> callable) timed ``repeats`` times, the cases interleaved within each
    round (a noisy shared machine drifts alike for all): (times per case [s], their medians)."""
    times = {name: [] for name in cases}
    for _ in range(repeats):
        for name, f in cases.items():
            t = time.perf_counter()
            f()
            times[name].append(time.perf_counter() - t)
    return times, {k: statistics.median(v) for k, v in times.items()}


def write_report(path, report: dict) -> None:
    """Write ``report`` as JSON through a temporary file (never a half-written report)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2))
    os.replace(tmp, out)
    print(f"wrote {out}")


def run_job(command: str, scene: Path, out: Path, *, smoke: bool, figure: str, extra: list[str] = ()) -> dict:
    """Run a sweep command of the CLI on an example scene (in --smoke: its first two chunks of at
    most 8 rods, with no figure copy) and copy its figure into docs/figures/. Returns summary.json."""
    import shutil
    import tomllib

    from tdcr_warp.cli import main

    data = tomllib.loads(Path(scene).read_text())
    args = [command, str(scene), "--out", str(out), "--quiet", *extra]
    if smoke:
        # a tiny sweep of the same scene: few samples, coarse grid, short runs
        sweep = data["sweep"]
        if "grid" in sweep:
            sweep["grid"] = {k: [v[0], v[1], min(v[2], 2)] for k, v in sweep["grid"].items()}
        sweep["samples"] = min(sweep.get("samples", 8), 8)
        sweep["chunk"] = 4
        if "dynamics" in data:
            data["dynamics"]["steps"] = 10
        tiny = Path(out) / "smoke_scene.toml"
        tiny.parent.mkdir(parents=True, exist_ok=True)
        tiny.write_text(_to_toml(data))
        args[1] = str(tiny)
    rc = main(args)
    if rc != 0:
        raise SystemExit(f"{command} failed with status {rc}")
    summary = json.loads((Path(out) / "summary.json").read_text())
    if not smoke:
        dest = ROOT / "docs" / "figures"
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy(Path(out) / figure, dest / figure)
    return summary


def _to_toml(data: dict, prefix: str = "") -> str:
    """A minimal TOML writer for scene dicts (tables, arrays of tables, numbers, strings, lists)."""
    def val(v):
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)
    lines, tables = [], []
    for k, v in data.items():
        if isinstance(v, dict):
            tables.append((k, v, False))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            tables.append((k, v, True))
        else:
            lines.append(f"{json.dumps(k)} = {val(v)}")
    text = "\n".join(lines) + ("\n" if lines else "")
    for k, v, many in tables:
        name = f"{prefix}{json.dumps(k) if '.' in k else k}"
        for item in (v if many else [v]):
            text += f"\n[[{name}]]\n" if many else f"\n[{name}]\n"
            text += _to_toml(item, prefix=f"{name}.")
    return text


def figures_main(command: str, scene: str, figure: str, argv=None) -> int:
    """The body of the experiments/*_figures.py scripts: run ``command`` on examples/``scene``,
    copy ``figure`` into docs/figures/ and write a JSON report."""
    import argparse
    import tempfile

    ap = argparse.ArgumentParser(description=f"Regenerate docs/figures/{figure} from examples/{scene}.")
    ap.add_argument("--smoke", action="store_true", help="a tiny version of the sweep, no figure copy")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=str(ROOT / "results" / f"{Path(scene).stem}.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_job(command, ROOT / "examples" / scene, Path(tmp) / "run", smoke=args.smoke, figure=figure,
                          extra=["--device", args.device])
    summary.pop("settings", None)
    write_report(args.out, {"meta": metadata(args.device), "summary": summary})
    return 0
