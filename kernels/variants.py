"""What selects a kernel variant, as plain data (no Warp here, so the model layer and the scene
reader can name the choices without building a kernel): the tendon models, the rod models, the
integrators with their stage counts, and the feature set of a scene."""

from typing import NamedTuple

__all__ = ["ALL", "INTEGRATORS", "MODELS", "RODS", "STAGES", "Features"]

MODELS = ("coupled", "point", "disks")
RODS = ("cosserat", "kirchhoff")
STAGES = {"euler": 1, "midpoint": 2, "rk4": 4}  # explicit Runge-Kutta schemes and their stage counts
INTEGRATORS = tuple(STAGES)


class Features(NamedTuple):
    """Physics a scene contains; a False field compiles its terms out (``ALL``: the general kernel)."""

    gravity: bool = True  # distributed external force rho A g
    point_loads: bool = True  # point forces along the rod
    helix: bool = True  # routing with a varying offset (helical, converging)
    drag: bool = True  # square-law drag (dynamics)
    kinks: bool = True  # coupled model: the push of tendons kinked at a jump of n or m
    friction: bool = False  # capstan friction: tensions vary along s
    tendons: int = 0  # K > 0: per-tendon states along s (turning, path length, unstretched length); 4K: disks
    displaced: int = 0  # displacement-controlled tendons: one shooting unknown and residual each
    spline: bool = False  # tendons routed through points (cubic segments in Model.route)
    contact: bool = False  # obstacles: a penalty contact force at every node (kernels/contact.py)
    tip: int = 0  # a constrained tip: the reaction's unknowns and residuals (3 point, 2 line, 1 plane)
    sections: bool = False  # a backbone varying along s: stiffness, its slope and rho A from Model.sect


ALL = Features()
