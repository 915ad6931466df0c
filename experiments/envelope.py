"""Where the solvers converge: random rods inside a documented envelope, convergence rates.

Statics envelope (dimensionless groups sampled, then turned into SI inputs):
  bend angle of the tendon load theta = sum(tau) r_off L / EI in [0, pi] (up to a half turn),
  E in [1e5, 1e12] Pa (log-uniform), L in [0.05, 5] m, slenderness L / r in [50, 500]
  (log-uniform, radius in [2e-4, 2e-2] m), tendon offsets in [1.5, 15] rod radii, 1 to 4
  tendons at random angles, gravity sag rho A g L^3 / EI in [0, 2] in a random direction,
  nodes N in {5, 10, 20, 50, 200, 2000} with theta <= N pi / 20 below N = 20 (20 nodes per half
  turn), coupled or point model, float64 or float32.
Full turn: theta up to 2 pi (N = 40) where theta r_off / L < 0.9, i.e. the tendon stays outside the
centre of curvature (the coupled model's tendon path degenerates at curvature x offset = 1).
Beyond it (measured, failures flagged): a full curl without that condition, slenderness 20 to 2000,
N = 5 and 10 up to a half turn.
Dynamics envelope: the same rods up to a quarter turn, 5 steps from rest under the tension step,
dt in [1e-3, 1] s (log-uniform), alpha in [-0.48, 0], Bbt giving a first-mode damping ratio zeta
in [0.01, 1], N in {10, 20, 50}, where the single-shooting amplification
exp(L (rho A c0^2 / EI)^(1/4) / sqrt 2) < 1e6 (float32: < 1e4) and the tendon compression
sum(tau) L^2 / EI < 20 (Beck's flutter load of a follower-loaded cantilever).
Beyond it (measured, failures flagged): zeta in [0, 0.01]; dt down to 1e-5 s (amplification > 1e6), with
single shooting only (segments = 1) and by default (a rod that single shooting fails is split into
segments, tdcr_warp/physics/segments.py; rods that need more segments than the grid has intervals
are counted apart).
Displacement-control envelope: the statics envelope's rods and loads, every tendon under
displacement control with a wire compliance c = chi r_off^2 / EI (chi in [0.01, 1], log-uniform)
and a pretension of up to 20% of the half-turn tension pi EI / (r_off L), commanded with the
displacements that give the sampled tensions (from a tension-control solve of the same rods),
the unused tendons released further by up to r_off theta (they go slack), where the tendons'
compression sum(tau) L^2 / EI < pi^2 / 4 (the Euler load of a cantilever: the statics envelope's
tensions reach 800 times it; a tendon's pull follows the rod, so tension control does not
buckle, but a length constraint admits other equilibria beyond it); every rod from the
straight-rod start, N = 20: converged, the shape of the tension-control solve (tip within 1e-8 m),
released tendons slack.
Beyond it (measured, failures flagged): compression from pi^2 / 4 to ~800 x.

    python experiments/envelope.py [--smoke] [--samples 100000] [--out results/envelope.json]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report  # noqa: E402

import tdcr_warp as tw  # noqa: E402
from tdcr_warp.physics.segments import segments_needed  # noqa: E402

NODES = (5, 10, 20, 50, 200, 2000)
ENVELOPE = dict(bend_max=np.pi, slender=(50.0, 500.0))
BEYOND = dict(bend_max=2 * np.pi, slender=(20.0, 2000.0))
FULL_TURN = dict(bend_max=2 * np.pi, slender=(50.0, 500.0), kr_max=0.9)
K_MAX = 4


def sample_envelope(n: int, rng, *, bend_max: float = np.pi, slender=(50.0, 500.0), kr_max: float | None = None) -> dict:
    """n random rods inside the statics envelope: per-rod Robot fields and tensions (n, 4).
    kr_max: also keep the tendons outside the centre of curvature, theta r_off / L < kr_max (the
    coupled model's tendon path degenerates at curvature x offset = 1)."""
    logu = lambda a, b: np.exp(rng.uniform(np.log(a), np.log(b), n))  # noqa: E731
    E = logu(1e5, 1e12)
    L = logu(0.05, 5.0)
    slender = logu(*slender)
    r = np.clip(L / slender, 2e-4, 2e-2)
    L = r * slender
    I = np.pi * r**4 / 4
    EI = E * I
    rho = 7800.0
    sag = rng.uniform(0, 2, n)
    g = sag * EI / (rho * np.pi * r**2 * L**3)  # gravity magnitude giving that sag [m/s^2]
    gdir = rng.normal(size=(n, 3))
    gdir /= np.linalg.norm(gdir, axis=1, keepdims=True)
    off = r * rng.uniform(1.5, 15.0, n)
    k_used = rng.integers(1, K_MAX + 1, n)
    theta = rng.uniform(0, 1, n) * (bend_max if kr_max is None else np.minimum(bend_max, kr_max * L / off))
    share = rng.dirichlet(np.ones(K_MAX), n) * (np.arange(K_MAX)[None] < k_used[:, None])
    share /= share.sum(axis=1, keepdims=True)
    tau = share * (theta * EI / (off * L))[:, None]
    angles = rng.uniform(0, 2 * np.pi, (n, K_MAX))
    tendons = [tw.Tendon(offset=np.c_[off * np.cos(angles[:, k]), off * np.sin(angles[:, k])]) for k in range(K_MAX)]
    return dict(robot=dict(length=L, youngs_modulus=E, radius=r, density=np.full(n, rho),
                           gravity=gdir * g[:, None], tendons=tendons), tensions=tau, theta=theta)


def run_statics(samples: int, rng, precision: str, model: str, nodes: int, region: dict = ENVELOPE) -> dict:
    s = sample_envelope(samples, rng, **region)
    rob = tw.Robot(**s["robot"])
    t0 = time.perf_counter()
    sol = tw.solve_static(rob, s["tensions"], nodes=nodes, model=model, precision=precision)
    wall = time.perf_counter() - t0
    ok = sol.converged
    finite = np.isfinite(sol.positions[ok]).all() and np.isfinite(sol.base_wrench[ok]).all()
    reasons = {}
    for reason in np.array(sol.failure_reasons())[~ok]:
        reasons[str(reason)] = reasons.get(str(reason), 0) + 1
    return dict(samples=samples, precision=precision, model=model, nodes=nodes, region=region,
                converged=float(ok.mean()),
                failed=int((~ok).sum()), reasons=reasons, converged_all_finite=bool(finite),
                precision_limited=int(((sol.status & 32) != 0).sum()), seconds=wall,
                failed_theta=s["theta"][~ok].tolist()[:20])


EULER = np.pi**2 / 4  # compression sum(tau) L^2 / EI bounding the displacement-control envelope


def run_displacement(samples: int, rng, nodes: int = 20) -> dict:
    """The displacement-control envelope (module docstring): convergence from the straight-rod
    start, slack where released, and the tensions of the matching tension-control solve."""
    from tdcr_warp.physics.statics import reference_lengths

    s = sample_envelope(8 * samples, rng, **ENVELOPE)  # then ``samples`` inside, samples / 4 beyond
    EI = s["robot"]["youngs_modulus"] * np.pi * s["robot"]["radius"] ** 4 / 4
    load = s["tensions"].sum(axis=1) * s["robot"]["length"] ** 2 / EI
    keep = np.r_[np.flatnonzero(load < EULER)[:samples], np.flatnonzero(load >= EULER)[:samples // 4]]
    s = {k: v[keep] for k, v in s.items() if k != "robot"} | {"robot": {
        k: ([tw.Tendon(offset=t.offset[keep]) for t in v] if k == "tendons" else v[keep])
        for k, v in s["robot"].items()}}
    samples = len(keep)
    rb = s["robot"]
    EI = EI[keep]
    off = np.linalg.norm(rb["tendons"][0].offset, axis=1)
    chi = np.exp(rng.uniform(np.log(0.01), np.log(1.0), (samples, K_MAX)))
    comp = chi * (off**2 / EI)[:, None]
    pre = rng.uniform(0, 0.2, (samples, K_MAX)) * (np.pi * EI / (off * rb["length"]))[:, None]

    def robot(control):
        tendons = [tw.Tendon(offset=t.offset, compliance=comp[:, k], pretension=pre[:, k], control=control)
                   for k, t in enumerate(rb["tendons"])]
        return tw.Robot(**(rb | dict(tendons=tendons)))

    tau = s["tensions"]
    forward = tw.solve_static(robot("tension"), tau, nodes=nodes, tendon_states=True)
    disp = robot("displacement")
    q = reference_lengths(disp, nodes=nodes) - forward.tendon_free_length
    released = tau == 0
    q = np.where(released, q - rng.uniform(0, 1, tau.shape) * (off * s["theta"])[:, None], q)
    t0 = time.perf_counter()
    sol = tw.solve_static(disp, np.zeros_like(tau), displacements=q, nodes=nodes)
    wall = time.perf_counter() - t0
    ok = sol.converged & forward.converged
    taut = ~released
    rel = np.abs(sol.tendon_tension_base - tau) / np.maximum(tau, 1e-300)
    match = ok & (np.abs(sol.tip_position - forward.tip_position).max(axis=1) < 1e-8)
    slack_ok = ok & np.where(released, sol.slack, True).all(axis=1)
    compression = tau.sum(axis=1) * rb["length"] ** 2 / EI
    out = {}
    for name, sel in (("envelope", compression < EULER), ("beyond: compression to 800", compression >= EULER)):
        reasons = {}
        for reason in np.array(sol.failure_reasons())[sel & ~sol.converged]:
            reasons[str(reason)] = reasons.get(str(reason), 0) + 1
        out[name] = dict(samples=int(sel.sum()), converged=float(sol.converged[sel].mean()),
                         same_shape=float(match[sel].mean()), released_slack=float(slack_ok[sel].mean()),
                         reasons=reasons, mean_iterations=float(sol.iterations[sel].mean()),
                         worst_tension_error=float(np.where((ok & sel)[:, None] & taut, rel, 0).max()))
    return dict(nodes=nodes, seconds=wall, reference_converged=float(forward.converged.mean()), **out)


DYN_ENVELOPE = dict(zeta=(0.01, 1.0), dt=(1e-3, 1.0), amp_max=1e6)
DYN_FLOAT32 = dict(zeta=(0.01, 1.0), dt=(1e-3, 1.0), amp_max=1e4)  # float32 eps x amplification << tol
DYN_UNDAMPED = dict(zeta=(0.0, 0.01), dt=(1e-3, 1.0), amp_max=1e6)
DYN_SMALL_DT = dict(zeta=(0.01, 1.0), dt=(1e-5, 1e-2), amp_min=1e6, amp_max=np.inf)


def run_dynamics(samples: int, rng, *, zeta=(0.01, 1.0), dt=(1e-3, 1.0), amp_min: float = 0.0, amp_max: float = 1e6,
                 nodes: int = 20, precision: str = "float64", segments: int | None = None) -> dict:
    """5 steps from rest under a tension step for each sampled rod whose single-shooting
    amplification lies in [amp_min, amp_max) and whose compression is below Beck's flutter load;
    ``segments``: the Simulator's (None: as many as dt needs; 1: single shooting)."""
    s = sample_envelope(samples, rng, bend_max=np.pi / 2)
    rob0 = tw.Robot(**s["robot"])
    sec = rob0.section()
    EI = sec["kbt"][:, 0]
    rhoA = 7800.0 * sec["area"]
    L = rob0.length
    omega = 1.8751**2 * np.sqrt(EI / (rhoA * L**4))
    zeta = rng.uniform(*zeta, samples)
    dt = np.exp(rng.uniform(np.log(dt[0]), np.log(dt[1]), samples))
    alpha = rng.uniform(-0.48, 0.0, samples)
    c0 = (1.5 + alpha) / (dt * (1 + alpha))
    amp = L * (rhoA * c0**2 / EI) ** 0.25 / np.sqrt(2)
    compression = s["tensions"].sum(axis=1) * L**2 / EI
    # beyond ~20 EI / L^2 a follower-loaded cantilever flutters (Beck's column): a physical
    # dynamic instability, outside the envelope
    inside = (amp >= np.log(max(amp_min, 1.0))) & (amp < np.log(amp_max)) & (compression < 20.0)
    results = {"inside": int(inside.sum()), "converged": 0, "failed": 0, "skipped_outside": int((~inside).sum()),
               "beyond_grid": 0, "beyond_grid_converged": 0,
               "nodes": nodes, "precision": precision, "reasons": {}, "failures": []}
    for b in np.flatnonzero(inside):
        rob = tw.Robot(length=L[b], youngs_modulus=rob0.youngs_modulus[b], radius=rob0.radius[b], density=7800.0,
                       gravity=s["robot"]["gravity"][b],
                       tendons=[tw.Tendon(offset=t.offset[b]) for t in s["robot"]["tendons"]],
                       damping_bending=np.full(3, 2 * zeta[b] * EI[b] / omega[b]))
        with warnings.catch_warnings():  # the small-dt row is beyond the single-shooting limit on purpose
            warnings.simplefilter("ignore")
            sim = tw.Simulator(rob, np.zeros((1, K_MAX)), dt=float(dt[b]), alpha=float(alpha[b]), nodes=nodes,
                               precision=precision, segments=segments)
        with np.errstate(over="ignore", invalid="ignore"):
            tr = sim.simulate(np.tile(s["tensions"][b], (5, 1)), 5)
        results["converged" if tr.converged.all() else "failed"] += 1
        if segments is None and segments_needed(rob, precision, float(dt[b]), c0[b] * dt[b]) > nodes:
            results["beyond_grid"] += 1  # more segments needed than the grid has intervals
            results["beyond_grid_converged"] += int(tr.converged.all())
        if not tr.converged.all():
            f = int(tr.failed_step[0])
            reason = tw.describe_status(int(tr.status[f, 0]))
            results["reasons"][reason] = results["reasons"].get(reason, 0) + 1
            results["failures"].append(dict(step=f, status=int(tr.status[f, 0]), dt=float(dt[b]),
                                            alpha=float(alpha[b]), amplification_log10=float(amp[b] / np.log(10)),
                                            zeta=float(zeta[b]), theta=float(s["theta"][b]), segments=sim.segments,
                                            slenderness=float(L[b] / rob0.radius[b]),
                                            rod=dict(length=float(L[b]), youngs_modulus=float(rob0.youngs_modulus[b]),
                                                     radius=float(rob0.radius[b]),
                                                     gravity=s["robot"]["gravity"][b].tolist(),
                                                     offsets=[t.offset[b].tolist() for t in s["robot"]["tendons"]],
                                                     damping_bending=float(2 * zeta[b] * EI[b] / omega[b]),
                                                     tensions=s["tensions"][b].tolist())))
    results["rate"] = results["converged"] / max(1, results["inside"])
    results["failures"] = results["failures"][:20]
    return results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--samples", type=int, default=100000, help="statics rods, main configuration")
    ap.add_argument("--dynamic-samples", type=int, default=20000, help="dynamic rods sampled, main configuration")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", default=str(ROOT / "results" / "envelope.json"))
    args = ap.parse_args(argv)
    n = 64 if args.smoke else args.samples
    rng = np.random.default_rng(2026)
    rows = []
    # (precision, model, nodes, region, share of the sample count)
    # (name, precision, model, nodes, region, share of the sample count); below N = 20 the envelope
    # keeps 20 nodes per half turn (theta <= N pi / 20): a coarser grid cannot resolve the bend
    coarse = lambda nn: dict(ENVELOPE, bend_max=np.pi * nn / 20)  # noqa: E731
    configs = [("envelope", "float64", "coupled", 20, ENVELOPE, 1.0), ("envelope", "float64", "point", 20, ENVELOPE, 0.1),
               ("envelope", "float32", "coupled", 20, ENVELOPE, 0.1)]
    configs += [("envelope", "float64", "coupled", nn, coarse(nn) if nn < 20 else ENVELOPE,
                 {200: 0.01, 2000: 0.001}.get(nn, 0.1)) for nn in NODES if nn != 20]
    configs += [("full turn, theta r_off / L < 0.9", "float64", "coupled", 40, FULL_TURN, 0.1),
                ("beyond: full curl, L/r 20-2000", "float64", "coupled", 20, BEYOND, 0.1),
                ("beyond: theta up to pi", "float64", "coupled", 5, ENVELOPE, 0.1),
                ("beyond: theta up to pi", "float64", "coupled", 10, ENVELOPE, 0.1)]
    for name, precision, model, nodes, region, share in configs:
        samples = max(16, int(n * share))
        row = run_statics(samples, rng, precision, model, nodes, region)
        row["region"] = name
        rows.append(row)
        print(f"statics {name:30s} {precision} {model:8s} N={nodes:4d}: {row['converged']:.4%} of {samples} converged "
              f"({row['failed']} failed: {row['reasons']}), {samples / row['seconds']:,.0f} rods/s")
    disp = run_displacement(max(64, n // 10), rng)
    for name in ("envelope", "beyond: compression to 800"):
        d = disp[name]
        print(f"displacement control {name}, N=20: {d['converged']:.4%} of {d['samples']} converged from the straight "
              f"start ({d['reasons']}); the tension-control shape (1e-8 m) in {d['same_shape']:.4%}, released "
              f"tendons slack in {d['released_slack']:.4%}; {d['mean_iterations']:.1f} iterations on average")
    m = 8 if args.smoke else args.dynamic_samples
    dyn = []
    # (name, region, nodes, precision, share of the dynamic sample count)
    # (name, region, nodes, precision, share of the dynamic sample count, segments: None splits a rod that single
    # shooting fails, 1 never does)
    for name, region, nodes, precision, share, segments in (
            ("envelope", DYN_ENVELOPE, 20, "float64", 1.0, None), ("envelope", DYN_ENVELOPE, 10, "float64", 0.1, None),
            ("envelope", DYN_ENVELOPE, 50, "float64", 0.1, None),
            ("envelope float32", DYN_FLOAT32, 20, "float32", 0.1, None),
            ("beyond: zeta < 0.01", DYN_UNDAMPED, 20, "float64", 0.1, None),
            ("beyond: small dt, single shooting", DYN_SMALL_DT, 20, "float64", 0.05, 1),
            ("beyond: small dt", DYN_SMALL_DT, 20, "float64", 0.05, None)):
        row = run_dynamics(max(8, int(m * share)), rng, nodes=nodes, precision=precision, segments=segments, **region)
        row.update(region=name, settings={k: list(v) if isinstance(v, tuple) else v for k, v in region.items()})
        dyn.append(row)
        print(f"dynamics {name:20s} {precision} N={nodes:3d}: {row['converged']} of {row['inside']} converged every "
              f"step ({row['rate']:.3%}; {row['skipped_outside']} sampled outside), failures: {row['reasons']}; "
              f"{row['beyond_grid']} needed more segments than intervals ({row['beyond_grid_converged']} converged)")
    write_report(args.out, {"meta": metadata(args.device), "statics": rows, "displacement": disp, "dynamics": dyn})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
