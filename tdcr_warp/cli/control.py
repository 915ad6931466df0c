"""``tdcr-warp control SCENE.toml``: sliding-mode tip control of a scene's [dynamics] and
[control] tables; metrics.json, control.npz, the control figures and (--animate, --html)
robot.gif and robot.html."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from tdcr_warp.cli.animation import add_run_arguments, check_shapes, drawings
from tdcr_warp.cli.common import (
    JSON_RODS,
    OutputRun,
    add_command,
    add_html_argument,
    add_log_arguments,
    add_solver_arguments,
    apply_overrides,
    settings,
    write_arrays,
    write_json,
    write_rod_table,
)
from tdcr_warp.model.robot import InputError

METRIC_TABLE = "metrics.parquet"
FILES = ("metrics.json", "control.npz", METRIC_TABLE, "control_tip.png", "control_tension.png", "control_error_phase.png",
         "robot.gif", "robot.html")


def register(subparsers) -> None:
    p = add_command(subparsers, "control", "sliding-mode tip control ([dynamics] and [control] tables)", run)
    add_solver_arguments(p)
    add_run_arguments(p)
    add_html_argument(p, animated=True)
    add_log_arguments(p)


def run(args) -> int:
    from tdcr_warp.io.scene import load_scene

    scene = apply_overrides(load_scene(args.scene), args, dynamic=True)
    spec, ctl = scene.dynamics, scene.control
    if spec is None or ctl is None:
        raise InputError(f"{args.scene}: control needs [dynamics] and [control] tables")
    steps = spec.steps if args.steps is None else args.steps
    check_shapes(args, spec)
    with OutputRun(args, Path("out") / Path(args.scene).stem, FILES) as out:
        return _run(args, scene, spec, steps, out)


def _run(args, scene, spec, steps: int, out: OutputRun) -> int:
    """Run the closed loops, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.apps.control import METRIC_UNITS, control_metrics, run_closed_loop
    from tdcr_warp.apps.jobs import scene_controller, scene_simulator
    from tdcr_warp.io.plotting import plot_control

    t0 = time.perf_counter()
    sim = scene_simulator(scene, args.device)
    controller = scene_controller(scene, sim, device=args.device)
    loop = run_closed_loop(sim, controller, steps, progress=not args.quiet, shapes_every=spec.shapes_every)
    wall = time.perf_counter() - t0
    metrics = control_metrics(loop, controller.tau_max)
    B = sim.B
    print(f"controlled {B} rod(s) x {steps} steps in {wall:.2f} s ({controller.method}, "
          f"{controller.input_model} input model)")
    for b in range(min(B, 10)):
        print(f"  rod {b}: final error {metrics['final_error'][b] * 1e3:.3f} mm, settling "
              f"{metrics['settling_time'][b]:.3f} s, chatter {metrics['chatter'][b]:.2e} N, "
              f"mean tension {np.round(metrics['mean_tension'][b], 3).tolist()} N")
    files = {"control.npz": write_arrays(out / "control.npz", loop)}
    completed = sim.failed_step < 0
    if B > JSON_RODS:
        files[METRIC_TABLE] = write_rod_table(out / METRIC_TABLE, "control", {"completed": completed},
                                              {"target": np.broadcast_to(controller.target, (B, 3))} | metrics)
    plot_control(loop, out, tension_max=controller.tau_max, gain_c=controller.C)
    drawn = drawings(args, scene, loop, sim.grid, out)
    results = {
        "scene": str(args.scene), "settings": settings(scene, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": steps, "method": controller.method,
           "input_model": controller.input_model, "command": controller.command},
        "batch_size": B, "wall_time_s": wall, "completed_rods": int(completed.sum()),
        "failed_rods": int((~completed).sum()), "files": files, "units": {k: METRIC_UNITS[k] for k in metrics},
    }
    if B <= JSON_RODS:
        results |= {"target": controller.target.tolist(), "completed": completed.tolist(),
                    "metrics": {k: np.where(np.isfinite(v), v, -1.0).tolist() for k, v in metrics.items()},
                    "metrics_note": "settling_time -1 means the tip never stayed inside the 0.5 mm band"}
    write_json(out / "metrics.json", results)
    out.commit()
    print(f"wrote {out}/metrics.json, {', '.join(files)}, control_tip.png, control_tension.png, "
          "control_error_phase.png")
    for note in drawn:
        print(f"wrote {out}/{note}")
    if (sim.failed_step >= 0).any():
        print(f"{int((sim.failed_step >= 0).sum())} of {B} rods failed and were frozen", file=sys.stderr)
        return 1
    return 0
