"""Column layout of the packed per-rod arrays and the status bits, shared by host and kernels.

``rod`` array, shape (1 or B, ROD_WIDTH), SI units:
  KSE..KSE+2   shear/extension stiffness diagonal (G A, G A, E A) [N]
  KBT..KBT+2   bending/torsion stiffness diagonal (E I, E I, G J) [N m^2]
  USTAR..+2    precurvature u* (body frame) [1/m]
  FE..FE+2     distributed external force rho A g (world frame) [N/m]
  TIP_F..+2    tip force (world frame) [N]
  TIP_M..+2    tip moment (world frame) [N m]
  LENGTH       rod length [m]
  FORCE_SCALE  E I / L^2 [N] and MOMENT_SCALE E I / L [N m]: the shooting unknowns and residual are
               n / FORCE_SCALE and m / MOMENT_SCALE (the one definition of that scaling)

``tendon`` array, shape (1 or B, K, TENDON_WIDTH): body-frame routing
  r(s) = [X0 + DX s + A cos(W s + PHASE), Y0 + DY s + A sin(W s + PHASE), 0]   [m], W in [rad/m],
  DX, DY [-] (converging or diverging routes); and the tendon itself:
  MU           friction coefficient mu [-] (capstan: tau' = -mu sigma kappa tau)
  COMPLIANCE   1 / (E_t A_t) of the wire [1/N] (0: inextensible)
  SLACK_SLOPE  slope of the slack branch of a displacement-controlled tendon's residual per
               scaled unknown (host-computed to match the taut branch at zero tension)
"""

KSE, KBT, USTAR, FE, TIP_F, TIP_M, LENGTH, FORCE_SCALE, MOMENT_SCALE = 0, 3, 6, 9, 12, 15, 18, 19, 20
ROD_WIDTH = 21

T_X0, T_Y0, T_A, T_W, T_PHASE, T_DX, T_DY, T_MU, T_COMPLIANCE, T_SLACK_SLOPE = range(10)
TENDON_WIDTH = 10

# ``sect`` array, shape (1|B, S, SEC_WIDTH): a backbone that varies along s (tdcr_warp.model.backbone),
# one row per section: SEC_START, SEC_END its ends [m] (nodes of the grid), then at its start the
# value and the slope d/ds of the outer radius SEC_RO [m], inner radius SEC_RI [m], Young's modulus
# SEC_E [Pa], shear modulus SEC_G [Pa] and density SEC_RHO [kg/m^3] (each linear in s). With
# sections (Features.sections) the rod table's KSE, KBT hold the values at the base (scales only) and
# FE holds the gravitational acceleration g [m/s^2]: the weight per length is rho A(s) g.
SEC_START, SEC_END, SEC_RO, SEC_RI, SEC_E, SEC_G, SEC_RHO = 0, 1, 2, 4, 6, 8, 10
SEC_WIDTH = 12

# ``obst`` array, shape (1 or B, O, OB_WIDTH): the obstacles (world frame, SI units) and the
# contact law of the rod with them (kernels/contact.py).
#   OB_KIND           PLANE, SPHERE, CAPSULE, TUBE or BENT_TUBE
#   OB_A..+2          plane: a point on it; sphere: centre; capsule, tube: axis start; bent tube: its start
#   OB_B..+2          plane: unit normal (the free side); capsule, tube: axis end; bent tube: unit tangent at start
#   OB_C..+2          bent tube: unit vector from its start toward the centre of its bend
#   OB_RADIUS         sphere, capsule: radius; tube, bent tube: inner radius [m]
#   OB_BEND, OB_ANGLE bent tube: radius of the bend's centre line [m] and its angle [rad]
#   OB_STIFF          penalty stiffness k of the contact [N/m per m of rod]
#   OB_REACH          the rod's contact radius (its radius) [m]
#   OB_DAMP           the contact's Hunt-Crossley damping factor [s/m] (dynamics)
#   OB_ALONG          1: a sphere or capsule pushes a node by the nearest point of its share of the
#                     centre line (tdcr_warp/physics/crossing.py), 0: by the node's point
PLANE, SPHERE, CAPSULE, TUBE, BENT_TUBE = range(5)
OB_KIND, OB_A, OB_B, OB_C, OB_RADIUS, OB_BEND, OB_ANGLE, OB_STIFF, OB_REACH, OB_DAMP, OB_ALONG = (
    0, 1, 4, 7, 10, 11, 12, 13, 14, 15, 16)
