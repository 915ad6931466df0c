"""A JAX (vmap + jit) port of the report robot's static problem, timed against tdcr_warp on one core.

The problem (written here from docs/physics.md sections 1, 2 and 5, sharing no code with
tdcr_warp): the report's robot (0.5 m steel-like rod, r = 1 mm, 4 straight tendons 10 mm off the
axis ending at the tip, gravity along -z), the coupled tendon model [RW11] with its 6x6 system for
(v', u') solved by the Schur complement, RK4 on N uniform intervals with R re-orthonormalised by one
Newton-Schulz step after each, float64. Shooting from the clamped base: the 6 unknowns are
n(0) / (EI/L^2) and m(0) / (EI/L); the residual is the internal wrench past the tip (the pull
-tau t(L-) of every tendon anchored there applied) in the same scaling, and a rod has converged when
L |r| < tol [m]. Newton from the straight rod's equilibrium, a fresh Jacobian at every iterate, by
(a) forward differences (6 probes, step 1.5e-8 max(1, |x|), as tdcr_warp) or (b) jax.jacfwd; the
step is bounded to length 10 in scaled unknowns. Everything is written component-wise, so that XLA
fuses each stage into loops over the batch.

Accuracy tiers (tip error against a converged fine-grid solution, 1e-9 m and 1e-6 m): for each
tier the script finds the fewest RK4 intervals N whose discretisation error (with a tight Newton
tolerance) stays below half the tier on a sample of the rods, uses tol = tier / 2, then checks that
both solvers' tips at (N, tol) are within the tier of the reference on every rod of the batch.

Timing (one core): every measurement in its own process pinned with ``taskset -c CPU`` (JAX with
``XLA_FLAGS=--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1``, tdcr_warp with
``threads=1``), rounds alternating the order; medians over the rounds of the warm solve of the
whole batch, timed in the process's CPU time (rods/s) and in wall time (rods_per_s_wall): on a
shared machine the CPU time leaves out the time other processes held the core. Sides: JAX with each Jacobian, today's main (``--old-path``, default
/tmp/h1/oldpkg, put on PYTHONPATH) and the working tree (stability "off" and its default if
that differs).

    python experiments/jax_port.py [--batch 4096] [--rounds 3] [--cpu 0] [--smoke] [--out results/jax_port.json]

Needs jax (``pip install -e .[bench]``); without it the script says so and exits with status 1.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "experiments")]

from _common import metadata, write_report

MARKER = "JAXPORT_RESULT "
OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]
ROD = {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 1e-3, "density": 17189.0,
           "gravity": (0.0, 0.0, -9.81)}
TIERS = (1e-9, 1e-6)
CANDIDATE_N = (4, 5, 6, 7, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 64)
REFERENCE_N, TIGHT_TOL = 256, 1e-12
FD_REL, MAX_STEP, MAX_ITER = 1.5e-8, 10.0, 50


def tensions(batch: int, seed: int = 1) -> np.ndarray:
    """The benchmark's commands: uniform in [0, 3] N (experiments/_ab_worker.py's static_batch)."""
    return np.random.default_rng(seed).uniform(0.0, 3.0, (batch, 4))


# ----------------------------------------------------------------------------------------------
# The JAX solver (imported only inside a JAX worker process).

def make_jax_solver(nodes: int, tol: float, jacobian: str, chunk: int = 32):
    """A jitted ``solve(tau (B, 4)) -> (tips (B, 3), iterations (B,), integrations (B,), L |r| (B,))``,
    B a multiple of ``chunk``: lax.map over chunks of ``chunk`` rods, each a vmapped Newton (its
    working set stays in cache: one integration of 4096 rods at once costs 5-10x more per rod)."""
    import jax
    import jax.numpy as jnp

    L, E, nu_p, rad, rho = (ROD[k] for k in ("length", "youngs_modulus", "poisson_ratio", "radius", "density"))
    area, inertia = np.pi * rad**2, np.pi * rad**4 / 4
    G = E / (2 * (1 + nu_p))
    kse = jnp.array([G * area, G * area, E * area])
    kbt = jnp.array([E * inertia, E * inertia, G * 2 * inertia])
    fe = rho * area * jnp.asarray(ROD["gravity"])
    fs, ms = E * inertia / L**2, E * inertia / L
    h = L / nodes
    e3 = jnp.array([0.0, 0.0, 1.0])
    off = jnp.array([(x, y, 0.0) for x, y in OFFSETS])  # (K, 3) body-frame routes r (straight)
    rr = jnp.array([[[y * y, -x * y, 0.0], [-x * y, x * x, 0.0], [0.0, 0.0, x * x + y * y]]
                    for x, y in OFFSETS])  # |r|^2 I - r r^T

    def mv(M, v):  # M v, element-wise (no batched dot)
        return (M * v[..., None, :]).sum(-1)

    def mtv(M, v):  # M^T v
        return (M * v[..., :, None]).sum(-2)

    def mm(A, B):
        return (A[..., :, :, None] * B[..., None, :, :]).sum(-2)

    def hat(x):
        z = jnp.zeros_like(x[0])
        return jnp.stack([jnp.stack([z, -x[2], x[1]]), jnp.stack([x[2], z, -x[0]]), jnp.stack([-x[1], x[0], z])])

    def inv3(M):  # columns: cross products of the rows, over the determinant
        a0, a1, a2 = M[0], M[1], M[2]
        c0 = jnp.cross(a1, a2)
        return jnp.stack([c0, jnp.cross(a2, a0), jnp.cross(a0, a1)], axis=-1) / jnp.dot(a0, c0)

    def rhs(R, n, m, tau):
        """d/ds of (p, R, n, m): the rod of docs/physics.md section 1 with the coupled tendon load."""
        rtn, rtm = mtv(R, n), mtv(R, m)
        v = rtn / kse + e3
        u = rtm / kbt
        lam_n = -mtv(R, fe)
        # per tendon: pb = u x r + v; its block J^T A_i J, A_i = tau (|pb|^2 I - pb pb^T) / |pb|^3
        pb = jnp.cross(u[None, :], off) + v[None, :]
        pp = (pb * pb).sum(-1)
        e = tau / (pp * jnp.sqrt(pp))
        w = e * pp
        q = jnp.cross(off, pb)
        epb, eq = e[:, None] * pb, e[:, None] * q
        As = w.sum() * jnp.eye(3) - (epb[:, :, None] * pb[:, None, :]).sum(0)
        Bs = hat((w[:, None] * off).sum(0)) - (eq[:, :, None] * pb[:, None, :]).sum(0)
        Hs = (w[:, None, None] * rr).sum(0) - (eq[:, :, None] * q[:, None, :]).sum(0)
        y = jnp.cross(u[None, :], pb)
        ai = w[:, None] * y - (pb * y).sum(-1)[:, None] * epb
        a_sum, b_sum = ai.sum(0), jnp.cross(off, ai).sum(0)
        c = lam_n - jnp.cross(u, rtn) - a_sum
        d = -jnp.cross(v, rtn) - jnp.cross(u, rtm) - b_sum
        # [[Kse + A, B^T], [B, Kbt + H]] [v'; u'] = [c; d] by the Schur complement of the upper block
        Pinv = inv3(jnp.diag(kse) + As)
        BP = mm(Bs, Pinv)
        du = mv(inv3(jnp.diag(kbt) + Hs - mm(BP, Bs.T)), d - mv(BP, c))
        dv = mv(Pinv, c - mtv(Bs, du))
        dp = mv(R, v)
        dR = mm(R, hat(u))
        dn = -fe - mv(R, a_sum + c - kse * dv)  # n' = -f_e - f_tendons
        dm = -jnp.cross(dp, n) - mv(R, b_sum + d - kbt * du)
        return dp, dR, dn, dm

    def rk4(_, state, tau):
        def at(a, k):
            return tuple(y + a * dy for y, dy in zip(state, k))

        k1 = rhs(*state[1:], tau)
        k2 = rhs(*at(0.5 * h, k1)[1:], tau)
        k3 = rhs(*at(0.5 * h, k2)[1:], tau)
        k4 = rhs(*at(h, k3)[1:], tau)
        p, R, n, m = (y + h / 6 * (a + 2 * b + 2 * c + d) for y, a, b, c, d in zip(state, k1, k2, k3, k4))
        return p, 1.5 * R - 0.5 * mm(R, mm(R.T, R)), n, m  # one Newton-Schulz step

    def shoot(x, tau):
        """Base to tip from the scaled unknowns: the scaled residual (6,) and the tip position (3,)."""
        state = (jnp.zeros(3), jnp.eye(3), x[:3] * fs, x[3:] * ms)
        p, R, n, m = jax.lax.fori_loop(0, nodes, lambda i, st: rk4(i, st, tau), state)
        v = mtv(R, n) / kse + e3
        u = mtv(R, m) / kbt
        t = mv(R[None], jnp.cross(u[None, :], off) + v[None, :])  # (K, 3) tendon tangents at L-
        F = -(tau / jnp.sqrt((t * t).sum(-1)))[:, None] * t  # each tendon's anchor pull
        n = n - F.sum(0)
        m = m - jnp.cross(mv(R[None], off), F).sum(0)
        return jnp.concatenate([n / fs, m / ms]), p

    def residual(x, tau):
        return shoot(x, tau)[0]

    def jac(x, r, tau):
        """dr/dx (6, 6) at x (r: the residual there), the columns in sequence (lax.map): a batch of
        6 x chunk rods at once would leave the cache again (measured: 3.5x slower with vmap)."""
        eye = jnp.eye(6)
        if jacobian == "jacfwd":  # forward mode, a tangent pass (with its primal) per column
            return jax.lax.map(lambda j: jax.jvp(lambda y: residual(y, tau), (x,), (j,))[1], eye).T
        hx = FD_REL * jnp.maximum(1.0, jnp.abs(x))
        return jax.lax.map(lambda j: (residual(x + hx * j, tau) - r) / (hx * j).sum(), eye).T

    def start(tau):
        """The straight rod's equilibrium under the same loads (every tangent along e3)."""
        n0 = jnp.asarray(fe) * L - jnp.sum(tau) * jnp.array([0.0, 0.0, 1.0])
        m0 = jnp.array([-L * L / 2 * fe[1], L * L / 2 * fe[0], 0.0])
        for k, (rx, ry) in enumerate(OFFSETS):  # arm (rx, ry, L) x F, F = (0, 0, -tau)
            m0 = m0 + tau[k] * jnp.array([-ry, rx, 0.0])
        return jnp.concatenate([n0 / fs, m0 / ms])

    def solve_one(tau):
        """Newton until L |r| < tol: 1 + 7 per iteration integrations (forward differences: 6
        probes and the new point; jacfwd: 6 tangent passes, each with its primal, and the new point)."""
        x = start(tau)
        r, p = shoot(x, tau)

        def cond(c):
            _x, r, _p, it = c
            return (L * jnp.linalg.norm(r) >= tol) & (it < MAX_ITER)

        def body(c):
            x, r, p, it = c
            dx = jnp.linalg.solve(jac(x, r, tau), -r)
            x = x + dx * jnp.minimum(1.0, MAX_STEP / jnp.linalg.norm(dx))
            r, p = shoot(x, tau)
            return x, r, p, it + 1

        x, r, p, it = jax.lax.while_loop(cond, body, (x, r, p, jnp.int32(0)))
        return p, it, 1 + 7 * it, L * jnp.linalg.norm(r)

    batched = jax.vmap(solve_one)

    def solve(tau):
        out = jax.lax.map(batched, tau.reshape(-1, chunk, tau.shape[-1]))
        return tuple(o.reshape(-1, *o.shape[2:]) for o in out)

    return jax.jit(solve)


