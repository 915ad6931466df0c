"""Figures of solved rods and trajectories (matplotlib, Agg backend: no screen needed)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tdcr_warp.io.drawing import AXIS_COLOURS, DISK_COLOUR, TENSION_SCALE, rod_colours  # noqa: E402
from tdcr_warp.io.files import write_atomic  # noqa: E402

MAX_RODS_DRAWN = 200
OBSTACLE_COLOUR = "0.45"  # the obstacles' outlines: grey


def _save(fig, path: Path) -> None:
    """Save atomically (tdcr_warp.io.files.write_atomic), then close the figure."""
    try:
        write_atomic(path, lambda tmp: fig.savefig(tmp, dpi=110))
    finally:
        plt.close(fig)


MAX_ROBOTS_DRAWN = 10  # rods drawn with disks and tendons; further rods: backbone only
MM = 1e3  # the robot figures are drawn in millimetres
BOX_FLOOR = 1 / 3  # no side of the 3D box or the side view shorter than this fraction of its longest side
MARGIN = 0.05  # space around the drawing, a fraction of its longest extent on every side
RIM_POINTS = 48  # segments of a disk's rim
RING = np.linspace(0.0, 2 * np.pi, RIM_POINTS + 1)  # [rad] around a rim
ROBOT_VIEWS = {"3d": (0, 1, 2), "side": (0, 2), "top": (0, 1)}  # world components drawn by each view


def _view_box(points: np.ndarray, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits (C,) of a box holding ``points`` (P, C) on one scale on every axis:
    each side the points' extent plus MARGIN x the longest extent either way, and at least
    ``floor`` x the longest side (a straight rod is not drawn as a sliver)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    longest = max(float((hi - lo).max()), 1e-9)
    side = np.maximum(hi - lo + 2 * MARGIN * longest, floor * (1 + 2 * MARGIN) * longest)
    centre = (lo + hi) / 2
    return centre - side / 2, centre + side / 2


def _base_rings(geom) -> np.ndarray:
    """Rings (B, RIM_POINTS + 1, 3) [m] of the disks' radius in the x-y plane around each rod's base."""
    ring = np.stack([np.cos(RING), np.sin(RING), np.zeros_like(RING)], axis=-1) * geom.disk_radius
    return geom.backbone[:, :1] + ring


def _robot_extent(geom) -> dict:
    """Per view of ROBOT_VIEWS: the points (P, C) [m] it must hold: backbones, tendons, the base,
    every disk and the frames' axes (the top view: the tip disk and the base ring, no frames) of the
    rods drawn."""
    n = MAX_ROBOTS_DRAWN
    rims = geom.disk_rims(RIM_POINTS)[:n]
    body = [geom.backbone.reshape(-1, 3), np.zeros((1, 3))] + [t[:n].reshape(-1, 3) for t in geom.tendon_points]
    axes_ends = geom.axis_length * np.concatenate([np.eye(3), np.swapaxes(geom.tip_rotation[:n], 1, 2).reshape(-1, 3)])
    axes_ends[3:] += np.repeat(geom.tip_position[:n], 3, axis=0)
    every = np.concatenate(body + [rims.reshape(-1, 3), axes_ends])
    top = np.concatenate(body + [rims[:, -1:].reshape(-1, 3), _base_rings(geom)[:n].reshape(-1, 3)])
    return {key: (top if key == "top" else every)[:, list(comp)] for key, comp in ROBOT_VIEWS.items()}


def _robot_axes(fig, extent: dict) -> dict:
    """A 3D view, a side view (x-z) and a top view (x-y) in mm, each on one scale on all its axes
    (the robot's true shape) around its points of ``extent`` (:func:`_robot_extent`); the 3D box
    and the side view no narrower than BOX_FLOOR x their height."""
    from matplotlib.ticker import MaxNLocator

    grid = fig.add_gridspec(1, 3, width_ratios=(1.0, 0.7, 1.3))
    axes = {"3d": fig.add_subplot(grid[0], projection="3d"), "side": fig.add_subplot(grid[1]),
            "top": fig.add_subplot(grid[2])}
    ax3 = axes["3d"]
    lo, hi = (x * MM for x in _view_box(extent["3d"], BOX_FLOOR))
    for c, set_lim in enumerate((ax3.set_xlim, ax3.set_ylim, ax3.set_zlim)):
        set_lim(lo[c], hi[c])
    ax3.set_box_aspect(hi - lo, zoom=0.95)
    ax3.view_init(elev=18, azim=-60)
    for c, axis in enumerate((ax3.xaxis, ax3.yaxis, ax3.zaxis)):
        axis.set_major_locator(MaxNLocator(max(3, round(6 * (hi[c] - lo[c]) / (hi - lo).max()))))
    ax3.set_xlabel("x [mm]")
    ax3.set_ylabel("y [mm]")
    ax3.set_zlabel("z [mm]", labelpad=18)
    ax3.set_title("3D view")
    for key, title in (("side", "side (x-z)"), ("top", "top (x-y): base (dashed) to tip disk")):
        ax = axes[key]
        lo, hi = (x * MM for x in _view_box(extent[key], BOX_FLOOR if key == "side" else 0.0))
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{'xyz'[ROBOT_VIEWS[key][0]]} [mm]")
        ax.set_ylabel(f"{'xyz'[ROBOT_VIEWS[key][1]]} [mm]")
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
    return axes


def _draw_robot(axes: dict, geom, converged, tension_norm, cmap) -> None:
    """Draw every rod of ``geom`` (drawing.RobotGeometry) into the views ``axes`` (3d, side, top;
    :func:`_robot_axes`): backbone, every disk (the top view: the tip disk alone, not a stack of
    rims, and a dashed ring of the disks' radius around the base), every tendon coloured by its
    tension, its ends (top view), the base and tip frames (3d and side), the obstacles' outlines
    (rod 0's). Artists carry a gid: backbone, disk, base, tendon, tendon end, frame, obstacle."""
    rims, rings = geom.disk_rims(RIM_POINTS), _base_rings(geom)
    colours = rod_colours(geom.rods)
    length = geom.axis_length

    def line(keys, pts, *fmt, **kw):
        for key in keys:
            axes[key].plot(*(pts[..., c] * MM for c in ROBOT_VIEWS[key]), *fmt, **kw)
    for outline in geom.obstacles:
        line(ROBOT_VIEWS, outline, color=OBSTACLE_COLOUR, lw=1.0, gid="obstacle", zorder=0)
    for b in range(geom.rods):
        ok = converged is None or bool(converged[b])
        full = b < MAX_ROBOTS_DRAWN
        line(ROBOT_VIEWS, geom.backbone[b], color=colours[b], lw=2.5 if full else 1.0, ls="-" if ok else "--",
             gid="backbone", zorder=3)
        if not full:
            continue
        for d in range(rims.shape[1]):
            line(("3d", "side") if d < rims.shape[1] - 1 else ROBOT_VIEWS, rims[b, d], color=DISK_COLOUR, lw=0.8,
                 gid="disk", zorder=1)
        line(("top",), rings[b], color=DISK_COLOUR, lw=0.8, ls="--", gid="base", zorder=1)
        for k, pts in enumerate(geom.tendon_points):
            colour = cmap(tension_norm(float(geom.tension[b, k])))
            line(ROBOT_VIEWS, pts[b], color=colour, lw=1.5, gid="tendon", zorder=2)
            line(("top",), pts[b, -1], "o", color=colour, mec="k", mew=0.5, ms=5, gid="tendon end", zorder=4)
        for origin, R in ((np.zeros(3), np.eye(3)), (geom.tip_position[b], geom.tip_rotation[b])):
            for c in range(3):
                line(("3d", "side"), np.stack([origin, origin + length * R[:, c]]), color=AXIS_COLOURS[c], lw=1.5,
                     gid="frame", zorder=3)


def _tension_scale(tensions: np.ndarray):
    """The tension colours: Normalize from 0 to the largest of ``tensions`` [N] and drawing's
    TENSION_SCALE as a colour map."""
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    top = float(np.max(tensions)) if tensions.size else 0.0
    return Normalize(0.0, top if top > 0 else 1.0), LinearSegmentedColormap.from_list("tension", TENSION_SCALE)


def _robot_legend(fig, geom, converged, cmap) -> None:
    """The legend below the views: each rod's backbone (one rod: "backbone"), disks, tendons and
    the frames' axes."""
    from matplotlib.legend_handler import HandlerTuple
    from matplotlib.lines import Line2D

    colours = rod_colours(geom.rods)
    shown = min(geom.rods, MAX_ROBOTS_DRAWN)
    handles = [Line2D([], [], color=colours[b], lw=2.5, ls="-" if converged is None or converged[b] else "--")
               for b in range(shown)]
    labels = ["backbone"] if geom.rods == 1 else [
        f"rod {b}" + ("" if converged is None or converged[b] else " (not converged)") for b in range(shown)]
    handles += [Line2D([], [], color=DISK_COLOUR, lw=0.8), Line2D([], [], color=cmap(0.6), lw=1.5),
                tuple(Line2D([], [], color=c, lw=1.5) for c in AXIS_COLOURS)]
    labels += ["spacer disks", "tendons (colour: tension)", "base and tip frames (x, y, z)"]
    if geom.obstacles:
        handles.append(Line2D([], [], color=OBSTACLE_COLOUR, lw=1.0))
        labels.append("obstacles")
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 7), fontsize=9, frameon=False,
               handler_map={tuple: HandlerTuple(ndivide=None)})


def _robot_figure(geom, extent: dict, tensions: np.ndarray, converged, size: tuple):
    """The figure, its views, legend and tension colour bar (scale: 0 to the largest of ``tensions``)."""
    fig = plt.figure(figsize=size, layout="constrained")
    axes = _robot_axes(fig, extent)
    norm, cmap = _tension_scale(tensions)
    _robot_legend(fig, geom, converged, cmap)
    if geom.tendon_points:
        fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes["top"], location="bottom", shrink=0.8,
                     aspect=30, label="tendon tension [N]")
    return fig, axes, norm, cmap


