"""``tdcr-warp static SCENE.toml``: the statics of a scene; results.json (a summary, and per rod
for batches of at most JSON_RODS rods), rods.parquet (the per-rod table of larger batches),
shapes.npz (every array of the solution), shapes.png and (--html) robot.html."""

from __future__ import annotations

import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

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
    write_atomic,
    write_json,
    write_rod_table,
)

ROD_TABLE = "rods.parquet"
FILES = ("results.json", "shapes.npz", ROD_TABLE, "shapes.png", "robot.html")  # the completion file first


def register(subparsers) -> None:
    p = add_command(subparsers, "static", "solve the statics of a scene", run)
    add_solver_arguments(p)
    add_html_argument(p, animated=False)
    add_no_figures_argument(p)
    add_log_arguments(p)


def run(args) -> int:
    from tdcr_warp.io.scene import load_scene

    t0 = time.perf_counter()
    scene = apply_overrides(load_scene(args.scene), args)
    scene_s = time.perf_counter() - t0
    with OutputRun(args, Path("out") / Path(args.scene).stem, FILES) as out:
        return _run(args, scene, scene_s, out)


def _run(args, scene, scene_s: float, out: OutputRun) -> int:
    """Solve, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.physics.statics import solve_static

    load_s = load_kernels(scene, args)
    t0 = time.perf_counter()
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=args.device,
                       **scene.static_command())
    wall = time.perf_counter() - t0
    B = len(sol.converged)
    reasons = _status_words(sol.status)
    print(f"solved {B} rod(s) in {wall:.3f} s ({B / wall:,.0f} rods/s, kernel loading excluded; "
          f"{scene.options.integrator}, N = {scene.options.nodes}, {scene.options.model}, {scene.options.precision})")
    print_rods(sol.tip_position, sol.success, sol.iterations, sol.residual, reasons)
    t0 = time.perf_counter()
    small = B <= JSON_RODS
    files = {"shapes.npz": write_arrays(out / "shapes.npz", sol)}
    if not small:
        files[ROD_TABLE] = _write_rod_table(out / ROD_TABLE, scene, sol, reasons)
    write_s = time.perf_counter() - t0
    drawn = not args.no_figures and _plot(scene, sol, out)
    html = args.html and _html(scene, sol, out)
    failed = ~sol.success  # not converged, or an unstable equilibrium
    unassessed = np.zeros(B, dtype=bool) if sol.assessed is None else sol.success & ~sol.assessed
    results = {
        "scene": str(args.scene), "settings": settings(scene, args.device or "default"),
        "batch_size": B, "wall_time_s": wall, "kernel_load_s": load_s, "scene_load_s": scene_s, "write_s": write_s,
        "converged_rods": int(sol.converged.sum()), "unstable_rods": int((sol.converged & failed).sum()),
        "failed_rods": int(failed.sum()),
        "failure_reasons": dict(Counter(reasons[b] for b in np.flatnonzero(failed))),
        "unassessed_rods": int(unassessed.sum()), "unassessed_reasons": _unassessed_reasons(sol, unassessed),
        "files": files,
    } | (_rods_json(sol, reasons) if small else {})
    write_json(out / "results.json", results)
    out.commit()  # results.json last: its presence means the run is complete
    print(f"wrote {out}/results.json, {', '.join(files)}{', shapes.png' if drawn else ''}")
    if html:
        print(f"wrote {out}/{html}")
    return _exit_status(results, B, ROD_TABLE if not small else "results.json")


def _unassessed_reasons(sol, unassessed: np.ndarray) -> dict:
    """How many of the ``unassessed`` rods (B,) bool the stability test left out, per reason."""
    if not unassessed.any():
        return {}
    text = sol.stability_reasons()
    return dict(Counter(text[b].removeprefix("not assessed: ") for b in np.flatnonzero(unassessed)))


def _exit_status(results: dict, B: int, where: str) -> int:
    """1 if a rod failed (not converged, unstable, through an obstacle), else 3 if a rod that
    converged has no stability verdict (never counted a plain success), else 0; each count and
    its reasons on stderr."""
    status = 0
    for key, reasons, what, code in (("failed_rods", "failure_reasons", "did not converge or are unstable", 1),
                                     ("unassessed_rods", "unassessed_reasons",
                                      "converged but their stability was not assessed", 3)):
        if results[key]:
            why = ", ".join(f"{n} x {reason}" for reason, n in results[reasons].items())
            print(f"tdcr-warp: {results[key]} of {B} rods {what}: {why} (per rod in {where})", file=sys.stderr)
            status = status or code
    return status


def _status_words(status: np.ndarray) -> list[str]:
    """Each rod's status bits in words (tw.describe_status), worded once per distinct status."""
    from tdcr_warp.model.options import describe_status

    codes, index = np.unique(status, return_inverse=True)
    words = [describe_status(c) for c in codes]
    return [words[i] for i in index.ravel()]


