"""Warp kernels of tdcr-warp. Imported as ``tdcr_warp.kernels``; imports only warp and siblings.

Each physics term is a named ``@wp.func``, built by a cached factory (``make_*``) of its
family's file and keyed only by what it needs; a feature a scene lacks compiles out
(``wp.static``). Where each term lives:

  term                                           file
  ---------------------------------------------  ----------------------------------------------
  MODELS, RODS, INTEGRATORS, STAGES, Features    variants.py   what selects a variant (plain data,
                                                               no Warp: the model layer reads it)
  Model, Control, Step; row, rvec, dvec,         structs.py    (packed tables: layout.py)
    term_node; the slots of the BDF history
  body_strains, strains, store_slot              strains.py    constitutive law (with strain damping)
  section_of, backbone, along, stiffness,        backbone.py   the stiffness along s: the rod table's, or
    boundary                                                   sections with tapers and jumps
  tendon_route, tendon_tangent                   tendons.py    tendon routing
  coupled_tendon_load                            tendons.py    distributed tendon load (coupled model)
  tendon_end_loads, kink_loads                   tendons.py    tendon point loads at a node
  tendon_rates, chord_rates                      tendons.py    tendon states E and the friction load
  base_tensions, length_residuals                tendons.py    displacement control
  tensions, tension_of, blend                    friction.py   capstan friction, stick-slip
  slip_state, store_profile, store_node_profile  friction.py   the tension profile a step keeps
  inertia_loads                                  inertia.py    inertia and drag (dynamics)
  damped_system                                  inertia.py    strain-rate damping in the (v', u') system
  kirchhoff_solve, cosserat_solve,               rod.py        (v', u') and the tendon load
    coupled_rates, point_rates
  rhs, point_jumps                               rod.py        d/ds of the state; point forces at a node
  stage_c, stage_w, orthonormalize, orth_error,  stepping.py   explicit Runge-Kutta, R a rotation
    interval
  disk_jumps                                     disks.py      spacer disks: chords between holes,
                                                               their pull at each disk (look-ahead)
  node_busy, span_end, node_jumps,               nodes.py      the jumps at a node; one variant's
    make_rod_funcs                                             rod functions gathered
  shoot, tip_residual, Nodes                     integration.py  base to tip: the shooting residual
  Newton, begin, update, solve_dense, ...        newton.py     damped (quasi-)Newton per rod
  totals, column, phases, track, sweep,          jacobi.py     the stability verdict: Jacobi fields
    verdict, asymmetry, restart (split rods),                  of the solution and their phases
    the verdict kernel
  invert, abs_det, symmetric_eigenvalues (6x6,  dense6.py     the verdict's dense algebra
    in a per-thread work array)
  solve / probe / update / finish / begin /      drivers.py    the Warp kernels (one module per
    evaluate / jacobian kernels                                variant and driver)
  make_shooting_kernels                          shooting.py   one variant's kernels, for the host
  end_step                                       history.py    BDF-alpha history between steps
  surface, contact_force, the contact_nodes      contact.py    obstacles: the penalty law at a node
    kernel                                                     and the contact outputs
  segmentable, the segment_ends kernel           segments.py   multiple shooting: a segment
                                                               integrated from a given start state
  band_widths, the band_solve kernel             banded.py     multiple shooting's Newton steps:
                                                               banded LU, one system per thread
"""
