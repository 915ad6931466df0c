"""Contact with obstacles in statics: closed forms derived for small deflection, the rate at which
a compliant contact converges to the rigid one, global balance with the contact forces, the
independence of the rods of a batch, bad input and unresolved contact, and contact compiled only
where a scene has obstacles. (The independent SciPy reference is compared in
tests/test_scipy_contact.py.)"""

import numpy as np
import pytest

from tdcr_warp.core.build import Tables
from tdcr_warp.kernels import layout
from tdcr_warp.kernels.drivers import module_names
from tdcr_warp.model.robot import InputError, Obstacle, PointForce, Robot, Tendon
from tdcr_warp.physics.statics import solve_static

# a nitinol wire sagging under its own weight (gravity -x): w = rho A g, tip sag w L^4 / (8 EI)
ROD = dict(radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(-9.81, 0.0, 0.0))
W = 6450.0 * np.pi * 0.5e-3**2 * 9.81  # [N/m]
EI = 60e9 * np.pi * 0.5e-3**4 / 4  # [N m^2]
NONE = np.zeros((1, 0))


def prop(a: float, stiffness=None) -> Obstacle:
    """A sphere of 5 mm radius just under the straight rod at s = a (touching it, gap 0)."""
    return Obstacle("sphere", center=(-(0.5e-3 + 5e-3), 0.0, a), radius=5e-3, stiffness=stiffness)


@pytest.mark.parametrize("a", [0.2, 0.15])
def test_propped_cantilever_reaction(a):
    """A clamped cantilever under its weight w, held at s = a by a rigid point: the prop's
    reaction by superposition (the prop cancels the deflection of the load there) is
    R = w (6 L^2 - 4 L a + a^2) / (8 a), 3 w L / 8 for a prop at the tip. The sag is L / 60, so
    the large-deflection terms are ~(1/60)^2 ~ 3e-4 of R; the penetration is held to 1e-3 r."""
    L = 0.2
    sol = solve_static(Robot(length=L, obstacles=[prop(a)], **ROD), NONE, nodes=80, contact_tolerance=1e-3)
    assert sol.success[0]
    R = sol.contact_force[0].sum(axis=0)
    exact = W * (6 * L * L - 4 * L * a + a * a) / (8 * a)
    assert abs(R[0] / exact - 1) < 3e-4
    assert abs(R[1]) < 1e-15 and abs(R[2]) < 1e-3 * exact  # pushed along the normal, up
    assert sol.penetration[0, 0] <= 1e-3 * 0.5e-3
    touched = np.flatnonzero(np.abs(sol.contact_force[0, :, 0]) > 0)
    assert np.allclose(sol.s[0, touched], a, atol=L / 80 + 1e-12)  # at the node on the prop


def test_compliant_contact_converges_to_rigid_at_first_order():
    """A compliant prop of stiffness k: the penetration under the reaction is ~R / (k w_node),
    so the reaction approaches the rigid one as 1 / k. Measured: successive differences of the
    reaction over decades of k shrink by 10 (order 1)."""
    L = 0.2
    R = [solve_static(Robot(length=L, obstacles=[prop(L, k)], **ROD), NONE, nodes=40).contact_force[0, :, 0].sum()
         for k in (1e4, 1e5, 1e6, 1e7)]
    d = np.abs(np.diff(R))
    ratios = d[:-1] / d[1:]
    assert np.all((ratios > 8.0) & (ratios < 12.5)), ratios


