"""Checks of solved contact shared by the tests, written from the rod's equations (no package
code): the centre line between the nodes integrated anew, and what is flagged where."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from tdcr_warp.kernels import layout
from tdcr_warp.physics.contact import penetration

E3 = np.array([0.0, 0.0, 1.0])


def between_nodes_only(sol, radius, tolerance=0.01):
    """(B,) bool: flagged PENETRATION only for what lies between the nodes: every node within the
    contact tolerance (``tolerance`` x ``radius`` [m]), an interval beyond it (a convex obstacle
    reaching in between two nodes that hold it off: the node-lumped law's error, shrinking with
    the node spacing)."""
    limit = tolerance * radius
    node = penetration(sol.contact_gap).max(axis=1)
    interval = penetration(sol.interval_gap).max(axis=1)
    return ((sol.status & layout.PENETRATION) != 0) & (node <= limit) & (interval > limit)


def centre_line(rod: dict, s: np.ndarray, base_wrench: np.ndarray, node_force: np.ndarray, per_interval=16):
    """The centre line of one solved rod sampled ``per_interval`` times in every interval, (M, 3)
    [m]: integrated anew (SciPy DOP853) from the base, p(0) = 0, R(0) = I, with its base wrench
    [n(0), m(0)] (6,) and the point force ``node_force`` (N+1, 3) [N] taken off n at every node.
    ``rod``: length, radius, youngs_modulus, poisson_ratio, density, gravity; no tendons, no
    precurvature. Kse = diag(GA, GA, EA), Kbt = diag(EI, EI, 2GI); v = Kse^-1 R^T n + e3,
    u = Kbt^-1 R^T m; p' = R v, R' = R [u]x, n' = -rho A g, m' = -p' x n."""
    E, nu, r = rod["youngs_modulus"], rod["poisson_ratio"], rod["radius"]
    G, A, inertia = E / (2 * (1 + nu)), np.pi * r**2, np.pi * r**4 / 4
    kse, kbt = np.array([G * A, G * A, E * A]), np.array([E * inertia, E * inertia, 2 * G * inertia])
    f = rod["density"] * A * np.asarray(rod["gravity"], float)

    def rhs(_s, y):
        R, n, m = y[3:12].reshape(3, 3), y[12:15], y[15:18]
        v, u = R.T @ n / kse + E3, R.T @ m / kbt
        dp = R @ v
        dR = R @ np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
        return np.concatenate([dp, dR.ravel(), -f, -np.cross(dp, n)])

    y = np.concatenate([np.zeros(3), np.eye(3).ravel(), base_wrench[:3], base_wrench[3:]])
    points = []
    for i in range(len(s) - 1):
        y[12:15] -= node_force[i]
        sol = solve_ivp(rhs, (s[i], s[i + 1]), y, method="DOP853", rtol=1e-11, atol=1e-13, dense_output=True)
        points.append(sol.sol(np.linspace(s[i], s[i + 1], per_interval + 1)[:-1])[0:3].T)
        y = sol.y[:, -1]
    points.append(y[None, 0:3])
    return np.concatenate(points)
