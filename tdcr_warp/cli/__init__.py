"""Command line: ``tdcr-warp static|simulate|control|ik SCENE.toml``, the sweeps
``tdcr-warp montecarlo|workspace|gain-grid SCENE.toml``, the gain search
``tdcr-warp search SCENE.toml`` and measured robots ``tdcr-warp fit|predict SCENE.toml DATA.csv``.

Exit status: 0 every rod converged; 1 some rods failed (outputs written, reasons recorded);
2 bad input (the message names the field and the value, no traceback); 130 interrupted (Ctrl-C:
one line on stderr, and no completion file: results.json, metrics.json, ik.json, fit.json).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from tdcr_warp.core.progress import Progress
from tdcr_warp.kernels.rod import MODELS
from tdcr_warp.kernels.shooting import INTEGRATORS
from tdcr_warp.model.robot import InputError


def _write_atomic(path: Path, write) -> None:
    """Write through a temporary file in the same directory, then rename."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _write_npz(path: Path, save) -> None:
    """``save(file)`` writes an .npz into an open binary file (np.savez would rename a path)."""
    def write(tmp):
        with open(tmp, "wb") as f:
            save(f)
    _write_atomic(path, write)


def _out_dir(args, default: Path, *complete: str) -> Path:
    """The output directory (created), without the files ``complete`` of an earlier run (the
    command writes them last: their presence means a run is complete, so an interrupted run
    leaves none beside its partial outputs); an unusable one is an InputError naming --out."""
    out = Path(args.out) if args.out else default
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {str(out)!r}: cannot create the output directory: {e.strerror or e}") from None
    for name in complete:
        (out / name).unlink(missing_ok=True)
    return out


def _strict(obj):
    """obj with every non-finite float as None (null): strict JSON has no NaN or Infinity."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_strict(v) for v in obj]
    return obj


def _write_json(path: Path, obj) -> None:
    """Strict JSON (a non-finite number is null), written atomically."""
    def write(tmp):
        with open(tmp, "w") as f:
            json.dump(_strict(obj), f, indent=1, allow_nan=False)
    _write_atomic(path, write)


def _settings(scene, args, device) -> dict:
    """The StaticOptions fields (``tol`` as the tolerance used, ``tolerance_m``), the device
    actually used, the tdcr-warp and Warp versions and the scene file's text (docs/outputs.md)."""
    import warp as wp

    from tdcr_warp import __version__
    out = asdict(scene.options)
    out.pop("tol", None)  # None means the precision's default: tolerance_m is the value used
    try:
        dev = str(wp.get_device(None if device in (None, "default") else device))
    except (RuntimeError, ValueError):
        dev = str(device)
    out.update(device=dev, tolerance_m=scene.options.tolerance, tdcr_warp=__version__, warp=wp.__version__,
               scene_text=scene.text)
    return out


def _apply_overrides(scene, args):
    over = {k: getattr(args, k) for k in ("nodes", "integrator", "model", "precision")
            if getattr(args, k) is not None}
    return replace(scene, options=replace(scene.options, **over)) if over else scene


def _print_rods(tips, ok, iters, resid, reasons, limit: int = 10) -> None:
    for b in range(min(len(tips), limit)):
        t = tips[b]
        state = "ok" if ok[b] else f"FAILED ({reasons[b]})"
        print(f"  rod {b}: tip [{t[0]: .6f} {t[1]: .6f} {t[2]: .6f}] m  iterations {iters[b]:3d}  "
              f"residual {resid[b]:.1e} m  {state}")
    if len(tips) > limit:
        print(f"  ... {len(tips) - limit} more rods")


def _load_kernels(scene, args, dynamic: bool = False) -> float:
    """Load (or compile, on first use) the scene's kernels before the timed run, so that its rate
    excludes them; a compile says so on stderr (tdcr_warp.core.solver.set_compile_notice)."""
    from tdcr_warp.core.solver import load_kernels

    return load_kernels(scene.robot, scene.options, args.device, dynamic=dynamic)


