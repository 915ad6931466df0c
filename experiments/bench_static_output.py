"""`tdcr-warp static` end to end against its solve: where the time goes around the solve.

A batch of B rods of the report's robot (4 tendons, gravity, RK4, N = 50, coupled, float64),
random tensions in [0, 3] N, given two ways: inline in the TOML scene (`tensions = [[...], ...]`)
and as a .npy file the scene names (`tensions = "tensions.npy"`; the old code cannot read it).
Each configuration runs `tdcr-warp static SCENE --no-figures` in a fresh process (from an empty
folder), its phases timed inside that process by wrapping load_scene, load_kernels and
solve_static: start (the interpreter, until the first line runs), import (tdcr_warp's CLI),
scene, kernels, solve, output (everything after the solve: per-rod lines, files), exit (from
the command's return until the process has ended: Python's and Warp's teardown), and the
process's wall time. Configurations
alternate within each repeat; medians over repeats. The ratio is end to end / solve; on a loaded
machine every phase stretches, so the table also gives the solve's CPU seconds (all its threads)
and the process's CPU seconds besides the solve's (the phases around the solve run on one
thread: on a quiet machine about their wall time).

    python experiments/bench_static_output.py [--rods 16384] [--repeats 3] [--old /tmp/ref26pkg]
        [--new PATH] [--smoke] [--out results/bench_static_output.json]

--old and --new: a folder put first on PYTHONPATH to import that tdcr_warp (--new: default the
installed one; --old: default none, only the new code is run).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
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

PHASES = ("start", "import", "scene", "kernels", "solve", "output", "exit")

CHILD = """
import json, sys, time
born = time.time()
t0 = time.perf_counter()
from tdcr_warp.cli import main
import tdcr_warp.cli.static as cs, tdcr_warp.io.scene as sc, tdcr_warp.physics.statics as st
T = dict.fromkeys(("scene", "kernels", "solve", "solve_cpu"), 0.0)
def timed(mod, name, key):
    f = getattr(mod, name)
    def g(*a, **k):
        t, c = time.perf_counter(), time.process_time()
        try:
            return f(*a, **k)
        finally:
            T[key] += time.perf_counter() - t
            if key == "solve":
                T["solve_cpu"] += time.process_time() - c
    setattr(mod, name, g)
timed(sc, "load_scene", "scene"); timed(cs, "load_kernels", "kernels"); timed(st, "solve_static", "solve")
t1 = time.perf_counter()
sys.argv[0] = "tdcr-warp"
rc = main()  # as the command runs: main() of the process's own command line
t2 = time.perf_counter()
T["import"] = t1 - t0
T["output"] = t2 - t1 - T["scene"] - T["kernels"] - T["solve"]
T["born"], T["done"] = born, time.time()
print("PHASES " + json.dumps(T), flush=True)
sys.exit(rc)
"""


def make_scenes(folder: Path, rods: int) -> dict[str, Path]:
    """The seed robot with ``rods`` rows of random tensions, inline and in tensions.npy."""
    base = (ROOT / "examples" / "seed_robot.toml").read_text()
    one = "tensions = [[3.0, 0.0, 0.0, 0.0]]"
    assert one in base
    tau = np.random.default_rng(0).uniform(0.0, 3.0, (rods, 4))
    rows = ",\n".join("[" + ", ".join(repr(float(x)) for x in r) + "]" for r in tau)
    inline, npy = folder / "inline.toml", folder / "npy.toml"
    inline.write_text(base.replace(one, "tensions = [\n" + rows + "\n]"))
    np.save(folder / "tensions.npy", tau)
    npy.write_text(base.replace(one, 'tensions = "tensions.npy"'))
    return {"toml": inline, "npy": npy}


def run_once(pythonpath: str | None, scene: Path, out: Path, cwd: Path) -> dict:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    t0, w0, r0 = time.perf_counter(), time.time(), resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([sys.executable, "-c", CHILD, "static", str(scene), "--out", str(out), "--no-figures",
                        "--quiet"], check=False, cwd=cwd, env=env, capture_output=True, text=True)
    wall, w1, r1 = time.perf_counter() - t0, time.time(), resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"static failed ({p.returncode}) with PYTHONPATH={pythonpath}:\n{p.stderr[-2000:]}")
    line = next(x for x in p.stdout.splitlines() if x.startswith("PHASES "))
    phases = json.loads(line[len("PHASES "):])
    phases["start"], phases["exit"] = phases.pop("born") - w0, w1 - phases.pop("done")
    cpu = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
    phases["cpu_besides_solve"] = cpu - phases["solve_cpu"]
    files = {f.name: f.stat().st_size for f in out.iterdir() if f.is_file()}
    return {**phases, "end_to_end": wall, "files": files}



def table(rows: dict[str, dict], rods: int) -> str:
    lines = [f"`tdcr-warp static --no-figures`, {rods:,} rods (medians; s)", "",
             "| configuration | " + " | ".join(PHASES) + " | end to end | end to end / solve | solve CPU s | CPU s "
             "besides the solve | files (MB) |",
             "|---|" + "---|" * (len(PHASES) + 5)]
    for name, r in rows.items():
        mb = ", ".join(f"{k} {v / 1e6:.1f}" for k, v in sorted(r["files"].items()))
        lines.append(f"| {name} | " + " | ".join(f"{r[p]:.3f}" for p in PHASES)
                     + f" | {r['end_to_end']:.3f} | {r['end_to_end'] / r['solve']:.2f} | {r['solve_cpu']:.3f} | "
                     f"{r['cpu_besides_solve']:.3f} | {mb} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, default=16384)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--old", default=None, help="PYTHONPATH folder of the old tdcr_warp (default: not run)")
    ap.add_argument("--new", default=None, help="PYTHONPATH folder of the new tdcr_warp (default: the installed one)")
    ap.add_argument("--smoke", action="store_true", help="64 rods, one repeat")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_static_output.json"))
    args = ap.parse_args(argv)
    rods, repeats = (64, 1) if args.smoke else (args.rods, args.repeats)
    configs = {"new, inline TOML": (args.new, "toml"), "new, tensions.npy": (args.new, "npy")}
    if args.old:
        configs = {"old, inline TOML": (args.old, "toml")} | configs
    samples: dict[str, list[dict]] = {name: [] for name in configs}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scenes = make_scenes(tmp, rods)
        cwd = tmp / "cwd"
        cwd.mkdir()
        for i in range(repeats):
            for name, (path, kind) in configs.items():
                out = tmp / f"out{len(samples[name])}_{kind}_{path is None}"
                samples[name].append(run_once(path, scenes[kind], out, cwd))
                print(f"repeat {i + 1}/{repeats} {name}: end to end {samples[name][-1]['end_to_end']:.2f} s, "
                      f"solve {samples[name][-1]['solve']:.2f} s", flush=True)
    medians = {name: {k: statistics.median(s[k] for s in runs) for k in (*PHASES, "end_to_end", "solve_cpu", "cpu_besides_solve")}
               | {"files": runs[-1]["files"]} for name, runs in samples.items()}
    text = table(medians, rods)
    print(text)
    write_report(args.out, {"meta": metadata("cpu", rods=rods, repeats=repeats, old=args.old, new=args.new),
                            "medians": medians, "samples": samples, "table": text})
    return 0


if __name__ == "__main__":
    sys.exit(main())
