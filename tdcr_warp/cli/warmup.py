"""``tdcr-warp warmup [SCENE ...]``: build this machine's kernels ahead of use.

Warp compiles a kernel module on its first use with a kernel cache (3-30 s each on a CPU, for this
CPU) and loads it from the cache in milliseconds afterwards. Warmup runs the example commands of
the README and the tutorials (or ``static`` on the scenes given) once, quietly and cut short
(QUICK), into a temporary directory, ``--jobs`` at a time, so that each builds exactly the kernels
its command needs, as the command itself would; meanwhile it builds matplotlib's font cache (the
first figure's extra second). It says what it is doing, and where everything is already built it
takes seconds and compiles nothing. The README's set-up command runs it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tdcr_warp.cli.common import number_type

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"  # in a clone of the repository
# (command, scene under examples/): the first command of the README, its tour, ik. Commands that
# share kernels stand apart (simulate and control: the dynamics), so that two jobs do not build one
# module twice.
DEFAULT_RUNS = (("simulate", "seed_dynamics.toml"), ("static", "seed_robot.toml"),
                ("static", "helix_two_sections.toml"), ("workspace", "tutorials/workspace.toml"),
                ("ik", "ik_targets.toml"), ("control", "circle_tracking.toml"),
                ("montecarlo", "tutorials/montecarlo.toml"))


# Each command's arguments for the least work that still loads every kernel of the full run: no
# figures, the first steps of a run (the start and the controller's linearisation come first), the
# first chunk of a sweep.
QUICK = {"static": ["--no-figures"], "simulate": ["--no-figures", "--steps", "2"], "control": ["--steps", "2"],
         "workspace": ["--max-chunks", "1"], "montecarlo": ["--max-chunks", "1"]}


def register(subparsers) -> None:
    p = subparsers.add_parser("warmup", help="compile the kernels of the example commands (or of SCENE's statics) "
                                             "into Warp's kernel cache, so that later runs start at once")
    p.set_defaults(run=run)
    p.add_argument("scenes", nargs="*", metavar="SCENE",
                   help="scene files whose statics to build (default: the README's and the tutorials' example runs)")
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
    p.add_argument("--jobs", type=number_type(1, integer=True), default=min(2, os.cpu_count() or 1),
                   help="runs at a time (default: 2)")
    p.add_argument("--quiet", action="store_true", help="print nothing unless a run fails")
    p.add_argument("-v", "--verbose", action="store_true", help="also every run's own output")


def runs_of(scenes: list[str]) -> list[tuple[str, str]]:
    """(command, scene path) of each run: ``static`` on each scene given, else DEFAULT_RUNS."""
    if scenes:
        return [("static", s) for s in scenes]
    if not EXAMPLES.is_dir():
        from tdcr_warp.model.robot import InputError
        raise InputError(f"no examples directory at {EXAMPLES} (an install without the repository): "
                         "name the scene files to build, e.g. tdcr-warp warmup my_robot.toml")
    return [(cmd, str(EXAMPLES / scene)) for cmd, scene in DEFAULT_RUNS]


def _shown(path: str) -> str:
    """The path relative to the working directory where it lies below it."""
    rel = os.path.relpath(path)
    return path if rel.startswith("..") else rel


def _cached_modules(cache: Path) -> set[str]:
    return set(os.listdir(cache)) if cache.is_dir() else set()


def _run_one(command: str, scene: str, out: Path, device: str | None) -> tuple[int, float, str]:
    """One command in its own process, as a user would run it but cut short (QUICK): exit status,
    seconds, its output."""
    cmd = [sys.executable, "-m", "tdcr_warp", command, scene, "--out", str(out), "--quiet", *QUICK.get(command, [])]
    t0 = time.perf_counter()
    done = subprocess.run(cmd + (["--device", device] if device else []), capture_output=True, text=True,
                          check=False)
    return done.returncode, time.perf_counter() - t0, done.stdout + done.stderr


def run(args) -> int:
    """Each run in turn, ``args.jobs`` at a time; a failed run (exit status above 1: an error, not
    a rod that did not converge) is reported with its output and makes the exit status 1."""
    import warp as wp

    runs = runs_of(args.scenes)
    wp.init()
    cache = Path(wp.config.kernel_cache_dir)
    say = (lambda *a, **k: None) if args.quiet else print
    before, t0 = _cached_modules(cache), time.perf_counter()
    say(f"tdcr-warp warmup: building the kernels of {len(runs)} run(s) for {args.device or wp.get_device()} "
        f"into {cache}, {min(max(1, args.jobs), len(runs))} at a time (a kernel module not built yet: 3-30 s each; "
        "already built: about a second a run) ...", flush=True)
    failed = 0
    with tempfile.TemporaryDirectory(prefix="tdcr-warp-warmup-") as tmp, ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futures = [pool.submit(_run_one, cmd, scene, Path(tmp) / str(i), args.device)
                   for i, (cmd, scene) in enumerate(runs)]
        import matplotlib.font_manager  # noqa: F401  (builds matplotlib's font cache where it is missing)
        for (cmd, scene), fut in zip(runs, futures):
            rc, sec, output = fut.result()
            ok = rc in (0, 1)  # 1: some rods did not converge; the kernels are built
            failed += not ok
            say(f"  {cmd} {_shown(scene)}: {sec:.1f} s" + ("" if ok else f", FAILED (exit status {rc})"), flush=True)
            if not ok or args.verbose:
                print(output.rstrip(), file=sys.stdout if ok else sys.stderr)
    after = _cached_modules(cache)
    say(f"{len(after - before)} kernel module(s) compiled in {time.perf_counter() - t0:.0f} s "
        f"(new in the cache, which holds {len(after)})")
    return 1 if failed else 0
