"""Sweeps over scene fields, run in chunks that survive interruption.

A ``[sweep]`` table turns fields of a single-rod scene into M sample rows:

    [sweep]
    chunk = 1024            # rods per chunk (memory bound)
    seed = 0                # random draws (deterministic whatever the chunk size)
    samples = 1000          # number of random samples when there is no grid
    max_total_tension = 6.0 # optional: drop rows whose tensions sum above it [N]
    [sweep.grid]            # cartesian product, first field slowest: [start, stop, count]
    "actuation.tensions[0]" = [0.0, 8.0, 33]
    [[uncertainty]]         # random per-rod perturbations: normal [mean, std], uniform [low, high],
    field = "robot.youngs_modulus"   # lognormal [mu, sigma] of the log
    distribution = "normal"
    params = [190e9, 10e9]

Field names: ``robot.<key>``, ``loads.<gravity|tip_force|tip_moment>[c]``,
``tendons[i].<offset[c]|radius|turns|phase|length>``, ``actuation.tensions[k]`` (tendon k),
``dynamics.<damping_shear|damping_bending|drag>[c]``, ``control.<gain_c[c]|gain_k[c]|target[c]|
epsilon|phi|tension_max>``; a vector field without an index sets all its components. Each chunk's results are written to ``chunks/chunk_NNNNN.npz`` as
soon as it is done, so ``resume=True`` continues where an interrupted sweep stopped, with
either backend (in-process, or Ray tasks on a cluster: :mod:`tdcr_warp.cluster`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import resource
import time
from pathlib import Path

import numpy as np

from .chunk import parse_field, solve_chunk
from .robot import InputError

__all__ = ["SweepSpec", "make_samples", "run_sweep"]

DISTRIBUTIONS = ("normal", "uniform", "lognormal")
MAX_ROWS = 10**8  # rows of one sweep (its sample table lives in memory)


class SweepSpec:
    """The parsed [sweep] table and [[uncertainty]] entries of a scene dict."""

    def __init__(self, data: dict):
        sw = data.get("sweep", {})
        if not isinstance(sw, dict):
            raise InputError("[sweep] must be a table")
        allowed = {"chunk", "seed", "samples", "grid", "max_total_tension"}
        for key in sw:
            if key not in allowed:
                raise InputError(f"unknown key {key!r} in [sweep] (known: {', '.join(sorted(allowed))})")
        self.chunk = sw.get("chunk", 1024)
        self.seed = sw.get("seed", 0)
        self.samples = sw.get("samples")
        self.max_total = sw.get("max_total_tension")
        for name, v in (("chunk", self.chunk), ("seed", self.seed)):
            if not isinstance(v, int) or isinstance(v, bool) or v < (1 if name == "chunk" else 0):
                raise InputError(f"[sweep].{name} must be a {'positive' if name == 'chunk' else 'non-negative'} "
                                 f"integer, got {v!r}")
        if self.max_total is not None and (isinstance(self.max_total, bool) or not isinstance(self.max_total, (int, float))
                                           or not self.max_total >= 0):
            raise InputError(f"[sweep].max_total_tension must be a non-negative number [N], got {self.max_total!r}")
        grid = sw.get("grid", {})
        if not isinstance(grid, dict):
            raise InputError(f"[sweep.grid] must be a table of field = [start, stop, count], got {grid!r}")
        self.grid = []
        for name, spec in grid.items():
            parse_field(name)
            if (not isinstance(spec, list) or len(spec) != 3 or not isinstance(spec[2], int) or spec[2] < 1
                    or not all(isinstance(x, (int, float)) for x in spec[:2])):
                raise InputError(f"[sweep.grid].{name!r}: expected [start, stop, count], got {spec!r}")
            if spec[2] > MAX_ROWS:
                raise InputError(f"[sweep.grid].{name!r}: count {spec[2]:,} is more than {MAX_ROWS:,} rows")
            self.grid.append((name, np.linspace(spec[0], spec[1], spec[2])))
        self.uncertainty = []
        entries = data.get("uncertainty", [])
        if not isinstance(entries, list):
            raise InputError(f"[[uncertainty]] must be an array of tables, got {entries!r}")
        for i, u in enumerate(entries):
            where = f"[[uncertainty]] #{i + 1}"
            if not isinstance(u, dict) or set(u) - {"field", "distribution", "params"}:
                raise InputError(f"{where}: expected keys field, distribution, params, got {u!r}")
            if u.get("distribution") not in DISTRIBUTIONS:
                raise InputError(f"{where}.distribution must be one of {DISTRIBUTIONS}, got {u.get('distribution')!r}")
            p = u.get("params")
            if not (isinstance(p, list) and len(p) == 2 and all(isinstance(x, (int, float)) for x in p)) or p[1] < 0:
                raise InputError(f"{where}.params: expected [a, b] with b >= 0, got {p!r}")
            parse_field(u.get("field", ""))
            self.uncertainty.append((u["field"], u["distribution"], (float(p[0]), float(p[1]))))
        rows = math.prod(len(v) for _, v in self.grid) if self.grid else self.samples
        if isinstance(rows, int) and rows > MAX_ROWS:
            raise InputError(f"the sweep has {rows:,} rows, more than {MAX_ROWS:,}: split it into several sweeps")
        if not self.grid and not self.uncertainty:
            raise InputError("a sweep needs [sweep.grid] or [[uncertainty]] entries")
        if not self.grid and not (isinstance(self.samples, int) and not isinstance(self.samples, bool)
                                  and self.samples >= 1):
            raise InputError(f"[sweep].samples must be a positive integer without a grid, got {self.samples!r}")


def make_samples(spec: SweepSpec) -> dict[str, np.ndarray]:
    """All M sample rows, field -> (M,) values, from the grid and the seeded random draws."""
    rows: dict[str, np.ndarray] = {}
    if spec.grid:  # cartesian product, first field slowest
        mesh = np.meshgrid(*[v for _, v in spec.grid], indexing="ij")
        for (name, _), m in zip(spec.grid, mesh):
            rows[name] = m.ravel()
    M = len(next(iter(rows.values()))) if rows else spec.samples
    rng = np.random.default_rng(spec.seed)
    for name, dist, (a, b) in spec.uncertainty:
        if name in rows:
            raise InputError(f"sweep field {name!r} is both on the grid and uncertain")
        rows[name] = {"normal": rng.normal, "uniform": rng.uniform, "lognormal": rng.lognormal}[dist](a, b, M)
    if spec.max_total is not None:
        tension_fields = [n for n in rows if n.startswith("actuation.tensions")]
        total = sum(rows[n] for n in tension_fields)
        keep = total <= spec.max_total + 1e-12
        rows = {n: v[keep] for n, v in rows.items()}
    return rows


def _scene_hash(data: dict) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _save_npz(path: Path, arrays: dict) -> None:
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


def peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _chunk_path(out_dir, c: int) -> Path:
    return Path(out_dir) / "chunks" / f"chunk_{c:05d}.npz"


def _local_chunks(data: dict, job, todo: list[int], rows_of):
    """The in-process backend: chunks one after another in this process."""
    for c in todo:
        yield c, solve_chunk(job, data, rows_of(c))


def run_sweep(data: dict, job, out_dir, *, chunk: int | None = None, resume: bool = False,
              progress: bool = True, max_chunks: int | None = None, job_name: str = "sweep",
              backend: str = "local", address: str | None = None, workers: int | None = None,
              gpus_per_task: float = 0.0, meta: dict | None = None) -> dict | None:
    """Run ``job(scene) -> dict of per-rod arrays`` over every sample row, chunk by chunk.

    backend "local" runs the chunks in this process; "ray" runs them as Ray tasks (see
    :mod:`tdcr_warp.cluster`: ``address`` of a cluster, else a local one of ``workers`` CPUs;
    ``job`` must then be picklable, e.g. a :class:`~tdcr_warp.jobs.SweepJob`). Either way this
    process writes each finished chunk atomically to ``out_dir/chunks/`` and the results do
    not depend on the backend, the chunk order or the chunk size. Returns the concatenated
    results (also in ``out_dir/results.npz``) plus ``samples``, or None when ``max_chunks``
    stopped it early (resume later, with either backend). ``resume`` reuses the chunks of an
    identical earlier sweep; ``meta`` (JSON-able) joins the manifest that guards it.
    """
    from .progress import Progress

    if backend not in ("local", "ray"):
        raise InputError(f"backend must be 'local' or 'ray', got {backend!r}")
    spec = SweepSpec(data)
    rows = make_samples(spec)
    M = len(next(iter(rows.values())))
    if M == 0:
        raise InputError("the sweep has no sample rows (check max_total_tension)")
    size = chunk or spec.chunk
    out = Path(out_dir)
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    manifest = {"job": job_name, "rods": M, "chunk": size, "scene": _scene_hash(data), "fields": list(rows),
                **(meta or {})}
    man_path = out / "manifest.json"
    if man_path.exists() and resume:
        old = json.loads(man_path.read_text())
        if old != manifest:
            raise InputError(f"--resume: {out} holds a different sweep ({old.get('job')}, {old.get('rods')} rods, "
                             f"chunk {old.get('chunk')}); use another --out or drop --resume")
    else:
        for f in (out / "chunks").glob("chunk_*.npz"):
            f.unlink()
        man_path.write_text(json.dumps(manifest))
    n_chunks = (M + size - 1) // size
    bounds = [(c * size, min(M, (c + 1) * size)) for c in range(n_chunks)]

    def rows_of(c):
        lo, hi = bounds[c]
        return {k: v[lo:hi] for k, v in rows.items()}

    parts = {c: dict(np.load(_chunk_path(out, c))) for c in range(n_chunks) if _chunk_path(out, c).exists()}
    missing = [c for c in range(n_chunks) if c not in parts]
    todo = missing if max_chunks is None else missing[:max_chunks]
    done_rods = sum(hi - lo for c, (lo, hi) in enumerate(bounds) if c in parts)
    bar = Progress(M, 1, unit="rods", rate_unit="rods/s", start=done_rods) if progress else None
    failed = int(sum((~p["ok"].astype(bool)).sum() for p in parts.values()))
    t0 = time.perf_counter()
    if backend == "local":
        finished = _local_chunks(data, job, todo, rows_of)
    else:
        from .cluster import ray_chunks
        finished = ray_chunks(data, job, todo, rows_of, address=address, workers=workers,
                              gpus_per_task=gpus_per_task)
    try:
        for c, res in finished:
            _save_npz(_chunk_path(out, c), res)
            parts[c] = res
            lo, hi = bounds[c]
            done_rods += hi - lo
            failed += int((~res["ok"].astype(bool)).sum())
            if bar:
                bar.update(done_rods, failed, f" ({len(parts)}/{n_chunks} chunks)")
    finally:
        finished.close()
        if bar:
            bar.close()
    if len(parts) < n_chunks:
        return None
    results = {k: np.concatenate([parts[c][k] for c in range(n_chunks)]) for k in parts[0]}
    results.update({f"sample:{k}": v for k, v in rows.items()})
    _save_npz(out / "results.npz", results)
    results["_wall_s"] = time.perf_counter() - t0
    return results