def cmd_static(args) -> int:
    from tdcr_warp.io.scene import load_scene
    from tdcr_warp.model.options import failure_reasons
    from tdcr_warp.physics.statics import solve_static

    scene = _apply_overrides(load_scene(args.scene), args)
    out = _out_dir(args, Path("out") / Path(args.scene).stem, "results.json")
    load_s = _load_kernels(scene, args)
    t0 = time.perf_counter()
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=args.device,
                       **scene.static_command())
    wall = time.perf_counter() - t0
    B = len(sol.converged)
    reasons = sol.failure_reasons()
    print(f"solved {B} rod(s) in {wall:.3f} s ({B / wall:,.0f} rods/s, kernel loading excluded; "
          f"{scene.options.integrator}, N = {scene.options.nodes}, {scene.options.model}, {scene.options.precision})")
    _print_rods(sol.tip_position, sol.converged, sol.iterations, sol.residual, reasons)
    _write_npz(out / "shapes.npz", sol.to_npz)
    if not args.no_figures:
        from tdcr_warp.io.drawing import robot_geometry
        from tdcr_warp.io.plotting import MAX_RODS_DRAWN, plot_robot
        n = min(B, MAX_RODS_DRAWN)
        geom = robot_geometry(scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
                              scene.display)
        plot_robot(geom, out / "shapes.png", converged=sol.converged[:n])
    if args.html:
        _html_static(scene, sol, out)
    results = {
        "scene": str(args.scene), "settings": _settings(scene, args, args.device or "default"),
        "batch_size": B, "wall_time_s": wall, "kernel_load_s": load_s,
        "tip_position": sol.tip_position.tolist(), "converged": sol.converged.tolist(),
        "iterations": sol.iterations.tolist(), "residual": sol.residual.tolist(),
        "rods": [{"tip_position": sol.tip_position[b].tolist(), "tip_rotation": sol.tip_rotation[b].tolist(),
                  "converged": bool(sol.converged[b]), "status": reasons[b],
                  "iterations": int(sol.iterations[b]), "residual": float(sol.residual[b]),
                  "orthogonality_error": float(sol.orthogonality_error[b]), "tendons": _tendon_rows(sol, b)}
                 | _sensitivity_row(sol, b) for b in range(B)],
    }
    _write_json(out / "results.json", results)  # last: its presence means the run is complete
    print(f"wrote {out}/results.json, shapes.npz{'' if args.no_figures else ', shapes.png'}")
    failed = int((~sol.converged).sum())
    if failed:
        why = ", ".join(f"{n} x {reason}" for reason, n in failure_reasons(sol.status, sol.converged).items())
        print(f"tdcr-warp: {failed} of {B} rods did not converge: {why} (per rod in results.json)",
              file=sys.stderr)
        return 1
    return 0


def _sensitivity_row(sol, b: int) -> dict:
    """Rod b's stability verdict and (with sensitivities) its tip Jacobian and compliance."""
    row = {}
    if sol.stability_index is not None:
        row |= {"stability_index": int(sol.stability_index[b]), "stable": bool(sol.stable[b])}
        if sol.branch is not None:
            row |= {"branch": int(sol.branch[b]), "multiple_stable": bool(sol.multiple_stable[b])}
    if sol.tip_jacobian is not None:
        row |= {"tip_jacobian": sol.tip_jacobian[b].tolist(), "tip_compliance": sol.tip_compliance[b].tolist()}
    return row


def _tendon_rows(sol, b: int) -> list[dict]:
    """Per tendon of rod b: tensions at the motor and the end [N]; with tendon states also the
    path length and unstretched length [m], turning [rad], slack; with friction the slip used."""
    rows = []
    for k in range(sol.tendon_tension_base.shape[1]):
        row = {"tension_base": float(sol.tendon_tension_base[b, k]), "tension_end": float(sol.tendon_tension_end[b, k])}
        if sol.tendon_path_length is not None:
            row |= {"path_length": float(sol.tendon_path_length[b, k]),
                    "free_length": float(sol.tendon_free_length[b, k]), "slack": bool(sol.slack[b, k])}
        if sol.slip is not None:
            row |= {"turning": float(sol.tendon_turning[b, k]), "slip": float(sol.slip[b, k])}
        rows.append(row)
    return rows


