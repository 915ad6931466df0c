"""Batched shooting of the rod ODE: statics, and one BDF-alpha time step of dynamics.

``make_shooting_kernels`` gathers one variant's kernels (kernels/drivers.py) and what the host
allocates for them: the integration and residual are in kernels/integration.py, the Newton
machinery (which sees only the unknowns x and the residual r) in kernels/newton.py.
"""

import functools
from types import SimpleNamespace

from .drivers import (
    make_evaluate_kernel,
    make_fused_kernel,
    make_jacobian_kernel,
    make_probe_kernels,
    module_names,
)
from .integration import N_BASE, make_shoot
from .jacobi import make_verdict_kernel
from .newton import make_newton
from .nodes import make_rod_funcs
from .structs import tendon_vectors
from .variants import ALL, INTEGRATORS, STAGES, Features

__all__ = ["make_shooting_kernels"]


@functools.cache
def make_shooting_kernels(dtype, integrator: str, model: str, dynamic: bool = False, rod: str = "cosserat",
                          features: Features = ALL):
    """Shooting and Newton kernels for one precision, integrator, tendon model and physics.

    ``dynamic``: one BDF-alpha time step (reads ``Step``); otherwise statics. ``rod`` and
    ``features``: see ``make_rod_funcs``.

    Jacobian probes: forward differences in statics (6 probes); central differences in
    dynamics (12 probes), where inertia at small dt amplifies bending along s by up to
    ~1e8 and the second-order term of a forward difference swamps the axial rows (measured:
    forward differences stall Newton at dt = 2.5e-4 s on a 0.5 m steel rod).
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {INTEGRATORS}, got {integrator!r}")
    variant = (dtype, integrator, model, dynamic, rod, features)
    rf = make_rod_funcs(dtype, integrator, model, dynamic, rod, features)
    nu = N_BASE + features.displaced + features.tip
    nt = make_newton(dtype, nu, dynamic)
    probes = make_probe_kernels(*variant)
    # statics: the stability verdict shares the evaluate module (both are loaded together)
    verdict = None if dynamic or features.tip else make_verdict_kernel(dtype, integrator, model, rod, features)
    return SimpleNamespace(solve=make_fused_kernel(*variant), probe=probes.probe, update=probes.update,
                           finish=probes.finish, begin=probes.begin, evaluate=make_evaluate_kernel(*variant),
                           jacobian=None if dynamic else make_jacobian_kernel(*variant),
                           verdict=verdict and verdict.kernel, Fields=verdict and verdict.Fields,
                           Model=rf.Model, Control=rf.Control, Step=rf.Step, Nodes=make_shoot(*variant).Nodes,
                           Newton=nt.Newton, vec3=rf.vec3, mat33=rf.mat33, evec=tendon_vectors(dtype, features.tendons)[1], vecu=nt.vec, matu=nt.mat,
                           stages=STAGES[integrator], n_probes=nt.n_probes, width=nt.width, nu=nu, K=rf.K,
                           tstate=rf.tstate, friction=features.friction, modules=module_names(*variant))
