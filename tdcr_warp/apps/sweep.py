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
epsilon|phi|tension_max>``; a vector field without an index sets all its components. Each
chunk's results are written to the output folder as soon as it is done (Parquet and Zarr,
checked on every read: :mod:`tdcr_warp.io.store`), so ``resume=True`` continues where an
interrupted sweep stopped, with either backend (in-process, or Ray tasks on a cluster:
:mod:`tdcr_warp.apps.cluster`), and memory stays flat in the number of rods.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import resource
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tdcr_warp.apps.chunk import solve_chunk
from tdcr_warp.io.files import FolderLock, printable
from tdcr_warp.io.store import (
    FORMAT,
    TABLE,
    ChunkError,
    ChunkStore,
    check_no_links,
    clear_outputs,
    read_manifest,
    write_manifest,
)
from tdcr_warp.model.fields import parse_field
from tdcr_warp.model.robot import InputError
from tdcr_warp.model.schema import MAX_ROWS, SCHEMA, out_of_bounds, span

__all__ = ["Samples", "SweepRun", "SweepSpec", "make_samples", "open_sweep", "run_sweep"]

DISTRIBUTIONS = ("normal", "uniform", "lognormal")


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
        for name, v in (("chunk", self.chunk), ("seed", self.seed), ("samples", self.samples)):
            bounds = SCHEMA["sweep"].key(name).bounds
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or out_of_bounds(v, bounds)):
                raise InputError(f"[sweep].{name} must be an integer {span(bounds)}, got {v!r}")
        if self.max_total is not None and (isinstance(self.max_total, bool) or not isinstance(self.max_total, (int, float))
                                           or not self.max_total >= 0):
            raise InputError(f"[sweep].max_total_tension must be a non-negative number [N], got {self.max_total!r}")
        grid = sw.get("grid", {})
        if not isinstance(grid, dict):
            raise InputError(f"[sweep.grid] must be a table of field = [start, stop, count], got {grid!r}")
        self.grid = []
        for name, spec in grid.items():
            parse_field(name)
            if (not isinstance(spec, list) or len(spec) != 3 or not _is_int(spec[2]) or spec[2] < 1
                    or not all(_is_finite(x) for x in spec[:2])):
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
            _check_params(u, where)
            parse_field(u.get("field", ""))
            self.uncertainty.append((u["field"], u["distribution"], tuple(map(float, u["params"]))))
        rows = math.prod(len(v) for _, v in self.grid) if self.grid else self.samples
        if isinstance(rows, int) and rows > MAX_ROWS:
            raise InputError(f"the sweep has {rows:,} rows, more than {MAX_ROWS:,}: split it into several sweeps")
        if not self.grid and not self.uncertainty:
            raise InputError("a sweep needs [sweep.grid] or [[uncertainty]] entries")
        if not self.grid and not (isinstance(self.samples, int) and not isinstance(self.samples, bool)
                                  and self.samples >= 1):
            raise InputError(f"[sweep].samples must be a positive integer without a grid, got {self.samples!r}")


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _check_params(u: dict, where: str) -> None:
    """An [[uncertainty]] entry's params: two finite numbers, normal [mean, std >= 0], uniform
    [low, high] with low <= high, lognormal [mu, sigma >= 0]."""
    p, dist = u.get("params"), u["distribution"]
    first, second = {"normal": ("mean", "std"), "uniform": ("low", "high"), "lognormal": ("mu", "sigma")}[dist]
    names = f"{dist} [{first}, {second}]"
    if not (isinstance(p, list) and len(p) == 2 and all(_is_finite(x) for x in p)):
        raise InputError(f"{where}.params: expected {names}, two finite numbers, got {p!r}")
    if dist == "uniform" and p[0] > p[1]:
        raise InputError(f"{where}.params: {names} needs low <= high, got {p!r}")
    if dist != "uniform" and p[1] < 0:
        raise InputError(f"{where}.params: {names} needs {second} >= 0, got {p!r}")


