"""The shooting core: both Newton drivers, batch independence, reuse across solves, and the
Newton machinery at a size other than the rod's six unknowns.

Equality here is exact (np.array_equal): the same arithmetic must give the same bits.
"""

import numpy as np
import pytest
import warp as wp
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.newton import make_newton

import tdcr_warp as tw

OFFSETS = [(0.01, 0.0), (0.0, 0.01), (-0.01, 0.0), (0.0, -0.01)]


def report_robot(**kw):
    base = dict(length=0.5, youngs_modulus=190e9, poisson_ratio=0.3, radius=1e-3, density=17189.0,
                gravity=(0.0, 0.0, -9.81), tendons=[tw.Tendon(offset=o) for o in OFFSETS])
    return tw.Robot(**(base | kw))


def heavy_batch():
    """Random rods, one at 400 N on a tendon and one under a tip force that loops the rod:
    both go through the load continuation, with more steps than their neighbours."""
    tau = np.random.default_rng(4).uniform(0.0, 3.0, (8, 4))
    tau[2, 0] = 400.0
    tip = np.zeros((8, 3))
    tip[5] = (6.0, 0.0, 0.0)
    return report_robot(tip_force=tip), tau


def fields(sol):
    return (sol.positions, sol.n, sol.m, sol.status, sol.iterations, sol.integrations, sol.residual)


def assert_same(a, b, what):
    for x, y in zip(fields(a), fields(b)):
        assert np.array_equal(x, y), f"{what}: max difference {np.max(np.abs(x - y))}"


def test_drivers_agree_statics():
    """The per-probe driver (one launch per iteration, the CUDA default) runs the same Newton
    update as the fused one (one launch per solve): identical rods, continuation included."""
    rob, tau = heavy_batch()
    fused = tw.solve_static(rob, tau, nodes=20, driver="fused")
    probes = tw.solve_static(rob, tau, nodes=20, driver="probes")
    assert fused.converged.all(), fused.failure_reasons()
    assert fused.iterations[2] > 3 * np.median(fused.iterations), "the heavy rod did not need continuation"
    assert_same(fused, probes, "fused vs probes")


def test_drivers_agree_dynamics():
    rob = report_robot(damping_bending=(0.008,) * 3, drag=(0.01,) * 3)
    runs = []
    for driver in ("fused", "probes"):
        sim = tw.Simulator(rob, np.zeros((3, 4)), dt=0.005, alpha=-0.2, nodes=20, driver=driver)
        runs.append(sim.simulate(np.tile([[2.0, 0.5, 0.0, 0.0]], (6, 1)), 6))
    assert runs[0].converged.all()
    for name in ("tip_position", "tip_velocity", "iterations"):
        assert np.array_equal(getattr(runs[0], name), getattr(runs[1], name)), name


def test_answer_independent_of_neighbours_and_threads():
    """Each rod of a batch with heavy neighbours equals the rod solved alone, bit for bit, and
    the thread split does not matter (the continuation is chosen per rod)."""
    rob, tau = heavy_batch()
    batch = tw.solve_static(rob, tau, nodes=20, threads=1)
    for b in range(len(tau)):
        alone = tw.solve_static(report_robot(tip_force=rob.tip_force[b]), tau[b:b + 1], nodes=20)
        for x, y in zip(fields(batch), fields(alone)):
            assert np.array_equal(x[b:b + 1], y), f"rod {b}"
    big = np.tile(tau, (16, 1))  # 128 rods: two threads of 64
    rob_big = report_robot(tip_force=np.tile(rob.tip_force, (16, 1)))
    one, two = (tw.solve_static(rob_big, big, nodes=20, threads=t) for t in (1, 2))
    assert_same(one, two, "threads 1 vs 2")
    assert np.array_equal(one.positions[:8], batch.positions)


def test_repeated_solves_reuse_and_match_fresh():
    """A cached problem (same robot object and shape) gives what a fresh one gives, whatever
    the previous solve left in its arrays (a failed rod, a warm start). Its first solve also made
    the rods' unloaded Jacobians (7 integrations each, counted there), which later ones reuse."""
    rob, tau = heavy_batch()
    first = tw.solve_static(rob, tau, nodes=20)
    tw.solve_static(rob, tau * 0.5, nodes=20, initial=first)
    tw.solve_static(rob, np.full_like(tau, 1e6), nodes=20, max_iter=3)  # fails, flagged
    again = tw.solve_static(rob, tau, nodes=20)
    assert (first.integrations - again.integrations == 7).all()
    again.integrations = first.integrations
    assert_same(first, again, "second solve of a reused problem")
    fresh = tw.solve_static(report_robot(tip_force=rob.tip_force), tau, nodes=20)
    assert_same(first, fresh, "reused vs fresh problem")
    first.positions[:] = 0.0  # results are the caller's copies
    assert np.abs(again.positions).max() > 0.1


