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


def plot_shapes(positions: np.ndarray, converged: np.ndarray, path: Path) -> None:
    """3D view and x-z projection of rod shapes (B, N+1, 3) [m]; failed rods dashed red."""
    fig = plt.figure(figsize=(11, 5))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    for b in range(min(len(positions), MAX_RODS_DRAWN)):
        p = positions[b]
        style = dict(color="C0", lw=1.2) if converged[b] else dict(color="red", ls="--", lw=1.0)
        ax3.plot(p[:, 0], p[:, 1], p[:, 2], **style)
        ax2.plot(p[:, 0], p[:, 2], **style)
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.set_title("rod shapes")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("z [m]")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_title("x-z projection")
    ax2.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, path)


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


def plot_control(run, out_dir: Path) -> None:
    """The report's control figures: tip displacement, tension history with its mean, error
    norm, and the phase portraits x vs x_t and e vs e_t (x components; at most
    ``MAX_RODS_DRAWN`` rods)."""
    nb = min(run.tip_position.shape[1], MAX_RODS_DRAWN)
    t = run.time
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for c, ax in enumerate(axes):
        ax.plot(t, run.tip_position[:, :nb, c] * 1e3, lw=1)
        ax.plot(t, np.broadcast_to(run.target[:nb, c] * 1e3, (len(t), nb)), "k--", lw=0.8)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"tip {'xyz'[c]} [mm]")
        ax.grid(True, alpha=0.3)
    fig.suptitle("tip displacement (dashed: target)")
    fig.tight_layout()
    _save(fig, out_dir / "control_tip.png")
    fig, ax = plt.subplots(figsize=(7, 4))
    K = run.tensions.shape[2]
    for k in range(K):
        line, = ax.plot(t[1:], run.tensions[:, 0, k], lw=1, label=f"tendon {k + 1}")
        ax.axhline(run.tensions[:, 0, k].mean(), color=line.get_color(), ls="--", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("tension [N] (rod 0; dashed: mean)")
    ax.legend()
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    _save(fig, out_dir / "control_tension.png")
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    axes[0].semilogy(t, np.linalg.norm(run.error[:, :nb], axis=2) + 1e-12, lw=1)
    axes[0].set_xlabel("t [s]")
    axes[0].set_ylabel("|e| [m]")
    axes[1].plot(run.tip_position[:, :nb, 0] * 1e3, run.tip_velocity[:, :nb, 0], lw=1)
    axes[1].set_xlabel("x [mm]")
    axes[1].set_ylabel("x_t [m/s]")
    axes[2].plot(run.error[:, :nb, 0] * 1e3, -run.tip_velocity[:, :nb, 0], lw=1)
    axes[2].set_xlabel("e_x [mm]")
    axes[2].set_ylabel("e_x,t [m/s]")
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
    """Tip cloud: 3D, top (x-y) and side (x-z) views coloured by total tension, the convex hull
    per height slice, and the constant-curvature prediction (grey) beside it."""
    sub = slice(None, None, max(1, len(tips) // 30000))
    fig = plt.figure(figsize=(15, 4.8))
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    sc = ax3.scatter(tips[sub, 0], tips[sub, 1], tips[sub, 2], c=total_tension[sub], s=1, cmap="viridis")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    for k, (i, j, name) in enumerate(((0, 1, "top (x-y)"), (0, 2, "side (x-z)"))):
        ax = fig.add_subplot(1, 3, k + 2)
        ax.scatter(cc[sub, i], cc[sub, j], s=1, c="0.75", label="constant curvature")
        ax.scatter(tips[sub, i], tips[sub, j], s=1, c=total_tension[sub], cmap="viridis", label="Cosserat")
        if i == 0 and j == 1:
            for sl in boundary:
                h = np.array(sl["hull_xy"] + sl["hull_xy"][:1])
                ax.plot(h[:, 0], h[:, 1], "k-", lw=0.6)
        ax.set_xlabel(f"{'xyz'[i]} [m]")
        ax.set_ylabel(f"{'xyz'[j]} [m]")
        ax.set_title(name)
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(markerscale=8, fontsize=8)
        ax.grid(True, alpha=0.3)
    fig.colorbar(sc, ax=fig.axes, label="total tension [N]", shrink=0.8)
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