class Samples:
    """The M sample rows of a sweep, made block by block on demand, so that a sweep of any size
    never holds its whole sample table: grid rows from their index, random draws from a
    generator seeded by (seed, field, block) for blocks of BLOCK rows (the same values whatever
    the chunk size), and with ``max_total_tension`` the kept rows counted per block up front."""

    BLOCK = 65536

    def __init__(self, spec: SweepSpec):
        self.spec = spec
        self.counts = [len(v) for _, v in spec.grid]
        self.raw = math.prod(self.counts) if spec.grid else spec.samples
        names = [n for n, _ in spec.grid]
        for name, _, _ in spec.uncertainty:
            if name in names:
                raise InputError(f"sweep field {name!r} is both on the grid and uncertain")
            names.append(name)
        self.fields = names
        n_blocks = (self.raw + self.BLOCK - 1) // self.BLOCK
        if spec.max_total is None:
            self.kept = None
            self.rows = self.raw
        else:
            self.kept = np.zeros(n_blocks + 1, dtype=np.int64)  # kept rows before each block
            for j in range(n_blocks):
                self.kept[j + 1] = self.kept[j] + int(self._keep(self._block(j)).sum())
            self.rows = int(self.kept[-1])

    def __len__(self) -> int:
        return self.rows

    def _block(self, j: int) -> dict[str, np.ndarray]:
        lo, hi = j * self.BLOCK, min(self.raw, (j + 1) * self.BLOCK)
        rows = {}
        if self.spec.grid:  # cartesian product, first field slowest
            idx = np.unravel_index(np.arange(lo, hi), self.counts)
            rows = {name: v[i] for (name, v), i in zip(self.spec.grid, idx)}
        for f, (name, dist, (a, b)) in enumerate(self.spec.uncertainty):
            rng = np.random.default_rng([self.spec.seed, f, j])
            rows[name] = {"normal": rng.normal, "uniform": rng.uniform, "lognormal": rng.lognormal}[dist](a, b, hi - lo)
        return rows

    def _keep(self, rows: dict[str, np.ndarray]) -> np.ndarray:
        total = sum(v for n, v in rows.items() if n.startswith("actuation.tensions"))
        return np.broadcast_to(total <= self.spec.max_total + 1e-12, (len(next(iter(rows.values()))),))

    def __call__(self, lo: int, hi: int) -> dict[str, np.ndarray]:
        """Sample rows lo..hi-1, field -> (hi - lo,) values."""
        if self.kept is None:
            first, last, skip = lo // self.BLOCK, (hi - 1) // self.BLOCK, lo % self.BLOCK
        else:
            first = int(np.searchsorted(self.kept, lo, side="right")) - 1
            last = int(np.searchsorted(self.kept, hi - 1, side="right")) - 1
            skip = lo - int(self.kept[first])
        parts = []
        for j in range(first, last + 1):
            rows = self._block(j)
            if self.kept is not None:
                keep = self._keep(rows)
                rows = {n: v[keep] for n, v in rows.items()}
            parts.append(rows)
        return {n: np.concatenate([p[n] for p in parts])[skip:skip + hi - lo] for n in self.fields}


def make_samples(spec: SweepSpec) -> dict[str, np.ndarray]:
    """All M sample rows of a sweep, field -> (M,) values (small sweeps; run_sweep makes them
    chunk by chunk)."""
    samples = Samples(spec)
    return samples(0, len(samples)) if len(samples) else {n: np.zeros(0) for n in samples.fields}


def fingerprint(data: dict, job_name: str, chunk: int, meta: dict | None = None) -> str:
    """What identifies a sweep: its scene (with the sweep table), job, chunk size and options.
    A [search] table (tdcr_warp.apps.gainsearch) changes no sweep row, so it is left out: a gain grid
    kept as a search's reference resumes whatever the search's options."""
    scene = {k: v for k, v in data.items() if k != "search"}
    ident = {"format": FORMAT, "job": job_name, "chunk": chunk, "scene": scene, "meta": meta or {}}
    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()


def peak_memory_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def chunk_memory_bytes(data: dict, size: int) -> int:
    """An upper estimate of the memory one chunk of ``size`` rods takes while it is solved:
    the per-rod scene rows, the solver's tables and results (shapes at N + 1 nodes, tension
    profiles, Jacobians) and their host copies."""
    from tdcr_warp.io.scene import scene_from_dict

    base = scene_from_dict({k: v for k, v in data.items() if k not in ("sweep", "uncertainty")})
    N, K = base.options.nodes, base.robot.n_tendons
    nu = 6 + K
    per_node = 18 + 6 * K + (18 * K if any(t.friction for t in base.robot.tendons) else 0)
    per_rod = 8 * (4 * (N + 1) * per_node + 4 * nu * nu) + 64 * (K + len(data.get("uncertainty", [])) + 8) + 2048
    if data.get("dynamics") and data.get("control"):
        per_rod += 8 * (N + 1) * per_node * 8 + 8 * (data["dynamics"].get("steps", 1)) * (6 + 2 * K)
    return size * per_rod


def available_memory_bytes() -> int | None:
    """MemAvailable of /proc/meminfo (None where there is none)."""
    with contextlib.suppress(OSError, ValueError, StopIteration):
        with open("/proc/meminfo") as f:
            line = next(ln for ln in f if ln.startswith("MemAvailable:"))
        return int(line.split()[1]) * 1024
    return None


