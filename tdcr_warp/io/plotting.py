"""Figures of solved rods and trajectories (matplotlib, Agg backend: no screen needed)."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

MAX_RODS_DRAWN = 200


def _save(fig, path: Path) -> None:
    """Save atomically: a hidden temporary file in the same directory, then a rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()


MAX_ROBOTS_DRAWN = 10  # rods drawn with disks and tendons; further rods: backbone only
FRAME_COLOURS = ("tab:red", "tab:green", "tab:blue")  # x, y, z axes of the base and tip frames


def _equal_limits(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) and half-width of a cube holding every point (..., 3)."""
    pts = points.reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return (lo + hi) / 2, max(float((hi - lo).max()) / 2 * 1.08, 1e-6)


def _draw_robot(axes: dict, geom, converged, tension_norm, cmap) -> None:
    """Draw every rod of ``geom`` (drawing.RobotGeometry) into the 3D axes ``axes['3d']`` and
    the projections ``axes[(i, j)]`` (world components i, j). Artists carry a gid: backbone,
    disk, tendon, frame."""
    B = geom.rods
    L = float(geom.s[:, -1].max())
    views = [("3d", (0, 1, 2))] + [(k, k) for k in axes if k != "3d"]

    def line(pts, **kw):
        for key, comp in views:
            ax = axes[key]
            ax.plot(*(pts[..., c] for c in comp), **kw)
    rims = geom.disk_rims()
    for b in range(B):
        ok = converged is None or bool(converged[b])
        colour = f"C{b % 10}" if ok else "red"
        full = b < MAX_ROBOTS_DRAWN
        line(geom.backbone[b], color=colour, lw=3.0 if full else 1.0, ls="-" if ok else "--", gid="backbone",
             label=(f"rod {b}" if ok else f"rod {b} (not converged)") if b < 20 else None)
        if not full:
            continue
        for d in range(rims.shape[1]):
            line(rims[b, d], color="0.55", lw=0.7, gid="disk")
        for k, pts in enumerate(geom.tendon_points):
            tau = float(geom.tension[b, k])
            line(pts[b], color=cmap(tension_norm(tau)), lw=1.6, gid="tendon")
        for origin, R in ((np.zeros(3), np.eye(3)), (geom.tip_position[b], geom.tip_rotation[b])):
            for c in range(3):
                line(np.stack([origin, origin + 0.05 * L * R[:, c]]), color=FRAME_COLOURS[c], lw=1.5, gid="frame")


def _robot_axes(fig, points: np.ndarray) -> dict:
    """A 3D view (a cube around every point: the true shape), a side view (x-z) and a top view
    (x-y), each 2D view with equal axes around its own extent of ``points`` (P, 3)."""
    axes = {"3d": fig.add_subplot(1, 3, 1, projection="3d"), (0, 2): fig.add_subplot(1, 3, 2),
            (0, 1): fig.add_subplot(1, 3, 3)}
    ax3 = axes["3d"]
    centre, half = _equal_limits(points)
    for c, set_lim in enumerate((ax3.set_xlim, ax3.set_ylim, ax3.set_zlim)):
        set_lim(centre[c] - half, centre[c] + half)
    ax3.set_box_aspect((1, 1, 1))
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    for (i, j), title in (((0, 2), "side (x-z)"), ((0, 1), "top (x-y)")):
        ax = axes[(i, j)]
        lo, hi = points[:, [i, j]].min(axis=0), points[:, [i, j]].max(axis=0)
        mid, h = (lo + hi) / 2, max(float((hi - lo).max()) / 2 * 1.1, 1e-6)
        ax.set_xlim(mid[0] - h, mid[0] + h)
        ax.set_ylim(mid[1] - h, mid[1] + h)
        ax.set_aspect("equal")
        ax.set_xlabel(f"{'xyz'[i]} [m]")
        ax.set_ylabel(f"{'xyz'[j]} [m]")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
    return axes


def _tension_scale(tensions: np.ndarray):
    from matplotlib.colors import Normalize
    top = float(np.max(tensions)) if tensions.size else 0.0
    return Normalize(0.0, top if top > 0 else 1.0), plt.get_cmap("plasma")


def plot_robot(geom, path: Path | None = None, converged=None, title: str | None = None):
    """The robot as roboticists draw it, from a drawing.RobotGeometry: backbone (a thick line,
    one colour per rod, legend), disks, every tendon's path through the disks coloured by its
    tension (colour bar; rod 0's tensions in the title), base and tip frames
    (x red, y green, z blue), in a 3D view, a side view and a top view, all with equal axes.
    Rods beyond MAX_ROBOTS_DRAWN are drawn as backbones only. Returns the Figure (saved to
    ``path`` and closed if given)."""
    pts = np.concatenate([p.reshape(-1, 3) for p in [geom.backbone, *geom.tendon_points]] + [np.zeros((1, 3))])
    fig = plt.figure(figsize=(15, 5.2), layout="constrained")
    axes = _robot_axes(fig, pts)
    norm, cmap = _tension_scale(geom.tension[:MAX_ROBOTS_DRAWN])
    _draw_robot(axes, geom, converged, norm, cmap)
    dx = np.linalg.norm(geom.tip_position[0, :2]) * 1e3
    tensions = ", ".join(f"{k}: {t:.2f}" for k, t in enumerate(geom.tension[0]))
    axes["3d"].set_title(title or f"rod 0: tip {np.round(geom.tip_position[0] * 1e3, 1).tolist()} mm "
                                  f"({dx:.1f} mm off the axis)\ntendon tensions [N] {tensions}", fontsize=9)
    if geom.rods > 1:
        axes[(0, 2)].legend(fontsize=7, loc="best")
    if geom.tendon_points:
        fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes[(0, 1)], shrink=0.8,
                     label="tendon tension [N]")
    if path is not None:
        _save(fig, path)
    return fig


def animate_robot(frames: list, times: np.ndarray, path: Path, converged=None, fps: int = 15, max_frames: int = 120):
    """An animated GIF (Pillow) of a run from its stored shapes: ``frames`` a list of
    drawing.RobotGeometry (one per stored step), ``times`` (S,) [s]. At most ``max_frames``
    frames (evenly picked), every frame on the same equal axes. Returns the frames drawn."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    pick = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    every = np.concatenate([np.concatenate([g.backbone.reshape(-1, 3)] + [t.reshape(-1, 3) for t in g.tendon_points])
                            for g in (frames[i] for i in pick)] + [np.zeros((1, 3))])
    norm, cmap = _tension_scale(np.stack([frames[i].tension[:MAX_ROBOTS_DRAWN] for i in pick]))
    fig = plt.figure(figsize=(12, 4.4), layout="constrained")
    axes = _robot_axes(fig, every)
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes[(0, 1)], shrink=0.8, label="tendon tension [N]")
    fig.canvas.draw()
    fig.set_layout_engine("none")  # laid out once: every frame keeps the same axes

    def draw(n):
        for ax in axes.values():
            for ln in list(ax.lines):
                ln.remove()
        _draw_robot(axes, frames[pick[n]], converged, norm, cmap)
        axes["3d"].set_title(f"t = {times[pick[n]]:.3f} s", fontsize=9)
    anim = FuncAnimation(fig, draw, frames=len(pick))
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        anim.save(tmp, writer=PillowWriter(fps=fps), dpi=80)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
    return len(pick)


