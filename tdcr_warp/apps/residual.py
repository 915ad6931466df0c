"""An optional learned correction on top of the physics, with an uncertainty per prediction: a
Gaussian process (scikit-learn's GaussianProcessRegressor) over the motors' commands [mm] that
predicts what the fitted physics misses at the measured point (measured less predicted [mm]; a
process per axis, each with its kernel: a constant times an RBF with a length per command, plus
white noise, fitted by maximum likelihood on the training rows only). Its mean is added to the physics'
prediction and its standard deviation (the noise included: an interval for a new measurement)
is each row's 1-sigma; ``Residual.interval`` gives the 95% interval. The physics alone stays the
default of ``predict``; experiments/hardware_families.py measures on motions the fit never saw
whether the residual helps or only memorises, and how often its 95% interval holds.

Saved as a plain .npz (``save`` / ``load``: the training commands and targets and the kernel's
hyperparameters; loading fits the process again with them fixed, which reproduces it exactly),
never a pickle."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tdcr_warp.model.robot import InputError

MAX_ROWS = 600  # training rows of the process (every n-th of more): its fit costs O(rows^3)
Z95 = 1.959963984540054  # the two-sided 95% quantile of the normal distribution
FORMAT = "tdcr-warp residual 1"


def _regressor(commands: int, theta: np.ndarray | None):
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    kernel = (ConstantKernel(1.0, (1e-3, 1e3)) * RBF(np.full(commands, 3.0), (1e-2, 1e3))
              + WhiteKernel(0.1, (1e-6, 1e1)))
    if theta is not None:
        return GaussianProcessRegressor(kernel.clone_with_theta(theta), optimizer=None, normalize_y=True)
    return GaussianProcessRegressor(kernel, normalize_y=True, n_restarts_optimizer=1, random_state=0)


@dataclass
class Residual:
    """A fitted correction: ``commands`` (n, K) [mm] and ``targets`` (n, 3) [mm] it was trained on,
    the kernels' log-hyperparameters ``theta`` (3, K + 2); ``gps`` the fitted process of each axis."""

    commands: np.ndarray
    targets: np.ndarray
    theta: np.ndarray
    gps: list

    def predict(self, commands: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean (M, 3), standard deviation (M, 3)) [mm] of the correction at ``commands`` (M, K)."""
        commands = np.asarray(commands, dtype=float)
        if commands.ndim != 2 or commands.shape[1] != self.commands.shape[1]:
            raise InputError(f"residual: commands of shape {commands.shape}, the residual was fitted on "
                             f"{self.commands.shape[1]} commands a row")
        out = [gp.predict(commands, return_std=True) for gp in self.gps]
        return np.stack([m for m, _ in out], axis=1), np.stack([s for _, s in out], axis=1)

    @staticmethod
    def interval(mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 95% interval (low, high) of each coordinate."""
        return mean - Z95 * std, mean + Z95 * std

    def save(self, path) -> None:
        with open(path, "wb") as f:  # a file object: numpy appends no .npz to the name
            np.savez(f, format=np.array(FORMAT), commands=self.commands, targets=self.targets, theta=self.theta)

    @classmethod
    def load(cls, path) -> "Residual":
        """A residual saved by ``save``; anything else (a pickle included) is an InputError."""
        try:
            with np.load(Path(path), allow_pickle=False) as z:
                if str(z["format"]) != FORMAT:
                    raise InputError(f"{path}: not a tdcr-warp residual (format {str(z['format'])!r})")
                X, Y, theta = (np.array(z[k], dtype=float) for k in ("commands", "targets", "theta"))
        except (OSError, ValueError, KeyError) as e:
            raise InputError(f"{path}: not a tdcr-warp residual file ({e})") from None
        if X.ndim != 2 or Y.shape != (len(X), 3) or theta.shape != (3, X.shape[1] + 2) or \
                not all(np.isfinite(a).all() for a in (X, Y, theta)):
            raise InputError(f"{path}: a residual's arrays have the wrong shapes or non-finite values")
        return cls(X, Y, theta, [_regressor(X.shape[1], t).fit(X, y) for t, y in zip(theta, Y.T)])


def fit_residual(commands: np.ndarray, targets: np.ndarray) -> Residual:
    from sklearn.exceptions import ConvergenceWarning

    """The process fitted on training rows: ``commands`` (M, K) [mm], ``targets`` (M, 3) [mm] (what
    the physics misses: measured less predicted; or the measured point itself for a residual
    alone), at most MAX_ROWS of them (every n-th)."""
    X, Y = np.asarray(commands, dtype=float), np.asarray(targets, dtype=float)
    keep = np.isfinite(X).all(axis=1) & np.isfinite(Y).all(axis=1)
    X, Y = X[keep], Y[keep]
    if len(X) < 2 * X.shape[1] + 4:
        raise InputError(f"residual: {len(X)} usable training rows, too few for a process over {X.shape[1]} "
                         f"commands (need at least {2 * X.shape[1] + 4})")
    take = np.arange(0, len(X), -(-len(X) // MAX_ROWS))
    with warnings.catch_warnings():  # a length at its bound: a command the correction does not depend on
        warnings.simplefilter("ignore", ConvergenceWarning)
        gps = [_regressor(X.shape[1], None).fit(X[take], y) for y in Y[take].T]
    return Residual(X[take], Y[take], np.stack([gp.kernel_.theta for gp in gps]), gps)


def coverage(measured: np.ndarray, mean: np.ndarray, std: np.ndarray) -> float:
    """The share of coordinates (of rows with finite values) whose measured value lies in the
    95% interval mean +- 1.96 std."""
    lo, hi = Residual.interval(mean, std)
    ok = np.isfinite(mean).all(axis=1) & np.isfinite(measured).all(axis=1)
    return float(((measured[ok] >= lo[ok]) & (measured[ok] <= hi[ok])).mean())
