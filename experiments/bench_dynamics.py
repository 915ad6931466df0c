"""Benchmark of the batched dynamics against a per-rod Python implementation, in one run.

Scenario: the report's dynamic run (dt = 5 ms, alpha = -0.2, Bbt = 0.008, C = 0.01, 4 tendons,
gravity), no tension for steps 1-4, then a per-rod random tension in [0, 3] N on tendon 1 (and
a smaller one on tendon 2). Ours: RK4, N = 50, coupled, float64, CPU. Peer: the report's
method in plain Python (tests/python_dynamics.py: Euler along s, N = 20, fsolve per step).
Reports rod-steps/s (median over repeats), the ratio to the peer, and the real-time factor
of a single rod (simulated seconds per wall second).

    python experiments/bench_dynamics.py [--smoke] [--device cpu] [--out results/bench_dynamics.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROD = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
           gravity=(0.0, 0.0, -9.81), damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
DT, ALPHA = 0.005, -0.2


def schedule(B: int, steps: int, rng) -> np.ndarray:
    s = np.zeros((B, steps, 4))
    s[:, 4:, 0] = rng.uniform(0.5, 3.0, B)[:, None]
    s[:, 4:, 1] = rng.uniform(0.0, 1.0, B)[:, None]
    return s


def run_ours(B, steps, sched, nodes, device):
    rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROD)
    sim = tw.Simulator(rob, np.zeros((B, 4)), dt=DT, alpha=ALPHA, nodes=nodes, device=device)
    t0 = time.perf_counter()
    tr = sim.simulate(sched, steps)
    return time.perf_counter() - t0, tr


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_dynamics.json"))
    args = ap.parse_args(argv)

    from python_dynamics import PythonRod  # tests/ helper, not in the package

    sizes = [1, 8] if args.smoke else [1, 256, 4096]
    repeats = 1 if args.smoke else args.repeats
    nodes = 10 if args.smoke else 50
    rng = np.random.default_rng(0)
    meta = metadata(args.device, dtype="float64", nodes=nodes, dt=DT, alpha=ALPHA)

    py_steps = 6 if args.smoke else 30
    sched1 = schedule(1, py_steps, rng)
    peer = PythonRod(dict(ROD, offsets=OFFSETS), [0.0] * 4, dt=DT, alpha=ALPHA, nodes=20)
    t0 = time.perf_counter()
    for i in range(py_steps):
        peer.step(sched1[0, i])
    py_per_step = (time.perf_counter() - t0) / py_steps
    print(f"per-rod Python (Euler N = 20, fsolve): {py_per_step * 1e3:.1f} ms per rod-step "
          f"({peer.nfev / py_steps:.0f} integrations per step)")

    rows = []
    print(f"{'B':>6} {'steps':>6} {'rod-steps/s':>12} {'x Python':>9} {'iters':>6} {'failed':>7}")
    for B in sizes:
        steps = (20 if args.smoke else (100 if B <= 256 else 20))
        sched = schedule(B, steps, rng)
        run_ours(min(B, 2), 2, sched[:min(B, 2), :2], nodes, args.device)  # compile outside the timing
        times = []
        for _ in range(repeats):
            t, tr = run_ours(B, steps, sched, nodes, args.device)
            times.append(t)
        t = float(np.median(times))
        rate = B * steps / t
        row = dict(batch=B, steps=steps, seconds=t, rod_steps_per_s=rate, speedup_vs_python=rate * py_per_step,
                   iterations_mean=float(tr.iterations.mean()), failed=int((tr.failed_step >= 0).sum()))
        if B == 1:
            row["real_time_factor"] = steps * DT / t
        rows.append(row)
        print(f"{B:>6} {steps:>6} {rate:>12.0f} {row['speedup_vs_python']:>9.0f} {row['iterations_mean']:>6.1f} "
              f"{row['failed']:>7}")
    rt = rows[0]["real_time_factor"]
    print(f"single rod, N = {nodes}: real-time factor {rt:.2f} (simulated s per wall s)")
    report = {"meta": meta, "python_seconds_per_rod_step": py_per_step, "rows": rows}
    write_report(args.out, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