# ----------------------------------------------------------------------------------------------
# Workers: one measurement each, in a fresh process; results on stdout after MARKER.

def jax_worker(batch: int, nodes: int, tol: float, jacobian: str, repeats: int, tips_out: str | None,
               chunk: int = 32):
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    tau = jnp.asarray(tensions(batch))
    chunk = min(chunk, batch)
    if batch % chunk:
        raise ValueError(f"batch {batch} is not a multiple of the chunk {chunk}")
    solve = make_jax_solver(nodes, tol, jacobian, chunk)
    t0 = time.perf_counter()
    out = jax.block_until_ready(solve(tau))
    compile_s = time.perf_counter() - t0
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(solve(tau))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    tips, iters, shots, resid = (np.asarray(o) for o in out)
    if tips_out:
        np.save(tips_out, tips)
    wall = statistics.median(times)
    return {"rods_per_s": batch / statistics.median(cpu), "rods_per_s_wall": batch / wall, "first_call_s": compile_s,
            "iterations": float(iters.mean()), "integrations": float(shots.mean()),
            "converged": float((resid < tol).mean()), "jax": jax.__version__}


def warp_worker(batch: int, nodes: int, tol: float, stability: str | None, repeats: int, tips_out: str | None,
                rows: int | None = None):
    import tdcr_warp as tw

    rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROD)
    tau = tensions(batch)[:rows]
    kw = {"nodes": nodes, "tol": tol, "threads": 1}
    if stability is not None:
        kw["stability"] = stability
    sol = tw.solve_static(rob, tau[:8], **kw)
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        sol = tw.solve_static(rob, tau, **kw)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    if tips_out:
        np.save(tips_out, sol.positions[:, -1])
    wall = statistics.median(times)
    return {"rods_per_s": len(tau) / statistics.median(cpu), "rods_per_s_wall": len(tau) / wall,
            "iterations": float(sol.iterations.mean()),
            "integrations": float(sol.integrations.mean()), "converged": float(sol.converged.mean()),
            "default_stability": tw.StaticOptions().stability,
            "statics": sys.modules["tdcr_warp.physics.statics"].__file__}