def plot_tip_history(time: np.ndarray, tip: np.ndarray, vel: np.ndarray, acc: np.ndarray, out_dir: Path) -> None:
    """The report's figures 2 and 3: tip x and z, tip velocity and acceleration against time
    (T+1, B, 3 arrays; at most ``MAX_RODS_DRAWN`` rods)."""
    nb = min(tip.shape[1], MAX_RODS_DRAWN)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, c, name in ((axes[0], 0, "x"), (axes[1], 2, "z")):
        ax.plot(time, tip[:, :nb, c] * 1e3, lw=1)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"tip {name} [mm]")
        ax.grid(True, alpha=0.3)
    fig.suptitle("tip position")
    fig.tight_layout()
    _save(fig, out_dir / "tip_position.png")
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for row, (data, unit, name) in enumerate(((vel, "m/s", "velocity"), (acc, "m/s^2", "acceleration"))):
        for col, (c, comp) in enumerate(((0, "x"), (2, "z"))):
            ax = axes[row, col]
            ax.plot(time, data[:, :nb, c], lw=1)
            ax.set_xlabel("t [s]")
            ax.set_ylabel(f"tip {name} {comp} [{unit}]")
            ax.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "tip_rates.png")


def _time_arrows(ax, x: np.ndarray, y: np.ndarray) -> None:
    """Mark where a phase curve starts (o) and ends (x), with arrows along it: time's direction."""
    ax.plot(x[0], y[0], "ko", ms=4)
    ax.plot(x[-1], y[-1], "kx", ms=6)
    for f in (0.1, 0.3, 0.6):
        i = int(f * (len(x) - 2))
        if x[i + 1] != x[i] or y[i + 1] != y[i]:
            ax.annotate("", xy=(x[i + 1], y[i + 1]), xytext=(x[i], y[i]),
                        arrowprops=dict(arrowstyle="->", color="k", lw=0.8))