@dataclass
class SweepRun:
    """A finished sweep in ``out``: its checked parts, one chunk at a time (``parts``), or all
    of them at once (``load``: memory grows with the sweep; for small ones and tests)."""

    out: Path
    store: ChunkStore
    rods: int
    computed_rods: int  # rods solved by this call (0: every chunk was already there)
    wall_s: float  # seconds this call spent computing chunks
    failed: int
    fields: list[str]

    def parts(self):
        for c in range(self.store.n_chunks):
            yield self.store.read(c)

    def load(self) -> dict[str, np.ndarray]:
        parts = list(self.parts())
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def open_sweep(out_dir) -> SweepRun:
    """The complete sweep in ``out_dir``, to read chunk by chunk (``parts``) or whole (``load``);
    every read is checked (a bad chunk raises :class:`~tdcr_warp.io.store.ChunkError`)."""
    out = Path(out_dir)
    man = read_manifest(out)
    if man is None or man.get("legacy") or man.get("state") != "complete":
        state = "no sweep" if man is None else ("an earlier version's layout" if man.get("legacy") else
                                                f"an unfinished sweep ({man.get('state')})")
        raise InputError(f"{out}: holds {state}; a complete sweep is needed")
    store = ChunkStore(out, man["fingerprint"], man["rods"], man["chunk"])
    return SweepRun(out=out, store=store, rods=man["rods"], computed_rods=0, wall_s=0.0, failed=man["failed"],
                    fields=man["fields"])


def _local_chunks(data: dict, job, todo: list[int], store: ChunkStore, samples: Samples, show=None):
    """The in-process backend: chunks one after another in this process, written here;
    ``show(note)`` tells what the running chunk is doing."""
    for c in todo:
        lo, hi = store.bounds(c)
        if show:
            show(f"chunk {c + 1}: {hi - lo} rods")
        rows = samples(lo, hi)
        step = None if show is None else (lambda i, n, c=c: show(f"chunk {c + 1}: step {i}/{n}"))
        yield c, store.write(c, solve_chunk(job, data, rows, progress=step), rows)


def _prepare(out: Path, manifest: dict, resume: bool, overwrite: bool) -> None:
    """Apply the folder rules: a new sweep needs an empty folder or ``overwrite`` (which removes
    the old outputs first); ``resume`` needs the same sweep or none. Then nothing complete-looking
    is left: the summary and figures go, and the manifest says the sweep is running."""
    try:
        old = read_manifest(out)
    except InputError:
        if not overwrite:
            raise
        old = {"legacy": True}  # an unreadable manifest: replaced like any other sweep
    if old is not None:
        same = old.get("fingerprint") == manifest["fingerprint"]
        what = ("results of an earlier tdcr-warp version" if old.get("legacy") else
                f"a {old.get('job')} sweep of {old.get('rods')} rods ({old.get('state')})")
        if resume and not same and not overwrite:
            raise InputError(f"--resume: {out} holds a different sweep ({what}); use another --out, or --overwrite "
                             "to replace it")
        if not resume and not overwrite:
            hint = "--resume continues it" if same else "--resume only continues the same sweep"
            raise InputError(f"{out} already holds {what}: {hint}; --overwrite replaces it; or use another --out")
        clear_outputs(out, everything=overwrite or not same)
    else:
        clear_outputs(out, everything=True)
    check_no_links(out)
    for tmp in (out / TABLE).glob(".part-*.tmp*"):
        tmp.unlink()
    write_manifest(out, manifest | {"state": "running"})


def _chunk_size(data: dict, size: int) -> int:
    """``size`` rods a chunk, or an InputError where solving a chunk of them needs more than 80 % of
    the memory available."""
    need, have = chunk_memory_bytes(data, size), available_memory_bytes()
    if have is not None and need > 0.8 * have:
        raise InputError(f"a chunk of {size:,} rods needs about {need / 2**30:.1f} GiB while it is solved and "
                         f"{have / 2**30:.1f} GiB are available: use a smaller --chunk (or [sweep].chunk)")
    return size