def test_global_balance_with_contact_forces():
    """No distributed load: a tip force pushes the rod on a sphere and a plane. The base wrench
    equals the wrench just before the tip node plus every contact force before it, with its
    moment about the base, to round-off (n is constant between nodes, so m' = -p' x n
    integrates exactly); there, n(L-) less the tip node's contact force is the tip load."""
    L = 0.25
    obstacles = [Obstacle("sphere", center=(0.0235, 0.0, 0.16), radius=0.02),
                 Obstacle("plane", point=(0.0, -0.0025, 0.0), normal=(0.0, 1.0, 0.0)),
                 Obstacle("capsule", start=(0.012, -0.05, 0.25), end=(0.012, 0.05, 0.25), radius=0.003)]
    rob = Robot(length=L, radius=0.5e-3, youngs_modulus=60e9, tip_force=(0.01, -0.002, 0.0), obstacles=obstacles)
    sol = solve_static(rob, NONE, nodes=60)
    assert sol.success[0]  # the sphere, reaching in between two nodes, pushes them by their shares (OB_ALONG)
    assert (sol.penetration[0] > 0).sum() >= 2  # two obstacles push (the sphere mid-rod, the plane at the tip)
    F, p = sol.contact_force[0], sol.positions[0]
    nL, mL = sol.n[0, -1], sol.m[0, -1]  # just proximal of the tip node
    n0 = nL + F[:-1].sum(axis=0)
    m0 = mL + np.cross(p[-1], nL) + np.cross(p[:-1], F[:-1]).sum(axis=0)
    scale_n, scale_m = np.abs(F).sum(), np.abs(np.cross(p, F)).sum()
    assert np.abs(sol.base_wrench[0, :3] - n0).max() < 1e-12 * scale_n
    assert np.abs(sol.base_wrench[0, 3:] - m0).max() < 1e-12 * scale_m
    # and at the tip, the tip node's contact force and the tip load to the Newton tolerance
    assert np.abs(nL - F[-1] - rob.tip_force[0]).max() < 1e-9 * scale_n


def test_global_balance_with_a_distributed_load_is_fourth_order():
    """A 0.3 m wire's cantilever under its weight (no contact): the base force equals the weight
    to the integrator's order, not to round-off (the load enters as R R^T f at the integrator's
    stages, where R is orthonormal only to the method's order; midpoint's error falls 4x per
    halving): RK4's shrinks ~16x per halving of the intervals (measured 7.6e-9, 4.7e-10, 2.9e-11,
    1.8e-12 of the weight at N = 25 .. 200)."""
    w = 6450.0 * np.pi * 0.5e-3**2 * 9.81 * 0.3
    rob = Robot(length=0.3, radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(-9.81, 0.0, 0.0))
    err = []
    for nodes in (25, 50, 100):
        sol = solve_static(rob, NONE, nodes=nodes)
        err.append(np.abs(sol.base_wrench[0, :3] - (sol.n[0, -1] + (-w, 0.0, 0.0))).max() / w)
    assert err[-1] < 1e-10
    assert all(12 < a / b < 20 for a, b in zip(err, err[1:]))


def test_rods_of_a_batch_are_independent():
    """Three rods, each with its own obstacle pose (one far away, two touched at different
    depths): the batch's answers are those of each rod alone, bit for bit."""
    centers = np.array([[-0.5, 0.0, 0.2], [-(0.5e-3 + 5e-3), 0.0, 0.2], [-(0.5e-3 + 5e-3) + 1e-3, 0.0, 0.15]])
    make = lambda c: Robot(length=0.2, obstacles=[Obstacle("sphere", center=c, radius=5e-3)], **ROD)  # noqa: E731
    batch = solve_static(make(centers), np.zeros((3, 0)), nodes=40)
    assert batch.success.all() and (np.abs(batch.contact_force[0]).sum() == 0) and (np.abs(batch.contact_force[1:]).sum() > 0)
    for b in range(3):
        alone = solve_static(make(centers[b]), NONE, nodes=40)
        for name in ("positions", "n", "m", "contact_force", "contact_gap", "contact_stiffness", "iterations"):
            assert np.array_equal(getattr(batch, name)[b], getattr(alone, name)[0]), (b, name)


