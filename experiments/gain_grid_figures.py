"""Regenerate the README's gain grid figure from examples/gain_grid.toml (docs/figures/gain_grid.png).

    python experiments/gain_grid_figures.py [--smoke] [--out results/gain_grid.json]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, run_job, write_report  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="a tiny version of the sweep, no figure copy")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=str(ROOT / "results" / "gain_grid.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_job("gain-grid", ROOT / "examples" / "gain_grid.toml", Path(tmp) / "run", smoke=args.smoke,
                          figure="gain_grid.png", extra=["--device", args.device])
    summary.pop("settings", None)
    write_report(args.out, {"meta": metadata(args.device), "summary": summary})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