def plot_robot(geom, path: Path | None = None, converged=None, title: str | None = None):
    """The robot as roboticists draw it, from a drawing.RobotGeometry, in mm: a 3D view, a side
    view (x-z) and a top view (x-y), each on one scale on all its axes (the true shape): backbone
    (thick; several rods: a colour each), spacer disks (the top view: the tip disk), every
    tendon's path through the disks coloured by its tension (colour bar), base and tip frames
    (x red, y green, z blue), a legend below; the title: rod 0's tip and tensions. Rods beyond
    MAX_ROBOTS_DRAWN are drawn as backbones only. Returns the Figure (saved to ``path`` and
    closed if given)."""
    fig, axes, norm, cmap = _robot_figure(geom, _robot_extent(geom), geom.tension[:MAX_ROBOTS_DRAWN], converged,
                                          (13, 6.4))
    _draw_robot(axes, geom, converged, norm, cmap)
    tip = geom.tip_position[0] * MM
    tensions = ", ".join(f"{k}: {t:.2f}" for k, t in enumerate(geom.tension[0]))
    fig.suptitle(title or f"rod 0: tip ({tip[0]:.1f}, {tip[1]:.1f}, {tip[2]:.1f}) mm, "
                          f"{np.linalg.norm(tip[:2]):.1f} mm off the axis; tendon tensions [N] {tensions}")
    if path is not None:
        _save(fig, path)
    return fig