def plot_control(run, out_dir: Path, tension_max=None, gain_c=None) -> None:
    """The report's control figures: tip displacement; tension history with its mean and the
    tension limit ``tension_max`` (B, K) [N] (and the commanded motor displacements, if any);
    error norm and the phase portraits x vs x_t and e vs e_t (x components, start o, end x, arrows
    in time's direction) with the sliding surface S = e_t + C e = 0 of ``gain_c`` (B, 3) [1/s] (at most ``MAX_RODS_DRAWN`` rods)."""
    nb = min(run.tip_position.shape[1], MAX_RODS_DRAWN)
    t = run.time
    desired = (run.tip_position + run.error)[:, :nb]  # the target, or the desired path, over time
    fig, axes = plt.subplots(1, 4, figsize=(17, 4))
    for c, ax in enumerate(axes[:3]):
        ax.plot(t, run.tip_position[:, :nb, c] * 1e3, lw=1)
        ax.plot(t, desired[..., c] * 1e3, "k--", lw=0.8)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"tip {'xyz'[c]} [mm]")
        ax.grid(True, alpha=0.3)
    axes[3].plot(run.tip_position[:, :nb, 0] * 1e3, run.tip_position[:, :nb, 1] * 1e3, lw=1, gid="actual")
    axes[3].plot(desired[..., 0] * 1e3, desired[..., 1] * 1e3, "k--", lw=0.8, gid="desired")
    axes[3].set_xlabel("x [mm]")
    axes[3].set_ylabel("y [mm]")
    axes[3].set_aspect("equal", adjustable="datalim")
    axes[3].set_title("tip path (x-y)")
    axes[3].grid(True, alpha=0.3)
    fig.suptitle("tip against the desired tip (dashed)")
    fig.tight_layout()
    _save(fig, out_dir / "control_tip.png")
    disp = run.displacements.size > 0  # commanded displacements: a second panel
    fig, axes = plt.subplots(1, 2 if disp else 1, figsize=(13 if disp else 7, 4), squeeze=False)
    ax = axes[0, 0]
    K = run.tensions.shape[2]
    for k in range(K):
        line, = ax.plot(t[1:], run.tensions[:, 0, k], lw=1, label=f"tendon {k + 1}")
        if disp:
            axes[0, 1].plot(t[1:], run.displacements[:, 0, k] * 1e3, lw=1, color=line.get_color())
        ax.axhline(run.tensions[:, 0, k].mean(), color=line.get_color(), ls="--", lw=0.8)
    if tension_max is not None:
        limits = np.unique(np.broadcast_to(tension_max, (run.tensions.shape[1], K))[0])
        for i, lim in enumerate(limits[np.isfinite(limits)]):
            ax.axhline(lim, color="k", ls=":", lw=1.2, label="tension limit" if i == 0 else None)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tension [N] (rod 0; dashed: mean)")
    ax.set_title("tendon tensions")
    ax.legend()
    ax.grid(True, alpha=0.3)
    if disp:
        axes[0, 1].set_xlabel("t [s]")
        axes[0, 1].set_ylabel("motor displacement [mm] (rod 0; pull +)")
        axes[0, 1].set_title("commanded displacements")
        axes[0, 1].grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "control_tension.png")
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
    axes[0].semilogy(t, np.linalg.norm(run.error[:, :nb], axis=2) + 1e-12, lw=1)
    axes[0].set_xlabel("t [s]")
    axes[0].set_ylabel("|e| [m]")
    axes[0].set_title("tip error")
    x_mm, v = run.tip_position[:, :nb, 0] * 1e3, run.tip_velocity[:, :nb, 0]
    e_mm, e_t = run.error[:, :nb, 0] * 1e3, -run.tip_velocity[:, :nb, 0]
    axes[1].plot(x_mm, v, lw=1)
    axes[1].set_xlabel("x [mm]")
    axes[1].set_ylabel("x_t [m/s]")
    axes[1].set_title("phase portrait of the tip (x)")
    axes[2].plot(e_mm, e_t, lw=1)
    if gain_c is not None:
        C = float(np.broadcast_to(gain_c, (run.tip_position.shape[1], 3))[0, 0])
        lim = np.array([e_mm.min(), e_mm.max()])
        axes[2].plot(lim, -C * lim / 1e3, "r--", lw=1, label=f"S = e_t + C e = 0 (C = {C:g} 1/s)")
        axes[2].legend(fontsize=8)
    axes[2].set_xlabel("e_x [mm]")
    axes[2].set_ylabel("e_x,t [m/s]")
    axes[2].set_title("error phase portrait (x)")
    for b in range(min(nb, 3)):
        _time_arrows(axes[1], x_mm[:, b], v[:, b])
        _time_arrows(axes[2], e_mm[:, b], e_t[:, b])
    for ax in axes:
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "control_error_phase.png")