def cmd_simulate(args) -> int:
    from tdcr_warp.io.scene import load_scene
    from tdcr_warp.physics.dynamics import Simulator

    scene = _apply_overrides(load_scene(args.scene), args)
    spec = scene.dynamics
    if spec is None:
        raise InputError(f"{args.scene}: simulate needs a [dynamics] table (dt, steps, ...)")
    steps = spec.steps if args.steps is None else args.steps
    if steps > spec.steps:
        raise InputError(f"--steps {steps} exceeds the scene's [dynamics].steps = {spec.steps}")
    _check_shapes(args, spec)
    out = _out_dir(args, Path("out") / Path(args.scene).stem, "results.json")
    load_s = _load_kernels(scene, args, dynamic=True)
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
    _print_rods(traj.tip_position[-1], ok, traj.iterations.max(axis=0), traj.residual[-1], reasons)
    _write_npz(out / "trajectory.npz", traj.to_npz)
    if not args.no_figures:
        from tdcr_warp.io.plotting import plot_tip_history
        plot_tip_history(traj.time, traj.tip_position, traj.tip_velocity, traj.tip_acceleration, out)
    if args.animate:
        _animate(scene, traj, sim.grid, out)
    if args.html:
        _html_run(scene, traj, sim.grid, out)
    results = {
        "scene": str(args.scene), "settings": _settings(scene, args, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": steps},
        "batch_size": B, "wall_time_s": wall, "stepping_s": stepping, "kernel_load_s": load_s,
        "final_tip_position": traj.tip_position[-1].tolist(), "completed": ok.tolist(),
        "failed_step": [int(f) + 1 if f >= 0 else None for f in traj.failed_step],
        "max_iterations": traj.iterations.max(axis=0).tolist(),
    }
    _write_json(out / "results.json", results)
    print(f"wrote {out}/results.json, trajectory.npz{'' if args.no_figures else ', tip_position.png, tip_rates.png'}")
    if not ok.all():
        print(f"{int((~ok).sum())} of {B} rods failed and were frozen (failed_step in results.json)",
              file=sys.stderr)
        return 1
    return 0


def _check_shapes(args, spec) -> None:
    """--animate and --html need stored shapes: refuse before the run when the scene stores none."""
    if getattr(args, "animate", False) and not spec.shapes_every:
        raise InputError("--animate: the run stores no shapes: set [dynamics].shapes_every (e.g. 5)")
    if getattr(args, "html", False) and not spec.shapes_every:
        raise InputError("--html: the run stores no shapes: set [dynamics].shapes_every (e.g. 5)")


def _html_static(scene, sol, out: Path) -> None:
    """robot.html: the interactive viewer of the first solved rods (tdcr_warp.io.viewer)."""
    from tdcr_warp.io.viewer import MAX_RODS, write_viewer

    n = min(len(sol.converged), MAX_RODS)
    names = [f"rod {b}" + ("" if sol.converged[b] else " (not converged)") for b in range(n)]
    _write_atomic(out / "robot.html", lambda tmp: write_viewer(
        tmp, scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
        display=scene.display, names=names))
    print(f"wrote {out}/robot.html ({n} rod{'s' * (n > 1)})")


def _html_run(scene, run, grid: np.ndarray, out: Path) -> None:
    """robot.html: the interactive viewer of a trajectory or closed-loop run from its stored shapes."""
    from tdcr_warp.io.viewer import write_run_viewer

    drawn = []
    _write_atomic(out / "robot.html", lambda tmp: drawn.append(write_run_viewer(
        tmp, scene.robot, run, grid, scene.tensions, display=scene.display)))
    print(f"wrote {out}/robot.html ({drawn[0]} frames)")


def _animate(scene, run, grid: np.ndarray, out: Path) -> None:
    """robot.gif of a trajectory or closed-loop run from its stored shapes (tdcr_warp.io.plotting)."""
    from tdcr_warp.io.drawing import robot_geometry
    from tdcr_warp.io.plotting import MAX_ROBOTS_DRAWN, animate_robot

    n = min(run.positions.shape[1], MAX_ROBOTS_DRAWN)
    tau = np.concatenate([scene.tensions[None, :n] if scene.tensions.shape[0] > 1 else
                          np.broadcast_to(scene.tensions, (1, n, scene.tensions.shape[1])), run.tensions[:, :n]])
    frames = [robot_geometry(scene.robot, run.positions[i, :n], run.rotations[i, :n], grid[:n], tau[step],
                             scene.display) for i, step in enumerate(run.shape_steps)]
    drawn = animate_robot(frames, run.time[run.shape_steps], out / "robot.gif")
    print(f"wrote {out}/robot.gif ({drawn} frames)")


def cmd_control(args) -> int:
    from tdcr_warp.apps.control import METRIC_UNITS, control_metrics, run_closed_loop
    from tdcr_warp.apps.jobs import scene_controller, scene_simulator
    from tdcr_warp.io.plotting import plot_control
    from tdcr_warp.io.scene import load_scene

    scene = _apply_overrides(load_scene(args.scene), args)
    spec, ctl = scene.dynamics, scene.control
    if spec is None or ctl is None:
        raise InputError(f"{args.scene}: control needs [dynamics] and [control] tables")
    steps = spec.steps if args.steps is None else args.steps
    _check_shapes(args, spec)
    out = _out_dir(args, Path("out") / Path(args.scene).stem, "metrics.json")
    t0 = time.perf_counter()
    sim = scene_simulator(scene, args.device)
    controller = scene_controller(scene, sim, device=args.device)
    run = run_closed_loop(sim, controller, steps, progress=not args.quiet, shapes_every=spec.shapes_every)
    wall = time.perf_counter() - t0
    metrics = control_metrics(run, controller.tau_max)
    B = sim.B
    print(f"controlled {B} rod(s) x {steps} steps in {wall:.2f} s ({controller.method}, "
          f"{controller.input_model} input model)")
    for b in range(min(B, 10)):
        print(f"  rod {b}: final error {metrics['final_error'][b] * 1e3:.3f} mm, settling "
              f"{metrics['settling_time'][b]:.3f} s, chatter {metrics['chatter'][b]:.2e} N, "
              f"mean tension {np.round(metrics['mean_tension'][b], 3).tolist()} N")
    _write_npz(out / "control.npz", run.to_npz)
    plot_control(run, out, tension_max=controller.tau_max, gain_c=controller.C)
    if args.animate:
        _animate(scene, run, sim.grid, out)
    if args.html:
        _html_run(scene, run, sim.grid, out)
    results = {
        "scene": str(args.scene), "settings": _settings(scene, args, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": steps, "method": controller.method,
           "input_model": controller.input_model, "command": controller.command},
        "batch_size": B, "wall_time_s": wall, "target": controller.target.tolist(),
        "completed": (sim.failed_step < 0).tolist(),
        "metrics": {k: np.where(np.isfinite(v), v, -1.0).tolist() for k, v in metrics.items()},
        "units": {k: METRIC_UNITS[k] for k in metrics},
        "metrics_note": "settling_time -1 means the tip never stayed inside the 0.5 mm band",
    }
    _write_json(out / "metrics.json", results)
    print(f"wrote {out}/metrics.json, control.npz, control_tip.png, control_tension.png, control_error_phase.png")
    if (sim.failed_step >= 0).any():
        print(f"{int((sim.failed_step >= 0).sum())} of {B} rods failed and were frozen", file=sys.stderr)
        return 1
    return 0


def cmd_ik(args) -> int:
    """Inverse kinematics of the scene's [ik] targets (tdcr_warp.apps.ik)."""
    from tdcr_warp.apps.ik import solve_ik
    from tdcr_warp.io.scene import load_scene

    scene = _apply_overrides(load_scene(args.scene), args)
    ik = scene.ik
    if ik is None:
        raise InputError(f"{args.scene}: ik needs an [ik] table (targets = [[x, y, z], ...] in m)")
    out = _out_dir(args, Path("out") / Path(args.scene).stem, "ik.json")
    load_s = _load_kernels(replace(scene, options=replace(scene.options, sensitivities=True)), args)
    t0 = time.perf_counter()
    kw = {k: ik[k] for k in ("tension_max", "displacement_range", "tol", "max_iter") if k in ik}
    res = solve_ik(scene.robot, ik["targets"], target_rotation=ik.get("target_rotations"), options=scene.options,
                   device=args.device, **kw)
    wall = time.perf_counter() - t0
    B = len(res.success)
    print(f"inverse kinematics of {B} target(s) in {wall:.3f} s ({B / wall:,.0f} targets/s, kernel loading excluded)")
    for b in range(min(B, 10)):
        print(f"  rod {b}: command {np.round(res.command[b], 6).tolist()}  error {res.position_error[b]:.2e} m  "
              f"{res.reason[b]} ({res.iterations[b]} iterations)")
    if B > 10:
        print(f"  ... {B - 10} more rods")
    _write_npz(out / "ik.npz", res.to_npz)
    targets = np.broadcast_to(np.array(ik["targets"], dtype=np.float64), (B, 3))
    results = {"scene": str(args.scene), "settings": _settings(scene, args, args.device or "default"),
               "batch_size": B, "wall_time_s": wall, "kernel_load_s": load_s,
               "command_units": ["N" if t.control == "tension" else "m" for t in scene.robot.tendons],
               "rods": [{"target": targets[b].tolist(), "command": res.command[b].tolist(),
                         "tip_position": res.tip_position[b].tolist(),
                         "position_error_m": float(res.position_error[b]),
                         "orientation_error_rad": float(res.orientation_error[b]), "success": bool(res.success[b]),
                         "reason": res.reason[b], "iterations": int(res.iterations[b])} for b in range(B)]}
    _write_json(out / "ik.json", results)  # last: its presence means the run is complete
    print(f"wrote {out}/ik.json, ik.npz")
    missed = int((~res.success).sum())
    if missed:
        print(f"tdcr-warp: {missed} of {B} targets not reached (for an unreachable one, the closest point found: "
              "ik.json)", file=sys.stderr)
        return 1
    return 0


def _write_predictions(path: Path, meas, pred: dict) -> None:
    """predictions.csv: one row per input row, predicted and measured tip [mm], error, flags."""
    import csv

    K = pred["slack"].shape[1] if pred["slack"] is not None else 0
    def write(tmp):
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["row", "source", "pattern_label", "pred_x_mm", "pred_y_mm", "pred_z_mm", "meas_x_mm",
                        "meas_y_mm", "meas_z_mm", "error_mm", "converged", "retried"] + [f"slack_{k}" for k in range(K)])
            err = np.linalg.norm(pred["error_mm"], axis=1)
            for i in range(len(meas)):
                w.writerow([i, meas.source[i], meas.labels[i], *np.round(pred["point_mm"][i], 6).tolist(),
                            *meas.tip_mm[i].tolist(), round(float(err[i]), 6), int(pred["converged"][i]),
                            int(pred["retried"][i])] + [int(x) for x in (pred["slack"][i] if K else [])])
    _write_atomic(path, write)


