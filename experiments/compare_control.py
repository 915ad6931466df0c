"""The report's control run against ours, side by side (same rod, same dynamics).

Rows: the report's settings (sgn(S), alpha input model, C = diag(15000, 1, 500),
k = diag(30, 1, 5), eps = 0.005, 8 N clamp) on its own target [0.027, 0, 0.4727] and on a
reachable one (our static tip at 3 N on tendon 1); ours (boundary layer, quasi-static Jacobian,
C = k = 20, phi = 1e-3) on both, and ours with sgn(S) for the chatter comparison.

    python experiments/compare_control.py [--smoke] [--out results/compare_control.json]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.apps.control import TipController, control_metrics, run_closed_loop, static_target  # noqa: E402

REPORT = dict(method="smc", input_model="alpha", gain_c=(15000.0, 1.0, 500.0), gain_k=(30.0, 1.0, 5.0),
              epsilon=0.005, tension_max=8.0)
OURS = dict(method="boundary_layer", input_model="jacobian", gain_c=20.0, gain_k=20.0, epsilon=0.005, phi=1e-3,
            tension_max=8.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=str(ROOT / "results" / "compare_control.json"))
    args = ap.parse_args(argv)
    nodes, steps = (10, 20) if args.smoke else (50, 200)
    rob = tw.Robot(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                   tendons=[tw.Tendon(offset=o) for o in [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]],
                   gravity=(0.0, 0.0, -9.81), damping_bending=(0.008, 0.008, 0.008), drag=(0.01, 0.01, 0.01))
    reachable = static_target(rob, [[3.0, 0.0, 0.0, 0.0]], nodes=nodes, device=args.device)[0]
    targets = {"report target": np.array([0.027, 0.0, 0.4727]), "own static tip at 3 N": reachable}
    runs = [("report settings", REPORT), ("ours", OURS), ("ours with sgn(S)", dict(OURS, method="smc"))]
    rows = []
    print(f"{'controller':>18} {'target':>22} {'final err [mm]':>15} {'settling [s]':>13} {'chatter [N]':>12} "
          f"{'reversals':>10} {'saturated':>10} {'mean tension [N]':>28}")
    for tname, target in targets.items():
        for cname, kw in runs:
            sim = tw.Simulator(rob, np.zeros((1, 4)), dt=0.005, alpha=-0.2, nodes=nodes, device=args.device)
            ctl = TipController(sim, target, **kw)
            m = control_metrics(run_closed_loop(sim, ctl, steps), ctl.tau_max)
            row = {"controller": cname, "target": tname, **{k: v[0].tolist() for k, v in m.items()}}
            rows.append(row)
            print(f"{cname:>18} {tname:>22} {m['final_error'][0] * 1e3:>15.3f} {m['settling_time'][0]:>13.3f} "
                  f"{m['chatter'][0]:>12.2e} {m['reversal_fraction'][0]:>10.2f} {m['saturation_fraction'][0]:>10.2f} "
                  f"{np.array2string(m['mean_tension'][0], precision=3):>28}")
    write_report(args.out, {"meta": metadata(args.device, nodes=nodes, steps=steps, dt=0.005), "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
