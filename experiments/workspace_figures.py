"""Regenerate the docs' workspace figure (docs/figures/workspace.png) from examples/workspace.toml.

    python experiments/workspace_figures.py [--smoke] [--out results/workspace.json]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import figures_main  # noqa: E402


def main(argv=None) -> int:
    return figures_main("workspace", "workspace.toml", "workspace.png", argv)


if __name__ == "__main__":
    raise SystemExit(main())