# The units of predict's metrics.json entries (hardware.metrics; "1": a count, "%": of the robot's length).
PREDICT_UNITS = {"rows": "1", "converged": "1", "rmse_mm": "mm", "rmse_aligned_mm": "mm", "median_mm": "mm",
                 "p95_mm": "mm", "mean_offset_mm": "mm", "rmse_percent_of_length": "%", "wall_time_s": "s",
                 "kernel_load_s": "s", "ms_per_row": "ms"}


def cmd_predict(args) -> int:
    """Predict measured tips of a scene with a [hardware] table (tdcr_warp.apps.hardware)."""
    from tdcr_warp.apps.hardware import metrics, predict, read_measurements
    from tdcr_warp.io.plotting import plot_prediction
    from tdcr_warp.io.scene import load_scene

    scene = _apply_overrides(load_scene(args.scene), args)
    if scene.hardware is None:
        raise InputError(f"{args.scene}: predict needs a [hardware] table (servo_columns, marker_offset, base_offset)")
    meas = read_measurements(args.data, scene.hardware["servo_columns"])
    out = _out_dir(args, Path("out") / Path(args.scene).stem, "metrics.json")
    load_s = _load_kernels(scene, args)
    pred = predict(scene, meas, device=args.device)
    m = metrics(pred["error_mm"], pred["converged"], float(np.max(scene.robot.length)))
    print(f"predicted {len(meas)} rows in {pred['wall_s']:.2f} s ({1e3 * pred['wall_s'] / len(meas):.2f} ms per row, "
          f"one batched solve; kernel loading excluded): RMSE {m['rmse_mm']:.2f} mm, aligned {m['rmse_aligned_mm']:.2f} mm, "
          f"median {m['median_mm']:.2f} mm, p95 {m['p95_mm']:.2f} mm, {m['converged']} of {m['rows']} converged")
    _write_predictions(out / "predictions.csv", meas, pred)
    plot_prediction(meas.tip_mm, pred["point_mm"], pred["converged"], out / "predict.png")
    _write_json(out / "metrics.json", m | {"scene": str(args.scene), "data": [str(d) for d in args.data],
                                           "wall_time_s": pred["wall_s"], "kernel_load_s": load_s,
                                           "ms_per_row": 1e3 * pred["wall_s"] / len(meas),
                                           "units": PREDICT_UNITS,
                                           "settings": _settings(scene, args, args.device or "default")})
    print(f"wrote {out}/metrics.json, predictions.csv, predict.png")
    return 0 if m["converged"] == m["rows"] else 1


