"""The users' jobs on top of chunked sweeps: Monte-Carlo robustness, workspace maps and
gain-grid searches. Each has a per-chunk job (scene -> per-rod arrays) and a summary
(results -> JSON-able statistics + figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tdcr_warp.apps.control import TipController, control_metrics, run_closed_loop, static_target
from tdcr_warp.io.scene import Scene, scene_from_dict
from tdcr_warp.model.robot import InputError
from tdcr_warp.model.tippath import path_from_table
from tdcr_warp.physics.dynamics import Simulator
from tdcr_warp.physics.statics import solve_static

__all__ = ["SweepJob", "constant_curvature_tip", "control_job", "convex_hull_2d", "failure_counts", "pareto_front",
           "scene_controller", "scene_simulator", "static_job", "summarize_gain_grid", "summarize_montecarlo",
           "summarize_workspace"]


def static_job(scene: Scene, device=None, shapes: bool = False) -> dict[str, np.ndarray]:
    """Compact per-rod statics: tip pose, success (converged and not unstable), status bits,
    iterations, residual, tensions; with ``shapes`` also the backbone positions (B, N+1, 3); the
    stability index (and branch) unless the solver's ``stability`` is off, with ``sensitivities``
    the tip Jacobian and compliance; with obstacles ``in_contact`` (B,) and ``penetration`` (B,) [m]
    (the deepest of any obstacle)."""
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=device, **scene.static_command())
    out = {"tip_position": sol.tip_position, "tip_rotation": sol.tip_rotation, "ok": sol.success,
           "status": sol.status, "iterations": sol.iterations, "residual": sol.residual, "tensions": scene.tensions,
           "tension_base": sol.tendon_tension_base, "tension_end": sol.tendon_tension_end}
    if sol.slack is not None:
        out["slack"] = sol.slack
    if sol.stability_index is not None:
        out["stability_index"] = sol.stability_index
        if sol.branch is not None:
            out["branch"] = sol.branch
    if sol.tip_jacobian is not None:
        out["tip_jacobian"], out["tip_compliance"] = sol.tip_jacobian, sol.tip_compliance
    if sol.contact_force is not None:  # with obstacles: whether the rod touches one, and how deep it sinks
        out["in_contact"] = np.abs(sol.contact_force).sum(axis=(1, 2)) > 0
        out["penetration"] = sol.penetration.max(axis=1)
    if shapes:
        out["positions"] = sol.positions
    return out


# [control] keys passed to TipController as they are
CONTROLLER_KEYS = ("method", "input_model", "gain_c", "gain_k", "epsilon", "phi", "tension_max", "model_every",
                   "gain_i", "command", "displacement_range")


def scene_simulator(scene: Scene, device=None) -> Simulator:
    """The scene's rods at rest under its [actuation] command, with its [dynamics] settings."""
    spec = scene.dynamics
    if spec is None:
        raise InputError("this job needs a [dynamics] table")
    return Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options,
                     device=device, displacements=scene.displacements)


def scene_controller(scene: Scene, sim: Simulator, nominal: Scene | None = None, device=None) -> TipController:
    """The scene's [control] table as a controller of ``sim``'s rods; it models ``nominal``'s
    robot if given (its target_tensions / target_displacements tip is the nominal one)."""
    ctl = scene.control
    if ctl is None:
        raise InputError("this job needs a [control] table")
    B, K = sim.B, scene.robot.n_tendons
    model = None if nominal is None else _tiled(nominal, B)
    if "target_tensions" in ctl or "target_displacements" in ctl:
        disp = "target_displacements" in ctl
        u = np.broadcast_to(np.array(ctl["target_displacements" if disp else "target_tensions"], float), (B, K))
        target = static_target(model or scene.robot, np.zeros((B, K)) if disp else u,
                               displacements=u if disp else None, options=scene.options, device=device)
    elif "path" in ctl:
        target = path_from_table(ctl["path"])
    else:
        target = ctl["target"]
    return TipController(sim, target, model_robot=model, **{k: ctl[k] for k in CONTROLLER_KEYS if k in ctl})


