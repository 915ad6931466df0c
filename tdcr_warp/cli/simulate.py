"""``tdcr-warp simulate SCENE.toml``: the dynamics of a scene's [dynamics] table; results.json,
trajectory.npz, the tip figures and (--animate, --html) robot.gif and robot.html."""

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
    add_no_figures_argument,
    add_solver_arguments,
    apply_overrides,
    load_kernels,
    print_rods,
    settings,
    write_arrays,
    write_json,
    write_rod_table,
)
from tdcr_warp.model.robot import InputError

ROD_TABLE = "rods.parquet"
FILES = ("results.json", "trajectory.npz", ROD_TABLE, "tip_position.png", "tip_rates.png", "robot.gif", "robot.html")


def register(subparsers) -> None:
    p = add_command(subparsers, "simulate", "run the dynamics of a scene ([dynamics] table)", run)
    add_solver_arguments(p)
    add_run_arguments(p)
    add_html_argument(p, animated=True)
    add_no_figures_argument(p)
    add_log_arguments(p)


def run(args) -> int:
    from tdcr_warp.io.scene import load_scene

    scene = apply_overrides(load_scene(args.scene), args, dynamic=True)
    spec = scene.dynamics
    if spec is None:
        raise InputError(f"{args.scene}: simulate needs a [dynamics] table (dt, steps, ...)")
    steps = spec.steps if args.steps is None else args.steps
    if steps > spec.steps:
        raise InputError(f"--steps {steps} exceeds the scene's [dynamics].steps = {spec.steps}")
    check_shapes(args, spec)
    with OutputRun(args, Path("out") / Path(args.scene).stem, FILES) as out:
        return _run(args, scene, spec, steps, out)


def _run(args, scene, spec, steps: int, out: OutputRun) -> int:
    """Simulate, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.physics.dynamics import Simulator

    load_s = load_kernels(scene, args, dynamic=True)
    t0 = time.perf_counter()
    sim = Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options,
                    device=args.device)
    t1 = time.perf_counter()
    traj = sim.simulate(spec.schedule[:, :steps], steps, shapes_every=spec.shapes_every,
                        progress=not args.quiet)
    wall, stepping = time.perf_counter() - t0, time.perf_counter() - t1
    B = sim.B
    ok = traj.failed_step < 0
    print(f"simulated {B} rod(s) x {steps} steps of {spec.dt} s in {stepping:.2f} s "
          f"({B * steps / stepping:,.0f} rod-steps/s, real-time factor {steps * spec.dt / stepping:.2f} per batch; "
          f"kernel loading and the {t1 - t0:.2f} s static start excluded)")
    reasons = ["ok" if f < 0 else f"failed at step {f + 1}" for f in traj.failed_step]
    print_rods(traj.tip_position[-1], ok, traj.iterations.max(axis=0), traj.residual[-1], reasons)
    files = {"trajectory.npz": write_arrays(out / "trajectory.npz", traj)}
    failed_step = np.where(traj.failed_step >= 0, traj.failed_step + 1, 0)  # 1-based, 0: none
    if B > JSON_RODS:
        files[ROD_TABLE] = write_rod_table(out / ROD_TABLE, "simulate", {"completed": ok, "failed_step": failed_step},
                                           {"final_tip_position": traj.tip_position[-1],
                                            "max_iterations": traj.iterations.max(axis=0)})
    if not args.no_figures:
        from tdcr_warp.io.plotting import plot_tip_history
        plot_tip_history(traj.time, traj.tip_position, traj.tip_velocity, traj.tip_acceleration, out)
    drawn = drawings(args, scene, traj, sim.grid, out)
    results = {
        "scene": str(args.scene), "settings": settings(scene, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": steps},
        "batch_size": B, "wall_time_s": wall, "stepping_s": stepping, "kernel_load_s": load_s,
        "completed_rods": int(ok.sum()), "failed_rods": int((~ok).sum()), "files": files,
    }
    if B <= JSON_RODS:
        results |= {"final_tip_position": traj.tip_position[-1].tolist(), "completed": ok.tolist(),
                    "failed_step": [int(f) if f else None for f in failed_step],
                    "max_iterations": traj.iterations.max(axis=0).tolist()}
    write_json(out / "results.json", results)
    out.commit()
    print(f"wrote {out}/results.json, {', '.join(files)}{'' if args.no_figures else ', tip_position.png, tip_rates.png'}")
    for note in drawn:
        print(f"wrote {out}/{note}")
    if not ok.all():
        print(f"{int((~ok).sum())} of {B} rods failed and were frozen (failed_step in "
              f"{'results.json' if B <= JSON_RODS else ROD_TABLE})", file=sys.stderr)
        return 1
    return 0
