"""Benchmark of the Ray sweep backend against the in-process backend, in one run.

Sweep: the workspace robot (0.5 m steel rod, 4 tendons, RK4 N = 20, coupled, float64), M
random tension rows (each tendon uniform in [0, 2] N), statics per rod. Backends: in-process
(this process, its default threads = all cores), a local Ray of 1 and of 2 worker CPUs (one
solver thread per task). Ray's start-up and the workers' first chunk (kernel load) are timed
apart from the warm sweeps; sweep times are medians over repeats. Overheads, from the same
1-thread compute in process and in one Ray worker: per sweep, F = t_ray - t_in_process for a
sweep of one 8-rod chunk; per chunk, (t_ray - t_in_process - F) / chunks at several chunk sizes.

    python experiments/bench_ray.py [--smoke] [--repeats 3] [--out results/bench_ray.json]
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

from tdcr_warp.apps.jobs import SweepJob  # noqa: E402
from tdcr_warp.apps.sweep import run_sweep  # noqa: E402

SCENE = {
    "robot": {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 7800.0},
    "tendons": [{"offset": [0.01, 0.0]}, {"offset": [0.0, 0.01]}, {"offset": [-0.01, 0.0]}, {"offset": [0.0, -0.01]}],
    "actuation": {"tensions": [[0.0, 0.0, 0.0, 0.0]]},
    "solver": {"nodes": 20},
    "uncertainty": [{"field": f"actuation.tensions[{k}]", "distribution": "uniform", "params": [0.0, 2.0]}
                    for k in range(4)],
}


def scene(rods: int, chunk: int, seed: int = 0, threads: int | None = None) -> dict:
    data = copy.deepcopy(SCENE)
    data["sweep"] = {"samples": rods, "chunk": chunk, "seed": seed}
    if threads:
        data["solver"]["threads"] = threads
    return data


def timed(data: dict, backend: str) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = run_sweep(data, SweepJob("workspace", device="cpu"), tmp, backend=backend, progress=False)
        wall = time.perf_counter() - t0
    assert res.failed == 0, "a rod failed: the benchmark scene must converge everywhere"
    return wall


def median_time(data: dict, backend: str, repeats: int) -> float:
    return statistics.median(timed(data, backend) for _ in range(repeats))


def local_times(chunk_sizes: list[int], rods: int, repeats: int) -> dict:
    """1-thread in-process times of the overhead sweeps, taken before Ray starts in this process
    (a Ray driver's threads would compete for the GIL with the in-process solve)."""
    times = {size: median_time(scene(rods, size, threads=1), "local", repeats) for size in chunk_sizes}
    times["fixed"] = median_time(scene(8, 8, threads=1), "local", 2 * repeats + 1)
    return times


def overheads(report: dict, local: dict, chunk_sizes: list[int], rods: int, repeats: int) -> None:
    """Ray's cost per sweep and per chunk, on a 1-worker Ray against 1-thread in-process runs."""
    fixed = median_time(scene(8, 8), "ray", 2 * repeats + 1) - local["fixed"]
    report["overhead_per_sweep_ms"] = 1e3 * fixed
    print(f"  Ray overhead per sweep: {1e3 * fixed:.0f} ms")
    for size in chunk_sizes:
        n = rods // size
        local1 = local[size]
        remote = median_time(scene(rods, size), "ray", repeats)
        per_chunk = (remote - local1 - fixed) / n
        report["overhead"].append({"chunk": size, "chunks": n, "in_process_s": local1, "ray_s": remote,
                                   "overhead_per_chunk_ms": 1e3 * per_chunk,
                                   "overhead_fraction": (remote - local1) / remote})
        print(f"  chunk {size:5d} x {n:4d}: in process (1 thread) {local1:.3f} s, Ray 1 worker {remote:.3f} s, "
              f"overhead {1e3 * per_chunk:.2f} ms per chunk ({(remote - local1) / remote:.0%} of the sweep)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_ray.json"))
    args = ap.parse_args(argv)
    try:
        import ray
    except ImportError:
        print("bench_ray: Ray is not installed (pip install -e \".[ray]\")", file=sys.stderr)
        return 2
    if ray.is_initialized():
        ray.shutdown()
    rods, chunk = (16, 4) if args.smoke else (16384, 1024)
    chunk_sizes = [4, 8] if args.smoke else [8, 32, 128, 512, 2048]
    over_rods = 16 if args.smoke else 4096
    repeats = 1 if args.smoke else args.repeats
    sweep = scene(rods, chunk)
    report = {"meta": metadata("cpu", rods=rods, chunk=chunk, repeats=repeats), "throughput": [], "overhead": []}

    timed(scene(chunk, chunk), "local")  # compile/load the kernels in this process
    t = median_time(sweep, "local", repeats)
    report["throughput"].append({"backend": "in-process", "workers": None, "seconds": t, "rods_per_s": rods / t})
    print(f"in-process: {rods} rods in {t:.2f} s = {rods / t:,.0f} rods/s")
    local = local_times(chunk_sizes, over_rods, repeats)
    for workers in (1, 2):
        t0 = time.perf_counter()
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        start = time.perf_counter() - t0
        t0 = time.perf_counter()
        timed(scene(chunk * workers, chunk), "ray")  # each worker starts and loads its kernels
        first = time.perf_counter() - t0
        t = median_time(sweep, "ray", repeats)
        report["throughput"].append({"backend": "ray", "workers": workers, "seconds": t, "rods_per_s": rods / t,
                                     "ray_start_s": start, "first_chunks_s": first})
        print(f"ray, {workers} worker(s): {rods} rods in {t:.2f} s = {rods / t:,.0f} rods/s "
              f"(Ray start {start:.1f} s, workers' first chunks {first:.1f} s)")
        if workers == 1:
            overheads(report, local, chunk_sizes, over_rods, repeats)
        ray.shutdown()
    base = report["throughput"][0]["rods_per_s"]
    for row in report["throughput"]:
        row["vs_in_process"] = row["rods_per_s"] / base
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