def cmd_fit(args) -> int:
    """Calibrate a [hardware] scene on measured rows (tdcr_warp.apps.hardware.fit); writes fitted.toml."""
    import tomli_w

    from tdcr_warp.apps.hardware import fit, read_measurements
    from tdcr_warp.io.scene import load_scene

    scene = load_scene(args.scene)
    if scene.hardware is None:
        raise InputError(f"{args.scene}: fit needs a [hardware] table (servo_columns, marker_offset, base_offset)")
    meas = read_measurements(args.data, scene.hardware["servo_columns"])
    out = _out_dir(args, Path("out") / (Path(args.scene).stem + "_fit"), "fit.json", "fitted.toml")
    print(f"fitting {Path(args.scene).name} on {len(meas)} rows ...", flush=True)
    res = fit(scene.source, meas, detail=args.detail, device=args.device, max_iter=args.max_iter,
              progress=None if args.quiet else lambda h: print(f"  iteration {h['iteration']}: RMSE {h['rmse_mm']:.3f} mm"
                                                               f"{'' if h['accepted'] else ' (no step lowered it)'}",
                                                               flush=True))
    rep = res["report"]
    header = (f"# Fitted by tdcr-warp fit from {Path(args.scene).name} on {', '.join(Path(d).name for d in args.data)}\n"
              f"# ({len(meas)} rows): training RMSE {rep['training']['rmse_mm']:.3f} mm, aligned "
              f"{rep['training']['rmse_aligned_mm']:.3f} mm; parameters and uncertainty in fit.json.\n")
    _write_atomic(out / "fitted.toml", lambda tmp: Path(tmp).write_text(header + tomli_w.dumps(res["scene"])))
    _write_predictions(out / "predictions.csv", meas, res["prediction"])
    _write_json(out / "fit.json", rep | {"scene": str(args.scene), "data": [str(d) for d in args.data],
                                         "settings": _settings(scene, args, args.device or "default")})
    t = rep["training"]
    print(f"fit in {rep['wall_s']:.0f} s, {rep['iterations']} iterations: training RMSE {t['rmse_mm']:.3f} mm "
          f"({t['rmse_percent_of_length']:.2f}% of the length), aligned {t['rmse_aligned_mm']:.3f} mm")
    for name, v in rep["parameters"].items():
        print(f"  {name:16s} {v['value']: .6g} +- {v['std']:.2g}")
    print(f"wrote {out}/fitted.toml, fit.json, predictions.csv")
    return 0


def cmd_sweep(args) -> int:
    """montecarlo, workspace and gain-grid: a [sweep] over the scene, run in chunks."""
    from tdcr_warp.apps.jobs import (
        SweepJob,
        failure_counts,
        summarize_gain_grid,
        summarize_montecarlo,
        summarize_workspace,
    )
    from tdcr_warp.apps.sweep import SweepSpec, peak_memory_mb, run_sweep
    from tdcr_warp.io.scene import load_scene
    from tdcr_warp.physics.statics import solve_static

    base = _apply_overrides(load_scene(args.scene), args)
    data = dict(base.source)
    if any(getattr(args, k) is not None for k in ("nodes", "integrator", "model", "precision")):
        data["solver"] = {k: v for k, v in vars(base.options).items() if v is not None}
    job_name = args.command
    dev = args.device
    if job_name == "gain-grid" and (base.control is None or base.dynamics is None):
        raise InputError("gain-grid needs [dynamics] and [control] tables")
    if args.shapes and job_name == "gain-grid":
        raise InputError("--shapes: gain-grid returns metrics, not shapes (use montecarlo or workspace)")
    gpus = args.gpus_per_task
    if gpus is None:
        gpus = 1.0 if args.backend == "ray" and str(dev or "").startswith("cuda") else 0.0
    if args.backend == "ray" and gpus > 0:
        dev = "cuda:0"  # Ray makes the task's GPU the first visible one
    job = SweepJob(job_name, device=dev, nominal=data if job_name == "montecarlo" else None, shapes=args.shapes)
    out = Path(args.out or Path("out") / f"{Path(args.scene).stem}_{job_name}")
    try:
        run = run_sweep(data, job, out, chunk=args.chunk, resume=args.resume, overwrite=args.overwrite,
                        progress=not args.quiet, max_chunks=args.max_chunks, job_name=job_name, backend=args.backend,
                        address=args.address, workers=args.workers, gpus_per_task=gpus, meta={"shapes": args.shapes})
        if run is None:
            print(f"stopped after {args.max_chunks} new chunk(s); rerun with --resume to finish ({out})")
            return 1
        if not args.quiet:
            print("summarising the chunks ...", flush=True)
        if job_name == "montecarlo":
            nominal = solve_static(base.robot, base.tensions, options=base.options, device=dev).tip_position[0]
            summary = summarize_montecarlo(run, nominal, out)
            summary["linearised"] = _linearised(data, dev, summary)
        elif job_name == "workspace":
            summary = summarize_workspace(run, base.robot, out)
        else:
            summary = summarize_gain_grid(run, [name for name, _ in SweepSpec(data).grid], out)
        if run.failed:
            summary["failure_reasons"] = failure_counts(run)
        rate = run.computed_rods / run.wall_s if run.computed_rods and run.wall_s > 0 else None
        summary.update(scene=str(args.scene), wall_time_s=run.wall_s, computed_rods=run.computed_rods, rods_per_s=rate,
                       chunk=run.store.chunk, peak_memory_mb=peak_memory_mb(),
                       settings=_settings(base, args, dev or "default"))
        _write_json(out / "summary.json", summary)  # last: its presence means the sweep is complete
    except KeyboardInterrupt:
        print(f"tdcr-warp: interrupted; the finished chunks are kept in {out}: rerun with --resume to finish",
              file=sys.stderr)
        return 130
    done = (f"{run.computed_rods:,} computed in {run.wall_s:.1f} s ({rate:,.0f} rods/s)" if rate else
            "every chunk was already done: nothing computed")
    print(f"{job_name}: {run.rods:,} rods, {done}, {run.failed} failed, peak memory {peak_memory_mb():.0f} MB")
    if job_name == "gain-grid":
        best = summary["best"]
        print(f"best gains {best['gains']}: settling {best['settling_time']:.3f} s, final error "
              f"{best['final_error'] * 1e3:.3f} mm, chatter {best['chatter']:.2e} N")
    print(f"wrote {out}/summary.json, results/ (Parquet){', arrays.zarr' if (out / 'arrays.zarr').exists() else ''}, "
          "figures")
    return 0


