"""What a static solve adds to a solved chunk of rods on request: its sensitivities and the
stability test's verdict (``linearised``), and for rods found unstable a search for a stable
equilibrium from restarts (``stable_branch``).
"""

from __future__ import annotations

import functools

import numpy as np

from tdcr_warp.core.build import Tables
from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.model.options import StaticOptions
from tdcr_warp.model.robot import Robot
from tdcr_warp.physics.sensitivity import linearise
from tdcr_warp.physics.slack import settle_slack
from tdcr_warp.physics.stability import jacobi_index, node_routing

__all__ = ["DISTINCT", "RESTARTS", "Assessor"]

# Restarts of an unstable rod: (scaled base-moment unknown, added moment in units of
# max(1, lambda L) EI / L, lambda L = sqrt(P L^2 / EI) for the axial compression P at the
# base). The bent branch of a compressed cantilever has a base moment of about 0.8 to 2
# lambda L EI / L (the elastica from 1.1 to 10 times the buckling load).
RESTARTS = tuple((j, sign * size) for size in (1.0, 2.0, 4.0) for j in (3, 4) for sign in (1.0, -1.0))
DISTINCT = 1e-6  # stable equilibria whose tips are this many rod lengths apart are distinct


class Assessor:
    """The sensitivities and stability of the solved chunks of one robot batch (``tables``) under
    one set of solver options."""

    def __init__(self, robot: Robot, tables: Tables, opts: StaticOptions):
        self.robot, self.tables, self.opts = robot, tables, opts

    @functools.cached_property
    def node_routes(self) -> tuple[np.ndarray, np.ndarray]:
        """r and r' of every tendon at the grid's nodes (tdcr_warp.physics.stability.node_routing), once."""
        return node_routing(self.robot, self.tables.grid)

    def linearised(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
                   ptables: list, stability: str) -> dict:
        """The sensitivities and (``stability``) the Jacobi index of rods lo:hi from their
        solution ``res`` (the base of the probes: its shapes and residual); taut (b, K) the taut set."""
        t, o = self.tables, self.opts
        base = {"res": sh.newton.r.numpy().astype(np.float64), "p": res["positions"][:, -1],
                "R": res["rotations"][:, -1], "P": res["positions"], "Rn": res["rotations"], "n": res["n"],
                "m": res["m"]}
        K = tau.shape[1]
        assess = stability != "off" and not t.features.friction and (o.model == "coupled" or K == 0)
        lin = linearise(sh, tau, t, lo, hi, o.precision, ptables, base=base, shapes=assess)
        b = hi - lo
        out = {k: lin[k] for k in ("tip_jacobian", "tip_compliance", "parameter_jacobian")}
        out["tension_jacobian"] = np.where(taut[:, :, None], lin["tension_jacobian"], 0.0)  # slack: no tension
        out["slack_jacobian"] = np.where(taut[:, :, None], 0.0, lin["slack_jacobian"])
        if stability != "off":
            index, lag = np.full(b, -1, dtype=np.int64), np.full(b, np.nan)
            if assess:
                tension = res["tendons"][..., layout.TO_BASE] if "tendons" in res else tau
                index, lag, _ = jacobi_index(sh, lin, t, self.node_routes, lo, hi, tension, o.precision,
                                             o.rod == "kirchhoff", o.model == "coupled",
                                             taut if t.features.displaced else None)
                index = np.where(res["converged"], index, -1)
            out |= {"stability_index": index, "lagrangian_error": lag}
        out["integrations"] = res["integrations"] + lin["integrations"]
        return out

    def stable_branch(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
                      ptables: list, newton: dict, disp: np.ndarray, j_of: np.ndarray) -> dict:
        """Rods whose equilibrium is unstable are solved again from restarts (``RESTARTS``: the
        solution with an added base moment about each bending axis, both ways, of growing
        size); the first stable equilibrium found is returned (branch 1), distinct
        stable ones are reported (multiple_stable); a rod with none keeps its unstable
        solution (branch -1). Iterations and integrations add up over the restarts."""
        b = hi - lo
        bad = res["stability_index"] > 0
        branch = np.zeros(b, dtype=np.int8)
        out = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in res.items()}
        if not bad.any():
            out["multiple_stable"] = np.zeros(b, dtype=bool)
            out["branch"] = branch
            return out
        x_star = res["x"]
        L = np.broadcast_to(self.tables.rows("rod", lo, hi)[:, layout.LENGTH], (b,))
        tips: list[list[np.ndarray]] = [[] for _ in range(b)]
        lam_l = np.sqrt(np.maximum(1.0, -x_star[:, 2]))  # x[2] = n_z(0) L^2 / EI
        for j, bend in RESTARTS:
            start = x_star.copy()
            start[:, j] += bend * lam_l
            sh.solve(start, mask=bad.astype(np.int32), **newton)
            if len(disp):
                settle_slack(sh, taut.copy(), disp, j_of, newton)
            it, sn = sh.counts()
            out["iterations"] = out["iterations"] + np.where(bad, it, 0)
            out["integrations"] = out["integrations"] + np.where(bad, sn, 0)
            got = sh.results()
            got |= self.linearised(sh, lo, hi, tau, taut, got, ptables, "check")
            ok = bad & got["converged"] & (got["stability_index"] == 0)
            for i in np.flatnonzero(ok):
                tip = got["positions"][i, -1]
                if all(np.linalg.norm(tip - t) > DISTINCT * L[i] for t in tips[i]):
                    tips[i].append(tip)
            take = ok & (branch == 0)
            for k, v in got.items():
                if isinstance(v, np.ndarray) and k not in ("iterations", "integrations"):
                    out[k][take] = v[take]
            branch[take] = 1
        branch[bad & (branch == 0)] = -1
        out["multiple_stable"] = np.array([len(t) > 1 for t in tips])
        out["branch"] = branch
        return out
