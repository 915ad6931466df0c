"""Regenerate the docs' montecarlo figure (docs/figures/montecarlo.png) from examples/montecarlo.toml.

    python experiments/montecarlo_figures.py [--smoke] [--out results/montecarlo.json]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import figures_main  # noqa: E402


def main(argv=None) -> int:
    return figures_main("montecarlo", "montecarlo.toml", "montecarlo.png", argv)


if __name__ == "__main__":
    raise SystemExit(main())
