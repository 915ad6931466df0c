"""A pull-release cycle of a displacement-driven tendon with capstan friction (quasi-static,
each step from the last: stick and slip along the tendon tracked by tdcr_warp.solve_static's
``history``), with mu = 0 beside it: tip position and motor tension against motor
displacement, and the energy friction dissipated over the cycle (the loop integral of
tau(0) dq). Writes docs/figures/hysteresis.png, results/hysteresis.json and results/hysteresis.csv
(pandas-readable: one row per step and mu).

    python experiments/hysteresis.py [--steps 20] [--mu 0.3] [--qmax 0.004] [--smoke] [--out results/hysteresis.json]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402


def cycle(mu: float, q: np.ndarray, nodes: int):
    """Solve the cycle q[0], q[1], ... each from the last; returns tips (n, 3), motor and tip
    tensions (n,), the slip state along the tendon (n, N+1) and the dissipated energy [J]."""
    rb = tw.Robot(density=7800.0, gravity=(0, 0, -9.81),
                  tendons=[tw.Tendon(offset=(0.0, 0.01), control="displacement", friction=mu, pretension=0.2,
                                     compliance=2.7e-5)])
    sol, tips, t_base, t_end, states = None, [], [], [], []
    for qi in q:
        sol = tw.solve_static(rb, displacements=[qi], history=sol, nodes=nodes)
        if not sol.converged.all():
            raise RuntimeError(f"mu = {mu}, q = {qi}: {sol.failure_reasons()[0]}")
        tips.append(sol.tip_position[0])
        t_base.append(sol.tendon_tension_base[0, 0])
        t_end.append(sol.tendon_tension_end[0, 0])
        states.append(sol.slip_state[0, :, 0] if sol.slip_state is not None else np.zeros(sol.s.shape[1]))
    t_base = np.array(t_base)
    work = float(np.sum(0.5 * (t_base[1:] + t_base[:-1]) * np.diff(q)))
    return np.array(tips), t_base, np.array(t_end), np.array(states), work


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20, help="steps each way")
    ap.add_argument("--mu", type=float, default=0.3)
    ap.add_argument("--qmax", type=float, default=0.004, help="largest motor displacement [m]")
    ap.add_argument("--nodes", type=int, default=40)
    ap.add_argument("--no-figure", action="store_true")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, no figure or CSV (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "hysteresis.json"))
    args = ap.parse_args(argv)
    if args.smoke:
        args.steps, args.nodes, args.no_figure = 2, 10, True
    q = np.r_[np.linspace(0.0, args.qmax, args.steps + 1), np.linspace(args.qmax, 0.0, args.steps + 1)[1:]]
    t0 = time.perf_counter()
    runs = {mu: cycle(mu, q, args.nodes) for mu in (0.0, args.mu)}
    wall = time.perf_counter() - t0
    out_csv = Path(args.out).with_suffix(".csv")
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    with open(out_csv, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["mu", "step", "q_m", "tip_x_m", "tip_y_m", "tip_z_m", "tension_motor_N", "tension_tip_N"])
        for mu, (tips, tb, te, _, _) in runs.items():
            for i in range(len(q)):
                w.writerow([mu, i, q[i], *tips[i], tb[i], te[i]])
    print(f"wrote {out_csv}")
    for mu, (_, tb, te, st, work) in runs.items():
        print(f"mu = {mu}: dissipated {work * 1e3:.4f} mJ over the cycle; motor tension at q_max "
              f"{tb[args.steps]:.3f} N, tip tension {te[args.steps]:.3f} N")
    print(f"{2 * len(q)} solves in {wall:.2f} s")
    report = {"meta": metadata("cpu"), "q_m": q.tolist(), "wall_s": wall,
              "dissipated_J": {str(mu): r[4] for mu, r in runs.items()}}
    write_report(args.out, report)
    if not args.no_figure:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for mu, (tips, tb, _, _, work) in runs.items():
            ax[0].plot(q * 1e3, tips[:, 1] * 1e3, "o-" if mu else "--", ms=3, label=f"mu = {mu}")
            lost_mj = round(work * 1e3, 2) + 0.0  # + 0.0: a round-off loss of -0.0004 mJ shows as 0.00
            ax[1].plot(q * 1e3, tb, "o-" if mu else "--", ms=3, label=f"mu = {mu} ({lost_mj:.2f} mJ lost)")
        ax[0].set(xlabel="motor displacement q [mm]", ylabel="tip deflection y [mm]", title="tip vs motor")
        ax[1].set(xlabel="motor displacement q [mm]", ylabel="motor tension [N]", title="tension vs motor")
        for a in ax:
            a.legend()
            a.grid(alpha=0.3)
        fig.tight_layout()
        path = ROOT / "docs" / "figures" / "hysteresis.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
