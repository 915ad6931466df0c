"""``tdcr-warp ik SCENE.toml``: inverse kinematics, the tendon commands for the scene's [ik]
targets (tdcr_warp.apps.ik); ik.json (per target up to JSON_RODS targets, else a summary),
ik.parquet (larger batches) and ik.npz."""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from tdcr_warp.cli.common import (
    JSON_RODS,
    OutputRun,
    add_command,
    add_log_arguments,
    add_solver_arguments,
    apply_overrides,
    load_kernels,
    settings,
    write_arrays,
    write_json,
    write_rod_table,
)
from tdcr_warp.model.robot import InputError

IK_TABLE = "ik.parquet"
FILES = ("ik.json", "ik.npz", IK_TABLE)  # the completion file first


def register(subparsers) -> None:
    p = add_command(subparsers, "ik", "inverse kinematics: tendon commands for the [ik] targets", run)
    add_solver_arguments(p)
    add_log_arguments(p)


def run(args) -> int:
    """Inverse kinematics of the scene's [ik] targets (tdcr_warp.apps.ik)."""
    from tdcr_warp.io.scene import load_scene

    scene = apply_overrides(load_scene(args.scene), args)
    ik = scene.ik
    if ik is None:
        raise InputError(f"{args.scene}: ik needs an [ik] table (targets = [[x, y, z], ...] in m)")
    with OutputRun(args, Path("out") / Path(args.scene).stem, FILES) as out:
        return _run(args, scene, ik, out)


def _run(args, scene, ik: dict, out: OutputRun) -> int:
    """Solve the targets, write the files into ``out`` and commit them; the exit status."""
    from tdcr_warp.apps.ik import solve_ik

    load_s = load_kernels(replace(scene, options=replace(scene.options, sensitivities=True)), args)
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
    targets = np.broadcast_to(np.array(ik["targets"], dtype=np.float64), (B, 3))
    files = {"ik.npz": write_arrays(out / "ik.npz", res, reason=np.array(res.reason))}
    if B > JSON_RODS:
        files[IK_TABLE] = _write_table(out / IK_TABLE, res, targets)
    results = {"scene": str(args.scene), "settings": settings(scene, args.device or "default"),
               "batch_size": B, "wall_time_s": wall, "kernel_load_s": load_s,
               "command_units": ["N" if t.control == "tension" else "m" for t in scene.robot.tendons],
               "reached": int(res.success.sum()), "reasons": dict(Counter(res.reason)), "files": files}
    if B <= JSON_RODS:
        results["rods"] = [{"target": targets[b].tolist(), "command": res.command[b].tolist(),
                            "tip_position": res.tip_position[b].tolist(),
                            "position_error_m": float(res.position_error[b]),
                            "orientation_error_rad": float(res.orientation_error[b]),
                            "success": bool(res.success[b]), "reason": res.reason[b],
                            "iterations": int(res.iterations[b])} for b in range(B)]
    write_json(out / "ik.json", results)
    out.commit()  # ik.json last: its presence means the run is complete
    print(f"wrote {out}/ik.json, {', '.join(files)}")
    missed = int((~res.success).sum())
    if missed:
        print(f"tdcr-warp: {missed} of {B} targets not reached (for an unreachable one, the closest point found: "
              f"{'ik.json' if B <= JSON_RODS else IK_TABLE})", file=sys.stderr)
        return 1
    return 0


def _write_table(path: Path, res, targets: np.ndarray) -> dict:
    """ik.parquet: one row per target (docs/outputs.md), a vector one column per component."""
    return write_rod_table(path, "ik", {"success": res.success, "reason": list(res.reason)},
                           {"target": targets, "command": res.command, "tip_position": res.tip_position,
                            "position_error": res.position_error, "orientation_error": res.orientation_error,
                            "iterations": res.iterations})
