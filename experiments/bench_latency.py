"""Latency of one rod: a static solve, a dynamics step and a closed-loop control step, for two
installs of tdcr_warp in the same run (alternating subprocesses, medians over many calls).

Cases (the report's robot: 4 tendons, gravity; RK4, coupled, float64, CPU, one thread):
- static: ``solve_static(robot, tau, nodes=20, stability="off")``, tau cycling through 16
  rows in [0, 1] N (a fresh straight-rod start every call);
- static default: the same without ``stability=`` (each install's default);
- dynamics: ``Simulator.step`` (N = 50, dt = 5 ms, alpha = -0.2), 1 N then 0.5 N on tendon 0,
  steady stepping after 20 steps; real-time factor = dt / (mean time a step);
- control: ``TipController()`` then ``Simulator.step`` (boundary layer, the statics' tip
  Jacobian refreshed every 5 steps), after 20 steps.

    python experiments/bench_latency.py [--old DIR] [--new DIR] [--rounds 5] [--calls 400]
        [--out results/bench_latency.json] [--smoke]

``--old`` / ``--new``: a directory whose tdcr_warp is measured (put first on PYTHONPATH, run from
an empty working directory); without ``--new`` the installed tdcr_warp (this checkout's editable
install), without ``--old`` only the new one. Prints a Markdown
table: per case the median over rounds of each install's median time a call, in wall time and in
the calling thread's CPU time (robust to a loaded machine: the CPU kernels run on that thread),
and the median of the per-round ratios old / new.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

CASES = ("static", "static default", "dynamics", "control")
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROD = {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 17189.0,
       "gravity": (0.0, 0.0, -9.81), "damping_bending": (0.008, 0.008, 0.008), "drag": (0.01, 0.01, 0.01)}
DT = 0.005


def _timed(fn, calls: int, warm: int) -> dict:
    """Median and mean seconds of ``calls`` calls of fn after ``warm`` unmeasured ones, in wall time
    and in the thread's CPU time (a CPU kernel runs on the calling thread: on a loaded machine the
    CPU time is close to what a quiet one's wall time would be)."""
    for _ in range(warm):
        fn()
    wall, cpu = np.empty(calls), np.empty(calls)
    for i in range(calls):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        wall[i], cpu[i] = time.perf_counter() - t0, time.thread_time() - c0
    return {"median_s": float(np.median(wall)), "mean_s": float(wall.mean()), "cpu_median_s": float(np.median(cpu)),
            "cpu_mean_s": float(cpu.mean())}


def worker(case: str, calls: int) -> dict:
    """One case measured in this process (whatever tdcr_warp it imports)."""
    import tdcr_warp as tw

    robot = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROD)
    if case.startswith("static"):
        taus = np.random.default_rng(0).uniform(0.0, 1.0, (16, 1, 4))
        kw = {} if case == "static default" else {"stability": "off"}
        it = iter(range(10**9))

        def solve():
            return tw.solve_static(robot, taus[next(it) % 16], nodes=20, threads=1, **kw)

        assert solve().converged.all()
        return _timed(solve, calls, 20)
    sim = tw.Simulator(robot, [[0.0] * 4], dt=DT, alpha=-0.2, nodes=50, threads=1)
    iters = []
    if case == "dynamics":
        tau = np.array([[1.0, 0.0, 0.0, 0.0]])
        flip = iter(range(10**9))

        def step():
            iters.append(sim.step(tau * (1.0 if (next(flip) // 100) % 2 == 0 else 0.5)).iterations[0])
    else:
        target = tw.solve_static(robot, [[1.0, 0.5, 0.0, 0.0]], nodes=50).tip_position
        from tdcr_warp.apps.control import TipController

        ctrl = TipController(sim, target)

        def step():
            iters.append(sim.step(ctrl()).iterations[0])
    t = _timed(step, calls, 20)
    return t | {"real_time_factor": DT / t["mean_s"], "real_time_factor_cpu": DT / t["cpu_mean_s"],
                "iterations": float(np.mean(iters[20:]))}


def _run(case: str, path: str | None, calls: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"} | {"OMP_NUM_THREADS": "1"}
    if path:
        env["PYTHONPATH"] = path
    with tempfile.TemporaryDirectory() as cwd:  # no tdcr_warp folder to shadow the install
        out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", case, "--calls", str(calls)],
                             env=env, cwd=cwd, capture_output=True, text=True, check=False)
    if out.returncode:
        raise RuntimeError(f"case {case!r} with {path or 'the installed tdcr_warp'} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _med(runs: list, key: str) -> float:
    return float(np.median([r[key] for r in runs]))


def table(results: dict, old: bool) -> str:
    """The Markdown table of ``results`` (case -> install -> list of per-round measurements): the
    median over rounds of each round's median time a call [ms], wall and thread CPU, the median of
    the per-round ratios old / new, and for time steps the real-time factor dt / mean time a step."""
    head = "| case | new wall [ms] | new CPU [ms] |" + (" old wall [ms] | old CPU [ms] | old / new wall | old / new CPU |"
                                                       if old else "") + " notes |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for case, by in results.items():
        new = by["new"]
        row = f"| {case} | {_med(new, 'median_s') * 1e3:.3f} | {_med(new, 'cpu_median_s') * 1e3:.3f} |"
        notes = []
        if "real_time_factor" in new[0]:
            notes.append(f"real time x{_med(new, 'real_time_factor'):.1f} new (CPU x{_med(new, 'real_time_factor_cpu'):.1f})")
            notes.append(f"{np.mean([r['iterations'] for r in new]):.2f} Newton iterations a step")
        if old:
            ratio = {k: np.median([o[k] / n[k] for o, n in zip(by["old"], new)]) for k in ("median_s", "cpu_median_s")}
            row += (f" {_med(by['old'], 'median_s') * 1e3:.3f} | {_med(by['old'], 'cpu_median_s') * 1e3:.3f} |"
                    f" {ratio['median_s']:.2f}x | {ratio['cpu_median_s']:.2f}x |")
            if "real_time_factor" in new[0]:
                notes.append(f"x{_med(by['old'], 'real_time_factor'):.1f} old (CPU "
                             f"x{_med(by['old'], 'real_time_factor_cpu'):.1f})")
        lines.append(row + " " + "; ".join(notes) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default=None, help="a directory holding the baseline tdcr_warp")
    ap.add_argument("--new", default=None, help="a directory holding the tdcr_warp to measure (default: installed)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=400)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_latency.json"))
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.worker, args.calls)))
        return 0
    rounds, calls = (1, 5) if args.smoke else (args.rounds, args.calls)
    cases = [c.strip() for c in args.cases.split(",")]
    installs = {"new": args.new} | ({"old": args.old} if args.old else {})
    results = {c: {k: [] for k in installs} for c in cases}
    for r in range(rounds):
        for case in cases:
            for name, path in (installs.items() if r % 2 == 0 else reversed(installs.items())):
                results[case][name].append(_run(case, path, calls))
    md = table(results, bool(args.old))
    print(md)
    write_report(args.out, {"meta": metadata("cpu", rounds=rounds, calls=calls, old=args.old, new=args.new),
                            "results": results, "table": md})
    return 0


if __name__ == "__main__":
    sys.exit(main())
