"""Issue 26's must-show numbers, today's main against the working tree, measured together in one run.

Each measurement runs in a fresh process on each side (old: ``--old-path`` put on PYTHONPATH, by
default /tmp/h1/oldpkg, a complete copy of today's main; new: this working tree), old and new
alternated (old first in odd rounds, new first in even ones), medians over the rounds. The
worker warms up before it times. Measurements (the report robot: 4 tendons, gravity, RK4,
coupled, float64, CPU; experiments/_ab_worker.py's robot, scenarios and timing, reused here):

  static_plain    B = 4096, N = 20, 1 thread, stability off: rods per CPU-second (the process's CPU
                  time: what other processes on a shared core take does not count; wall rate in
                  the run's info), iterations and integrations per rod
  static_check    the same with stability="check"
  static_default  the same with each side's default options (tw.StaticOptions().stability)
  static1         one rod, N = 20, the same Robot, a new tension row each call: median ms per call
  dyn1            one rod, N = 50, dt 5 ms, steady stepping: ms per step and real-time factor
  threads         B = 4096, N = 20, default options, 1 and 2 threads: rods/s and their ratio

    python experiments/bench_trust.py [--rounds 3] [--batch 4096] [--old-path /tmp/h1/oldpkg]
        [--only static_plain ...] [--smoke] [--out results/bench_trust.json]

Prints a Markdown table (old median, new median, new/old speed-up, the range of the per-round
speed-ups) and writes it with every run to --out (JSON). Exit status 1 if any worker failed.
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

MARKER = "TRUST_RESULT "
SIDES = ("old", "new")
NAMES = ("static_plain", "static_check", "static_default", "static1", "dyn1", "threads")
# metric: (measurement, label, unit, better)
METRICS = {
    "plain_rods_s": ("static_plain", "B={batch} statics N=20, 1 thread, stability off", "rods/CPU-s", "higher"),
    "plain_iterations": ("static_plain", "  iterations per rod", "", "lower"),
    "plain_integrations": ("static_plain", "  integrations per rod", "", "lower"),
    "check_rods_s": ("static_check", "B={batch} statics, stability=\"check\"", "rods/CPU-s", "higher"),
    "check_integrations": ("static_check", "  integrations per rod", "", "lower"),
    "default_rods_s": ("static_default", "B={batch} statics, default options", "rods/CPU-s", "higher"),
    "default_integrations": ("static_default", "  integrations per rod", "", "lower"),
    "static1_ms": ("static1", "one-rod static solve N=20 (median call)", "ms", "lower"),
    "dyn1_ms_step": ("dyn1", "one-rod dynamics N=50, dt 5 ms: per step", "ms", "lower"),
    "dyn1_rtf": ("dyn1", "  real-time factor", "x", "higher"),
    "t1_rods_s": ("threads", "B={batch} statics default, 1 thread", "rods/s", "higher"),
    "t2_rods_s": ("threads", "B={batch} statics default, 2 threads", "rods/s", "higher"),
    "t2_over_t1": ("threads", "  2 threads / 1 thread", "x", "higher"),
}


# ----------------------------------------------------------------------------------------------
# The worker (runs in the side's Python, imports that side's tdcr_warp).

def _static(batch: int, inner: int, stability: str | None, nodes: int = 20):
    import _ab_worker as ab

    import tdcr_warp as tw
    rob = ab.robot()
    tau = np.random.default_rng(1).uniform(0.0, 3.0, (batch, 4))
    kw = {"nodes": nodes, "threads": 1}
    if stability == "default":
        stability = None
    if stability is not None:
        kw["stability"] = stability
    tw.solve_static(rob, tau[:8], **kw)
    times, cpu = [], []
    for _ in range(inner):
        t0, c0 = time.perf_counter(), time.process_time()
        sol = tw.solve_static(rob, tau, **kw)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return (batch / statistics.median(cpu), float(sol.iterations.mean()), float(sol.integrations.mean()),
            {"stability": kw.get("stability", tw.StaticOptions().stability), "converged": float(sol.converged.mean()),
             "rods_per_s_wall": batch / statistics.median(times)})


def w_static(variant: str, batch: int, inner: int):
    rate, its, ints, info = _static(batch, inner, {"plain": "off", "check": "check", "default": "default"}[variant])
    return {f"{variant}_rods_s": rate, f"{variant}_iterations": its, f"{variant}_integrations": ints}, info


def w_static1(nodes: int, calls: int, warmup: int):
    import _ab_worker as ab
    metrics, info = ab.static1(nodes, calls, warmup)
    return {"static1_ms": metrics["static1_random"]}, info


def w_dyn1(nodes: int, warmup: int, steps: int, tension: list[float]):
    import _ab_worker as ab
    metrics, info = ab.dyn1(nodes, warmup, steps, tension)
    return {"dyn1_rtf": metrics["dyn1_rtf"], "dyn1_ms_step": 1e3 * ab.DT / metrics["dyn1_rtf"]}, info


def w_threads(batch: int, nodes: int, inner: int):
    import _ab_worker as ab
    metrics, info = ab.static_batch(batch, nodes, inner)
    return {"t1_rods_s": metrics["static_b_t1"], "t2_rods_s": metrics["static_b_t2"],
            "t2_over_t1": metrics["static_b_t2_over_t1"]}, info


def worker_main(name: str, kwargs: dict) -> int:
    fn = {"static_plain": lambda **k: w_static("plain", **k), "static_check": lambda **k: w_static("check", **k),
          "static_default": lambda **k: w_static("default", **k), "static1": w_static1, "dyn1": w_dyn1,
          "threads": w_threads}[name]
    metrics, info = fn(**kwargs)
    info["statics"] = sys.modules["tdcr_warp.physics.statics"].__file__
    print(MARKER + json.dumps({"metrics": metrics, "info": info}), flush=True)
    return 0


# ----------------------------------------------------------------------------------------------
# The driver.

def plan(batch: int, smoke: bool) -> dict:
    if smoke:
        return {"static_plain": {"batch": 16, "inner": 1}, "static_check": {"batch": 16, "inner": 1},
                "static_default": {"batch": 16, "inner": 1}, "static1": {"nodes": 20, "calls": 3, "warmup": 1},
                "dyn1": {"nodes": 10, "warmup": 2, "steps": 3, "tension": [1.5, 0.3, 0.0, 0.0]},
                "threads": {"batch": 16, "nodes": 20, "inner": 1}}
    return {"static_plain": {"batch": batch, "inner": 3}, "static_check": {"batch": batch, "inner": 3},
            "static_default": {"batch": batch, "inner": 3}, "static1": {"nodes": 20, "calls": 200, "warmup": 5},
            "dyn1": {"nodes": 50, "warmup": 10, "steps": 200, "tension": [1.5, 0.3, 0.0, 0.0]},
            "threads": {"batch": batch, "nodes": 20, "inner": 3}}


def run_worker(name: str, kwargs: dict, pythonpath: str | None, cwd: str) -> dict:
    """One measurement in a fresh process; ``pythonpath`` None: this venv's (editable) tdcr_warp."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = os.pathsep.join([*([pythonpath] if pythonpath else []), str(ROOT / "experiments")])
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", name, json.dumps(kwargs)]
    try:
        out = subprocess.run(cmd, check=False, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)
    except subprocess.TimeoutExpired:
        return {"error": "timed out after 900 s"}
    lines = [ln[len(MARKER):] for ln in out.stdout.splitlines() if ln.startswith(MARKER)]
    if out.returncode == 0 and lines:
        return json.loads(lines[-1])
    return {"error": f"exit {out.returncode}: " + "\n".join((out.stdout + out.stderr).strip().splitlines()[-12:])}


