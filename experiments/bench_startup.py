"""Start-up of ``tdcr-warp static examples/seed_robot.toml``, old against new in the same run.

    python experiments/bench_startup.py [--old DIR] [--new DIR] [--repeats 5]
        [--cold-repeats 1] [--warmup-args "warmup"] [--out results/bench_startup.json] [--smoke]

Both run as ``python -m tdcr_warp`` from a temporary working directory (no tdcr_warp folder in
it): the old one is the tdcr_warp found on ``--old`` (PYTHONPATH), the new one that on ``--new``,
else the package this interpreter imports (the checkout; a snapshot is steadier where others edit
the kernels meanwhile: each edit is a compile). Measured, each a separate process timed from outside:

- cold (``--cold-repeats``; 0: the caches are filled untimed): an empty kernel cache
  (WARP_CACHE_PATH), an empty matplotlib cache (MPLCONFIGDIR) and no bytecode of the package
  (its __pycache__ folders removed, as after ``pip install -e .``), as on a fresh machine. Old: its
  first ``static``. New: ``tdcr-warp warmup`` (the README's set-up command runs it;
  ``--warmup-args`` replaces its arguments), then its first ``static``.

Bytecode is written as on a user's machine (PYTHONDONTWRITEBYTECODE is dropped: where it is set,
every run compiles the package's ~50 modules again, ~0.3-0.6 s).
- warm: ``static`` again with those caches, with and without figures (``--no-figures``), old
  and new alternating, median over ``--repeats``.
- ``python -c "import tdcr_warp"``, alternating, median.

Prints two Markdown tables, wall and CPU seconds (user + system of the process and its children:
on a loaded machine closer to what a quiet one would take), each with medians, the range over
repeats and the new/old ratio. On a shared machine only the same-run ratios mean much. Without
``--old`` only the new side runs. ``--smoke`` (the test suite's): the new side once, warm, with
the user's own caches (no cold run, no figure).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

SCENE = str(ROOT / "examples" / "seed_robot.toml")


def timed(cmd: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """Wall seconds from start to exit of ``cmd`` and its CPU seconds (user + system, with its
    children's); its failure (exit status above 1) raises with its output."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, check=False)
    sec = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode > 1:
        raise RuntimeError(f"{' '.join(cmd)} exited {done.returncode}:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return sec, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


class Side:
    """One code version (old or new) with its own kernel and matplotlib caches."""

    def __init__(self, name: str, pythonpath: str | None, tmp: Path, own_caches: bool = True):
        self.name, self.tmp = name, tmp / name
        self.cwd = self.tmp / "cwd"
        drop = ("PYTHONPATH", "PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX")
        drop += ("WARP_CACHE_PATH", "MPLCONFIGDIR") if own_caches else ()
        self.env = {k: v for k, v in os.environ.items() if k not in drop}
        if pythonpath:
            self.env["PYTHONPATH"] = pythonpath
        if own_caches:
            self.env |= {"WARP_CACHE_PATH": str(self.tmp / "warp"), "MPLCONFIGDIR": str(self.tmp / "mpl")}
        self.cwd.mkdir(parents=True)
        where = "import tdcr_warp, tdcr_warp.kernels as k; print(tdcr_warp.__path__[0]); print(k.__path__[0])"
        self.roots = subprocess.run([sys.executable, "-c", where], env=self.env, cwd=self.cwd, capture_output=True,
                                    text=True, check=True).stdout.split()

    def empty_caches(self) -> None:
        """No kernels, no matplotlib font list, no bytecode of the package (an editable install has none)."""
        for d in ("warp", "mpl"):
            shutil.rmtree(self.tmp / d, ignore_errors=True)
        for root in self.roots:
            for pyc in Path(root).rglob("__pycache__"):
                shutil.rmtree(pyc, ignore_errors=True)

    def cli(self, *args: str) -> tuple[float, float]:
        return timed([sys.executable, "-m", "tdcr_warp", *args], self.env, str(self.cwd))

    def static(self, *extra: str) -> tuple[float, float]:
        return self.cli("static", SCENE, "--out", str(self.cwd / "out"), *extra)

    def import_time(self) -> tuple[float, float]:
        return timed([sys.executable, "-c", "import tdcr_warp"], self.env, str(self.cwd))


def measure(args) -> dict[str, dict[str, list[list[float]]]]:
    """{row: {"old": [[wall, cpu] s...], "new": [...]}} of every measurement."""
    rows: dict[str, dict[str, list[list[float]]]] = {}

    def add(row: str, side: Side, sec: tuple[float, float]) -> None:
        rows.setdefault(row, {}).setdefault(side.name, []).append(list(sec))
        print(f"  {row:<45} {side.name}: {sec[0]:6.2f} s wall, {sec[1]:6.2f} s CPU", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp:
        if args.smoke:
            new = Side("new", args.new, Path(tmp), own_caches=False)
            add("warm: `static --no-figures`", new, new.static("--no-figures"))
            add('`python -c "import tdcr_warp"`', new, new.import_time())
            return rows
        old, new = Side("old", args.old, Path(tmp)) if args.old else None, Side("new", args.new, Path(tmp))
        sides = [s for s in (old, new) if s]
        for _ in range(args.cold_repeats):
            if old:
                old.empty_caches()
                add("cold: first `static` (empty caches)", old, old.static())
            new.empty_caches()
            add("cold: `tdcr-warp " + args.warmup_args + "` (empty caches)", new, new.cli(*args.warmup_args.split()))
            add("cold: first `static` after the set-up", new, new.static())
        if not args.cold_repeats:  # the warm runs' caches, untimed
            for side in sides:
                side.empty_caches()
            if old:
                old.static()
            new.cli(*args.warmup_args.split())
        for _ in range(args.repeats):
            for side in sides:
                add("warm: `static` (with the figure)", side, side.static())
                add("warm: `static --no-figures`", side, side.static("--no-figures"))
                add('`python -c "import tdcr_warp"`', side, side.import_time())
        if args.repeats:
            add("warm: `tdcr-warp " + args.warmup_args + "` again", new, new.cli(*args.warmup_args.split()))
    return rows


def table(rows: dict, col: int, what: str) -> str:
    """Medians (and ranges over repeats) of column ``col`` (0 wall, 1 CPU) of every row."""
    def cell(xs):
        if not xs:
            return ""
        med = statistics.median(xs)
        return f"{med:.2f} s" + (f" ({min(xs):.2f}-{max(xs):.2f})" if len(xs) > 1 else "")

    out = [f"| measurement ({what}) | old | new | new/old |", "|---|---|---|---|"]
    for row, sides in rows.items():
        o, n = ([t[col] for t in sides.get(k, [])] for k in ("old", "new"))
        ratio = f"{statistics.median(n) / statistics.median(o):.2f}" if o and n else ""
        out.append(f"| {row} | {cell(o)} | {cell(n)} | {ratio} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", help="PYTHONPATH of the old tdcr_warp (default: none, the new side alone)")
    ap.add_argument("--new", help="PYTHONPATH of the new tdcr_warp (default: the one this interpreter imports)")
    ap.add_argument("--repeats", type=int, default=5, help="warm repeats (old and new alternating)")
    ap.add_argument("--cold-repeats", type=int, default=1, help="cold repeats (each empties the caches)")
    ap.add_argument("--warmup-args", default="warmup", help="the new side's set-up command after tdcr-warp")
    ap.add_argument("--smoke", action="store_true", help="the new side once, warm (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_startup.json"), help="the raw times and tables")
    args = ap.parse_args(argv)
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S')}, load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs",
          file=sys.stderr)
    rows = measure(args)
    tables = [table(rows, 0, "wall"), table(rows, 1, "CPU: user + system, with child processes")]
    print("\n\n".join(tables))
    write_report(args.out, {"meta": metadata("cpu", old=args.old, new=args.new, load=os.getloadavg()[0]),
                            "times": rows, "tables": tables})
    return 0


if __name__ == "__main__":
    sys.exit(main())
