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
table: per case the median over rounds of each install's median time per call, and the median
of the per-round ratios old / new.
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


def _timed(fn, calls: int, warm: int) -> tuple[float, float]:
    """Median and mean seconds of ``calls`` calls of fn after ``warm`` unmeasured ones."""
    for _ in range(warm):
        fn()
    times = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.median(times)), float(times.mean())


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
        med, mean = _timed(solve, calls, 20)
        return {"median_s": med, "mean_s": mean}
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
    med, mean = _timed(step, calls, 20)
    return {"median_s": med, "mean_s": mean, "real_time_factor": DT / mean,
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


def _ms(x: float) -> str:
    return f"{x * 1e3:.3f}"


def table(results: dict, old: bool) -> str:
    """The Markdown table of ``results`` (case -> install -> list of per-round measurements)."""
    head = "| case | new [ms] | new mean [ms] |" + (" old [ms] | old / new |" if old else "") + " notes |"
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for case, by in results.items():
        new = by["new"]
        row = f"| {case} | {_ms(np.median([r['median_s'] for r in new]))} | " \
              f"{_ms(np.median([r['mean_s'] for r in new]))} |"
        notes = []
        if "real_time_factor" in new[0]:
            notes.append(f"real time x{np.median([r['real_time_factor'] for r in new]):.1f} new")
            notes.append(f"{np.mean([r['iterations'] for r in new]):.2f} Newton iterations a step")
        if old:
            ratios = [o["median_s"] / n["median_s"] for o, n in zip(by["old"], new)]
            row += f" {_ms(np.median([r['median_s'] for r in by['old']]))} | {np.median(ratios):.2f}x |"
            if "real_time_factor" in new[0]:
                rt = [n["real_time_factor"] / o["real_time_factor"] for o, n in zip(by["old"], new)]
                notes.append(f"x{np.median([r['real_time_factor'] for r in by['old']]):.1f} old "
                             f"(real-time factor new / old {np.median(rt):.2f}x)")
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
