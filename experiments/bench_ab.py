"""A/B benchmark: an old install of tdcr_warp against a new one, measured together in one run.

Only ratios measured side by side mean something on a shared, noisy machine, so each repeat runs
every measurement in a fresh worker process (experiments/_ab_worker.py) on both sides back to
back: old then new in odd repeats, new then old in even ones (a side that always ran first or
always right after the previous heavy measurement would be biased). Each worker warms up (kernel
compilation, first call) before it times, and runs in an empty temporary directory, so that each
Python imports its own installed tdcr_warp. Reported per metric: each side's median over the
repeats and its spread (max - min) / median, the new/old ratio of the medians, the speed-up
(> 1: the new side is faster) and the median and range of the speed-ups of the back-to-back
(old, new) pairs. A warning says when a side's sources changed during the run (an editable
install being edited).

Measurements (the report's robot: 4 tendons, gravity; RK4, coupled, float64, CPU):
  static1       one rod, solve_static called repeatedly on the same Robot (N = 20): median ms
                per call, with a new random tension row each call and with the same row
  static_batch  B rods, random tensions in [0, 3] N, N = 20, default tol, threads = 1 and 2:
                rods/s and the 2-thread/1-thread ratio
  sens_batch    B / 4 rods with sensitivities (tip, tension and slack Jacobians), N = 20: rods/s
                under tension control and under displacement control (elastic wires)
  dyn1          one rod (dt 5 ms, alpha -0.2, N = 50) from rest, stepped under [1.5, 0.3, 0, 0] N:
                real-time factor (simulated s per wall s) of 200 steps after 10 warm-up steps
  dyn_batch     B rods, experiments/bench_dynamics.py's scenario, N = 50, 20 steps: rod-steps/s
  startup       `tdcr-warp static examples/seed_robot.toml` with a fresh kernel cache (cold) and
                again (warm), and `python -c "import tdcr_warp"`: wall seconds

    python experiments/bench_ab.py --base-python /tmp/base_venv/bin/python [--new-python PY]
        [--repeats 5] [--batch 4096] [--only MEASUREMENT ...] [--smoke] [--out results/bench_ab.json]

--new-python defaults to this Python; with --smoke (tiny sizes, 1 repeat) --base-python does too.
A repeat takes 2-3 minutes at B = 4096 on the shared 2-core machine, most of it in dyn_batch.
A measurement that fails on a side is reported with its error and the run goes on; the exit
status is 1 if any worker failed (the report is written either way), else 0.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

WORKER = ROOT / "experiments" / "_ab_worker.py"
SCENE = ROOT / "examples" / "seed_robot.toml"
SIDES = ("old", "new")
WORKER_TIMEOUT_S = 600
MARKER = "AB_RESULT "  # the worker's result line (experiments/_ab_worker.py)

# metric: (measurement, label (formatted with the measurement's arguments), unit, better)
METRICS = {
    "static1_random": ("static1", "1 rod static N={nodes}, new tau/call", "ms/call", "lower"),
    "static1_same": ("static1", "1 rod static N={nodes}, same tau", "ms/call", "lower"),
    "static_b_t1": ("static_batch", "B={batch} static N={nodes}, 1 thread", "rods/s", "higher"),
    "static_b_t2": ("static_batch", "B={batch} static N={nodes}, 2 threads", "rods/s", "higher"),
    "static_b_t2_over_t1": ("static_batch", "B={batch} static, 2-thr/1-thr", "x", "higher"),
    "sens_b_tension": ("sens_batch", "B={batch} static N={nodes} + Jacobians, tension", "rods/s", "higher"),
    "sens_b_displacement": ("sens_batch", "B={batch} static N={nodes} + Jacobians, displacement", "rods/s",
                            "higher"),
    "dyn1_rtf": ("dyn1", "1 rod dynamics N={nodes}, real-time", "sim s/s", "higher"),
    "dyn_b": ("dyn_batch", "B={batch} dynamics N={nodes}", "rod-steps/s", "higher"),
    "cli_cold": ("startup", "tdcr-warp static, cold cache", "s", "lower"),
    "cli_warm": ("startup", "tdcr-warp static, warm cache", "s", "lower"),
    "import": ("startup", "python -c 'import tdcr_warp'", "s", "lower"),
}


MEASUREMENT_NAMES = ("static1", "static_batch", "sens_batch", "dyn1", "dyn_batch", "startup")


def plan(batch: int, smoke: bool) -> dict[str, dict]:
    """Each measurement's worker arguments."""
    tension = [1.5, 0.3, 0.0, 0.0]
    if smoke:
        return {"static1": dict(nodes=20, calls=3, warmup=1),
                "static_batch": dict(batch=16, nodes=20, inner=1),
                "sens_batch": dict(batch=8, nodes=20, inner=1),
                "dyn1": dict(nodes=10, warmup=2, steps=3, tension=tension),
                "dyn_batch": dict(batch=8, nodes=10, steps=6),
                "startup": dict(scene=str(SCENE))}
    return {"static1": dict(nodes=20, calls=200, warmup=5),
            "static_batch": dict(batch=batch, nodes=20, inner=3),
            "sens_batch": dict(batch=batch // 4, nodes=20, inner=3),
            "dyn1": dict(nodes=50, warmup=10, steps=200, tension=tension),
            "dyn_batch": dict(batch=batch, nodes=50, steps=20),
            "startup": dict(scene=str(SCENE))}


def run_worker(python: str, name: str, kwargs: dict, cwd: str) -> dict:
    """One worker process: its {"metrics", "info"}, or {"error"} with the tail of its output."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    try:
        out = subprocess.run([python, str(WORKER), name, json.dumps(kwargs)], cwd=cwd, env=env,
                             capture_output=True, text=True, timeout=WORKER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {WORKER_TIMEOUT_S} s"}
    except OSError as exc:
        return {"error": f"could not start {python}: {exc}"}
    results = [line[len(MARKER):] for line in out.stdout.splitlines() if line.startswith(MARKER)]
    if out.returncode == 0 and results:
        return json.loads(results[-1])
    tail = "\n".join((out.stdout + out.stderr).strip().splitlines()[-15:])
    return {"error": f"exit status {out.returncode}\n{tail}"}


def speedup(old: float, new: float, better: str) -> float:
    """> 1 when the new side is faster: new/old for rates, old/new for times."""
    return new / old if better == "higher" else old / new


def summarise(runs: dict, labels: dict) -> dict:
    """Per metric: each side's values, median and spread (max - min) / median; the new/old ratio of
    the medians, its speed-up, and the speed-ups of the back-to-back (old, new) pairs of each repeat."""
    table = {}
    for key, (name, _, unit, better) in METRICS.items():
        if name not in runs:  # not measured (--only)
            continue
        row = {"label": labels[key], "unit": unit, "better": better}
        for side in SIDES:
            values = [r["metrics"][key] for r in runs[name][side] if "metrics" in r]
            med = statistics.median(values) if values else None
            row[side] = {"values": values, "median": med,
                         "spread": (max(values) - min(values)) / med if values and med else None}
        old, new = row["old"]["median"], row["new"]["median"]
        ok = old and new
        row["ratio_new_old"] = new / old if ok else None
        row["speedup"] = speedup(old, new, better) if ok else None
        row["paired_speedups"] = [speedup(o["metrics"][key], n["metrics"][key], better)
                                  for o, n in zip(runs[name]["old"], runs[name]["new"])
                                  if "metrics" in o and "metrics" in n]
        table[key] = row
    return table


def print_table(table: dict, repeats: int) -> None:
    def num(x, spec, width):
        return f"{'-' if x is None else format(x, spec):>{width}}"

    def pct(x):
        return "-" if x is None else f"{100 * x:.0f}%"

    def pairs(v):
        return f"{statistics.median(v):.2f} [{min(v):.2f}, {max(v):.2f}]" if v else "-"

    print(f"\n{'measurement':<38} {'unit':<11} {'old median':>11} {'new median':>11} {'new/old':>8} "
          f"{'speedup':>8} {'paired speedup [range]':>23} {'spread old/new':>15} {'n old/new':>10}")
    for row in table.values():
        o, n = row["old"], row["new"]
        print(f"{row['label']:<38} {row['unit']:<11} {num(o['median'], '.4g', 11)} {num(n['median'], '.4g', 11)} "
              f"{num(row['ratio_new_old'], '.3f', 8)} {num(row['speedup'], '.3f', 8)} "
              f"{pairs(row['paired_speedups']):>23} {pct(o['spread']) + '/' + pct(n['spread']):>15} "
              f"{len(o['values'])}/{len(n['values'])} of {repeats}")
    print("speedup: new/old for rates (higher is better), old/new for times (lower is better); > 1: the new side "
          "is faster. paired: the median and range of the speed-ups of each repeat's back-to-back (old, new) runs. "
          "spread: (max - min) / median of a side's repeats.")


def print_errors(runs: dict) -> int:
    """Each distinct worker error once, with where it happened; returns the number of failed runs."""
    where: dict[str, list[str]] = {}
    for name, sides in runs.items():
        for side, results in sides.items():
            for i, res in enumerate(results):
                if "error" in res:
                    where.setdefault(res["error"], []).append(f"{name} {side} #{i + 1}")
    for err, places in where.items():
        print(f"\nFAILED ({', '.join(places)}):\n{err}")
    return sum(map(len, where.values()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-python", help="Python of the old install (default with --smoke: this Python)")
    ap.add_argument("--new-python", default=sys.executable, help="Python of the new install (default: this one)")
    ap.add_argument("--repeats", type=int, default=5, help="old/new rounds (default 5)")
    ap.add_argument("--batch", type=int, default=4096, help="rods in the batched measurements")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, 1 repeat (for the test suite)")
    ap.add_argument("--only", nargs="+", choices=MEASUREMENT_NAMES, help="run these measurements only")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_ab.json"))
    args = ap.parse_args(argv)
    if args.base_python is None and not args.smoke:
        ap.error("--base-python is required (except with --smoke)")
    pythons = {"old": args.base_python or sys.executable, "new": args.new_python}
    repeats = 1 if args.smoke else args.repeats
    work = plan(args.batch, args.smoke)
    work = {k: v for k, v in work.items() if args.only is None or k in args.only}
    labels = {key: label.format(**work[name]) for key, (name, label, _, _) in METRICS.items() if name in work}

    runs = {name: {side: [] for side in SIDES} for name in work}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as cwd:
        for r in range(repeats):
            for name, kwargs in work.items():
                for side in SIDES if r % 2 == 0 else SIDES[::-1]:
                    t0 = time.perf_counter()
                    res = run_worker(pythons[side], name, kwargs, cwd)
                    runs[name][side].append(res)
                    shown = (", ".join(f"{k} {v:.4g}" for k, v in res["metrics"].items()) if "metrics" in res
                             else "FAILED: " + res["error"].splitlines()[-1])
                    print(f"[{r + 1}/{repeats}] {name:<12} {side}: {shown} ({time.perf_counter() - t0:.1f} s)",
                          flush=True)
    table = summarise(runs, labels)
    print_table(table, repeats)
    failed = print_errors(runs)
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")

    installs = {}
    for side in SIDES:
        infos = [res["info"] for sides in runs.values() for res in sides[side] if "info" in res]
        installs[side] = {"path": sorted({i["tdcr_warp"] for i in infos}),
                          "sources": sorted({i["sources"] for i in infos})}
        if len(installs[side]["sources"]) > 1:
            print(f"WARNING: the {side} side's sources changed during the run "
                  f"({len(installs[side]['sources'])} versions): its repeats did not all time the same code")
    meta = metadata("cpu", dtype="float64", repeats=repeats, batch=work["static_batch"]["batch"], smoke=args.smoke,
                    pythons=pythons, tdcr_warp=installs)
    write_report(args.out, {"meta": meta, "plan": work, "metrics": table, "runs": runs})
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