def _rod_arrays(scene, sol) -> dict:
    """The per-rod table's arrays after its first columns (docs/outputs.md: ``rods.parquet``)."""
    B, K = sol.tendon_tension_base.shape
    res = {"iterations": sol.iterations, "integrations": sol.integrations, "residual": sol.residual,
           "orthogonality_error": sol.orthogonality_error, "tip_position": sol.tip_position,
           "tensions": np.broadcast_to(scene.tensions, (B, K))}
    if scene.displacements is not None:
        res["displacements"] = np.broadcast_to(scene.displacements, (B, K))
    res |= {"tension_base": sol.tendon_tension_base, "tension_end": sol.tendon_tension_end}
    optional = {"path_length": sol.tendon_path_length, "free_length": sol.tendon_free_length, "slack": sol.slack,
                "turning": sol.tendon_turning, "slip": sol.slip, "tip_error_estimate": sol.tip_error_estimate,
                "stability_index": sol.stability_index, "stable": sol.stable, "stability_margin": sol.stability_margin,
                "lagrangian_error": sol.lagrangian_error,
                "branch": sol.branch, "multiple_stable": sol.multiple_stable, "penetration": sol.penetration,
                "tip_reaction": sol.tip_reaction}
    return res | {k: v for k, v in optional.items() if v is not None}


def _write_rod_table(path: Path, scene, sol, reasons: list[str]) -> dict:
    """rods.parquet: one row per rod, a (B, K) array one column per tendon (``key[k]``), as the
    sweeps' tables."""
    first = {"success": sol.success, "converged": sol.converged, "status": sol.status, "status_text": reasons}
    if sol.stability_index is not None:
        first["stability_text"] = sol.stability_reasons()
    return write_rod_table(path, "static", first, _rod_arrays(scene, sol))


def _rods_json(sol, reasons: list[str]) -> dict:
    """The per-rod keys of results.json (batches of at most JSON_RODS rods)."""
    B, stability = len(sol.converged), sol.stability_reasons()
    return {
        "tip_position": sol.tip_position.tolist(), "converged": sol.converged.tolist(),
        "iterations": sol.iterations.tolist(), "residual": sol.residual.tolist(),
        "rods": [{"tip_position": sol.tip_position[b].tolist(), "tip_rotation": sol.tip_rotation[b].tolist(),
                  "success": bool(sol.success[b]), "converged": bool(sol.converged[b]), "status": reasons[b],
                  "iterations": int(sol.iterations[b]), "residual": float(sol.residual[b]),
                  "orthogonality_error": float(sol.orthogonality_error[b]), "tendons": _tendon_rows(sol, b)}
                 | _sensitivity_row(sol, b, stability) for b in range(B)],
    }


def _sensitivity_row(sol, b: int, stability: list[str] | None) -> dict:
    """Rod b's stability verdict (``stability``: sol.stability_reasons()) and (with sensitivities)
    its tip Jacobian and compliance."""
    row = {}
    if sol.stability_index is not None:
        row |= {"stability_index": int(sol.stability_index[b]), "stable": bool(sol.stable[b]),
                "stability_margin": float(sol.stability_margin[b]), "stability": stability[b]}
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


def _plot(scene, sol, out: OutputRun) -> bool:
    """shapes.png: the first solved rods (tdcr_warp.io.plotting); whether it was drawn."""
    from tdcr_warp.io.drawing import robot_geometry
    from tdcr_warp.io.plotting import MAX_RODS_DRAWN, plot_robot

    n = _drawable(sol, MAX_RODS_DRAWN)
    if n == 0:
        print("shapes.png not drawn: the first rod has no finite shape")
        return False
    geom = robot_geometry(scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
                          scene.display)
    plot_robot(geom, out / "shapes.png", converged=sol.converged[:n])
    return True


def _drawable(sol, most: int) -> int:
    """How many of the first rods can be drawn: up to ``most``, ending before the first rod whose
    shape is not finite (one that failed on a non-finite state)."""
    n = min(len(sol.converged), most)
    finite = np.isfinite(sol.positions[:n]).all(axis=(1, 2)) & np.isfinite(sol.rotations[:n]).all(axis=(1, 2, 3))
    return n if finite.all() else int(np.argmin(finite))


def _html(scene, sol, out: OutputRun) -> str | None:
    """robot.html: the interactive viewer of the first solved rods (tdcr_warp.io.viewer); what
    was written (``robot.html (n rods)``), None for nothing."""
    from tdcr_warp.io.viewer import MAX_RODS, write_viewer

    n = _drawable(sol, MAX_RODS)
    if n == 0:
        print("robot.html not written: the first rod has no finite shape")
        return None
    names = [f"rod {b}" + ("" if sol.converged[b] else " (not converged)") for b in range(n)]
    write_atomic(out / "robot.html", lambda tmp: write_viewer(
        tmp, scene.robot, sol.positions[:n], sol.rotations[:n], sol.s[:n], sol.tendon_tension_base[:n],
        display=scene.display, names=names))
    return f"robot.html ({n} rod{'s' * (n > 1)})"