@pytest.mark.parametrize("routing", ["straight", "helix"])
def test_first_jacobian_over_long_steps(routing):
    """A straight-started Broyden solve starts from the rod's unloaded Jacobian (at the straight
    start of a zero command; physics/statics.py _unloaded_jacobian), from probes over about 8 RK4
    steps that stop where a load sits (core/solver.py coarse_stride; here a tendon ending
    mid-rod): close to the finite-difference Jacobian on the fine grid there (plain Newton's
    first). A robot with one row per table makes it once, for its first rod: one more (coarse)
    integration than plain Newton's probes, and none for the others."""
    if routing == "helix":
        tendons = [tw.Tendon(routing="helix", helix_radius=0.01, turns=1.0, phase=k * np.pi / 2) for k in range(4)]
    else:
        tendons = [tw.Tendon(offset=o) for o in OFFSETS[:3]] + [tw.Tendon(offset=OFFSETS[3], length=0.25)]
    rob = report_robot(tendons=tendons)
    tau = np.random.default_rng(3).uniform(0.0, 3.0, (6, 4))
    for nodes in (4, 10, 50):
        kw = {"nodes": nodes, "max_iter": 1, "continuation": 0, "stability": "off"}
        coarse = tw.solve_static(rob, tau, **kw)
        fine = tw.solve_static(rob, np.zeros((1, 4)), jacobian="newton", **kw)
        assert (coarse.jacobian == coarse.jacobian[0]).all()  # one Jacobian, shared
        J, Jf = coarse.jacobian[0], fine.jacobian[0]
        rel = np.linalg.norm(J - Jf) / np.linalg.norm(Jf)
        # measured: helix 5e-4, 1e-4 (N = 10, 50), 3e-2 (N = 4: two steps over the turn); straight 1e-6 (N = 4: 5e-5)
        assert rel < (1e-4 if routing == "straight" else 1e-2 if nodes > 4 else 5e-2), rel
        assert coarse.integrations.tolist() == [fine.integrations[0] + 1] + [1] * 5


@pytest.mark.parametrize("integrator", ["euler", "midpoint", "rk4"])
def test_unloaded_rod_is_exact_in_float64(integrator):
    """A straight, unloaded rod: every integrator is exact, so the tip sits at L to round-off. A
    float32 constant hidden in a float64 kernel (a bare literal) shows here as ~1e-8 m."""
    L = 0.5 * (1 + 2.0**-30)
    rob = report_robot(length=L, gravity=(0.0, 0.0, 0.0))
    sol = tw.solve_static(rob, np.zeros((1, 4)), nodes=7, integrator=integrator)
    assert abs(sol.tip_position[0, 2] - L) < 4e-16, sol.tip_position[0, 2] - L
    sim = tw.Simulator(rob, np.zeros((1, 4)), dt=0.01, nodes=7, integrator=integrator)
    assert abs(sim.step(np.zeros((1, 4))).tip_position[0, 2] - L) < 4e-16


@pytest.mark.parametrize("central", [False, True])
def test_newton_any_size(central):
    """The Newton update knows nothing of rods: at nu = 9 it solves a nonlinear system with a
    known root, x_i^3 + x_i + sum_j 0.1 x_j = c_i (root x* = 1..9 / 9)."""
    nu = 9
    nt = make_newton(wp.float64, nu, central)
    vec = nt.vec

    @wp.func
    def residual(x: vec, c: vec):
        s = wp.float64(0.0)
        for j in range(nu):
            s += x[j]
        r = vec()
        for i in range(nu):
            r[i] = x[i] * x[i] * x[i] + x[i] + wp.float64(0.1) * s - c[i]
        return r

    @wp.kernel
    def solve(nw: nt.Newton, x0: wp.array(dtype=vec), c: wp.array(dtype=vec)):
        b = wp.tid()
        nt.begin(nw, b, x0, 1)
        for _it in range(40):
            if nw.active[b] == 0:
                break
            for j in range(nt.n_probes):
                if j == 0 or nw.need_jac[b] != 0:
                    nw.res[b, j] = residual(nt.probe_point(nw.xt[b], j), c[b])
            nt.update(nw, b, wp.float64(1.0), wp.float64(1e-12), 40, wp.float64(10.0), 1, 0)

    B = 3
    root = np.tile(np.arange(1, nu + 1) / nu, (B, 1)) * np.array([[1.0], [-0.5], [2.0]])
    c = root**3 + root + 0.1 * root.sum(axis=1, keepdims=True)
    nw = nt.Newton()
    for name in ("x", "r", "xt"):
        setattr(nw, name, wp.zeros(B, dtype=vec, device="cpu"))
    nw.J = wp.zeros(B, dtype=nt.mat, device="cpu")
    nw.res = wp.zeros((B, nt.width), dtype=vec, device="cpu")
    for name in ("active", "need_jac", "flags", "status", "iters", "n_shoot"):
        setattr(nw, name, wp.zeros(B, dtype=int, device="cpu"))
    nw.lam = wp.zeros(B, dtype=wp.float64, device="cpu")
    nw.resnorm = wp.zeros(B, dtype=wp.float64, device="cpu")
    nw.n_active = wp.zeros(1, dtype=int, device="cpu")
    x0 = wp.array(np.zeros((B, nu)), dtype=vec, device="cpu")
    wp.launch(solve, dim=B, inputs=[nw, x0, wp.array(c, dtype=vec, device="cpu")], device="cpu")
    assert np.all(nw.status.numpy() & layout.CONVERGED), nw.status.numpy()
    assert np.abs(nw.x.numpy() - root).max() < 1e-10
    assert (nw.n_shoot.numpy() >= nt.n_probes).all()
