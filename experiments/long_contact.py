"""Long line contacts in statics, single shooting against the default (multiple shooting where
needed): a 0.5 mm nitinol wire sagging in a horizontal straight tube (0.2 mm clearance) and pushed
into tubes bent on an arc (0.3 mm clearance). Prints per scene whether it succeeded, the segments,
the deepest penetration against the tolerance (0.01 r = 5 um) and the wall time (after a first
solve that compiles). Writes results/long_contact.json.

    python experiments/long_contact.py [--smoke] [--out results/long_contact.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402

WIRE = dict(radius=0.5e-3, youngs_modulus=60e9)
SAG = dict(WIRE, density=6450.0, gravity=(-9.81, 0.0, 0.0))


def straight(L: float) -> tw.Robot:
    """The wire clamped on the axis of a straight tube of 0.2 mm clearance, sagging onto its wall."""
    return tw.Robot(length=L, obstacles=[tw.Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, L + 0.01),
                                                     radius=0.5e-3 + 0.2e-3)], **SAG)


def bent(L: float, bend: float) -> tw.Robot:
    """The wire pushed into a tube bent on an arc of radius ``bend`` [m] (0.3 mm clearance)."""
    tube = tw.Obstacle("bent_tube", start=(0, 0, -1e-3), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=bend,
                       angle=L / bend + 0.1, radius=0.5e-3 + 0.3e-3)
    return tw.Robot(length=L, obstacles=[tube], **WIRE)


SCENES = [("straight tube, L = 0.5 m", straight(0.5), 100), ("straight tube, L = 1.0 m", straight(1.0), 100),
          ("straight tube, L = 1.5 m", straight(1.5), 100), ("bent tube R 0.4 m, L = 0.2 m", bent(0.2, 0.4), 50),
          ("bent tube R 0.4 m, L = 0.3 m", bent(0.3, 0.4), 60), ("bent tube R 0.3 m, L = 0.4 m", bent(0.4, 0.3), 80)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="the first scene only (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "long_contact.json"))
    args = ap.parse_args(argv)
    rows = []
    print("| scene | N | segments option | success | segments | penetration [um] | s |")
    print("|---|---|---|---|---|---|---|")
    for name, robot, nodes in SCENES[:1] if args.smoke else SCENES:
        tw.solve_static(robot, np.zeros((1, 0)), nodes=nodes, segments=1)  # compile outside the timing
        for option in (1, None):
            t0 = time.perf_counter()
            sol = tw.solve_static(robot, np.zeros((1, 0)), nodes=nodes, segments=option)
            rows.append({"scene": name, "nodes": nodes, "segments_option": option, "success": bool(sol.success[0]),
                         "segments": int(sol.segments[0]), "penetration_m": float(sol.penetration[0].max()),
                         "seconds": time.perf_counter() - t0})
            r = rows[-1]
            print(f"| {name} | {nodes} | {option} | {r['success']} | {r['segments']} | "
                  f"{r['penetration_m'] * 1e6:.3g} | {r['seconds']:.2f} |")
    write_report(args.out, {"meta": metadata("cpu"), "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
