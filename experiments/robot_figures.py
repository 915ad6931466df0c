"""Regenerate the docs' pictures of the robot: docs/figures/robot.png (the figure
`tdcr-warp static examples/seed_robot.toml` draws), docs/figures/robot.gif (the animation
`tdcr-warp simulate examples/seed_dynamics.toml --animate` draws, shapes every 5 steps) and
docs/figures/viewer.png (the robot.html of `tdcr-warp static examples/helix_two_sections.toml
--html`, rendered by a headless Chromium; skipped when no Chromium is on PATH).

    python experiments/robot_figures.py [--smoke] [--out results/robot_figures.json]

--smoke: the figure and the animation of tiny runs, no viewer, nothing copied into docs/figures.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

FIGURES = ROOT / "docs" / "figures"


def viewer_png(scene: Path, work: Path, out: Path | None, size=(760, 1000)) -> dict:
    """Render the --html viewer of ``scene`` in headless Chromium; trim the blank rows below it."""
    from PIL import Image

    from tdcr_warp.cli import main as cli
    from tdcr_warp.io.viewer import screenshot

    if shutil.which("chromium") is None:
        return {"viewer": "skipped: no chromium on PATH"}
    if cli(["static", str(scene), "--out", str(work / "html"), "--html", "--no-figures", "--quiet"]) != 0:
        raise SystemExit(f"static --html failed on {scene}")
    t0 = time.perf_counter()
    png = screenshot(work / "html" / "robot.html", work / "shot.png", width=size[0], height=size[1])
    img = np.asarray(Image.open(png).convert("RGB"))
    ink = np.flatnonzero((img < 250).any(axis=(1, 2)))  # headless Chromium's page is shorter than its window
    img = img[:min(len(img), ink.max() + 12)] if len(ink) else img
    if out is not None:
        Image.fromarray(img).save(out, optimize=True)
    return {"viewer_render_s": time.perf_counter() - t0, "viewer_px": list(img.shape[:2])}


def main(argv=None) -> int:
    from tdcr_warp.cli import main as cli

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "results" / "robot_figures.json"))
    args = ap.parse_args(argv)
    report = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        extra = ["--nodes", "10"] if args.smoke else []
        if cli(["static", str(ROOT / "examples" / "seed_robot.toml"), "--out", str(work / "static"), "--quiet",
                *extra]) != 0:
            raise SystemExit("static failed")
        dyn = tomllib.loads((ROOT / "examples" / "seed_dynamics.toml").read_text())
        dyn["dynamics"]["shapes_every"] = 5
        if args.smoke:
            dyn["dynamics"]["steps"] = 10
        (work / "dyn.toml").write_text(tomli_w.dumps(dyn))
        t0 = time.perf_counter()
        if cli(["simulate", str(work / "dyn.toml"), "--out", str(work / "dyn"), "--animate", "--no-figures",
                "--quiet", *extra]) != 0:
            raise SystemExit("simulate --animate failed")
        report["animation_s"] = time.perf_counter() - t0
        if not args.smoke:  # (tests/test_viewer.py renders a viewer in Chromium already)
            report.update(viewer_png(ROOT / "examples" / "helix_two_sections.toml", work, FIGURES / "viewer.png"))
            for name, src in (("robot.png", work / "static" / "shapes.png"), ("robot.gif", work / "dyn" / "robot.gif")):
                shutil.copy(src, FIGURES / name)
                print(f"wrote {FIGURES / name}")
    write_report(args.out, {"meta": metadata("cpu"), **report})
    return 0


if __name__ == "__main__":
    sys.exit(main())
