"""One chunk of a sweep: the base scene with its sample rows applied per rod, solved by a job.
Shared by the in-process backend (tdcr_warp.apps.sweep) and the Ray backend (tdcr_warp.apps.cluster)."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np

from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.fields import parse_field
from tdcr_warp.model.robot import InputError

__all__ = ["apply_rows", "solve_chunk"]

ACTUATION_ROWS = ("tensions", "displacements", "slip")  # per-rod rows of K in [actuation]


def apply_rows(data: dict, rows: dict[str, np.ndarray]) -> dict:
    """A copy of the single-rod scene dict with every swept field given per rod."""
    out = copy.deepcopy(data)
    for key in ("sweep", "uncertainty"):
        out.pop(key, None)
    b = len(next(iter(rows.values())))
    tensions = out.get("actuation", {}).get("tensions")
    if not (isinstance(tensions, list) and len(tensions) == 1):
        raise InputError("a sweep needs a single-rod scene: [actuation].tensions with one row")
    done: set[tuple] = set()
    for key in ACTUATION_ROWS:  # B rows of K: fixes the batch size
        rows_k = out["actuation"].get(key)
        if rows_k is not None:
            if not (isinstance(rows_k, list) and len(rows_k) == 1):
                raise InputError(f"a sweep needs a single-rod scene: [actuation].{key} with one row")
            out["actuation"][key] = _copies(rows_k[0], b)
            done.add(("actuation", key))
    for name, values in rows.items():
        path = parse_field(name)
        if path[0] == "actuation" and path[1:2] and path[1] in ACTUATION_ROWS:
            if len(path) != 3:
                raise InputError(f"sweep field {name!r}: use actuation.{path[1]}[k] for tendon k")
            if ("actuation", path[1]) not in done:
                raise InputError(f"sweep field {name!r}: set a base value for [actuation].{path[1]} in the scene")
            leaf_path, comp = ("actuation", path[1]), path[2]
        elif isinstance(path[-1], int):
            leaf_path, comp = tuple(path[:-1]), path[-1]
        else:
            leaf_path, comp = tuple(path), None
        parent = out
        for key in leaf_path[:-1]:
            try:
                parent = parent[key]
            except (KeyError, IndexError, TypeError):
                raise InputError(f"sweep field {name!r}: the scene has no {key!r} there") from None
        leaf = leaf_path[-1]
        if leaf not in parent and leaf_path not in done:
            raise InputError(f"sweep field {name!r}: set a base value for it in the scene")
        if leaf_path not in done:
            base = parent[leaf]
            if isinstance(base, list) and base and isinstance(base[0], list):
                raise InputError(f"sweep field {name!r}: the base scene must be single-rod")
            parent[leaf] = _copies(base, b)
            done.add(leaf_path)
        cur = parent[leaf]
        for r, v in enumerate(np.asarray(values, dtype=np.float64).tolist()):
            if comp is None:  # a scalar, or every component of a vector
                cur[r] = [v] * len(cur[r]) if isinstance(cur[r], list) else v
            else:
                if not isinstance(cur[r], list) or comp >= len(cur[r]):
                    raise InputError(f"sweep field {name!r}: index {comp} out of range")
                cur[r][comp] = v
    return out


def _copies(base, b: int) -> list:
    """b independent copies of a scene value (numbers are immutable: flat lists copy shallow)."""
    if not isinstance(base, list):
        return [base] * b
    if all(not isinstance(x, (list, dict)) for x in base):
        return [list(base) for _ in range(b)]
    return [copy.deepcopy(base) for _ in range(b)]


def solve_chunk(job, data: dict, rows: dict, threads: int | None = None, progress=None) -> dict:
    """One chunk: the scene with its sample rows, through ``job``. ``threads`` sets the solver's
    CPU threads where the scene leaves them open (a Ray task uses the one core it holds);
    ``progress(step, steps)`` goes to jobs that take it (the time steps of control runs)."""
    scene = scene_from_dict(apply_rows(data, rows))
    if threads is not None and scene.options.threads is None:
        scene = replace(scene, options=replace(scene.options, threads=threads))
    return job(scene, progress=progress) if progress is not None and _takes_progress(job) else job(scene)


def _takes_progress(job) -> bool:
    import inspect
    try:
        return "progress" in inspect.signature(job).parameters
    except (TypeError, ValueError):
        return False