OB_WIDTH = 17

# ``tipc`` array, shape (1 or B, TC_WIDTH): a constrained tip (Robot.tip_constraint). TC_POINT..+2
# the point c the tip is held to; TC_BASIS..+8 up to three unit vectors e_i: the tip is held
# e_i . (p(L) - c) = -kappa lambda_i by a reaction sum_i lambda_i e_i, lambda_i shooting unknowns
# (a point: 3, a line: the 2 across it, a plane: its normal); TC_COMPLIANCE kappa [m/N]: 0 holds
# the tip, > 0 a spring of stiffness 1 / kappa (the host's path toward holding it).
TC_POINT, TC_BASIS, TC_COMPLIANCE = 0, 3, 12
TC_WIDTH = 13

# ``tendon_out`` columns (per rod and tendon) written by the final integration of a solve.
TO_BASE, TO_END, TO_PATH, TO_FREE, TO_TURN = range(5)  # tension at s=0 and at the end [N],
TO_WIDTH = 5  # stretched path length, unstretched length [m], total turning of the path [rad]

# Status bits of a rod's solve (uint16-compatible).
CONVERGED = 1
MAX_ITER = 2
NONFINITE = 4
SINGULAR = 8
STALLED = 16
PRECISION_LIMITED = 32  # with CONVERGED: stopped at the round-off floor, residual above tol
UNSETTLED = 64  # displacement control: the taut / slack set of the tendons did not settle
UNSTABLE = 128  # with CONVERGED: an equilibrium, but an unstable one (tdcr_warp/physics/stability.py)
PENETRATION = 256  # contact not resolved: a rigid obstacle penetrated beyond tolerance, or the base inside one
ENERGY = 512  # dynamics, with CONVERGED: the step created mechanical energy beyond energy_tolerance (physics/dynamics.py)
CROSSED = 1024  # a rigid obstacle crossed on the way to the answer (tdcr_warp/physics/crossing.py)

STATUS_NAMES = {
    CONVERGED: "converged",
    MAX_ITER: "iteration cap reached",
    NONFINITE: "non-finite state",
    SINGULAR: "singular Jacobian",
    STALLED: "line search stalled",
    PRECISION_LIMITED: "precision-limited (residual at round-off, above tol)",
    UNSETTLED: "taut/slack set of the displaced tendons did not settle",
    UNSTABLE: "unstable equilibrium",
    PENETRATION: "contact not resolved (a rigid obstacle penetrated beyond contact_tolerance at a node or between two, "
                 "or the base inside an obstacle; raise nodes for obstacles smaller than the node spacing)",
    ENERGY: "energy gained (free motion created mechanical energy beyond energy_tolerance)",
    CROSSED: "a rigid obstacle crossed on the way to the answer (no load path around it was found)",
}

# ``dyn`` array, shape (1 or B, DYN_WIDTH): dynamics parameters, SI units.
#   RHOA     mass per length rho A [kg/m]
#   RHOJ..+2 rotational inertia per length rho (Ixx, Iyy, 2 Ixx) [kg m]
#   BSE..+2  shear/extension damping diagonal [N s]
#   BBT..+2  bending/torsion damping diagonal [N m^2 s]
#   DRAG..+2 square-law drag diagonal C [kg/m^2]
RHOA, RHOJ, BSE, BBT, DRAG = 0, 1, 4, 7, 10
DYN_WIDTH = 13