def control_job(scene: Scene, nominal: Scene | None = None, device=None, progress=None) -> dict[str, np.ndarray]:
    """One closed-loop run per rod; the controller models ``nominal``'s robot if given;
    ``progress(step, steps)`` is called after every time step."""
    if scene.dynamics is None or scene.control is None:
        raise InputError("this job needs [dynamics] and [control] tables")
    sim = scene_simulator(scene, device)
    controller = scene_controller(scene, sim, nominal, device)
    run = run_closed_loop(sim, controller, scene.dynamics.steps, progress=progress or False)
    m = control_metrics(run, controller.tau_max)
    ok = sim.failed_step < 0
    return {"ok": ok, "final_tip": run.tip_position[-1], "target": controller.target,
            **{k: v for k, v in m.items()}}


@dataclass(frozen=True)
class SweepJob:
    """The per-chunk job of a sweep command, picklable so that another process (a Ray
    worker) can run it: ``job(scene) -> dict of per-rod arrays``.

    name: montecarlo | workspace | gain-grid; device: Warp device (None: Warp's default);
    nominal: the base scene dict whose robot the Monte-Carlo controller models; shapes:
    return backbone positions too (statics jobs)."""

    name: str
    device: str | None = None
    nominal: dict | None = None
    shapes: bool = False

    def __call__(self, scene: Scene, progress=None) -> dict[str, np.ndarray]:
        """The chunk's per-rod arrays; ``progress(step, steps)``: the time steps of control runs."""
        if self.name == "gain-grid":
            return control_job(scene, device=self.device, progress=progress)
        res = static_job(scene, self.device, shapes=self.shapes)
        if self.name == "montecarlo" and scene.control is not None:
            ctl = control_job(scene, nominal=scene_from_dict(self.nominal), device=self.device, progress=progress)
            res["control_ok"] = ctl.pop("ok")
            res.update(ctl)
        return res


def _tiled(scene: Scene, B: int):
    """The nominal single-rod robot as a batch of B (so it pairs with B plants)."""
    if scene.robot.batch_size == B:
        return scene.robot
    data = dict(scene.source)
    data["actuation"] = dict(data["actuation"], tensions=[list(scene.tensions[0])] * B)
    return scene_from_dict(data).robot


def convex_hull_2d(pts: np.ndarray) -> np.ndarray:
    """Convex hull of 2D points (scipy.spatial, Qhull): its vertices counter-clockwise from the
    lowest-x (then lowest-y) one; a degenerate set (fewer than 3 distinct points, or all on a
    line) gives its distinct points, or the two ends of the line."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.unique(np.asarray(pts, dtype=np.float64), axis=0)  # sorted by x, then y
    if len(pts) < 3:
        return pts
    try:
        v = ConvexHull(pts).vertices  # counter-clockwise in 2D
    except QhullError:  # all on a line: its ends (the first and last in x, then y)
        return pts[[0, -1]]
    first = int(np.lexsort((pts[v, 1], pts[v, 0]))[0])
    return pts[np.roll(v, -first)]


def constant_curvature_tip(robot, tensions: np.ndarray) -> np.ndarray:
    """Closed-form constant-curvature tip (point-moment model: straight tendons ending at the
    tip, no external load, inextensible). Curvature u = sum_i r_i x (-tau_i e3) / EI."""
    L = float(robot.length[0])
    EI = float(robot.section()["kbt"][0, 0])
    u = np.zeros((len(tensions), 3))
    for k, t in enumerate(robot.tendons):
        r = np.array([t.offset[0, 0], t.offset[0, 1], 0.0])
        u += np.cross(r, [0.0, 0.0, -1.0])[None] * tensions[:, k:k + 1]
    u /= EI
    kappa = np.linalg.norm(u, axis=1)
    theta = kappa * L
    # bending about axis u: the tip moves along e3 x u / |u| (in the x-y plane)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(kappa[:, None] > 0, np.cross(u, [0.0, 0.0, 1.0]) / kappa[:, None], 0.0)
        lateral = np.where(kappa > 0, (1 - np.cos(theta)) / kappa, 0.0)
        axial = np.where(kappa > 0, np.sin(theta) / kappa, L)
    return d * lateral[:, None] + np.array([0.0, 0.0, 1.0]) * axial[:, None]


def pareto_front(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Indices of the points not dominated in (x, y), both minimised, sorted by x."""
    order = np.lexsort((y, x))
    front, best = [], math.inf
    for i in order:
        if y[i] < best:
            front.append(i)
            best = y[i]
    return np.array(front, dtype=int)


