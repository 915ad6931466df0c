"""Cost of contact: statics of the report's robot (four straight tendons, gravity, coupled
Cosserat, RK4) with a rigid plane that most rods press on, against the same batch with no
obstacle, in the same run, medians over interleaved repeats (the issue's goal: <= 2x at
B = 4096). Each rod pulls one tendon with a random tension; the plane x = -d (normal +x) stops
the rods bending toward -x, so about a quarter of the batch touches it. ``--obstacle bar``
puts a rigid bar (a capsule of radius 5 mm along y at x = -d, z = 0.15 m) there instead, which
the crossing check (tdcr_warp/physics/crossing.py) looks at. Also the cold start: the contact
variant's kernels compile only for scenes with obstacles. Writes results/bench_contact.json.

    python experiments/bench_contact.py [--rods 4096] [--repeats 5] [--obstacle plane|bar] [--smoke]
        [--out results/bench_contact.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, interleaved_times, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.model.world import Obstacle  # noqa: E402

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
WALL = 0.05  # the plane's distance from the rods' axis [m]


def robot(obstacles=()) -> tw.Robot:
    return tw.Robot(length=0.2, radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(0, 0, -9.81),
                    tendons=[tw.Tendon(offset=o) for o in OFFSETS], obstacles=obstacles)


def tensions(rods: int, rng) -> np.ndarray:
    """One tendon per rod pulled with up to 3 N (enough to bend the rod past the wall)."""
    tau = np.zeros((rods, 4))
    tau[np.arange(rods), rng.integers(0, 4, rods)] = rng.uniform(0.0, 3.0, rods)
    return tau


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--nodes", type=int, default=40)
    ap.add_argument("--obstacle", choices=("plane", "bar"), default="plane")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_contact.json"))
    args = ap.parse_args(argv)
    if args.smoke:
        args.rods, args.repeats, args.nodes = 16, 1, 20
    tau = tensions(args.rods, np.random.default_rng(0))
    free = robot()
    wall = (Obstacle("plane", point=(-WALL, 0.0, 0.0), normal=(1.0, 0.0, 0.0)) if args.obstacle == "plane" else
            Obstacle("capsule", start=(-WALL, -0.05, 0.15), end=(-WALL, 0.05, 0.15), radius=5e-3))
    walled = robot([wall])
    cases = {"free": lambda: tw.solve_static(free, tau, nodes=args.nodes),  # "plane": the obstacle's batch
             "plane": lambda: tw.solve_static(walled, tau, nodes=args.nodes)}
    cold = {}
    sols = {}
    for name, f in cases.items():
        t = time.perf_counter()
        sols[name] = f()
        cold[name] = time.perf_counter() - t
    touching = (np.abs(sols["plane"].contact_force).sum(axis=(1, 2)) > 0)
    pen = sols["plane"].penetration[:, 0]
    times, med = interleaved_times(cases, args.repeats)
    ratio = med["plane"] / med["free"]
    success = {k: int(s.success.sum()) for k, s in sols.items()}
    iters = {k: float(np.mean(s.iterations)) for k, s in sols.items()}
    shots = {k: float(np.mean(s.integrations)) for k, s in sols.items()}
    for k in cases:
        print(f"{k:6s} {med[k] * 1e3:9.1f} ms per batch of {args.rods} (first call {cold[k]:.1f} s)  "
              f"successes {success[k]}  iterations {iters[k]:.1f}  integrations {shots[k]:.1f}")
    print(f"{args.obstacle} / free: {ratio:.2f}x; rods touching it: {int(touching.sum())}; "
          f"largest penetration {pen.max():.2e} m (tolerance {0.01 * 0.5e-3:.0e} m)")
    write_report(args.out, {"meta": metadata("cpu", rods=args.rods, repeats=args.repeats, nodes=args.nodes,
                                             obstacle=args.obstacle),
                            "median_s": med, "ratio_plane_to_free": ratio, "first_call_s": cold,
                            "touching": int(touching.sum()), "successes": success, "max_penetration_m": float(pen.max()),
                            "mean_iterations": iters, "mean_integrations": shots, "times_s": times})
    return 0


if __name__ == "__main__":
    sys.exit(main())