def test_straight_tube_closed_form():
    """A cantilever under its weight in a horizontal straight tube with clearance c: it lies on the
    wall from s = a to the tip, where (clamped-free span with zero slope and moment at a)
    c = w a^4 / (72 EI) and the wall takes a point reaction w a / 3 at a plus w per length beyond.
    Checked: the total reaction w (L - 2a/3) and its moment about the base
    w a^2 / 3 + w (L^2 - a^2) / 2."""
    L, a = 0.5, 0.42
    c = W * a**4 / (72 * EI)
    rob = Robot(length=L, obstacles=[Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, L + 0.01), radius=0.5e-3 + c)],
                **ROD)
    sol = solve_static(rob, NONE, nodes=200)
    assert sol.success[0]
    F = sol.contact_force[0, :, 0]
    assert abs(F.sum() / (W * (L - 2 * a / 3)) - 1) < 5e-4
    moment = (F * sol.positions[0, :, 2]).sum()
    assert abs(moment / (W * a * a / 3 + W * (L * L - a * a) / 2) - 1) < 5e-3
    first = sol.s[0, np.flatnonzero(F > 0)[0]]
    assert abs(first - a) < 0.03  # the contact begins near a (the nodal law spreads the point reaction)


def test_a_wire_on_a_narrow_tubes_axis_is_left_alone():
    """A 0.5 m wire clamped on the axis of a tube of 0.2 mm clearance, unloaded or pulled by 1 mN
    (the tip moves 17 um): the cold start's soft law has a 5 mm band, which reaches the axis, where
    a lumen has no nearest wall; less its axis value the law leaves the rod alone. Single shooting
    succeeds unsplit, with no contact force unloaded, and the pulled rod is the free rod's to
    1e-9 m (before: flagged PENETRATION, stuck at 1e-3 k0)."""
    tube = Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 0.51), radius=0.7e-3)
    kw = dict(length=0.5, radius=0.5e-3, youngs_modulus=60e9, tendons=[Tendon(offset=(0.4e-3, 0.0))])
    for tau in (0.0, 1e-3):
        sol = solve_static(Robot(obstacles=[tube], **kw), np.full((1, 1), tau), nodes=100)
        assert sol.success[0] and sol.segments[0] == 1
        free = solve_static(Robot(**kw), np.full((1, 1), tau), nodes=100)
        assert np.abs(sol.positions - free.positions).max() < 1e-9
        if tau == 0.0:
            assert not sol.contact_force.any()


def test_rod_in_a_bent_tube_follows_it():
    """A straight rod pushed into a tube bent on an arc of radius Rb (clearance 0.3 mm): its tip
    stays within the clearance of the arc's centre line, and its base moment approaches the
    EI / Rb of a rod bent to the arc (measured 3.6% above it: the contact at the ends)."""
    L, Rb, c = 0.2, 0.4, 0.3e-3
    tube = Obstacle("bent_tube", start=(0, 0, -1e-3), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=Rb,
                    angle=L / Rb + 0.1, radius=0.5e-3 + c)
    sol = solve_static(Robot(length=L, radius=0.5e-3, youngs_modulus=60e9, obstacles=[tube]), NONE, nodes=50)
    assert sol.success[0]
    off_axis = np.abs(np.hypot(sol.positions[0, :, 0] - Rb, sol.positions[0, :, 2] + 1e-3) - Rb)
    assert off_axis.max() <= c + 0.01 * 0.5e-3
    assert 1.0 < np.linalg.norm(sol.base_wrench[0, 3:]) / (EI / Rb) < 1.06


def test_bad_obstacles_are_refused():
    """NaN or negative sizes, missing or foreign fields, an unknown kind: one-line errors."""
    cases = [(dict(kind="sphere", center=(0, 0, np.nan), radius=1.0), "sphere center: non-finite"),
             (dict(kind="sphere", center=(0, 0, 1), radius=-1.0), "sphere radius must be positive"),
             (dict(kind="plane", point=(0, 0, 1)), "normal is required"),
             (dict(kind="plane", point=(0, 0, 1), normal=(0, 0, 0)), "plane normal must be a non-zero"),
             (dict(kind="plane", point=(0, 0, 1), normal=(0, 0, 1), radius=1.0), "radius is not a field"),
             (dict(kind="tube", start=(0, 0, 0), end=(0, 0, 0), radius=1.0), "tube end - start"),
             (dict(kind="wall", point=(0, 0, 1)), "obstacle kind must be one of"),
             (dict(kind="sphere", center=(0, 0, 1), radius=1.0, stiffness=0.0), "sphere stiffness must be positive")]
    for kwargs, message in cases:
        with pytest.raises(InputError, match=message):
            Obstacle(**kwargs)
    with pytest.raises(InputError, match="obstacles\\[0\\]: expected Obstacle"):
        Robot(obstacles=[{"kind": "sphere"}])