PLOT_POINTS = 20000  # rods drawn in a scatter figure (every stride-th row: the same whatever the chunks)
# |tip error| histogram: a zero bin, then 200 bins a decade from 1e-15 m to 10 m (percentiles to 1.2%)
ERROR_EDGES = np.concatenate([[0.0], np.logspace(-15, 1, 16 * 200 + 1)])


class Moments:
    """Count, mean and scatter matrix of points (n, d) merged chunk by chunk (Chan et al.)."""

    def __init__(self, d: int):
        self.n, self.mean, self.m2 = 0, np.zeros(d), np.zeros((d, d))

    def add(self, x: np.ndarray) -> None:
        if not len(x):
            return
        nb, mb = len(x), x.mean(axis=0)
        dx = x - mb
        delta, n = mb - self.mean, self.n + nb
        self.m2 += dx.T @ dx + np.outer(delta, delta) * (self.n * nb / n)
        self.mean = self.mean + delta * (nb / n)
        self.n = n

    def cov(self) -> np.ndarray | None:
        return self.m2 / (self.n - 1) if self.n > 1 else None


class Histogram:
    """Counts of values in fixed bins (``edges``; above the last edge: the last bin), with
    percentiles interpolated inside a bin."""

    def __init__(self, edges: np.ndarray):
        self.edges, self.counts = edges, np.zeros(len(edges) - 1, dtype=np.int64)
        self.max = -math.inf

    def add(self, v: np.ndarray) -> None:
        if len(v):
            i = np.clip(np.searchsorted(self.edges, v, side="right") - 1, 0, len(self.counts) - 1)
            self.counts += np.bincount(i, minlength=len(self.counts))
            self.max = max(self.max, float(v.max()))

    def percentile(self, p: float) -> float:
        cdf = np.cumsum(self.counts)
        k = p / 100 * cdf[-1]
        i = min(int(np.searchsorted(cdf, k)), len(self.counts) - 1)
        before = cdf[i - 1] if i else 0
        lo, hi = self.edges[i], min(self.edges[i + 1], self.max)
        return float(lo + (hi - lo) * ((k - before) / self.counts[i] if self.counts[i] else 0.0))


