"""kill -9 at random moments, then --resume: the results must equal an uninterrupted run's.

A Monte-Carlo statics sweep of examples/montecarlo.toml (cheapest preset, 20,000 rods in
chunks of 500) runs once uninterrupted (the reference, timed). Then, TRIALS times: a fresh
sweep is started in its own process and killed with SIGKILL at a moment drawn uniformly over
the reference's whole process time (start-up, kernel loading, chunks, summary), then resumed
with --resume until it completes. Every trial's per-rod results (every column and array) and
its summary (less timings) must equal the reference's bit for bit.

    python experiments/kill_resume.py [--trials 20] [--rods 20000] [--chunk 500] [--seed 0] [--smoke]
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402
from sweep_scale import scene  # noqa: E402

from tdcr_warp.apps.sweep import open_sweep  # noqa: E402

TIMINGS = ("wall_time_s", "rods_per_s", "computed_rods", "peak_memory_mb", "settings")


def sweep(path: Path, out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tdcr_warp", "montecarlo", str(path), "--out", str(out), "--quiet",
                             "--device", "cpu", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def same(a: Path, b: Path) -> list[str]:
    """What differs between two complete sweeps (empty: nothing)."""
    ra, rb = open_sweep(a).load(), open_sweep(b).load()
    diff = [k for k in set(ra) | set(rb) if k not in ra or k not in rb or not np.array_equal(ra[k], rb[k])]
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    diff += [f"summary.{k}" for k in set(sa) | set(sb) if k not in TIMINGS and sa.get(k) != sb.get(k)]
    return diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--rods", type=int, default=20000)
    ap.add_argument("--chunk", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--smoke", action="store_true", help="1 trial of a 400-rod sweep")
    ap.add_argument("--out", default=str(ROOT / "results" / "kill_resume.json"))
    args = ap.parse_args(argv)
    trials, rods, chunk = (1, 400, 100) if args.smoke else (args.trials, args.rods, args.chunk)
    rng = np.random.default_rng(args.seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        path = work / "mc.toml"
        path.write_text(tomli_w.dumps(scene(rods, chunk)))
        t0 = time.perf_counter()
        ref = sweep(path, work / "ref")
        _, err = ref.communicate()
        full = time.perf_counter() - t0
        if ref.returncode != 0:
            raise SystemExit(f"the reference sweep failed ({ref.returncode}): {err[-2000:]}")
        print(f"reference: {rods} rods in {full:.1f} s (process)", flush=True)
        for t in range(trials):
            out = work / f"trial{t}"
            at = float(rng.uniform(0.0, full))
            proc = sweep(path, out)
            time.sleep(at)
            killed = proc.poll() is None
            proc.send_signal(signal.SIGKILL)
            proc.communicate()
            parts = len(list((out / "results").glob("part-*.parquet")))
            resumed = sweep(path, out, "--resume")
            _, err = resumed.communicate()
            diff = same(work / "ref", out) if resumed.returncode == 0 else ["resume failed: " + err[-500:]]
            rows.append({"trial": t, "kill_after_s": at, "killed_running": killed, "parts_at_kill": parts,
                         "resume_status": resumed.returncode, "differences": diff})
            print(f"trial {t:2d}: SIGKILL after {at:5.2f} s ({'running' if killed else 'already done'}, "
                  f"{parts} parts on disk), resume exit {resumed.returncode}, "
                  f"{'identical' if not diff else 'DIFFERS: ' + ', '.join(diff)}", flush=True)
    bad = [r for r in rows if r["differences"] or r["resume_status"] != 0]
    write_report(args.out, {"meta": metadata("cpu", preset="fast"), "rods": rods, "chunk": chunk,
                            "reference_process_s": full, "trials": rows, "identical": len(rows) - len(bad)})
    print(f"{len(rows) - len(bad)} of {len(rows)} killed-and-resumed sweeps identical to the uninterrupted one")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