def warp_calibrate(rows: int, tips_out: str):
    """Tips of the first ``rows`` rods at every candidate N and at REFERENCE_N (tight tolerance)."""
    import tdcr_warp as tw

    rob = tw.Robot(tendons=[tw.Tendon(offset=o) for o in OFFSETS], **ROD)
    tau = tensions(max(rows, 1))[:rows]
    tips = {}
    for n in (*CANDIDATE_N, REFERENCE_N):
        sol = tw.solve_static(rob, tau, nodes=n, tol=TIGHT_TOL, threads=1, stability="off")
        tips[str(n)] = sol.positions[:, -1]
    np.savez(tips_out, **tips)
    return {"rows": rows}


WORKERS = {"jax": jax_worker, "warp": warp_worker, "calibrate": warp_calibrate}


def worker_main(name: str, kwargs: str) -> int:
    res = WORKERS[name](**json.loads(kwargs))
    print(MARKER + json.dumps(res), flush=True)
    return 0


# ----------------------------------------------------------------------------------------------
# The driver.

def run(kind: str, kwargs: dict, *, pythonpath: str | None, cpu: int | None, cwd: str) -> dict:
    """One worker process pinned to ``cpu``, single-threaded; its result dict or {"error"}."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "XLA_FLAGS")}
    env.update(XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
               JAX_COMPILATION_CACHE_DIR=os.path.join(cwd, "jax_cache"), JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
               OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", kind, json.dumps(kwargs)]
    if cpu is not None and shutil.which("taskset"):
        cmd = ["taskset", "-c", str(cpu), *cmd]
    out = subprocess.run(cmd, check=False, cwd=cwd, env=env, capture_output=True, text=True, timeout=1800)
    lines = [ln[len(MARKER):] for ln in out.stdout.splitlines() if ln.startswith(MARKER)]
    if out.returncode == 0 and lines:
        return json.loads(lines[-1])
    return {"error": f"exit {out.returncode}: " + "\n".join((out.stdout + out.stderr).strip().splitlines()[-12:])}


def calibrate(rows: int, old_path: str | None, cpu: int | None, cwd: str) -> dict:
    """Per tier: the fewest candidate N with discretisation error <= tier / 2 (max over ``rows``
    rods, tdcr_warp of today's main with a tight tolerance, against N = REFERENCE_N)."""
    path = os.path.join(cwd, "calib.npz")
    res = run("calibrate", {"rows": rows, "tips_out": path}, pythonpath=old_path, cpu=cpu, cwd=cwd)
    if "error" in res:
        raise SystemExit("calibration failed: " + res["error"])
    tips = np.load(path)
    ref = tips[str(REFERENCE_N)]
    errors = {n: float(np.abs(tips[str(n)] - ref).max()) for n in CANDIDATE_N}
    choice = {}
    for tier in TIERS:
        ok = [n for n in CANDIDATE_N if errors[n] <= tier / 2]
        choice[tier] = {"nodes": ok[0] if ok else CANDIDATE_N[-1], "tol": tier / 2}
    return {"discretisation_error": errors, "tiers": choice}


def sides(old_path: str | None, new_default: str | None) -> dict:
    """The measured sides: name -> (worker, extra kwargs, PYTHONPATH)."""
    out = {"jax_fd": ("jax", {"jacobian": "fd"}, None), "jax_jacfwd": ("jax", {"jacobian": "jacfwd"}, None),
           "main": ("warp", {"stability": None}, old_path),
           "tree_off": ("warp", {"stability": "off"}, str(ROOT))}
    if new_default not in (None, "off"):
        out[f"tree_{new_default}"] = ("warp", {"stability": new_default}, str(ROOT))
    return out


def measure(args, cwd: str, calib: dict) -> dict:
    probe = run("warp", {"batch": 8, "nodes": 4, "tol": 1e-6, "stability": None, "repeats": 1, "tips_out": None},
                pythonpath=str(ROOT), cpu=args.cpu, cwd=cwd)
    plan = sides(args.old_path, probe.get("default_stability"))
    results = {tier: {name: [] for name in plan} for tier in TIERS}
    accuracy = {tier: {} for tier in TIERS}
    for tier in TIERS:
        nodes, tol = calib["tiers"][tier]["nodes"], calib["tiers"][tier]["tol"]
        ref_path = os.path.join(cwd, "ref.npy")
        res = run("warp", {"batch": args.batch, "nodes": REFERENCE_N, "tol": TIGHT_TOL, "stability": None,
                           "repeats": 1, "tips_out": ref_path}, pythonpath=args.old_path, cpu=args.cpu, cwd=cwd)
        if "error" in res:
            raise SystemExit("reference solve failed: " + res["error"])
        ref = np.load(ref_path)
        for rnd in range(args.rounds):
            names = list(plan) if rnd % 2 == 0 else list(plan)[::-1]
            for name in names:
                kind, extra, pp = plan[name]
                tips_path = os.path.join(cwd, f"{name}.npy") if rnd == 0 else None
                kw = dict(batch=args.batch, nodes=nodes, tol=tol, repeats=args.repeats, tips_out=tips_path, **extra)
                res = run(kind, kw, pythonpath=pp, cpu=args.cpu, cwd=cwd)
                results[tier][name].append(res)
                if tips_path and "error" not in res:
                    accuracy[tier][name] = float(np.abs(np.load(tips_path) - ref).max())
                shown = res.get("error", "").splitlines()[-1:] if "error" in res else \
                    f"{res['rods_per_s']:,.0f} rods/s, {res['integrations']:.2f} integrations/rod"
                print(f"tier {tier:g} m (N = {nodes}, tol {tol:g}) round {rnd + 1}: {name:<12} {shown}", flush=True)
    return {"plan": {k: [v[0], v[1], v[2]] for k, v in plan.items()}, "runs": results, "accuracy": accuracy}


def summarise(runs: dict, accuracy: dict, calib: dict) -> dict:
    table = {}
    for tier, by_side in runs.items():
        rows = {}
        for name, rs in by_side.items():
            ok = [r for r in rs if "error" not in r]
            if not ok:
                rows[name] = {"error": rs[-1]["error"] if rs else "not run"}
                continue
            rows[name] = {"rods_per_s": statistics.median(r["rods_per_s"] for r in ok),
                          "values": [r["rods_per_s"] for r in ok],
                          "rods_per_s_wall": statistics.median(r["rods_per_s_wall"] for r in ok),
                          "iterations": ok[-1]["iterations"], "integrations": ok[-1]["integrations"],
                          "converged": ok[-1]["converged"], "max_tip_error_m": accuracy[tier].get(name)}
            rows[name]["us_per_integration"] = 1e6 / (rows[name]["rods_per_s"] * rows[name]["integrations"])
        jax_best = max((rows[k] for k in ("jax_fd", "jax_jacfwd") if "rods_per_s" in rows.get(k, {})),
                       key=lambda r: r["rods_per_s"], default=None)
        for row in rows.values():
            if jax_best and "rods_per_s" in row:
                row["vs_best_jax"] = row["rods_per_s"] / jax_best["rods_per_s"]
        table[tier] = {"nodes": calib["tiers"][tier]["nodes"], "tol": calib["tiers"][tier]["tol"], "sides": rows}
    return table


def print_markdown(table: dict) -> None:
    print("\n| tier | N | tol | side | rods per CPU-s (1 core) | wall rods/s | vs best JAX | iterations | integrations/rod "
          "| us/integration | max tip error |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for tier, t in table.items():
        for name, r in t["sides"].items():
            if "error" in r:
                print(f"| {tier:g} m | {t['nodes']} | {t['tol']:g} | {name} | failed | | | | | | |")
                continue
            err = r["max_tip_error_m"]
            print(f"| {tier:g} m | {t['nodes']} | {t['tol']:g} | {name} | {r['rods_per_s']:,.0f} | {r['rods_per_s_wall']:,.0f} | "
                  f"{r.get('vs_best_jax', float('nan')):.2f}x | {r['iterations']:.2f} | {r['integrations']:.2f} | "
                  f"{r['us_per_integration']:.2f} | {'-' if err is None else format(err, '.1e')} m |")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["--worker"]:
        return worker_main(argv[1], argv[2])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--rounds", type=int, default=3, help="rounds of all sides, order alternated (default 3)")
    ap.add_argument("--repeats", type=int, default=3, help="timed solves per process (median; default 3)")
    ap.add_argument("--calibrate-rows", type=int, default=256, help="rods of the N calibration (default 256)")
    ap.add_argument("--cpu", type=int, default=0, help="the core every process is pinned to (taskset)")
    ap.add_argument("--old-path", default="/tmp/h1/oldpkg", help="PYTHONPATH of today's main's install")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, 1 round (for the test suite)")
    ap.add_argument("--out", default=str(ROOT / "results" / "jax_port.json"))
    args = ap.parse_args(argv)
    try:
        import jax  # noqa: F401
    except ImportError:
        print("jax_port.py needs jax: pip install 'jax[cpu]' (or pip install -e '.[bench]')", file=sys.stderr)
        return 1
    if not os.path.isdir(args.old_path or ""):
        print(f"no install of today's main at {args.old_path}: comparing the working tree with itself")
        args.old_path = str(ROOT)
    if args.smoke:
        args.batch, args.rounds, args.repeats, args.calibrate_rows = 8, 1, 1, 4
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as cwd:
        calib = calibrate(args.calibrate_rows, args.old_path, args.cpu, cwd)
        print("discretisation error (max over rods) by N:",
              ", ".join(f"{n}: {e:.1e}" for n, e in calib["discretisation_error"].items()))
        meas = measure(args, cwd, calib)
    table = summarise(meas["runs"], meas["accuracy"], calib)
    print_markdown(table)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    meta = metadata("cpu", dtype="float64", batch=args.batch, rounds=args.rounds, repeats=args.repeats,
                    cpu=args.cpu, smoke=args.smoke, old_path=args.old_path)
    write_report(args.out, {"meta": meta, "calibration": {str(k): v for k, v in calib["tiers"].items()},
                            "discretisation_error": calib["discretisation_error"],
                            "tiers": {str(k): v for k, v in table.items()}, "plan": meas["plan"],
                            "runs": {str(k): v for k, v in meas["runs"].items()}})
    failed = any("error" in r for t in table.values() for r in t["sides"].values())
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