def summarise(runs: dict, labels: dict) -> dict:
    table = {}
    for key, (name, _, unit, better) in METRICS.items():
        if name not in runs:
            continue
        row = {"label": labels[key], "unit": unit, "better": better}
        for side in SIDES:
            vals = [r["metrics"][key] for r in runs[name][side] if key in r.get("metrics", {})]
            row[side] = {"values": vals, "median": statistics.median(vals) if vals else None}
        o, n = row["old"]["median"], row["new"]["median"]
        row["speedup"] = (n / o if better == "higher" else o / n) if o and n else None
        pairs = [(a["metrics"][key], b["metrics"][key]) for a, b in zip(runs[name]["old"], runs[name]["new"])
                 if key in a.get("metrics", {}) and key in b.get("metrics", {})]
        row["paired"] = [(b / a if better == "higher" else a / b) for a, b in pairs if a and b]
        table[key] = row
    return table


def fmt(x) -> str:
    return "-" if x is None else f"{x:,.4g}"


def print_markdown(table: dict) -> None:
    print("\n| measurement | unit | old (main) | new (tree) | speed-up | per-round range |")
    print("|---|---|---:|---:|---:|---|")
    for row in table.values():
        o, n = row["old"]["median"], row["new"]["median"]
        sp = "-" if row["speedup"] is None else f"{row['speedup']:.2f}x"
        rng = f"{min(row['paired']):.2f}-{max(row['paired']):.2f}" if row["paired"] else "-"
        print(f"| {row['label']} | {row['unit']} | {fmt(o)} | {fmt(n)} | {sp} | {rng} |")
    print("speed-up > 1: the new side is better (new/old for rates, old/new for times and counts).")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--worker"]:
        return worker_main(argv[1], json.loads(argv[2]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--old-path", default="/tmp/h1/oldpkg", help="PYTHONPATH of today's main (complete package)")
    ap.add_argument("--only", nargs="+", choices=NAMES)
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, 1 round, the tree on both sides")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_trust.json"))
    args = ap.parse_args(argv)
    old = args.old_path
    if args.smoke or not os.path.isdir(old):
        if not args.smoke:
            print(f"no package at {old}: the working tree on both sides")
        old = None
    paths = {"old": old, "new": None}
    rounds = 1 if args.smoke else args.rounds
    work = {k: v for k, v in plan(args.batch, args.smoke).items() if args.only is None or k in args.only}
    labels = {k: lab.format(batch=work[m].get("batch", args.batch))
              for k, (m, lab, _, _) in METRICS.items() if m in work}
    runs = {name: {s: [] for s in SIDES} for name in work}
    t_start, load_start = time.perf_counter(), os.getloadavg()
    with tempfile.TemporaryDirectory() as cwd:
        for r in range(rounds):
            for name, kw in work.items():
                for side in SIDES if r % 2 == 0 else SIDES[::-1]:
                    res = run_worker(name, kw, paths[side], cwd)
                    runs[name][side].append(res)
                    shown = (", ".join(f"{k} {v:.4g}" for k, v in res["metrics"].items()) if "metrics" in res
                             else "FAILED " + res["error"].splitlines()[-1])
                    print(f"[{r + 1}/{rounds}] {name:<15} {side}: {shown}", flush=True)
    table = summarise(runs, labels)
    print_markdown(table)
    failed = [f"{n} {s}" for n, sides in runs.items() for s, rs in sides.items() for x in rs if "error" in x]
    for f in sorted(set(failed)):
        print("FAILED:", f)
    load = {"start": load_start, "end": os.getloadavg()}
    print(f"total {time.perf_counter() - t_start:.0f} s; load average (1, 5, 15 min) at the start "
          f"{', '.join(f'{x:.1f}' for x in load['start'])}, at the end {', '.join(f'{x:.1f}' for x in load['end'])} "
          f"on {os.cpu_count()} cores (a 2-thread rate needs the second core free)")
    statics = {s: sorted({x["info"]["statics"] for sides in runs.values() for x in sides[s] if "info" in x})
               for s in SIDES}
    meta = metadata("cpu", dtype="float64", rounds=rounds, batch=args.batch, smoke=args.smoke, paths=paths,
                    statics=statics, load_average=load)
    write_report(args.out, {"meta": meta, "plan": work, "metrics": table, "runs": runs})
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