def _grid_reference(path: str, gains: list[str], dt: float, duration: float) -> dict:
    """The best run of the finished gain-grid sweep in ``path`` (its summary.json), with the
    search's objective of it (tdcr_warp.apps.gainsearch.gain_objective): ``search --grid``."""
    from tdcr_warp.apps.gainsearch import gain_objective
    from tdcr_warp.io.store import read_manifest

    out = Path(path)
    man = read_manifest(out)
    if man is None or man.get("job") != "gain-grid" or man.get("state") != "complete":
        raise InputError(f"--grid {path!r}: not a finished gain-grid sweep (tdcr-warp gain-grid SCENE --out {path})")
    if sorted(man["fields"]) != sorted(gains):
        raise InputError(f"--grid {path!r}: its grid is over {man['fields']}, the search over {gains}")
    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"--grid {path!r}: cannot read its summary.json: {e}") from None
    best = summary["best"]
    settle, error = (float("inf") if best[k] is None else best[k] for k in ("settling_time", "final_error"))
    f = gain_objective(best["final_error"] is not None, settle, best["chatter"], error, dt=dt, duration=duration)
    return {"path": str(out), "closed_loops": summary["rods"], "wall_time_s": summary["wall_time_s"],
            "best": best | {"objective": float(f)}}


def cmd_search(args) -> int:
    """CMA-ES over the [search] gains, each generation one batch of closed loops
    (tdcr_warp.apps.gainsearch); with --grid beside the best of a finished gain-grid sweep."""
    from tdcr_warp.apps.gainsearch import search_gains
    from tdcr_warp.io.plotting import plot_search
    from tdcr_warp.io.scene import load_scene, scene_from_dict

    base = _apply_overrides(load_scene(args.scene), args)
    if base.search is None or base.dynamics is None:
        raise InputError(f"{args.scene}: search needs [dynamics], [control] and [search] tables")
    data = dict(base.source)
    if any(getattr(args, k) is not None for k in ("nodes", "integrator", "model", "precision")):
        data["solver"] = {k: v for k, v in vars(base.options).items() if v is not None}
    scene = replace(scene_from_dict(data), text=base.text)
    opts = scene.search | ({} if args.budget is None else {"budget": args.budget})
    spec = scene.dynamics
    duration = spec.steps * spec.dt
    grid = None if args.grid is None else _grid_reference(args.grid, list(opts["ranges"]), spec.dt, duration)
    out = _out_dir(args, Path("out") / f"{Path(args.scene).stem}_search", "results.json")
    bar = None if args.quiet else Progress(opts["budget"], 1, rate_unit="loops/s")
    done = {"loops": 0, "failed": 0, "generations": 0}

    def step(i: int, n: int) -> None:
        bar.update(done["loops"], done["failed"], f" (generation {done['generations'] + 1}: step {i}/{n})")

    def generation(res) -> None:
        done.update(loops=res.closed_loops, failed=int((~res.candidates["ok"]).sum()), generations=res.generations)
        bar.update(res.closed_loops, done["failed"], f" (generation {res.generations}, best {res.objective:.4f})")

    t0 = time.perf_counter()
    try:
        res = search_gains(replace(scene, search=opts), device=args.device, progress=step if bar else None,
                           on_generation=generation if bar else None)
    finally:
        if bar:
            bar.close()
    wall = time.perf_counter() - t0
    failed = int((~res.candidates["ok"]).sum())
    loops_at = np.array([h["closed_loops"] for h in res.history])[res.candidates["generation"] - 1]
    plot_search(res.history, (loops_at, res.candidates["objective"]),
                None if grid is None else (grid["best"]["objective"], grid["closed_loops"]), duration + spec.dt,
                out / "search.png")
    results = {
        "scene": str(args.scene), "settings": _settings(scene, args, args.device or "default")
        | {"dt": spec.dt, "alpha": spec.alpha, "steps": spec.steps},
        "gains": list(opts["ranges"]), "ranges": {g: list(r) for g, r in opts["ranges"].items()},
        "budget": opts["budget"], "population": res.population, "seed": opts["seed"], "sigma": opts["sigma"],
        "closed_loops": res.closed_loops, "failed_loops": failed, "generations": res.generations,
        "restarts": res.restarts, "wall_time_s": wall,
        "best": {"gains": res.gains, "objective": res.objective, **res.metrics}, "history": res.history,
        "objective_note": "settled: settling time + (dt/2) c/(c + 1e-3 N) (c: chatter); outside the 0.5 mm band at "
                          "the end: duration + dt + e/(e + 5e-4 m) (e: final error); a failed step: duration + dt + "
                          "1; lower is better, in the gain grid's order (tdcr_warp.apps.gainsearch)",
    }
    if grid is not None:
        results["grid"] = grid | {"search_at_least_as_good": res.objective <= grid["best"]["objective"]}
    _write_json(out / "results.json", results)

    def settle(t):
        return f"{t:.3f} s" if t is not None and np.isfinite(t) else "never"
    m = res.metrics
    print(f"search: {res.closed_loops:,} closed loops in {res.generations} generations ({res.restarts} restarts), "
          f"{wall:.1f} s, {failed} failed")
    print(f"best gains {res.gains}: settling {settle(m['settling_time'])}, final error "
          f"{m['final_error'] * 1e3:.3f} mm, chatter {m['chatter']:.2e} N")
    if grid is not None:
        g = grid["best"]
        verdict = "at least as good" if results["grid"]["search_at_least_as_good"] else "worse"
        print(f"grid ({grid['closed_loops']:,} closed loops): best gains {g['gains']}: settling "
              f"{settle(g['settling_time'])}, chatter {g['chatter']:.2e} N; the search is {verdict}")
    print(f"wrote {out}/results.json, search.png")
    return 0