def animate_robot(frames: list, times: np.ndarray, path: Path, converged=None, fps: int = 15, max_frames: int = 120):
    """An animated GIF (Pillow) of a run from its stored shapes: ``frames`` a list of
    drawing.RobotGeometry (one per stored step), ``times`` (S,) [s]. At most ``max_frames``
    frames (evenly picked), every frame on the same axes (:func:`plot_robot`'s views, holding
    every frame), the tips' path so far (dotted) in the side and top views. Returns the frames drawn."""
    from matplotlib.animation import FuncAnimation, PillowWriter

    pick = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    extents = [_robot_extent(frames[i]) for i in pick]
    extent = {key: np.concatenate([e[key] for e in extents]) for key in ROBOT_VIEWS}
    tensions = np.stack([frames[i].tension[:MAX_ROBOTS_DRAWN] for i in pick])
    fig, axes, norm, cmap = _robot_figure(frames[pick[0]], extent, tensions, converged, (11, 5.6))
    title = fig.suptitle(f"t = {times[pick[-1]]:.3f} s", x=0.02, ha="left")
    tips = np.stack([frames[i].tip_position[:MAX_ROBOTS_DRAWN] for i in pick]) * MM  # (F, B, 3) [mm]
    fig.canvas.draw()
    fig.set_layout_engine("none")  # laid out once: every frame keeps the same axes

    def draw(n):
        for ax in axes.values():
            for ln in list(ax.lines):
                ln.remove()
        _draw_robot(axes, frames[pick[n]], converged, norm, cmap)
        for key in ("side", "top"):
            i, j = ROBOT_VIEWS[key]
            axes[key].plot(tips[:n + 1, :, i], tips[:n + 1, :, j], ":", color="0.35", lw=1.0, gid="tip path")
        title.set_text(f"t = {times[pick[n]]:.3f} s")
    anim = FuncAnimation(fig, draw, frames=len(pick))
    try:
        write_atomic(path, lambda tmp: anim.save(tmp, writer=PillowWriter(fps=fps), dpi=80))
    finally:
        plt.close(fig)
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
    in time's direction) with the sliding surface S = e_t + C e = 0 of ``gain_c`` (B, 3) [1/s]
    (at most ``MAX_RODS_DRAWN`` rods)."""
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


def _coarse_histogram(hist, per_decade: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Counts and edges of ``hist`` (jobs.Histogram of log-spaced bins) over its used bins,
    merged into about ``per_decade`` bins a decade (a readable histogram of a few thousand values);
    the last edge at the largest value."""
    used = np.flatnonzero(hist.counts)
    lo, hi = used[0], used[-1] + 1
    counts, edges = hist.counts[lo:hi], hist.edges[lo:hi + 1]
    step = max(1, round(np.log(10.0) / np.log(hist.edges[-1] / hist.edges[-2]) / per_decade))
    starts = np.arange(0, len(counts), step)
    return np.add.reduceat(counts, starts), np.append(edges[starts], min(edges[-1], max(hist.max, edges[0])))


