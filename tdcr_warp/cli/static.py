"""``tdcr-warp static SCENE.toml``: the statics of a scene; results.json, shapes.npz, shapes.png
and (--html) robot.html."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from tdcr_warp.cli.common import (
    add_command,
    add_html_argument,
    add_log_arguments,
    add_no_figures_argument,
    add_solver_arguments,
    apply_overrides,
    load_kernels,
    out_dir,
    print_rods,
    settings,
    write_atomic,
    write_json,
    write_npz,
)


def register(subparsers) -> None:
    p = add_command(subparsers, "static", "solve the statics of a scene", run)
    add_solver_arguments(p)
    add_html_argument(p, animated=False)
    add_no_figures_argument(p)
    add_log_arguments(p)


def run(args) -> int:
    from tdcr_warp.io.scene import load_scene
    from tdcr_warp.model.options import failure_reasons
    from tdcr_warp.physics.statics import solve_static

    scene = apply_overrides(load_scene(args.scene), args)
    out = out_dir(args, Path("out") / Path(args.scene).stem, "results.json")
    load_s = load_kernels(scene, args)
    t0 = time.perf_counter()
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=args.device,
                       **scene.static_command())
    wall = time.perf_counter() - t0
    B = len(sol.converged)
    reasons = sol.failure_reasons()
    print(f"solved {B} rod(s) in {wall:.3f} s ({B / wall:,.0f} rods/s, kernel loading excluded; "
          f"{scene.options.integrator}, N = {scene.options.nodes}, {scene.options.model}, {scene.options.precision})")
    print_rods(sol.tip_position, sol.converged, sol.iterations, sol.residual, reasons)
    write_npz(out / "shapes.npz", sol.to_npz)
    if not args.no_figures:
        _plot(scene, sol, out)
    if args.html:
        _html(scene, sol, out)
    results = {
        "scene": str(args.scene), "settings": settings(scene, args.device or "default"),
        "batch_size": B, "wall_time_s": wall, "kernel_load_s": load_s,
        "tip_position": sol.tip_position.tolist(), "converged": sol.converged.tolist(),
        "iterations": sol.iterations.tolist(), "residual": sol.residual.tolist(),
        "rods": [{"tip_position": sol.tip_position[b].tolist(), "tip_rotation": sol.tip_rotation[b].tolist(),
                  "converged": bool(sol.converged[b]), "status": reasons[b],
                  "iterations": int(sol.iterations[b]), "residual": float(sol.residual[b]),
                  "orthogonality_error": float(sol.orthogonality_error[b]), "tendons": _tendon_rows(sol, b)}
                 | _sensitivity_row(sol, b) for b in range(B)],
    }
    write_json(out / "results.json", results)  # last: its presence means the run is complete
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


def _plot(scene, sol, out: Path) -> None:
    """shapes.png: the first solved rods (tdcr_warp.io.plotting)."""
    from tdcr_warp.io.drawing import robot_geometry
    from tdcr_warp.io.plotting import MAX_RODS_DRAWN, plot_robot

    n = min(len(sol.converged), MAX_RODS_DRAWN)
    geom = robot_geometry(scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
                          scene.display)
    plot_robot(geom, out / "shapes.png", converged=sol.converged[:n])


def _html(scene, sol, out: Path) -> None:
    """robot.html: the interactive viewer of the first solved rods (tdcr_warp.io.viewer)."""
    from tdcr_warp.io.viewer import MAX_RODS, write_viewer

    n = min(len(sol.converged), MAX_RODS)
    names = [f"rod {b}" + ("" if sol.converged[b] else " (not converged)") for b in range(n)]
    write_atomic(out / "robot.html", lambda tmp: write_viewer(
        tmp, scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
        display=scene.display, names=names))
    print(f"wrote {out}/robot.html ({n} rod{'s' * (n > 1)})")
