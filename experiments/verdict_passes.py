"""The stability verdict's passes against a reference grid: how far their margins are off, how far
the phases move between steps, and whether a count that tdcr_warp/physics/stability.py's trust rule
keeps is ever wrong.

Each family (the report robot at working and at heavy tensions; columns under dead loads around
the Euler loads, both rod models; helical tendons; a precurved rod; with gravity) is solved once,
then its verdict is made by one pass alone at each of the first three passes of the cascade
(stability.passes: double steps 2, the full grid 1, -m: m steps an interval) and, as the reference, by 16 steps an interval on the same
solution (the fields of the same equilibrium, integrated 16x finer). Per family, N and pass: the
largest |margin - reference margin| [rad], the largest phase move between steps, the rods the trust
rule keeps, and among them how many counts differ from the reference (must be 0).

    python experiments/verdict_passes.py [--nodes 20 40 60] [--batch 256] [--smoke] [--out verdict_passes.json]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent)]
from _common import metadata, write_report

import tdcr_warp as tw
from tdcr_warp.core import solver
from tdcr_warp.physics import stability

E, NU, RB, L = 190e9, 0.3, 1e-3, 0.5
P_CR = np.pi**2 * E * np.pi * RB**4 / 4 / (4 * L**2)
FOUR = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
BASE = {"length": L, "youngs_modulus": E, "poisson_ratio": NU, "radius": RB, "density": 7800.0,
        "gravity": (0.0, 0.0, -9.81)}


def families(batch: int, rng) -> dict:
    """name: (robot, tensions, rod model)."""
    three = [tw.Tendon(offset=(0.01 * np.cos(a), 0.01 * np.sin(a))) for a in (0.0, 2.1, 4.2)]
    F = np.zeros((batch, 3))
    F[:, 2] = -rng.uniform(0.0, 12.0, batch) * P_CR  # past the second pair of Euler modes (9 P_CR)
    F[:, :2] = rng.normal(0.0, 0.02, (batch, 2)) * P_CR
    helix = [tw.Tendon(offset=(0.0, 0.0), helix_radius=0.01, turns=1.0, routing="helix"),
             tw.Tendon(offset=(0.0, 0.0), helix_radius=0.01, turns=-1.0, phase=np.pi, routing="helix")]
    report = tw.Robot(tendons=[tw.Tendon(offset=o) for o in FOUR], **(BASE | {"density": 17189.0}))
    return {
        "report robot, 0-3 N": (report, rng.uniform(0.0, 3.0, (batch, 4)), "cosserat"),
        "report robot, 0-30 N": (report, rng.uniform(0.0, 30.0, (batch, 4)), "cosserat"),
        "column 0-12 P_cr, cosserat": (tw.Robot(tendons=three, tip_force=F, **BASE), rng.uniform(0, 3, (batch, 3)),
                                       "cosserat"),
        "column 0-12 P_cr, kirchhoff": (tw.Robot(tendons=three, tip_force=F, **BASE), rng.uniform(0, 3, (batch, 3)),
                                        "kirchhoff"),
        "helical tendons": (tw.Robot(tendons=helix, tip_force=F, **BASE), rng.uniform(0, 3, (batch, 2)), "cosserat"),
        "precurved": (tw.Robot(tendons=three, tip_force=F, **(BASE | {"precurvature": (2.0, 0.0, 0.5)})),
                      rng.uniform(0, 3, (batch, 3)), "cosserat"),
    }


def one_pass(robot, tau, nodes: int, rod: str, stride: int) -> dict:
    """The verdict of every rod by the pass of ``stride`` alone, with that pass's trust rule."""
    kept = {"trusted": [], "jumps": []}  # per chunk of the solve, in order
    run = stability.Verdict._run

    def only(self, mask, _stride):
        left = run(self, mask, stride)
        kept["trusted"].append(mask & ~left)
        kept["jumps"].append(self.host["jumps"].get(np.float64).copy())
        return np.zeros_like(mask)

    stability.Verdict._run = only
    try:
        sol = tw.solve_static(robot, tau, nodes=nodes, rod=rod, tol=1e-12, continuation=0, threads=1)
    finally:
        stability.Verdict._run = run
    return {"index": sol.stability_index, "margin": sol.stability_margin, "ok": sol.converged,
            **{k: np.concatenate(v) for k, v in kept.items()}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, nargs="+", default=[20, 40, 60])
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--smoke", action="store_true", help="a quick run: one N, 16 rods")
    parser.add_argument("--out", type=Path, default=Path("verdict_passes.json"))
    args = parser.parse_args(argv)
    if args.smoke:
        args.nodes, args.batch = [20], 16
    rows = []
    print("| family | N | stride | max margin error [rad] | max phase move [rad] | kept | kept and wrong "
          "| reference's max move [rad] |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for nodes in args.nodes:
        strides = stability.passes(solver.verdict_strides(nodes, "rk4", False), nodes)[:3]
        for name, (robot, tau, rod) in families(args.batch, np.random.default_rng(nodes)).items():
            fine = one_pass(robot, tau, nodes, rod, -16)
            for stride in strides:
                got = one_pass(robot, tau, nodes, rod, stride)
                ok = fine["ok"] & got["ok"] & (fine["index"] >= 0)
                kept = ok & got["trusted"]
                row = {"family": name, "nodes": nodes, "stride": stride, "rods": int(ok.sum()),
                       "margin_error": float(np.abs(got["margin"] - fine["margin"])[ok].max(initial=0.0)),
                       "max_move": float(got["jumps"][ok].max(initial=0.0)), "kept": int(kept.sum()),
                       "kept_wrong": int((kept & (got["index"] != fine["index"])).sum()),
                       "unstable": int((ok & (fine["index"] > 0)).sum()),
                       "reference_max_move": float(fine["jumps"][ok].max(initial=0.0))}
                rows.append(row)
                print(f"| {name} | {nodes} | {stride} | {row['margin_error']:.2e} | {row['max_move']:.2f} | "
                      f"{row['kept']} of {row['rods']} ({row['unstable']} unstable) | {row['kept_wrong']} | "
                      f"{row['reference_max_move']:.2f} |")
    write_report(args.out, {"meta": metadata("cpu", batch=args.batch), "rows": rows})
    if any(r["kept_wrong"] for r in rows):
        print("a pass kept a wrong count")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