def _deviation_panel(ax, err_hist, rods: int) -> None:
    """The histogram of the tips' distance from the nominal tip (log x) with its median and 95th percentile."""
    counts, edges = _coarse_histogram(err_hist)
    ax.stairs(counts, edges * 1e3, fill=True, color="C0", alpha=0.8)
    if edges[0] > 0:
        ax.set_xscale("log")
    for p, ls in ((50, "-"), (95, "--")):
        v = err_hist.percentile(p) * 1e3
        ax.axvline(v, color="k", ls=ls, lw=1, label=f"{'median' if p == 50 else f'{p}th percentile'}: {v:.2g} mm")
    ax.set_xlabel("|tip - nominal tip| [mm]")
    ax.set_ylabel("rods per bin (20 bins a decade)")
    ax.set_title(f"tip deviation ({rods:,} rods)")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)


def plot_montecarlo(tips: np.ndarray, nominal: np.ndarray, err_hist, mean: np.ndarray, cov: np.ndarray | None,
                    out_dir: Path) -> None:
    """Histogram of the tip deviation from the nominal tip (``err_hist``: jobs.Histogram of
    every rod; median and 95th percentile marked), and the tips from above (x-y, equal axes) and
    from the side (x-z, z stretched) in mm (``tips``: an evenly spaced subset of the rods) with
    1, 2, 3 sigma confidence ellipses of all rods' ``mean`` and ``cov``."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6), layout="constrained")
    _deviation_panel(axes[0], err_hist, int(err_hist.counts.sum()))
    for ax, (i, j), title in zip(axes[1:], ((0, 1), (0, 2)), ("tips from above (x-y, equal axes)",
                                                            "tips from the side (x-z, z stretched)")):
        ax.scatter(tips[:, i] * 1e3, tips[:, j] * 1e3, s=6, alpha=0.5, color="C0", lw=0,
                   label=f"tips ({len(tips):,} drawn)")
        if cov is not None:
            sd = np.sqrt(np.maximum(np.diag(cov), 0.0)) * 1e3
            for k in (1, 2, 3):
                e = _ellipse(mean[[i, j]], cov[np.ix_([i, j], [i, j])], k)
                ax.plot(e[0] * 1e3, e[1] * 1e3, color="0.25", lw=0.7, label=(
                    f"1, 2, 3 sigma (sigma {'xyz'[i]} {sd[i]:.2g}, {'xyz'[j]} {sd[j]:.2g} mm)") if k == 1 else None)
        ax.plot(nominal[i] * 1e3, nominal[j] * 1e3, "r+", ms=14, mew=2, label="nominal tip")
        if j == 1:
            ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"{'xyz'[i]} [mm]")
        ax.set_ylabel(f"{'xyz'[j]} [mm]")
        ax.set_title(title)
        ax.legend(fontsize=8, markerscale=2)
        ax.grid(True, alpha=0.3)
    _save(fig, out_dir / "montecarlo.png")


def _workspace_3d(fig, spec, tips: np.ndarray, tau: np.ndarray, norm):
    """The tip cloud [mm] in 3D, the box twice as wide as tall (z stretched; the factor in the title)."""
    from matplotlib.ticker import MaxNLocator

    ax = fig.add_subplot(spec, projection="3d")
    sc = ax.scatter(*tips.T, c=tau, s=2, cmap="viridis", norm=norm, depthshade=False)
    span = np.maximum(np.ptp(tips, axis=0), 1e-9)
    box = np.array([span[0], span[1], 0.5 * max(span[0], span[1])])
    ax.set_box_aspect(box, zoom=0.8)  # room for the z label inside the panel
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.zaxis.set_major_locator(MaxNLocator(4))
    ax.set_zlabel("z [mm]", labelpad=2)
    ax.set_title(f"3D (z stretched x{box[2] / span[2] * span[0] / box[0]:.0f})")
    return sc


def plot_workspace(tips: np.ndarray, total_tension: np.ndarray, cc: np.ndarray, boundary: list, out_dir: Path) -> None:
    """The tip cloud [mm] coloured by total tension (where several tensions reach one tip, the
    least is drawn on top): 3D, top (x-y, equal axes, the convex hull of each height slice) and
    side (x-z, z stretched: a workspace is a thin bowl) views, the constant-curvature prediction
    of the same tensions (grey) under the side view's tips, and the distance between the two
    models [µm] against the tip's horizontal reach."""
    from matplotlib.colors import Normalize

    sub = np.arange(0, len(tips), max(1, len(tips) // 30000))
    sub = sub[np.argsort(-total_tension[sub], kind="stable")]  # the least tension on top: the least that reaches a tip
    t, c, tau = tips[sub] * 1e3, cc[sub] * 1e3, total_tension[sub]
    norm = Normalize(float(tau.min()), float(tau.max()) if tau.max() > tau.min() else float(tau.min()) + 1.0)
    fig = plt.figure(figsize=(17, 4.8), layout="constrained")
    grid = fig.add_gridspec(1, 4, width_ratios=(1.35, 1, 1, 1))
    sc = _workspace_3d(fig, grid[0], t, tau, norm)
    top, side, dev = (fig.add_subplot(grid[k]) for k in (1, 2, 3))
    top.scatter(t[:, 0], t[:, 1], c=tau, s=3, cmap="viridis", norm=norm)
    for k, sl in enumerate(boundary):
        h = np.array(sl["hull_xy"] + sl["hull_xy"][:1]) * 1e3
        top.plot(h[:, 0], h[:, 1], "k-", lw=0.5, alpha=0.6, label="outline of each height slice" if k == 0 else None)
    top.set_aspect("equal", adjustable="datalim")
    top.set_title("top (x-y): where the tip reaches")
    side.scatter(c[:, 0], c[:, 2], s=14, c="0.8", label="constant curvature")
    side.scatter(t[:, 0], t[:, 2], s=3, c=tau, cmap="viridis", norm=norm, label="Cosserat (this model)")
    side.set_title("side (x-z), z stretched")
    for ax, j in ((top, 1), (side, 2)):
        ax.set_xlabel("x [mm]")
        ax.set_ylabel(f"{'xyz'[j]} [mm]")
    gap = np.linalg.norm(t - c, axis=1) * 1e3  # [µm]
    dev.scatter(np.linalg.norm(t[:, :2], axis=1), gap, s=3, c=tau, cmap="viridis", norm=norm)
    dev.set_xlabel("horizontal reach sqrt(x^2 + y^2) [mm]")
    dev.set_ylabel("|Cosserat - constant curvature| [µm]")
    dev.set_title(f"the two models' tips (at most {gap.max():.3g} µm apart)")
    for ax in (top, side, dev):
        ax.grid(True, alpha=0.3)
    for ax in (top, side) if boundary else (side,):
        ax.legend(markerscale=3, fontsize=8, loc="lower right" if ax is top else "lower center")
    fig.colorbar(sc, ax=dev, label="total tension [N]", shrink=0.9)
    _save(fig, out_dir / "workspace.png")


def _cell_grid(cells: dict, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first field's values (A,), the second's (C,) and metric ``m`` of every cell (C, A) (NaN where none)."""
    ua = np.unique([a for a, _ in cells])
    ub = np.unique([b for _, b in cells])
    grid = np.full((len(ub), len(ua)), np.nan)
    for (a, b), vals in cells.items():
        grid[np.searchsorted(ub, b), np.searchsorted(ua, a)] = vals[m]
    return ua, ub, grid


def _gain_heatmap(fig, ax, cells: dict, m: int, fields: tuple, best: tuple) -> None:
    """Heatmap of metric ``m`` (0 settling time [s], 1 final error [mm], 2 chatter [N], the last
    two on a log scale) over the first two gain fields; blank (hatched): no settled run; a star on
    the ``best`` cell (None: none); settling times written in their cells."""
    from matplotlib.colors import LogNorm, Normalize

    ua, ub, grid = _cell_grid(cells, m)
    grid = grid * (1e3 if m == 1 else 1.0)
    finite = grid[np.isfinite(grid)]
    positive = finite[finite > 0]
    if not finite.size:  # no run settled
        norm = Normalize(0.0, 1.0)
    elif m == 0 or not positive.size:
        norm = Normalize(finite.min(), finite.max())
    else:
        norm = LogNorm(positive.min(), positive.max())
    ax.add_patch(plt.Rectangle((0, 0), len(ua), len(ub), fill=False, hatch="//", color="0.8", lw=0, zorder=0))
    im = ax.imshow(np.where(grid > 0, grid, np.nan) if m else grid, origin="lower", aspect="auto", cmap="magma_r",
                   norm=norm, extent=(0, len(ua), 0, len(ub)), zorder=1)
    if m == 0:
        for (r, c), v in np.ndenumerate(grid):
            if np.isfinite(v):
                ax.text(c + 0.5, r + 0.5, f"{v:.2f}", ha="center", va="center", fontsize=6,
                        color="w" if norm(v) > 0.6 else "k")
    if best is not None:
        ax.plot(np.searchsorted(ua, best[0]) + 0.5, np.searchsorted(ub, best[1]) + 0.5, "*", ms=14, mfc="c", mec="k",
                gid="best")
    ax.set_xticks(np.arange(len(ua)) + 0.5, [f"{x:.3g}" for x in ua], fontsize=8)
    ax.set_yticks(np.arange(len(ub)) + 0.5, [f"{y:.3g}" for y in ub], fontsize=8)
    ax.set_xlabel(fields[0])
    ax.set_ylabel(fields[1])
    ax.set_title(("settling time [s] (hatched: never settled)", "final error [mm]", "chatter index [N]")[m])
    fig.colorbar(im, ax=ax)


def plot_gain_grid(cells: dict, fields: tuple, scatter: tuple, front: tuple, out_dir: Path) -> None:
    """Heatmaps over the first two gain fields (``cells``: (a, b) -> the best settling time [s],
    final error [m] and chatter [N] over the other fields), the fastest-settling cell starred (if any
    settled), and settling time vs chatter (``scatter``: a subset of the runs) with the Pareto ``front``."""
    settle = {k: v[0] for k, v in cells.items() if np.isfinite(v[0])}
    best = min(settle, key=lambda k: (settle[k], cells[k][2])) if settle else None
    fig, axes = plt.subplots(1, 4, figsize=(19, 4.6), layout="constrained")
    for m in range(3):
        _gain_heatmap(fig, axes[m], cells, m, fields, best)
    st, ch = scatter
    ok = np.isfinite(st) & (ch > 0)
    ax = axes[3]
    ax.scatter(st[ok], ch[ok], s=8, alpha=0.5, label=f"runs ({ok.sum()} settled of {len(st)} drawn)")
    if len(front[0]):
        ax.plot(front[0], front[1], "r.-", ms=8, label="Pareto front")
    ax.set_xlabel("settling time [s]")
    ax.set_ylabel("chatter index [N]")
    ax.set_yscale("log")
    ax.set_title("each run: settling time vs chatter")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.suptitle("each cell: the best run over the other gain fields; star: the fastest-settling cell", fontsize=10)
    _save(fig, out_dir / "gain_grid.png")


def plot_prediction(measured: np.ndarray, predicted: np.ndarray, converged: np.ndarray, path: Path) -> None:
    """Measured against predicted tips (M, 3) [mm] of the converged rows: in 3D on one scale
    (the box sized by the tips' extent), the error's length per row (its median over 25 rows,
    the median and RMSE marked) and the histograms of its x, y, z components; the title: the
    converged rows, RMSE and median."""
    ok = np.asarray(converged, dtype=bool)
    err = np.where(ok[:, None], predicted - measured, np.nan)
    size = np.linalg.norm(err, axis=1)
    rmse, median = float(np.sqrt(np.nanmean(size ** 2))), float(np.nanmedian(size))
    fig = plt.figure(figsize=(16, 5), layout="constrained")
    grid = fig.add_gridspec(1, 3, width_ratios=(1.2, 1.3, 1))
    ax3 = fig.add_subplot(grid[0], projection="3d")
    ax3.scatter(*measured[ok].T, s=3, color="C0", label="measured", depthshade=False)
    ax3.scatter(*predicted[ok].T, s=3, color="C1", label="predicted", depthshade=False)
    ax3.set_box_aspect(np.ptp(np.concatenate([measured[ok], predicted[ok]]), axis=0), zoom=0.85)
    from matplotlib.ticker import MaxNLocator
    ax3.zaxis.set_major_locator(MaxNLocator(4))
    for axis, name in ((ax3.set_xlabel, "x"), (ax3.set_ylabel, "y"), (ax3.set_zlabel, "z")):
        axis(f"{name} [mm]")
    ax3.set_title("tips (one scale on x, y, z)")
    ax3.legend(markerscale=4, loc="upper left")
    ax = fig.add_subplot(grid[1])
    rows = np.arange(len(size))
    ax.plot(rows, size, ".", ms=2, color="0.6", label="|predicted - measured| per row")
    window = min(25, len(size))
    run = np.array([np.nanmedian(size[max(0, i - window // 2):i + window // 2 + 1]) for i in rows])
    ax.plot(rows, run, "k-", lw=1, label=f"its median over {window} rows")
    ax.axhline(rmse, color="C3", ls="--", lw=1, label=f"RMSE {rmse:.2f} mm")
    ax.axhline(median, color="C3", ls=":", lw=1, label=f"median {median:.2f} mm")
    ax.set_xlabel("row of the data file")
    ax.set_ylabel("tip error [mm]")
    ax.set_title("tip error per row")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(alpha=0.3)
    ax = fig.add_subplot(grid[2])
    bins = np.linspace(np.nanmin(err), np.nanmax(err), 60) if ok.any() else 10
    for i, name in enumerate("xyz"):
        e = err[ok, i]
        ax.hist(e, bins=bins, histtype="step", lw=1.2, label=f"{name}: mean {e.mean():+.2f}, sd {e.std():.2f} mm")
    ax.set_xlabel("predicted - measured [mm]")
    ax.set_ylabel("rows per bin")
    ax.set_title("error components")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.suptitle(f"{ok.sum()} of {len(ok)} rows converged: RMSE {rmse:.2f} mm, median {median:.2f} mm")
    _save(fig, path)


def plot_search(history: list[dict], candidates: tuple, grid: tuple | None, settled_below: float, path: Path) -> None:
    """A gain search's best-so-far objective against closed loops spent (``history``: per
    generation ``closed_loops`` and ``best_objective``), each candidate's objective (``candidates``:
    (closed loops spent after its generation, objective)), the objective value above which runs
    did not settle (``settled_below``, shaded above) and, with ``grid`` = (objective, closed loops),
    the exhaustive grid's best as a line and a point at its cost. Log axes, plain tick labels."""
    from matplotlib.ticker import FuncFormatter

    fig, ax = plt.subplots(figsize=(8, 4.8), layout="constrained")
    loops, f = candidates
    ax.scatter(loops, f, s=6, alpha=0.35, color="C0", label="candidates (one closed loop each)")
    x = [h["closed_loops"] for h in history]
    ax.step(x, [h["best_objective"] for h in history], where="post", color="C1", lw=2, label="search: best so far")
    if grid is not None:
        ax.axhline(grid[0], color="C3", ls="--", lw=1, label="grid's best")
        ax.plot([grid[1]], [grid[0]], "o", color="C3", label=f"grid: {grid[1]:,} closed loops")
    ax.axhspan(settled_below, max(float(np.max(f)), settled_below) * 1.5, color="0.9", zorder=0)
    ax.text(x[0], settled_below, " did not settle (above)", va="bottom", fontsize=8, color="0.35")
    ax.set_xscale("log")
    ax.set_yscale("log")
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(plain)
    ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}"[-1] in "2357" else ""))
    ax.set_xlabel("closed loops spent")
    ax.set_ylabel("objective: settling time [s] (settled runs)")
    ax.set_title("gain search (CMA-ES) against the exhaustive grid")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8, loc="upper right")
    _save(fig, path)