def _output_dir(out_dir) -> Path:
    """The sweep's output folder, made where it does not exist yet."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {str(out)!r}: cannot create the output directory: {e.strerror or e}") from None
    return out


def _kept_chunks(store: ChunkStore) -> tuple[set, int]:
    """The chunks already on disk that pass their checks, and the number of failed rods in them; a
    chunk that fails its checks is deleted (to be recomputed), and said so on stderr."""
    done, failed = set(), 0
    for c in range(store.n_chunks):
        if not store.exists(c):
            continue
        try:
            part = store.read(c)
        except ChunkError as e:
            print(f"tdcr-warp: chunk {c} rejected, recomputing it: {printable(e)}", file=sys.stderr)
            store.part(c).unlink()
            continue
        done.add(c)
        failed += int((~part["ok"].astype(bool)).sum()) if "ok" in part else 0
    return done, failed


def run_sweep(data: dict, job, out_dir, *, chunk: int | None = None, resume: bool = False, overwrite: bool = False,
              progress: bool = True, max_chunks: int | None = None, job_name: str = "sweep",
              backend: str = "local", address: str | None = None, workers: int | None = None,
              gpus_per_task: float = 0.0, meta: dict | None = None) -> SweepRun | None:
    """Run ``job(scene) -> dict of per-rod arrays`` over every sample row, chunk by chunk, into
    ``out_dir`` (layout and rules: :mod:`tdcr_warp.io.store`).

    backend "local" runs the chunks in this process; "ray" runs them as Ray tasks that write
    their own chunks (see :mod:`tdcr_warp.apps.cluster`: ``address`` of a cluster, else a local one
    of ``workers`` CPUs; ``job`` must be picklable, e.g. a :class:`~tdcr_warp.apps.jobs.SweepJob`).
    A rod's results do not depend on the backend, the chunk order or the chunk size. Returns
    the :class:`SweepRun`, or None when ``max_chunks`` stopped it early (resume later, with
    either backend). ``resume`` keeps the checked chunks of the same sweep (a bad one is
    recomputed, and said so on stderr); a folder holding another sweep needs ``overwrite``.
    ``meta`` (JSON-able) joins the fingerprint.
    """
    from tdcr_warp.core.progress import Progress

    if backend not in ("local", "ray"):
        raise InputError(f"backend must be 'local' or 'ray', got {backend!r}")
    for name, v in (("chunk", chunk), ("max_chunks", max_chunks)):
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
            raise InputError(f"--{name.replace('_', '-')} must be a positive integer, got {v!r}")
    spec = SweepSpec(data)
    samples = Samples(spec)
    M = len(samples)
    if M == 0:
        raise InputError("the sweep has no sample rows (check max_total_tension)")
    size = _chunk_size(data, min(chunk or spec.chunk, M))
    out = _output_dir(out_dir)
    fp = fingerprint(data, job_name, size, meta)
    store = ChunkStore(out, fp, M, size)
    manifest = {"format": FORMAT, "fingerprint": fp, "job": job_name, "rods": M, "chunk": size,
                "chunks": store.n_chunks, "fields": samples.fields, **(meta or {})}
    with FolderLock(out, job_name) as lock:
        if lock.stale and lock.stale.get("pid") != os.getpid():
            print(printable(f"tdcr-warp: {out}: the previous writer (pid {lock.stale.get('pid')}, started "
                            f"{lock.stale.get('started')}) is gone; its lock is taken over"), file=sys.stderr)
        _prepare(out, manifest, resume, overwrite)
        done, failed = _kept_chunks(store)
        missing = [c for c in range(store.n_chunks) if c not in done]
        todo = missing if max_chunks is None else missing[:max_chunks]
        start_rods = done_rods = sum(store.bounds(c)[1] - store.bounds(c)[0] for c in done)
        bar = Progress(M, 1, rate_unit="rods/s", start=done_rods) if progress and todo else None

        def show(note: str = "") -> None:
            bar.update(done_rods, failed, f" ({len(done)}/{store.n_chunks} chunks{'; ' + note if note else ''})")
        if bar:
            show("starting")
        t0 = time.perf_counter()
        if backend == "local":
            finished = _local_chunks(data, job, todo, store, samples, show if bar else None)
        else:
            from tdcr_warp.apps.cluster import ray_chunks
            finished = ray_chunks(data, job, todo, store, samples, address=address, workers=workers,
                                  gpus_per_task=gpus_per_task)
        try:
            for c, n_failed in finished:
                done.add(c)
                lo, hi = store.bounds(c)
                done_rods += hi - lo
                failed += n_failed
                if bar:
                    show()
        finally:
            finished.close()
            if bar:
                bar.close()
        wall = time.perf_counter() - t0
        if len(done) < store.n_chunks:
            return None
        store.finish()
        write_manifest(out, manifest | {"state": "complete", "failed": failed})
    return SweepRun(out=out, store=store, rods=M, computed_rods=done_rods - start_rods, wall_s=wall, failed=failed,
                    fields=samples.fields)
