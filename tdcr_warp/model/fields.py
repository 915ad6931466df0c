"""Field paths: how a sweep, an uncertainty table or a parameter Jacobian names one value of a
scene, e.g. ``robot.young`` or ``tendons[1].offset[0]``."""

from __future__ import annotations

import re

from tdcr_warp.model.robot import InputError

__all__ = ["parse_field"]

_TOKEN = re.compile(r"([A-Za-z_]+)(?:\[([0-9]+)\])?")


def parse_field(name: str) -> list:
    """'tendons[1].offset[0]' -> ['tendons', 1, 'offset', 0]."""
    path = []
    for part in name.split("."):
        m = _TOKEN.fullmatch(part)
        if not m:
            raise InputError(f"sweep field {name!r}: cannot parse {part!r}")
        path.append(m.group(1))
        if m.group(2) is not None:
            path.append(int(m.group(2)))
    return path