def _linearised(data: dict, device, summary: dict) -> dict:
    """The first-order tip spread of the Monte-Carlo scene (tdcr_warp.apps.uncertainty) beside the
    sampled one: per axis the standard deviations [m] and their ratio, or why it is not there."""
    from tdcr_warp.apps.uncertainty import linearised_spread

    try:
        lin = linearised_spread(data, device)
    except InputError as e:
        return {"available": False, "reason": str(e)}
    mc = np.sqrt(np.diag(summary["tip_covariance"])) if summary.get("tip_covariance") else None
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = None if mc is None else np.where(lin["tip_std"] > 0, mc / lin["tip_std"], np.nan)
    return {"available": True, "tip_std_m": lin["tip_std"].tolist(),
            "montecarlo_tip_std_m": None if mc is None else mc.tolist(),
            "montecarlo_over_linearised": None if ratio is None else [None if not np.isfinite(r) else float(r)
                                                                      for r in ratio],
            "contributions_m2": dict(zip(lin["parameters"], lin["contributions"].tolist())),
            "note": "first order: J Sigma J^T from one solve; the Monte-Carlo spread departs from it as the "
                    "scatter grows (README, Sensitivities)"}


def _positive_int(text: str) -> int:
    """The argparse type of the counts (--steps, --nodes, --max-iter): an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return n


def build_parser() -> argparse.ArgumentParser:
    import warp as wp

    from tdcr_warp import __version__

    ap = argparse.ArgumentParser(prog="tdcr-warp", description="Batched tendon-driven continuum robots on Warp.")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__} (Warp {wp.__version__})")
    sub = ap.add_subparsers(dest="command", required=True)
    for name, helptext in (("static", "solve the statics of a scene"),
                           ("simulate", "run the dynamics of a scene ([dynamics] table)"),
                           ("control", "sliding-mode tip control ([dynamics] and [control] tables)"),
                           ("montecarlo", "tip distribution (and control success) under [[uncertainty]]"),
                           ("workspace", "tip cloud over a [sweep] of tensions"),
                           ("gain-grid", "controller metrics over a [sweep.grid] of control gains"),
                           ("search", "CMA-ES over the [search.ranges] control gains, a batch of closed loops a "
                                      "generation"),
                           ("ik", "inverse kinematics: tendon commands for the [ik] targets"),
                           ("predict", "predict measured tips (a scene with [hardware], a keypoint CSV)"),
                           ("fit", "calibrate a [hardware] scene on keypoint CSVs; writes fitted.toml")):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("scene", help="scene file (TOML)")
        if name in ("predict", "fit"):
            p.add_argument("data", nargs="+", help="keypoint CSV file(s) (tdcr_warp.apps.hardware)")
        if name == "fit":
            p.add_argument("--max-iter", type=_positive_int, default=30,
                           help="Levenberg-Marquardt iterations (default 30)")
            p.add_argument("--detail", choices=["segment", "tendon"], default="tendon",
                           help="a rotation per tendon and a compliance per segment (default), or one per segment "
                                "and one compliance")
        p.add_argument("--out", help="output directory (default: out/<scene name>)")
        p.add_argument("--device", default=None, help="cpu or cuda:0 (default: Warp's default device)")
        p.add_argument("--nodes", type=_positive_int, help="override [solver].nodes")
        p.add_argument("--integrator", choices=list(INTEGRATORS), help="override [solver].integrator")
        p.add_argument("--model", choices=[*MODELS, "constant_curvature"], help="override [solver].model")
        p.add_argument("--precision", choices=["float64", "float32"], help="override [solver].precision")
        if name in ("simulate", "control"):
            p.add_argument("--steps", type=_positive_int, help="run only the first STEPS steps")
            p.add_argument("--animate", action="store_true",
                           help="write robot.gif from the shapes stored every [dynamics].shapes_every steps")
        if name in ("static", "simulate", "control"):
            p.add_argument("--html", action="store_true",
                           help="write robot.html, an interactive 3D viewer (one file, opens offline): the first "
                                "10 rods" + ("" if name == "static" else
                                             ", animated from the shapes stored every [dynamics].shapes_every steps"))
        if name in ("static", "simulate"):
            p.add_argument("--no-figures", action="store_true", help="skip the PNG figures (matplotlib costs ~0.7 s)")
        p.add_argument("--quiet", action="store_true", help="no progress bar, no compile notice")
        p.add_argument("-v", "--verbose", action="store_true",
                       help="also Warp's line per kernel module loaded or compiled, with its time")
        if name == "search":
            p.add_argument("--budget", type=_positive_int, help="closed loops to spend (default [search].budget)")
            p.add_argument("--grid", help="a finished gain-grid sweep folder over the same gains: its best run "
                                          "beside the search's (results.json, search.png)")
        if name in ("montecarlo", "workspace", "gain-grid"):
            p.add_argument("--chunk", type=int, help="rods per chunk (default [sweep].chunk)")
            p.add_argument("--resume", action="store_true", help="continue an interrupted sweep in --out")
            p.add_argument("--overwrite", action="store_true",
                           help="replace the results of another sweep in --out (removed before this one starts)")
            p.add_argument("--max-chunks", type=int, help="stop after computing this many chunks")
            p.add_argument("--backend", choices=["local", "ray"], default="local",
                           help="local: in this process (default); ray: chunks as Ray tasks (pip install -e .[ray])")
            p.add_argument("--address", help="Ray cluster address (default: start a local Ray for the run)")
            p.add_argument("--workers", type=int, help="CPUs of the local Ray (default: all cores)")
            p.add_argument("--gpus-per-task", type=float,
                           help="GPUs per Ray task (default 1 with --device cuda..., else 0)")
            p.add_argument("--shapes", action="store_true", help="also save every rod's backbone positions")
    return ap


def _on_sigint(signum, frame) -> None:
    """The first Ctrl-C: ignore any further one (the process is ending: its cleanups run to
    their end), then interrupt as Python does."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