def test_unresolved_contact_is_flagged_never_silent():
    """A rod clamped inside a sphere, and a rigid contact not allowed to stiffen (contact_steps
    = 0, tolerance 1e-6 r): converged penalty equilibria, flagged PENETRATION, not successes."""
    inside = Robot(length=0.2, obstacles=[Obstacle("sphere", center=(0, 0, 0.01), radius=0.02)], **ROD)
    sol = solve_static(inside, NONE, nodes=20)
    assert sol.status[0] & layout.PENETRATION and not sol.success[0]
    assert "contact not resolved" in sol.failure_reasons()[0]
    stiff = Robot(length=0.2, obstacles=[prop(0.2)], **ROD)
    sol = solve_static(stiff, NONE, nodes=20, contact_tolerance=1e-6, contact_steps=0)
    assert sol.converged[0] and sol.status[0] & layout.PENETRATION and not sol.success[0]
    assert sol.penetration[0, 0] > 1e-6 * 0.5e-3


def test_contact_compiles_only_with_obstacles():
    """A scene without obstacles builds the contact-free kernels (no contact term, the modules of
    before); one with obstacles its own variant."""
    free, touched = Robot(length=0.2, **ROD), Robot(length=0.2, obstacles=[prop(0.2)], **ROD)
    f0, f1 = Tables.of(free, 20).features, Tables.of(touched, 20).features
    assert not f0.contact and f1.contact
    import warp as wp

    names = [module_names(wp.float64, "rk4", "coupled", False, "cosserat", f)["fused"] for f in (f0, f1)]
    assert "contact" not in names[0] and names[1].endswith("_contact")
    assert solve_static(free, NONE, nodes=20).contact_force is None


def test_sensitivities_with_contact_are_the_derivatives_of_the_solves():
    """Four tendons pull a rod onto a compliant wall (a fixed penalty: the solve is a smooth
    function of the tensions) while a second rod stays clear of it: the tip Jacobian (the probes
    count contact only at the nodes near the wall and take double steps elsewhere) equals the
    central differences of whole solves, h = 1e-4 N. A point force on the rod (a load at a node,
    as contact is) compiles with contact."""
    rob = Robot(length=0.2, radius=0.5e-3, youngs_modulus=60e9, density=6450.0, gravity=(0.0, 0.0, -9.81),
                tendons=[Tendon(offset=o) for o in [(0.004, 0.0), (0.0, 0.004), (-0.004, 0.0), (0.0, -0.004)]],
                point_forces=[PointForce(0.1, (0.0, 0.01, 0.0))],
                obstacles=[Obstacle("plane", point=(0.012, 0.0, 0.0), normal=(-1.0, 0.0, 0.0), stiffness=1e5)])
    tau = np.array([[2.0, 0.3, 0.1, 0.1], [0.1, 0.3, 1.0, 0.1]])
    sol = solve_static(rob, tau, nodes=40, sensitivities=True, tol=1e-12)
    assert sol.success.all() and np.abs(sol.contact_force[0]).sum() > 0 and np.abs(sol.contact_force[1]).sum() == 0
    h = 1e-4
    for k in range(4):
        d = np.zeros(4)
        d[k] = h
        up, down = (solve_static(rob, tau + sgn * d, nodes=40, tol=1e-12).tip_position for sgn in (1, -1))
        fd = (up - down) / (2 * h)
        assert np.abs(sol.tip_jacobian[:, :3, k] - fd).max() < 1e-5 * np.abs(fd).max() + 1e-9, k
    assert (sol.stability_index == 0).all()
