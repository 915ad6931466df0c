"""Integrations and Newton iterations per rod of a static solve, and rods/s, for two installs of
tdcr_warp in the same run (today's main and the working tree: same-run ratios, one thread).

    python experiments/bench_integrations.py --old /tmp/h1/oldpkg [--new DIR] [--batch 4096]

Cases: the report robot (4 straight tendons at 10 mm, gravity, tensions in [0, 3] N) at N = 4,
10, 20 and 50, each at two tolerances (tol = tier / 2 for the 1e-9 m and 1e-6 m tip tiers), and
harder families at N = 20: heavier tensions ([0, 10] N), helical routing (one turn), and tip
forces (up to 0.5 N lateral). Each side runs in its own process from a folder without a
tdcr_warp package (``PYTHONPATH`` picks the install); sides alternate over ``--rounds`` rounds,
medians of the timings: rods/s per CPU-second of the solving process (one thread; a shared
machine stretches wall time), wall rods/s beside it. The tips of the two sides are compared
(max |tip_new - tip_old| [m]), which must stay below the tier: a different Jacobian path to
the same root moves a tip by at most about the stopping rule L |r| < tol.
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

sys.path[:0] = [str(Path(__file__).resolve().parent)]

from _common import ROOT, metadata, write_report

MARKER = "BENCH_INT "
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROBOT = {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 17189.0,
         "gravity": (0.0, 0.0, -9.81)}
TIERS = (1e-9, 1e-6)
FAMILIES = {  # name: (nodes, tension range [N], routing, tip force [N])
    "report N=4": (4, 3.0, "straight", 0.0),
    "report N=10": (10, 3.0, "straight", 0.0),
    "report N=20": (20, 3.0, "straight", 0.0),
    "report N=50": (50, 3.0, "straight", 0.0),
    "heavy N=20": (20, 10.0, "straight", 0.0),
    "helix N=20": (20, 3.0, "helix", 0.0),
    "tip force N=20": (20, 3.0, "straight", 0.5),
}


def _case(name: str, batch: int):
    """The robot and tensions (batch, 4) of one family."""
    import tdcr_warp as tw

    nodes, tmax, routing, fmax = FAMILIES[name]
    rng = np.random.default_rng(7)
    tau = rng.uniform(0.0, tmax, (batch, 4))
    if routing == "helix":
        tendons = [tw.Tendon(routing="helix", helix_radius=0.01, turns=1.0, phase=k * np.pi / 2) for k in range(4)]
    else:
        tendons = [tw.Tendon(offset=o) for o in OFFSETS]
    extra = {}
    if fmax:
        f = rng.uniform(-fmax, fmax, (batch, 3))
        f[:, 2] = 0.0
        extra["tip_force"] = f
    return tw.Robot(tendons=tendons, **ROBOT, **extra), tau, nodes


def worker(name: str, batch: int, tol: float, repeats: int, tips_out: str) -> dict:
    """One side, one case: warm up, then the median of ``repeats`` timed solves (threads = 1)."""
    import tdcr_warp as tw

    rob, tau, nodes = _case(name, batch)
    kw = {"nodes": nodes, "tol": tol, "threads": 1, "stability": "off"}
    tw.solve_static(rob, tau[:1] if rob.batch_size == 1 else tau, **kw)
    times, cpu, sol = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        sol = tw.solve_static(rob, tau, **kw)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    np.save(tips_out, sol.tip_position)
    return {"seconds": float(np.median(times)), "rods_per_s": batch / float(np.median(cpu)),
            "rods_per_s_wall": batch / float(np.median(times)),
            "integrations": float(sol.integrations.mean()), "iterations": float(sol.iterations.mean()),
            "max_integrations": int(sol.integrations.max()), "converged": float(sol.converged.mean()),
            "package": str(Path(tw.__file__).parent)}


def _run_side(pythonpath: str | None, args: dict) -> dict:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(args)]
    with tempfile.TemporaryDirectory() as cwd:  # no tdcr_warp folder: the install on PYTHONPATH is imported
        proc = subprocess.run(cmd, check=False, cwd=cwd, env=env, capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(MARKER)]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"worker failed ({pythonpath or 'working tree'}): {proc.stderr[-2000:]}")
    return json.loads(lines[-1][len(MARKER):])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default=None, help="PYTHONPATH of today's main (a complete copy of the package)")
    ap.add_argument("--new", default=None, help="PYTHONPATH of the new side (default: the working tree)")
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=3, help="timed solves per process (median)")
    ap.add_argument("--rounds", type=int, default=2, help="alternating old/new processes per case")
    ap.add_argument("--cases", default=None, help="comma-separated family names (default all)")
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_integrations.json"))
    args = ap.parse_args(argv)
    if args.worker:
        w = json.loads(args.worker)
        print(MARKER + json.dumps(worker(w["case"], w["batch"], w["tol"], w["repeats"], w["tips"])), flush=True)
        return 0
    names = args.cases.split(",") if args.cases else list(FAMILIES)
    batch, repeats, rounds = (8, 1, 1) if args.smoke else (args.batch, args.repeats, args.rounds)
    tiers = TIERS[1:] if args.smoke else TIERS
    if args.smoke:
        names = names[:1]
    sides = {"new": args.new or str(ROOT)} | ({"old": args.old} if args.old else {})
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for tier in tiers:
                got = {s: [] for s in sides}
                for rnd in range(rounds):
                    for side, path in (sides.items() if rnd % 2 == 0 else reversed(sides.items())):
                        tips = str(Path(tmp) / f"{side}.npy")
                        got[side].append(_run_side(path, {"case": name, "batch": batch, "tol": tier / 2,
                                                          "repeats": repeats, "tips": tips}))
                row = {"case": name, "tier": tier, "tol": tier / 2}
                for side, res in got.items():
                    row[side] = res[-1] | {"rods_per_s": float(np.median([r["rods_per_s"] for r in res]))}
                if "old" in sides:
                    diff = np.abs(np.load(Path(tmp) / "new.npy") - np.load(Path(tmp) / "old.npy")).max()
                    row["max_tip_difference_m"] = float(diff)
                    row["speedup"] = row["new"]["rods_per_s"] / row["old"]["rods_per_s"]
                rows.append(row)
                print(_line(row), flush=True)
    write_report(args.out, {"meta": metadata("cpu", dtype="float64", batch=batch, threads=1, sides=sides),
                            "rows": rows})
    return 0


def _line(row: dict) -> str:
    def side(s):
        r = row.get(s)
        if r is None:
            return ""
        return (f"{s}: {r['integrations']:.2f} integrations, {r['iterations']:.2f} iterations, "
                f"{r['rods_per_s']:,.0f} rods/CPU-s, converged {r['converged']:.3f}; ")
    tail = ""
    if "speedup" in row:
        tail = f"new/old {row['speedup']:.2f}x, max |tip diff| {row['max_tip_difference_m']:.1e} m"
    return f"{row['case']:<16} tier {row['tier']:g} m: {side('old')}{side('new')}{tail}"


if __name__ == "__main__":
    sys.exit(main())