def _stride(rods: int) -> int:
    return max(1, rods // PLOT_POINTS)


def failure_counts(run) -> dict[str, int]:
    """The failed rods of every chunk counted per reason (jobs with status bits)."""
    from tdcr_warp.model.options import failure_reasons
    counts: dict[str, int] = {}
    for part in run.parts():
        if "status" not in part:
            return {}
        failure_reasons(part["status"], part["ok"].astype(bool), counts)
    return counts


def summarize_montecarlo(run, nominal_tip: np.ndarray, out: Path) -> dict:
    """The tip distribution of a Monte-Carlo sweep (and with control its success rate), one
    chunk at a time: moments merged exactly, error percentiles from a histogram (1.2%)."""
    from tdcr_warp.io.plotting import plot_montecarlo
    tips_m, err_h, stride = Moments(3), Histogram(ERROR_EDGES), _stride(run.rods)
    rods = failed = 0
    shown, control = [], None
    for part in run.parts():
        ok = part["ok"].astype(bool)
        rods, failed = rods + len(ok), failed + int((~ok).sum())
        tips = part["tip_position"][ok]
        tips_m.add(tips)
        err_h.add(np.linalg.norm(tips - nominal_tip, axis=1))
        shown.append(tips[part["row"][ok] % stride == 0])
        if "final_error" in part:
            control = control or {"runs": 0, "success": 0, "failed_runs": 0, "final": Histogram(ERROR_EDGES)}
            cok = part["control_ok"].astype(bool)
            control["runs"] += len(cok)
            control["success"] += int((cok & (part["final_error"] < 5e-4)).sum())
            control["failed_runs"] += int((~cok).sum())
            control["final"].add(part["final_error"][cok])
    cov, n = tips_m.cov(), tips_m.n
    summary = {"rods": rods, "failed": failed, "failure_rate": failed / rods,
               "tip_mean": tips_m.mean.tolist() if n else None, "tip_covariance": None if cov is None else cov.tolist(),
               "nominal_tip": nominal_tip.tolist(),
               "tip_error_percentiles_m": {str(p): err_h.percentile(p) for p in (5, 25, 50, 75, 95, 99)} if n else None,
               "percentile_resolution": "histogram of 200 bins a decade: 1.2% of the value"}
    if control is not None:
        fin = control["final"]
        summary["control"] = {"success_rate": control["success"] / control["runs"], "band_m": 5e-4,
                              "final_error_percentiles_m": {str(p): fin.percentile(p) for p in (50, 95, 99)}
                              if fin.counts.sum() else None, "failed_runs": control["failed_runs"]}
    if n:
        plot_montecarlo(np.concatenate(shown), nominal_tip, err_h, tips_m.mean, cov, out)
    return summary


def summarize_workspace(run, robot, out: Path, slices: int = 8) -> dict:
    """The tip cloud of a workspace sweep, in two passes over the chunks: the z range and the
    constant-curvature deviation, then a convex hull per height slice (merged hull by hull)."""
    from tdcr_warp.io.plotting import plot_workspace
    rods = failed = 0
    lo, hi = np.full(3, math.inf), np.full(3, -math.inf)
    dev, stride = Histogram(ERROR_EDGES), _stride(run.rods)
    shown = []
    for part in run.parts():
        ok = part["ok"].astype(bool)
        rods, failed = rods + len(ok), failed + int((~ok).sum())
        tips, tau = part["tip_position"][ok], part["tensions"][ok]
        if not len(tips):
            continue
        lo, hi = np.minimum(lo, tips.min(0)), np.maximum(hi, tips.max(0))
        cc = constant_curvature_tip(robot, tau)
        dev.add(np.linalg.norm(tips - cc, axis=1))
        pick = part["row"][ok] % stride == 0
        shown.append((tips[pick], tau[pick].sum(axis=1), cc[pick]))
    if rods == failed:
        return {"rods": rods, "failed": failed, "note": "no rod converged: no workspace to map"}
    edges = np.linspace(lo[2], hi[2] + 1e-12, slices + 1)
    hulls: list[np.ndarray] = [np.zeros((0, 2)) for _ in range(slices)]
    counts = np.zeros(slices, dtype=np.int64)
    for part in run.parts():
        tips = part["tip_position"][part["ok"].astype(bool)]
        which = np.searchsorted(edges, tips[:, 2], side="right") - 1
        for k in range(slices):
            sel = which == k
            if sel.any():
                counts[k] += int(sel.sum())
                hulls[k] = convex_hull_2d(np.concatenate([hulls[k], tips[sel, :2]]))
    boundary = [{"z_range": [float(a), float(b)], "hull_xy": hulls[k].tolist()}
                for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])) if counts[k] >= 3]
    t, tau, cc = (np.concatenate(x) for x in zip(*shown))
    plot_workspace(t, tau, cc, boundary, out)
    return {"rods": rods, "failed": failed, "tip_min": lo.tolist(), "tip_max": hi.tolist(), "boundary_slices": boundary,
            "constant_curvature_deviation_m": {"median": dev.percentile(50), "max": dev.max},
            "percentile_resolution": "histogram of 200 bins a decade: 1.2% of the value"}


