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
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


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
