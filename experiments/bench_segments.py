"""Cost of multiple shooting (rods split into segments): wall time and peak host memory of three
scenes whose rods single shooting cannot carry. Run it in two trees (PYTHONPATH=<tree>) to compare
them: it uses the public API only. Medians over repeats after a first call that compiles; the
peak memory (tracemalloc: numpy's arrays included) is that of one more call.

  dynamics   the report's robot at dt = 1e-5 s, N = 40 (split into 11 segments), ``--rods`` rods
             pulled with random tensions: ``--steps`` steps, once split
  bent tube  a 0.5 mm wire pushed 0.4 m into a tube bent at R 0.3 m, N = 80 (80 segments): a solve
             (experiments/long_contact.py's last scene)
  batch      ``--rods`` wires sagging in straight tubes of 0.6 to 1.0 m, N = 100 (24 to 39
             segments each): a solve

    python experiments/bench_segments.py [--rods 16] [--repeats 5] [--smoke] [--out results/bench_segments.json]
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from long_contact import SAG, bent  # noqa: E402
from tdcr_warp.io.scene import load_scene  # noqa: E402


def dynamics_case(rods: int, steps: int):
    """The next ``steps`` steps of ``rods`` report robots at dt = 1e-5 s, pulled from rest with
    tensions U[0, 3] N (the first step, in the call that compiles, splits them: single shooting
    fails)."""
    tau = np.random.default_rng(0).uniform(0.0, 3.0, (rods, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the single-shooting warning: expected here
        robot = load_scene(ROOT / "examples" / "seed_control.toml").robot  # the report's robot, damped
        sim = tw.Simulator(robot, np.zeros((rods, 4)), dt=1e-5, nodes=40)

    def run():
        t = time.perf_counter()
        ok = all(bool(sim.step(tau).converged.all()) for _ in range(steps))
        return time.perf_counter() - t, ok
    return run


def static_case(robot: tw.Robot, nodes: int):
    def run():
        t = time.perf_counter()
        sol = tw.solve_static(robot, np.zeros((1, 0)), nodes=nodes)
        return time.perf_counter() - t, bool(sol.success.all())
    return run


def tube_batch(rods: int) -> tw.Robot:
    """Wires of 0.6 to 1.0 m sagging onto the wall of straight tubes (0.2 mm clearance)."""
    L = np.linspace(0.6, 1.0, rods)
    tube = tw.Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 1.01), radius=0.7e-3)
    return tw.Robot(length=L, obstacles=[tube], **SAG)


def measure(run, repeats: int) -> dict:
    run()  # compiles
    times, ok = zip(*(run() for _ in range(repeats)))
    tracemalloc.start()
    run()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"median_s": float(np.median(times)), "times_s": list(times), "all_converged": all(ok),
            "peak_host_mb": peak / 2**20}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--steps", type=int, default=10, help="dynamics: the steps a repeat times")
    ap.add_argument("--smoke", action="store_true", help="two rods, one repeat, the batch only (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_segments.json"))
    args = ap.parse_args(argv)
    if args.smoke:
        args.rods, args.repeats = 2, 1
    cases = {"batch": static_case(tube_batch(args.rods), 100)}
    if not args.smoke:
        cases = {"dynamics": dynamics_case(args.rods, args.steps), "bent tube": static_case(bent(0.4, 0.3), 80)} | cases
    results = {}
    for name, run in cases.items():
        results[name] = measure(run, args.repeats)
        r = results[name]
        print(f"{name:10s} {r['median_s'] * 1e3:9.1f} ms  (all converged: {r['all_converged']}; "
              f"peak host memory {r['peak_host_mb']:.1f} MiB)", flush=True)
    write_report(args.out, {"meta": metadata("cpu", rods=args.rods, repeats=args.repeats, steps=args.steps,
                                             package=str(Path(tw.__file__).resolve().parent)), "cases": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
