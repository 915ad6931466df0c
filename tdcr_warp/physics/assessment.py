"""What a static solve adds to a solved chunk of rods: on request its sensitivities, by default the
stability test's verdict (``assess``), and for rods found unstable, on request, a search for a
stable equilibrium from restarts (``stable_branch``).
"""

from __future__ import annotations

import numpy as np

from tdcr_warp.core.build import Tables
from tdcr_warp.core.solver import Shooting
from tdcr_warp.kernels import layout
from tdcr_warp.model.options import StaticOptions
from tdcr_warp.model.robot import Robot
from tdcr_warp.physics.sensitivity import linearise
from tdcr_warp.physics.slack import settle_slack
from tdcr_warp.physics.stability import Verdict

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
        self.verdicts: dict[int, Verdict] = {}  # per Shooting (id), made on first use

    @property
    def unassessed(self) -> str:
        """Why the stability test does not apply to this batch ("" where it does)."""
        if self.tables.features.friction:
            return "friction (not conservative)"
        if self.opts.model == "point" and self.robot.n_tendons:
            return "point-model tendon loads (follower forces)"
        if self.tables.features.tip:
            return "a constrained tip (the test covers a free tip)"
        if self.opts.model == "disks" and len(self.robot.disks) > 1:
            return "disk model with more than one disk (a chord's pull depends on both holes it joins)"
        return ""

    def assess(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
               ptables: list, sensitivities: bool, stability: str) -> dict:
        """Rods lo:hi from their solution ``res``: with ``sensitivities`` (or parameters) the
        sensitivities (tdcr_warp.physics.sensitivity.linearise, probes from the solution), and unless
        ``stability`` is "off" the stability verdict on the device (tdcr_warp.physics.stability:
        index -1 where it is not assessed); taut (b, K) the taut set. The integrations add up."""
        t, o = self.tables, self.opts
        b = hi - lo
        out = {"integrations": res["integrations"]}
        if sensitivities:
            base = {"res": sh.newton.r.numpy().astype(np.float64), "p": res["positions"][:, -1],
                    "R": res["rotations"][:, -1]}
            lin = linearise(sh, tau, t, lo, hi, o.precision, ptables, base=base)
            out |= {k: lin[k] for k in ("tip_jacobian", "tip_compliance", "parameter_jacobian")}
            out["tension_jacobian"] = np.where(taut[:, :, None], lin["tension_jacobian"], 0.0)  # slack: no tension
            out["slack_jacobian"] = np.where(taut[:, :, None], 0.0, lin["slack_jacobian"])
            out["integrations"] = out["integrations"] + lin["integrations"]
        if stability != "off":
            ok = res["converged"].astype(bool)
            if self.unassessed:
                out |= {"stability_index": np.full(b, -1, dtype=np.int64), "lagrangian_error": np.full(b, np.nan),
                        "stability_margin": np.full(b, np.nan)}
            else:
                if id(sh) not in self.verdicts:
                    self.verdicts[id(sh)] = Verdict(sh, t, o.precision, sh.verdict_strides)
                v = self.verdicts[id(sh)](ok, taut if t.features.displaced else None, res["segments"])
                out |= {k: v[k] for k in ("stability_index", "lagrangian_error", "stability_margin")}
                out["integrations"] = out["integrations"] + np.where(ok, 1 + t.nu, 0)
        return out

    def stable_branch(self, sh: Shooting, lo: int, hi: int, tau: np.ndarray, taut: np.ndarray, res: dict,
                      ptables: list, sensitivities: bool, newton: dict, disp: np.ndarray, j_of: np.ndarray) -> dict:
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
            got = sh.results() | {"segments": np.ones(b, dtype=int)}  # single shooting's restarts
            got |= self.assess(sh, lo, hi, tau, taut, got, ptables, sensitivities, "check")
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
