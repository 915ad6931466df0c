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

# ``tendon_out`` columns (per rod and tendon) written by the final integration of a solve.
TO_BASE, TO_END, TO_PATH, TO_FREE, TO_TURN = range(5)  # tension at s=0 and at the end [N],
TO_WIDTH = 5  # stretched path length, unstretched length [m], total turning of the path [rad]

# Status bits of a rod's solve (uint8-compatible).
CONVERGED = 1
MAX_ITER = 2
NONFINITE = 4
SINGULAR = 8
STALLED = 16
PRECISION_LIMITED = 32  # with CONVERGED: stopped at the round-off floor, residual above tol
UNSETTLED = 64  # displacement control: the taut / slack set of the tendons did not settle
UNSTABLE = 128  # with CONVERGED: an equilibrium, but an unstable one (tdcr_warp/physics/stability.py)

STATUS_NAMES = {
    CONVERGED: "converged",
    MAX_ITER: "iteration cap reached",
    NONFINITE: "non-finite state",
    SINGULAR: "singular Jacobian",
    STALLED: "line search stalled",
    PRECISION_LIMITED: "precision-limited (residual at round-off, above tol)",
    UNSETTLED: "taut/slack set of the displaced tendons did not settle",
    UNSTABLE: "unstable equilibrium",
}

# ``dyn`` array, shape (1 or B, DYN_WIDTH): dynamics parameters, SI units.
#   RHOA     mass per length rho A [kg/m]
#   RHOJ..+2 rotational inertia per length rho (Ixx, Iyy, 2 Ixx) [kg m]
#   BSE..+2  shear/extension damping diagonal [N s]
#   BBT..+2  bending/torsion damping diagonal [N m^2 s]
#   DRAG..+2 square-law drag diagonal C [kg/m^2]
RHOA, RHOJ, BSE, BBT, DRAG = 0, 1, 4, 7, 10
DYN_WIDTH = 13
