"""The mechanical energy of every rod after a dynamics step, for the energy monitor
(tdcr_warp/physics/dynamics.py): one thread per rod, from the slots of its nodes.

  H = T + U_el + sum_k tau_k ell_k - int rho A g . p ds - F_tip . p(L) - sum_j F_j . p(s_j)

T = int (rho A |q|^2 + w . rho J w) / 2 ds the kinetic energy, U_el = int ((v - v*) . Kse (v - v*)
+ (u - u*) . Kbt (u - u*)) / 2 ds the elastic energy, ell_k = int |v + u x r_k + r_k'| ds the
path length of tendon k up to its end (the coupled model's tendon under a held tension tau_k is
conservative with potential tau_k ell_k), and the dead loads' potentials. The integrals are the
trapezoidal rule over the nodes (each interval from the distal side of its first node to the
proximal side of its last: the strains jump where loads act). Without damping, drag, contact
or a changing command H is conserved by the motion itself.
"""

import functools
from types import SimpleNamespace

import warp as wp

from .layout import FE, KBT, KSE, RHOA, RHOJ, TIP_F, USTAR
from .structs import SLOT_Q, SLOT_U, SLOT_V, SLOT_W, make_rows, make_structs
from .tendons import make_routes


@functools.cache
def make_energy_kernels(dtype, helix: bool, spline: bool):
    """``helix``, ``spline``: the routes compiled in (as in the shooting kernels' features)."""
    vec3 = wp.types.vector(3, dtype)
    Model = make_structs(dtype, True).Model
    rows = make_rows(dtype, True)
    row, rvec, dvec, term_node = rows.row, rows.rvec, rows.dvec, rows.term_node
    tendon_route = make_routes(dtype, True, helix, spline).tendon_route
    module = f"tdcr_warp_energy_{wp.types.type_repr(dtype)}_{int(helix)}{int(spline)}"

    @wp.func
    def motion(md: Model, b: int, y: wp.array3d(dtype=vec3), slot: int):
        """Kinetic plus elastic energy per length at one slot [J/m] (float64)."""
        v = y[b, slot, SLOT_V] - vec3(dtype(0.0), dtype(0.0), dtype(1.0))
        u = y[b, slot, SLOT_U] - rvec(md, b, USTAR)
        q = y[b, slot, SLOT_Q]
        w = y[b, slot, SLOT_W]
        e = md.dyn[row(b, md.dyn), RHOA] * wp.dot(q, q) + wp.dot(w, wp.cw_mul(dvec(md, b, RHOJ), w))
        e += wp.dot(v, wp.cw_mul(rvec(md, b, KSE), v)) + wp.dot(u, wp.cw_mul(rvec(md, b, KBT), u))
        return wp.float64(e) * wp.float64(0.5)

    @wp.func
    def tendon_lengths(md: Model, b: int, y: wp.array3d(dtype=vec3), tau: wp.array2d(dtype=dtype), slot: int,
                       s: dtype, node: int):
        """sum_k tau_k |v + u x r_k + r_k'| at one slot over the tendons that run past ``node`` [J/m]."""
        v = y[b, slot, SLOT_V]
        u = y[b, slot, SLOT_U]
        e = wp.float64(0.0)
        for k in range(md.n_tendons):
            t = tau[b, k]
            if t != dtype(0.0) and term_node(md, b, k) > node:
                r, dr, _ddr = tendon_route(md, b, k, s)
                e += wp.float64(t * wp.length(v + wp.cross(u, r) + dr))
        return e

    @wp.kernel(module=module, enable_backward=False)
    def energy(md: Model, tau: wp.array2d(dtype=dtype), p: wp.array2d(dtype=vec3), y: wp.array3d(dtype=vec3),
               jslot: int, coupled: int, out: wp.array2d(dtype=wp.float64)):
        """Per rod: out[b, 0] = H, out[b, 1] = T + U_el [J]; y: Step.ycur (B, S, SLOT_WIDTH), its
        node slots from ``jslot`` on (two per node: proximal and distal side); ``coupled``: add the
        tendons' potentials (the coupled model)."""
        b = wp.tid()
        ig = row(b, md.grid)
        n_int = md.grid.shape[1] - 1
        fe = rvec(md, b, FE)
        kin = wp.float64(0.0)
        pot = wp.float64(0.0)
        for k in range(n_int):
            h = wp.float64(md.grid[ig, k + 1] - md.grid[ig, k]) * wp.float64(0.5)
            a = jslot + 2 * k + 1
            c = jslot + 2 * k + 2
            kin += h * (motion(md, b, y, a) + motion(md, b, y, c))
            pot -= h * wp.float64(wp.dot(fe, p[b, k] + p[b, k + 1]))
            if coupled != 0:
                pot += h * (tendon_lengths(md, b, y, tau, a, md.grid[ig, k], k)
                            + tendon_lengths(md, b, y, tau, c, md.grid[ig, k + 1], k))
        pot -= wp.float64(wp.dot(rvec(md, b, TIP_F), p[b, n_int]))
        for j in range(md.n_points):
            i = row(b, md.pforce)
            f = vec3(md.pforce[i, j, 0], md.pforce[i, j, 1], md.pforce[i, j, 2])
            pot -= wp.float64(wp.dot(f, p[b, md.pnode[row(b, md.pnode), j]]))
        out[b, 0] = kin + pot
        out[b, 1] = kin

    return SimpleNamespace(energy=energy, module=module)
