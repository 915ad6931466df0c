"""Sweeps at any size: rods/s and peak memory of a Monte-Carlo sweep at 1e5, 1e6 and 1e7 rods.

The scene is examples/montecarlo.toml (4 tendons, gravity, scatter in E, radius, offset and
density) as a statics sweep at the cheapest preset ("fast": RK4, N = 10, Kirchhoff rod).
Each size runs `tdcr-warp montecarlo` in a fresh process under /usr/bin/time -v, which reports
the peak resident set size of the whole process; the sweep's own summary gives the rods/s of
its chunks. The output folder of each size is deleted afterwards (a 1e7 sweep writes ~2 GB).
Prints the table of docs/performance.md in Markdown.

    python experiments/sweep_scale.py [--rods 100000 1000000 10000000] [--chunk 16384] [--smoke]
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402


def scene(rods: int, chunk: int) -> dict:
    data = tomllib.loads((ROOT / "examples" / "montecarlo.toml").read_text())
    for key in ("dynamics", "control"):
        data.pop(key)
    data["solver"] = {"preset": "fast"}
    data["sweep"].update(samples=rods, chunk=chunk)
    return data


def run(rods: int, chunk: int, work: Path) -> dict:
    path = work / f"mc_{rods}.toml"
    path.write_text(tomli_w.dumps(scene(rods, chunk)))
    out = work / f"out_{rods}"
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "tdcr_warp", "montecarlo", str(path), "--out", str(out),
           "--quiet", "--device", "cpu"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{rods} rods: exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-3000:]}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr).group(1))
    summary = json.loads((out / "summary.json").read_text())
    disk = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    shutil.rmtree(out)
    row = {"rods": rods, "chunk": chunk, "failed": summary["failed"], "rods_per_s": summary["rods_per_s"],
           "sweep_s": summary["wall_time_s"], "process_s": wall, "peak_rss_mib": rss_kb / 1024,
           "output_mib": disk / 2**20, "tip_mean": summary["tip_mean"]}
    print(f"{rods:>10,} rods: {row['rods_per_s']:,.0f} rods/s, process {wall:.0f} s, peak RSS "
          f"{row['peak_rss_mib']:.0f} MiB, output {row['output_mib']:.0f} MiB, {row['failed']} failed", flush=True)
    return row


def markdown(rows: list[dict]) -> str:
    """The table of docs/performance.md (sweeps at scale) from the runs."""
    lines = ["| rods | rods/s | process time | peak RSS | output on disk |", "|---:|---:|---:|---:|---:|"]
    for r in rows:
        disk = f"{r['output_mib'] / 1024:.1f} GiB" if r["output_mib"] >= 1024 else f"{r['output_mib']:.0f} MiB"
        lines.append(f"| {r['rods']:,} | {r['rods_per_s']:,.0f} | {r['process_s']:.0f} s | {r['peak_rss_mib']:.0f} MiB "
                     f"| {disk} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, nargs="+", default=[100_000, 1_000_000, 10_000_000])
    ap.add_argument("--chunk", type=int, default=16384)
    ap.add_argument("--smoke", action="store_true", help="one tiny size (a check that the script runs)")
    ap.add_argument("--out", default=str(ROOT / "results" / "sweep_scale.json"))
    args = ap.parse_args(argv)
    sizes, chunk = ([1000], 500) if args.smoke else (args.rods, args.chunk)
    with tempfile.TemporaryDirectory() as tmp:
        rows = [run(n, chunk, Path(tmp)) for n in sizes]
    print(markdown(rows))
    write_report(args.out, {"meta": metadata("cpu", preset="fast"), "runs": rows,
                            "rss_ratio_largest_to_smallest": rows[-1]["peak_rss_mib"] / rows[0]["peak_rss_mib"]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
