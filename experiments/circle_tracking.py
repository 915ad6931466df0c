"""Tracking a 10 mm circle of the tip at one revolution per second on the report's robot:
our controller (examples/circle_tracking.toml: boundary layer, quasi-static Jacobian input model)
against the report's law on the same trajectory (sgn(S), its alpha input model and gains
C = diag(15000, 1, 500), k = diag(30, 1, 5), eps = 0.005; examples/seed_control.toml), both with
the desired velocity and acceleration in the law, tensions within [0, 8] N.

Metrics per law (tdcr_warp.apps.control.control_metrics): RMS tracking error over the whole run and
the largest error over its second half (after the tip has caught the circle), the lag, the
chatter index, the saturation fraction. Writes the JSON report and docs/figures/circle_tracking.png.

    python experiments/circle_tracking.py [--smoke] [--out results/circle_tracking.json]
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

from tdcr_warp.apps.control import TipController, control_metrics, run_closed_loop  # noqa: E402
from tdcr_warp.io.scene import scene_from_dict  # noqa: E402
from tdcr_warp.model.tippath import path_from_table  # noqa: E402
from tdcr_warp.physics.dynamics import Simulator  # noqa: E402

REPORT = {"method": "smc", "input_model": "alpha", "gain_c": [15000.0, 1.0, 500.0], "gain_k": [30.0, 1.0, 5.0],
          "epsilon": 0.005, "phi": 1e-3, "tension_max": 8.0}


def run(data: dict, law: dict, steps: int) -> tuple[dict, object]:
    sc = scene_from_dict(data)
    spec = sc.dynamics
    sim = Simulator(sc.robot, sc.tensions, dt=spec.dt, alpha=spec.alpha, options=sc.options)
    ctl = TipController(sim, path_from_table(sc.control["path"]), **law)
    r = run_closed_loop(sim, ctl, steps)
    m = control_metrics(r, ctl.tau_max)
    keep = ("rms_error", "max_error", "lag", "chatter", "saturation_fraction", "final_error", "peak_tension")
    return {k: float(m[k][0]) for k in keep} | {"completed": bool(r.converged.all())}, r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="20 steps, no figure")
    ap.add_argument("--out", default=str(ROOT / "results" / "circle_tracking.json"))
    args = ap.parse_args(argv)
    data = tomllib.loads((ROOT / "examples" / "circle_tracking.toml").read_text())
    steps = 20 if args.smoke else data["dynamics"]["steps"]
    ours_law = {k: data["control"][k] for k in ("method", "gain_c", "gain_k", "epsilon", "phi", "tension_max")}
    rows, runs = {}, {}
    for name, law in (("ours", ours_law), ("report", REPORT)):
        rows[name], runs[name] = run(data, law, steps)
        m = rows[name]
        print(f"{name:7s}: RMS {m['rms_error'] * 1e3:7.3f} mm, max over the 2nd half {m['max_error'] * 1e3:7.3f} mm, "
              f"lag {m['lag'] * 1e3:5.1f} ms, chatter {m['chatter']:.2e} N, saturated {100 * m['saturation_fraction']:.0f}% "
              f"of steps")
    if not args.smoke:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), layout="constrained")
        r0 = runs["ours"]
        axes[0].plot(r0.desired[:, 0, 0] * 1e3, r0.desired[:, 0, 1] * 1e3, "k--", lw=1, label="desired")
        for name, r in runs.items():
            axes[0].plot(r.tip_position[:, 0, 0] * 1e3, r.tip_position[:, 0, 1] * 1e3, lw=1, label=f"{name} law")
            axes[1].semilogy(r.time, np.linalg.norm(r.error[:, 0], axis=1) * 1e3 + 1e-6, lw=1, label=f"{name} law")
        axes[0].set_aspect("equal", adjustable="datalim")
        axes[0].set_xlabel("x [mm]")
        axes[0].set_ylabel("y [mm]")
        axes[0].set_title("tip path (10 mm circle, 1 rev/s)")
        axes[0].legend(fontsize=8)
        axes[1].set_xlabel("t [s]")
        axes[1].set_ylabel("|desired - tip| [mm]")
        axes[1].set_title("tracking error")
        axes[1].legend(fontsize=8)
        for ax in axes:
            ax.grid(True, alpha=0.3)
        fig.savefig(ROOT / "docs" / "figures" / "circle_tracking.png", dpi=110)
        plt.close(fig)
    write_report(args.out, {"meta": metadata("cpu", steps=steps), "laws": {"ours": ours_law, "report": REPORT},
                            "results": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
