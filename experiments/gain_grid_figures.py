"""Regenerate the docs' gain grid figure (docs/figures/gain_grid.png) from examples/gain_grid.toml.

    python experiments/gain_grid_figures.py [--smoke] [--out results/gain_grid.json]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import figures_main  # noqa: E402


def main(argv=None) -> int:
    return figures_main("gain-grid", "gain_grid.toml", "gain_grid.png", argv)


if __name__ == "__main__":
    raise SystemExit(main())