def summarize_gain_grid(run, fields: list[str], out: Path) -> dict:
    """Best gains and the Pareto front (settling time vs chatter) of a gain grid, chunk by
    chunk: the front of the union is the front of the fronts; heat maps keep each cell's best."""
    from tdcr_warp.io.plotting import plot_gain_grid
    metrics = ("settling_time", "final_error", "chatter", "overshoot", "peak_tension")
    rods = failed = 0
    keep: dict[str, list] = {k: [] for k in ("row", "settle", "chatter", "error", *metrics, *fields)}
    cells: dict[tuple, np.ndarray] = {}
    a_f, b_f = fields[0], fields[min(1, len(fields) - 1)]
    stride, shown = _stride(run.rods), []

    def cut(kept: dict, idx: np.ndarray) -> dict:
        return {k: np.asarray(v)[idx] for k, v in kept.items()}

    for part in run.parts():
        ok = part["ok"].astype(bool)
        rods, failed = rods + len(ok), failed + int((~ok).sum())
        chunk = {"row": part["row"], "settle": np.where(ok, part["settling_time"], np.inf),
                 "chatter": np.where(ok, part["chatter"], np.inf), "error": np.where(ok, part["final_error"], np.inf),
                 **{k: part[k] for k in metrics}, **{f: part[f"sample:{f}"] for f in fields}}
        for x, y, *vals in zip(part[f"sample:{a_f}"], part[f"sample:{b_f}"],
                               *(np.where(np.isfinite(part[k]), part[k], np.nan) for k in metrics[:3])):
            cur = cells.get((x, y), np.full(3, np.nan))
            cells[(x, y)] = np.fmin(cur, vals)
        shown.append((chunk["settle"][part["row"] % stride == 0], chunk["chatter"][part["row"] % stride == 0]))
        merged = {k: np.concatenate([np.asarray(keep[k], dtype=np.asarray(chunk[k]).dtype), chunk[k]]) for k in keep}
        front = pareto_front(np.where(np.isfinite(merged["settle"]), merged["settle"], 1e9), merged["chatter"])
        front = front[np.isfinite(merged["settle"][front])]
        # the candidates of "best": the fastest settled run (ties: least chatter, then row) and the
        # smallest final error (used when nothing settled)
        best_s = np.lexsort((merged["row"], merged["chatter"], merged["settle"]))[:1]
        best_e = np.lexsort((merged["row"], merged["error"]))[:1]
        keep = cut(merged, np.unique(np.concatenate([front, best_s, best_e])))
    settled = np.isfinite(keep["settle"])
    best = (np.lexsort((keep["row"], keep["chatter"], keep["settle"])) if settled.any()
            else np.lexsort((keep["row"], keep["error"])))[0]
    front = pareto_front(np.where(settled, keep["settle"], 1e9), keep["chatter"])
    front = front[settled[front]]
    st, ch = (np.concatenate(x) for x in zip(*shown))
    plot_gain_grid(cells, (a_f, b_f), (st, ch), (keep["settle"][front], keep["chatter"][front]), out)
    return {"rods": rods, "failed": failed,
            "best": {"gains": {f: float(keep[f][best]) for f in fields}, **{k: float(keep[k][best]) for k in metrics}},
            "pareto": [{"gains": {f: float(keep[f][i]) for f in fields}, "settling_time": float(keep["settle"][i]),
                        "chatter": float(keep["chatter"][i])} for i in front]}
