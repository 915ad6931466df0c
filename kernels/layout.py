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
  r(s) = [X0 + A cos(W s + PHASE), Y0 + A sin(W s + PHASE), 0]   [m], W in [rad/m].
"""

KSE, KBT, USTAR, FE, TIP_F, TIP_M, LENGTH, FORCE_SCALE, MOMENT_SCALE = 0, 3, 6, 9, 12, 15, 18, 19, 20
ROD_WIDTH = 21

T_X0, T_Y0, T_A, T_W, T_PHASE = 0, 1, 2, 3, 4
TENDON_WIDTH = 5

# Status bits of a rod's solve (uint8-compatible).
CONVERGED = 1
MAX_ITER = 2
NONFINITE = 4
SINGULAR = 8
STALLED = 16
PRECISION_LIMITED = 32  # with CONVERGED: stopped at the round-off floor, residual above tol

STATUS_NAMES = {
    CONVERGED: "converged",
    MAX_ITER: "iteration cap reached",
    NONFINITE: "non-finite state",
    SINGULAR: "singular Jacobian",
    STALLED: "line search stalled",
    PRECISION_LIMITED: "precision-limited (residual at round-off, above tol)",
}

# ``dyn`` array, shape (1 or B, DYN_WIDTH): dynamics parameters, SI units.
#   RHOA     mass per length rho A [kg/m]
#   RHOJ..+2 rotational inertia per length rho (Ixx, Iyy, 2 Ixx) [kg m]
#   BSE..+2  shear/extension damping diagonal [N s]
#   BBT..+2  bending/torsion damping diagonal [N m^2 s]
#   DRAG..+2 square-law drag diagonal C [kg/m^2]
RHOA, RHOJ, BSE, BBT, DRAG = 0, 1, 4, 7, 10
DYN_WIDTH = 13