def main(argv=None) -> int:
    """Run the command line; returns the exit status (0 ok, 1 some rods failed, 2 bad input,
    130 interrupted). A malformed command line (argparse) raises SystemExit(2) after printing
    the usage. Ctrl-C (SIGINT, KeyboardInterrupt) ends any command with one line on stderr and
    no completion file; from the first SIGINT on, SIGINT is ignored (_on_sigint)."""
    from tdcr_warp.apps.cluster import SweepError

    args = build_parser().parse_args(argv)
    own = (threading.current_thread() is threading.main_thread()
           and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
    if own:  # (not where SIGINT is ignored, as in a background job, or handled by the caller)
        signal.signal(signal.SIGINT, _on_sigint)
    from tdcr_warp.core.solver import COMPILE_NOTICE, set_compile_notice

    notice = COMPILE_NOTICE["enabled"]
    set_compile_notice(not args.quiet)
    if args.verbose:
        import warp as wp
        log_level, wp.config.log_level = wp.config.log_level, wp.LOG_INFO
    try:
        if args.device is not None and getattr(args, "backend", "local") == "local":
            import warp as wp
            try:
                wp.get_device(args.device)
            except (RuntimeError, ValueError) as e:
                raise InputError(f"--device {args.device!r}: {e}") from None
        cmds = {"static": cmd_static, "simulate": cmd_simulate, "control": cmd_control, "montecarlo": cmd_sweep,
                "workspace": cmd_sweep, "gain-grid": cmd_sweep, "ik": cmd_ik, "predict": cmd_predict,
                "fit": cmd_fit, "search": cmd_search}
        return cmds[args.command](args)
    except KeyboardInterrupt:
        Progress.end_line()
        print("tdcr-warp: interrupted", file=sys.stderr)
        return 130
    except InputError as e:
        print(f"tdcr-warp: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"tdcr-warp: error: {e}", file=sys.stderr)
        return 2
    except SweepError as e:
        print(f"tdcr-warp: error: {e}", file=sys.stderr)
        return 1
    finally:
        set_compile_notice(notice)
        if args.verbose:
            wp.config.log_level = log_level
        if own and signal.getsignal(signal.SIGINT) is _on_sigint:  # no SIGINT came: as it was
            signal.signal(signal.SIGINT, signal.default_int_handler)
