"""The users' jobs on top of chunked sweeps: Monte-Carlo robustness, workspace maps and
gain-grid searches. Each has a per-chunk job (scene -> per-rod arrays) and a summary
(results -> JSON-able statistics + figures).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .control import TipController, control_metrics, run_closed_loop
from .dynamics import Simulator
from .robot import InputError
from .scene import Scene, scene_from_dict
from .statics import solve_static

__all__ = ["SweepJob", "constant_curvature_tip", "control_job", "convex_hull_2d", "pareto_front", "static_job"]


def static_job(scene: Scene, device=None, shapes: bool = False) -> dict[str, np.ndarray]:
    """Compact per-rod statics: tip pose, convergence, status bits, iterations, residual,
    tensions; with ``shapes`` also the backbone positions (B, N+1, 3); with the solver's
    ``stability`` the stability index (and branch), with ``sensitivities`` the tip Jacobian and
    compliance."""
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=device, **scene.static_command())
    out = {"tip_position": sol.tip_position, "tip_rotation": sol.tip_rotation, "ok": sol.converged,
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
    if shapes:
        out["positions"] = sol.positions
    return out


def control_job(scene: Scene, nominal: Scene | None = None, device=None) -> dict[str, np.ndarray]:
    """One closed-loop run per rod; the controller models ``nominal``'s robot if given."""
    spec, ctl = scene.dynamics, scene.control
    if spec is None or ctl is None:
        raise InputError("this job needs [dynamics] and [control] tables")
    sim = Simulator(scene.robot, scene.tensions, dt=spec.dt, alpha=spec.alpha, options=scene.options, device=device)
    B = sim.B
    if "target_tensions" in ctl:
        model = (nominal or scene).robot
        tt = np.broadcast_to(np.array(ctl["target_tensions"], float), (B, scene.robot.n_tendons))
        target = solve_static(model if nominal is None else _tiled(nominal, B), tt, options=scene.options,
                              device=device).tip_position
    else:
        target = ctl["target"]
    kw = {k: ctl[k] for k in ("method", "input_model", "gain_c", "gain_k", "epsilon", "phi", "tension_max",
                              "model_every") if k in ctl}
    controller = TipController(sim, target, model_robot=None if nominal is None else _tiled(nominal, B), **kw)
    run = run_closed_loop(sim, controller, spec.steps)
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

    def __call__(self, scene: Scene) -> dict[str, np.ndarray]:
        if self.name == "gain-grid":
            return control_job(scene, device=self.device)
        res = static_job(scene, self.device, shapes=self.shapes)
        if self.name == "montecarlo" and scene.control is not None:
            ctl = control_job(scene, nominal=scene_from_dict(self.nominal), device=self.device)
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
    """Convex hull (counter-clockwise vertices) of 2D points, Andrew's monotone chain."""
    pts = np.unique(pts, axis=0)
    if len(pts) < 3:
        return pts

    def half(points):
        h = []
        for p in points:
            while len(h) >= 2 and _turn(h[-2], h[-1], p) <= 0:
                h.pop()
            h.append(p)
        return h
    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _turn(o, a, b) -> float:
    """z of (a - o) x (b - o): > 0 for a left turn."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


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


def summarize_montecarlo(res: dict, nominal_tip: np.ndarray, out: Path) -> dict:
    from .plotting import plot_montecarlo
    ok = res["ok"].astype(bool)
    tips = res["tip_position"][ok]
    err = np.linalg.norm(tips - nominal_tip, axis=1)
    summary = {"rods": int(len(ok)), "failed": int((~ok).sum()), "failure_rate": float((~ok).mean()),
               "tip_mean": tips.mean(axis=0).tolist() if len(tips) else None,
               "tip_covariance": np.cov(tips.T).tolist() if len(tips) > 1 else None,
               "nominal_tip": nominal_tip.tolist(),
               "tip_error_percentiles_m": {str(p): float(np.percentile(err, p)) for p in (5, 25, 50, 75, 95, 99)}
               if len(err) else None}
    if "final_error" in res:
        cok = res["control_ok"].astype(bool)
        success = cok & (res["final_error"] < 5e-4)
        summary["control"] = {"success_rate": float(success.mean()), "band_m": 5e-4,
                              "final_error_percentiles_m": {str(p): float(np.percentile(res["final_error"][cok], p))
                                                            for p in (50, 95, 99)} if cok.any() else None,
                              "failed_runs": int((~cok).sum())}
    if len(tips):
        plot_montecarlo(tips, nominal_tip, err, out)
    return summary


def summarize_workspace(res: dict, robot, out: Path, slices: int = 8) -> dict:
    from .plotting import plot_workspace
    ok = res["ok"].astype(bool)
    if not ok.any():
        return {"rods": len(ok), "failed": len(ok), "note": "no rod converged: no workspace to map"}
    tips, tau = res["tip_position"][ok], res["tensions"][ok]
    cc = constant_curvature_tip(robot, tau)
    z = tips[:, 2]
    edges = np.linspace(z.min(), z.max() + 1e-12, slices + 1)
    boundary = []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (z >= a) & (z < b)
        if sel.sum() >= 3:
            hull = convex_hull_2d(tips[sel, :2])
            boundary.append({"z_range": [float(a), float(b)], "hull_xy": hull.tolist()})
    plot_workspace(tips, tau.sum(axis=1), cc, boundary, out)
    dev = np.linalg.norm(tips - cc, axis=1)
    return {"rods": int(len(ok)), "failed": int((~ok).sum()), "tip_min": tips.min(0).tolist(),
            "tip_max": tips.max(0).tolist(), "boundary_slices": boundary,
            "constant_curvature_deviation_m": {"median": float(np.median(dev)), "max": float(dev.max())}}


def summarize_gain_grid(res: dict, fields: list[str], out: Path) -> dict:
    from .plotting import plot_gain_grid
    ok = res["ok"].astype(bool)
    settle = np.where(ok, res["settling_time"], np.inf)
    chatter = np.where(ok, res["chatter"], np.inf)
    front = pareto_front(np.where(np.isfinite(settle), settle, 1e9), chatter)
    front = front[np.isfinite(settle[front])]
    settled = np.isfinite(settle)
    # best: the fastest settling run (ties: least chatter); if none settled, the smallest final error
    best = int(np.lexsort((chatter, settle))[0]) if settled.any() else \
        int(np.argmin(np.where(ok, res["final_error"], np.inf)))
    gains = {f: float(res[f"sample:{f}"][best]) for f in fields}
    plot_gain_grid(res, fields, front, out)
    return {"rods": int(len(ok)), "failed": int((~ok).sum()),
            "best": {"gains": gains, **{k: float(res[k][best]) for k in ("settling_time", "final_error", "chatter",
                                                                         "overshoot", "peak_tension")}},
            "pareto": [{"gains": {f: float(res[f"sample:{f}"][i]) for f in fields},
                        "settling_time": float(settle[i]), "chatter": float(chatter[i])} for i in front]}
