"""The tip controller commanding motor displacements (what hardware accepts) against the same
controller commanding tensions, on the report's robot (examples/displacement_control.toml:
four elastic wires with 1 N of pretension at the zero of their motors, +-5 mm of travel, 8 N
of tension at most).

Two tasks: the step to the static tip of target_displacements (tendon 1 pulled 1.5 mm, tendon 3
released 1.5 mm: it goes slack) over 1 s, and a 10 mm circle of the tip around that point at one
revolution per second over 2 s. Each under the boundary-layer and the integral law, commanding
displacements on the scene's robot and tensions on the same robot with tension-controlled
tendons (the tension command sees no wire stretch). Reports per run: RMS error over the run and
largest error over its second half (3-D, and across the base axis, the axes a displacement
command tracks), settling time, peak tension, the fraction of steps with a slack tendon, chatter
and wall time; writes the JSON report and docs/figures/displacement_control.png (desired
against actual tip paths).

    python experiments/displacement_control.py [--smoke] [--out results/displacement_control.json]
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

from tdcr_warp.apps.control import control_metrics, run_closed_loop  # noqa: E402
from tdcr_warp.apps.jobs import scene_controller, scene_simulator  # noqa: E402
from tdcr_warp.io.scene import scene_from_dict  # noqa: E402
from tdcr_warp.physics.statics import solve_static  # noqa: E402


def scenes(smoke: bool) -> dict[str, dict]:
    """The scene dicts of every run: (task, command, method)."""
    base = tomllib.loads((ROOT / "examples" / "displacement_control.toml").read_text())
    tension = {k: v for k, v in base.items()}
    tension["tendons"] = [{"offset": t["offset"]} for t in base["tendons"]]
    tension["actuation"] = {"tensions": [[1.0] * 4]}  # the pretension, the start of both
    sc = scene_from_dict({k: v for k, v in base.items() if k != "control"})
    centre = solve_static(sc.robot, np.zeros((1, 4)), displacements=base["control"]["target_displacements"],
                          options=sc.options).tip_position[0]
    out = {}
    for task in ("step", "circle"):
        for command, data in (("displacement", base), ("tension", tension)):
            for method in ("boundary_layer", "integral"):
                d = dict(data)
                ctl = {k: v for k, v in base["control"].items() if k not in ("target_displacements", "command",
                                                                             "displacement_range")}
                ctl["method"] = method
                if command == "displacement":
                    ctl |= {"command": "displacement", "displacement_range": base["control"]["displacement_range"]}
                if task == "step":
                    ctl["target"] = centre.tolist()
                else:
                    ctl["path"] = {"shape": "circle", "centre": centre.tolist(), "radius": 0.01, "frequency": 1.0}
                steps = 20 if smoke else (200 if task == "step" else 400)
                d["control"], d["dynamics"] = ctl, dict(base["dynamics"], steps=steps)
                out[f"{task}/{command}/{method}"] = d
    return out


def measure(data: dict) -> tuple[dict, object]:
    sc = scene_from_dict(data)
    t0 = time.perf_counter()
    sim = scene_simulator(sc)
    ctl = scene_controller(sc, sim)
    run = run_closed_loop(sim, ctl, sc.dynamics.steps)
    wall = time.perf_counter() - t0
    m = control_metrics(run, ctl.tau_max)
    T = len(run.time) - 1
    lateral = np.linalg.norm(run.error[..., :2], axis=2)[:, 0]
    row = {k: float(m[k][0]) for k in ("rms_error", "max_error", "settling_time", "peak_tension", "chatter")}
    row |= {"lateral_rms_error": float(np.sqrt((lateral[1:] ** 2).mean())),
            "lateral_max_error": float(lateral[T // 2:].max()),
            "slack_fraction": float((run.tensions[:, 0] <= 0).any(axis=1).mean()),
            "completed": bool((sim.failed_step < 0).all()), "wall_s": wall}
    return row, run


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="20 steps a run, no figure")
    ap.add_argument("--out", default=str(ROOT / "results" / "displacement_control.json"))
    args = ap.parse_args(argv)
    rows, runs = {}, {}
    print(f"{'run':36s} {'RMS':>7s} {'max 2nd':>8s} {'lat RMS':>8s} {'lat max':>8s} {'settle':>7s} {'peak':>6s} "
          f"{'slack':>6s} {'wall':>6s}")
    print(f"{'':36s} {'[mm]':>7s} {'[mm]':>8s} {'[mm]':>8s} {'[mm]':>8s} {'[s]':>7s} {'[N]':>6s} {'[%]':>6s} {'[s]':>6s}")
    for name, data in scenes(args.smoke).items():
        rows[name], runs[name] = measure(data)
        r = rows[name]
        print(f"{name:36s} {r['rms_error'] * 1e3:7.3f} {r['max_error'] * 1e3:8.3f} {r['lateral_rms_error'] * 1e3:8.3f} "
              f"{r['lateral_max_error'] * 1e3:8.3f} {r['settling_time']:7.3f} {r['peak_tension']:6.2f} "
              f"{100 * r['slack_fraction']:6.1f} {r['wall_s']:6.2f}")
    if not args.smoke:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), layout="constrained")
        ref = runs["circle/displacement/integral"]
        axes[0].plot(ref.desired[:, 0, 0] * 1e3, ref.desired[:, 0, 1] * 1e3, "k--", lw=1, label="desired")
        for name in ("circle/displacement/boundary_layer", "circle/displacement/integral", "circle/tension/integral"):
            r = runs[name]
            axes[0].plot(r.tip_position[:, 0, 0] * 1e3, r.tip_position[:, 0, 1] * 1e3, lw=1, label=name[7:])
        for name in ("step/displacement/boundary_layer", "step/displacement/integral", "step/tension/integral"):
            r = runs[name]
            axes[1].semilogy(r.time, np.linalg.norm(r.error[:, 0], axis=1) * 1e3 + 1e-6, lw=1, label=name[5:])
        r = runs["step/displacement/integral"]
        for k in range(r.displacements.shape[2]):
            axes[2].plot(r.time[1:], r.displacements[:, 0, k] * 1e3, lw=1, label=f"tendon {k + 1}")
        axes[0].set_aspect("equal", adjustable="datalim")
        axes[0].set(xlabel="x [mm]", ylabel="y [mm]", title="tip path: 10 mm circle, 1 rev/s")
        axes[1].set(xlabel="t [s]", ylabel="|desired - tip| [mm]", title="step to the static tip")
        axes[2].set(xlabel="t [s]", ylabel="motor displacement [mm] (pull +)", title="the step's commands (integral)")
        for ax in axes:
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
        fig.savefig(ROOT / "docs" / "figures" / "displacement_control.png", dpi=110)
        plt.close(fig)
    write_report(args.out, {"meta": metadata("cpu", smoke=args.smoke), "results": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