def _ellipse(mean2: np.ndarray, cov2: np.ndarray, k: float) -> np.ndarray:
    w, V = np.linalg.eigh(cov2)
    t = np.linspace(0, 2 * np.pi, 100)
    return mean2[:, None] + V @ (k * np.sqrt(np.maximum(w, 0))[:, None] * np.stack([np.cos(t), np.sin(t)]))


def plot_montecarlo(tips: np.ndarray, nominal: np.ndarray, err_hist, mean: np.ndarray, cov: np.ndarray | None,
                    out_dir: Path) -> None:
    """Histogram of the tip deviation from the nominal tip (``err_hist``: jobs.Histogram of
    every rod), and tip scatter (x-y, x-z; ``tips``: an evenly spaced subset of the rods) with
    1, 2, 3 sigma confidence ellipses of all rods' ``mean`` and ``cov``."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    used = np.flatnonzero(err_hist.counts)
    lo, hi = used[0], used[-1] + 1
    edges = err_hist.edges[lo:hi + 1]
    axes[0].stairs(err_hist.counts[lo:hi], np.minimum(edges, max(err_hist.max, edges[0])) * 1e3, fill=True, color="C0")
    axes[0].set_xlabel("|tip - nominal tip| [mm]")
    axes[0].set_ylabel("rods per bin (200 bins a decade)")
    if edges[0] > 0:
        axes[0].set_xscale("log")
    for ax, (i, j) in zip(axes[1:], ((0, 1), (0, 2))):
        ax.scatter(tips[:, i] * 1e3, tips[:, j] * 1e3, s=2, alpha=0.3)
        if cov is not None:
            for k in (1, 2, 3):
                e = _ellipse(mean[[i, j]], cov[np.ix_([i, j], [i, j])], k)
                ax.plot(e[0] * 1e3, e[1] * 1e3, "k-", lw=0.8)
        ax.plot(nominal[i] * 1e3, nominal[j] * 1e3, "r+", ms=12, label="nominal")
        ax.set_xlabel(f"{'xyz'[i]} [mm]")
        ax.set_ylabel(f"{'xyz'[j]} [mm]")
        ax.legend()
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "montecarlo.png")


def plot_workspace(tips: np.ndarray, total_tension: np.ndarray, cc: np.ndarray, boundary: list, out_dir: Path) -> None:
    """Tip cloud: 3D, top (x-y, equal axes) and side (x-z, z scaled to its own extent: a workspace
    is a thin bowl) views coloured by total tension, the convex hull per height slice, and the
    constant-curvature prediction (grey) beside it."""
    sub = slice(None, None, max(1, len(tips) // 30000))
    fig = plt.figure(figsize=(16, 5), layout="constrained")
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    sc = ax3.scatter(tips[sub, 0], tips[sub, 1], tips[sub, 2], c=total_tension[sub], s=1, cmap="viridis")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    both = np.concatenate([tips[sub], cc[sub]])
    for k, (i, j, name) in enumerate(((0, 1, "top (x-y)"), (0, 2, "side (x-z), z exaggerated"))):
        ax = fig.add_subplot(1, 3, k + 2)
        ax.scatter(cc[sub, i], cc[sub, j], s=1, c="0.75", label="constant curvature")
        ax.scatter(tips[sub, i], tips[sub, j], s=1, c=total_tension[sub], cmap="viridis", label="Cosserat")
        if i == 0 and j == 1:
            for sl in boundary:
                h = np.array(sl["hull_xy"] + sl["hull_xy"][:1])
                ax.plot(h[:, 0], h[:, 1], "k-", lw=0.6)
            ax.set_aspect("equal", adjustable="datalim")
        else:
            lo, hi = both[:, j].min(), both[:, j].max()
            pad = 0.05 * max(hi - lo, 1e-6)
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_xlabel(f"{'xyz'[i]} [m]")
        ax.set_ylabel(f"{'xyz'[j]} [m]")
        ax.set_title(name)
        ax.legend(markerscale=8, fontsize=8)
        ax.grid(True, alpha=0.3)
    fig.colorbar(sc, ax=fig.axes[-1], label="total tension [N]", shrink=0.8)
    _save(fig, out_dir / "workspace.png")


def plot_gain_grid(cells: dict, fields: tuple, scatter: tuple, front: tuple, out_dir: Path) -> None:
    """Heatmaps over the first two gain fields (``cells``: (a, b) -> the best settling time,
    final error and chatter over the other fields) and settling time vs chatter (``scatter``:
    a subset of the runs) with the Pareto ``front``."""
    ua = np.unique([a for a, _ in cells])
    ub = np.unique([b for _, b in cells])
    fig, axes = plt.subplots(1, 4, figsize=(18, 4.2))
    for m, (ax, label) in enumerate(zip(axes[:3], ("settling time [s]", "final error [m]", "chatter index [N]"))):
        grid = np.full((len(ub), len(ua)), np.nan)
        for (a, b), vals in cells.items():
            grid[np.searchsorted(ub, b), np.searchsorted(ua, a)] = vals[m]
        im = ax.imshow(grid, origin="lower", aspect="auto", cmap="magma_r",
                       extent=(0, len(ua), 0, len(ub)))
        ax.set_xticks(np.arange(len(ua)) + 0.5, [f"{x:.3g}" for x in ua], rotation=90, fontsize=7)
        ax.set_yticks(np.arange(len(ub)) + 0.5, [f"{y:.3g}" for y in ub], fontsize=7)
        ax.set_xlabel(fields[0])
        ax.set_ylabel(fields[1])
        ax.set_title(label)
        fig.colorbar(im, ax=ax)
    st, ch = scatter
    axes[3].scatter(np.where(np.isfinite(st), st, np.nan), ch, s=4, alpha=0.4)
    if len(front[0]):
        axes[3].plot(front[0], front[1], "r.-", label="Pareto front")
        axes[3].legend()
    axes[3].set_xlabel("settling time [s]")
    axes[3].set_ylabel("chatter index [N]")
    axes[3].set_yscale("symlog", linthresh=1e-6)
    axes[3].grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "gain_grid.png")


def plot_prediction(measured: np.ndarray, predicted: np.ndarray, converged: np.ndarray, path: Path) -> None:
    """Measured against predicted tips (M, 3) [mm] in 3D, and the error per axis against row."""
    fig = plt.figure(figsize=(12, 5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ok = converged
    ax3.scatter(*measured[ok].T, s=4, color="C0", label="measured")
    ax3.scatter(*predicted[ok].T, s=4, color="C1", label="predicted")
    ax3.set_xlabel("x [mm]")
    ax3.set_ylabel("y [mm]")
    ax3.set_zlabel("z [mm]")
    ax3.legend()
    ax = fig.add_subplot(1, 2, 2)
    err = np.where(ok[:, None], predicted - measured, np.nan)
    for i, name in enumerate("xyz"):
        ax.plot(err[:, i], lw=0.8, label=f"{name}")
    ax.plot(np.linalg.norm(err, axis=1), color="k", lw=0.8, label="|error|")
    ax.set_xlabel("row")
    ax.set_ylabel("predicted - measured [mm]")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


def plot_search(history: list[dict], candidates: tuple, grid: tuple | None, settled_below: float, path: Path) -> None:
    """A gain search's best-so-far objective against closed loops spent (``history``: per
    generation ``closed_loops`` and ``best_objective``), each candidate's objective (``candidates``:
    (closed loops spent after its generation, objective)), the objective value above which runs
    did not settle (``settled_below``) and, with ``grid`` = (objective, closed loops), the exhaustive
    grid's best as a line and a point at its cost."""
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    loops, f = candidates
    ax.scatter(loops, f, s=5, alpha=0.3, color="C0", label="candidates")
    x = [h["closed_loops"] for h in history]
    ax.step(x, [h["best_objective"] for h in history], where="post", color="C1", label="search: best so far")
    if grid is not None:
        ax.axhline(grid[0], color="C3", ls="--", lw=1, label="grid's best")
        ax.plot([grid[1]], [grid[0]], "o", color="C3", label=f"grid: {grid[1]:,} closed loops")
    ax.axhline(settled_below, color="0.5", lw=0.8)
    ax.text(x[0], settled_below, " unsettled above", va="bottom", fontsize=8, color="0.4")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("closed loops spent")
    ax.set_ylabel("objective (settled: settling time [s])")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
