"""Cost per solve of the tendon features relative to tension control, on the report's robot
(four straight tendons of 0.3 mm steel wire, gravity, coupled Cosserat, RK4, N = 40), in the same run, medians over
interleaved repeats: displacement control of all four tendons (10 unknowns instead of 6; the
displacements are those of the tension-control shapes, so every variant solves the same
robots), and capstan friction (mu = 0.2, slip +1) under tension control. Half the sampled
tensions are zero: those tendons sit exactly on the taut/slack boundary under displacement
control; "*_taut" repeats tension and displacement control with every tension in [0.5, 4] N.
The issue's goals: <= 1.5x and <= 1.3x. Writes results/bench_tendons.json and prints the table of
docs/performance.md in Markdown.

    python experiments/bench_tendons.py [--rods 256] [--repeats 5] [--smoke] [--out results/bench_tendons.json]
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
from tdcr_warp.physics.statics import reference_lengths  # noqa: E402

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def robot(**tendon) -> tw.Robot:
    """Steel wires of 0.3 mm (compliance 1 / (E_t A_t)): four displacement-controlled tendons at
    90 degrees with inextensible wires have a co-contraction mode (+,-,+,-) that no length fixes."""
    return tw.Robot(density=7800.0, gravity=(0, 0, -9.81),
                    tendons=[tw.Tendon(offset=o, compliance=2.7e-5, **tendon) for o in OFFSETS])


CASES = {"tension": "tension control, random tensions in [0, 4] N, half of them 0",
         "displacement": "displacement control of all 4 tendons, the same shapes",
         "friction": "friction, mu = 0.2, slip +1",
         "tension_taut": "tension control, every tension in [0.5, 4] N",
         "displacement_taut": "displacement control, the same shapes (every tendon taut)"}


def markdown(median_s: dict, ratio: dict, iterations: dict, integrations: dict) -> str:
    """The table of docs/performance.md (tendon features against tension control) from a run."""
    lines = ["| case | time per batch | against | iterations | integrations per rod |", "|---|---|---|---|---|"]
    for k, case in CASES.items():
        against = "" if k.startswith("tension") else f"{ratio[k]:.2f}x"
        lines.append(f"| {case} | {median_s[k] * 1e3:.1f} ms | {against} | {iterations[k]:.1f} "
                     f"| {integrations[k]:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rods", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--nodes", type=int, default=40)
    ap.add_argument("--smoke", action="store_true", help="tiny sizes (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_tendons.json"))
    args = ap.parse_args(argv)
    if args.smoke:
        args.rods, args.repeats, args.nodes = 8, 1, 10
    rng = np.random.default_rng(0)
    tau = rng.uniform(0.0, 4.0, (args.rods, 4)) * (rng.random((args.rods, 4)) < 0.5)
    opts = dict(nodes=args.nodes)
    plain, disp, fric = robot(), robot(control="displacement"), robot(friction=0.2)
    t0 = time.perf_counter()
    tau_taut = rng.uniform(0.5, 4.0, (args.rods, 4))
    ref_len = reference_lengths(disp, **opts)
    q = ref_len - tw.solve_static(plain, tau, tendon_states=True, **opts).tendon_free_length
    q_taut = ref_len - tw.solve_static(plain, tau_taut, tendon_states=True, **opts).tendon_free_length
    cases = {"tension": lambda: tw.solve_static(plain, tau, **opts),
             "displacement": lambda: tw.solve_static(disp, displacements=q, **opts),
             "friction": lambda: tw.solve_static(fric, tau, **opts),
             "tension_taut": lambda: tw.solve_static(plain, tau_taut, **opts),
             "displacement_taut": lambda: tw.solve_static(disp, displacements=q_taut, **opts)}
    sols = {name: f() for name, f in cases.items()}  # warm-up: kernels compiled or loaded
    print(f"kernels ready in {time.perf_counter() - t0:.1f} s")
    for name, s in sols.items():
        assert s.converged.all(), (name, s.failure_reasons())
    err = np.abs(sols["displacement"].tip_position - sols["tension"].tip_position).max()
    times, med = interleaved_times(cases, args.repeats)
    iters = {k: float(np.mean(s.iterations)) for k, s in sols.items()}
    shots = {k: float(np.mean(s.integrations)) for k, s in sols.items()}
    base = {k: "tension_taut" if k.endswith("_taut") else "tension" for k in cases}
    ratio = {k: med[k] / med[base[k]] for k in cases}
    for k in cases:
        print(f"{k:18s} {med[k] * 1e3:8.1f} ms per batch of {args.rods}  ({ratio[k]:.2f}x {base[k]})  "
              f"iterations {iters[k]:.1f}  integrations {shots[k]:.1f}")
    print(f"displacement-controlled tips vs tension-controlled: {err:.1e} m")
    print(markdown(med, ratio, iters, shots))
    write_report(args.out,
                 {"meta": metadata("cpu", rods=args.rods, repeats=args.repeats, nodes=args.nodes),
                  "median_s": med, "ratio_to_tension": ratio,
                  "mean_iterations": iters, "mean_integrations": shots, "times_s": times,
                  "displacement_tip_vs_tension_m": err})
    return 0


if __name__ == "__main__":
    sys.exit(main())
