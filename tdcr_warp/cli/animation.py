"""The shapes a trajectory or closed-loop run stores every [dynamics].shapes_every steps, drawn
as robot.gif (--animate) and robot.html (--html): shared by simulate and control."""

from __future__ import annotations

import argparse
import numpy as np

from tdcr_warp.cli.common import positive_int, write_atomic
from tdcr_warp.model.robot import InputError


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """--steps and --animate."""
    p.add_argument("--steps", type=positive_int, help="run only the first STEPS steps")
    p.add_argument("--animate", action="store_true",
                   help="write robot.gif from the shapes stored every [dynamics].shapes_every steps")


def check_shapes(args, spec) -> None:
    """--animate and --html need stored shapes: refuse before the run when the scene stores none."""
    if args.animate and not spec.shapes_every:
        raise InputError("--animate: the run stores no shapes: set [dynamics].shapes_every (e.g. 5)")
    if args.html and not spec.shapes_every:
        raise InputError("--html: the run stores no shapes: set [dynamics].shapes_every (e.g. 5)")


def drawings(args, scene, run, grid: np.ndarray, out) -> list[str]:
    """robot.gif (--animate) and robot.html (--html) into ``out`` (a cli.common.OutputRun); what
    was written, e.g. ``robot.gif (24 frames)``, for the lines the command prints once its files
    are in place."""
    return ([animate(scene, run, grid, out)] if args.animate else []) + ([html_run(scene, run, grid, out)]
                                                                         if args.html else [])


def html_run(scene, run, grid: np.ndarray, out) -> str:
    """robot.html: the interactive viewer of a trajectory or closed-loop run from its stored
    shapes; ``robot.html (n frames)``."""
    from tdcr_warp.io.viewer import write_run_viewer

    drawn = []
    write_atomic(out / "robot.html", lambda tmp: drawn.append(write_run_viewer(
        tmp, scene.robot, run, grid, scene.tensions, display=scene.display)))
    return f"robot.html ({drawn[0]} frames)"


def animate(scene, run, grid: np.ndarray, out) -> str:
    """robot.gif of a trajectory or closed-loop run from its stored shapes (tdcr_warp.io.plotting);
    ``robot.gif (n frames)``."""
    from tdcr_warp.io.drawing import robot_geometry
    from tdcr_warp.io.plotting import MAX_ROBOTS_DRAWN, animate_robot

    n = min(run.positions.shape[1], MAX_ROBOTS_DRAWN)
    tau = np.concatenate([scene.tensions[None, :n] if scene.tensions.shape[0] > 1 else
                          np.broadcast_to(scene.tensions, (1, n, scene.tensions.shape[1])), run.tensions[:, :n]])
    frames = [robot_geometry(scene.robot, run.positions[i, :n], run.rotations[i, :n], grid[:n], tau[step],
                             scene.display) for i, step in enumerate(run.shape_steps)]
    drawn = animate_robot(frames, run.time[run.shape_steps], out / "robot.gif")
    return f"robot.gif ({drawn} frames)"
