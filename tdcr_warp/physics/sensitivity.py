"""Sensitivities of solved rods from the converged shooting problem (implicit-function theorem).

At a converged rod the shooting residual vanishes, r(x*, p) = 0 (x: the scaled unknowns, p: an
input), so dx/dp = -J^-1 dr/dp with J = dr/dx, and a tip quantity y(x, p) moves as
dy/dp = dy/dp|_x + dy/dx dx/dp. J and dy/dx come from nu forward-difference probes at x* (a
fresh J: Newton's last one may be a Broyden update); dr/dp and dy/dp|_x from one probe
integration per input, or in closed form where the input enters the residual alone: the tip
wrench (dr/dF = -I / (EI/L^2), dr/dM = -I / (EI/L): the residual's scales) and a motor
displacement (dr/dq = 1/L, kernels/tendons.py ``length_residuals``). No Newton solve is repeated.

The tip pose y = [p(L) [m], theta [rad]]: theta is the world-frame rotation vector of a small
change of the tip frame, dR R^T = [theta]x.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tdcr_warp.core.build import Tables, put_model
from tdcr_warp.kernels import layout
from tdcr_warp.model.robot import InputError, Robot

__all__ = ["PROBE_REL", "linearise", "parameter_tables", "parameter_value", "perturbed", "pose_rate"]

PROBE_REL = {"float64": 1.5e-8, "float32": 3e-4}  # forward-difference step, relative to max(1, |value / scale|)
PARAM_REL = {"float64": 1e-5, "float32": 3e-3}  # central differences of a parameter (relative step)
AXIAL = 2  # the scaled unknown of the axial base force n_z(0)
AXIAL_STRAIN = {"float64": 1e-9, "float32": 1e-8}  # float32: the tip's round-off swamps the axial entries


def vee_rate(R0: np.ndarray, R1: np.ndarray, h) -> np.ndarray:
    """The world-frame rotation vector per unit h from R0 to R1 (..., 3, 3): vee of the skew
    part of (R1 - R0) R0^T / h."""
    W = np.einsum("...ij,...kj->...ik", R1 - R0, R0) / h
    return 0.5 * np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
                          axis=-1)


def pose_rate(base: dict, probe: dict, h: np.ndarray) -> np.ndarray:
    """(b, 6) the tip pose change per unit input: [dp (3), dtheta (3)] / h (h: (b,))."""
    return np.concatenate([(probe["p"] - base["p"]) / h[:, None], vee_rate(base["R"], probe["R"], h[:, None, None])],
                          axis=1)


# Robot fields a parameter Jacobian may perturb, and the size a zero value is measured against
# (the step is PARAM_REL times the larger of |value| and it).
_SCALAR = {"youngs_modulus": "E", "poisson_ratio": 1.0, "radius": "r", "density": 1000.0, "length": "L"}
_VECTOR = {"gravity": 10.0, "tip_force": "fs", "tip_moment": "ms", "precurvature": "1/L"}
_TENDON = {"offset": "r", "friction": 1.0, "compliance": "c", "pretension": "fs", "helix_radius": "r", "angle": 1.0}
# "angle": a tendon's route turned about the backbone [rad] from where it is (its offsets rotated;
# a derived parameter with no stored field, its value 0)


def _field_scale(robot: Robot, what, B: int) -> np.ndarray:
    if not isinstance(what, str):
        return np.full(B, float(what))
    sec = robot.section()
    L = np.broadcast_to(robot.length, (B,))
    ei = np.broadcast_to(sec["kbt"][:, 0], (B,))
    return {"E": np.broadcast_to(robot.youngs_modulus, (B,)), "r": np.broadcast_to(robot.radius, (B,)), "L": L,
            "fs": ei / L**2, "ms": ei / L, "1/L": 1.0 / L,
            "c": 1.0 / np.broadcast_to(sec["kse"][:, 2], (B,))}[what]


def parse_parameter(name: str):
    """'youngs_modulus' | 'robot.radius' | 'loads.tip_force[0]' | 'tendons[1].offset[0]' ->
    (tendon index or None, field, component or None)."""
    from tdcr_warp.model.fields import parse_field  # the scene's field syntax

    path = parse_field(name)
    if path[0] in ("robot", "loads"):
        path = path[1:]
    tendon = None
    if path[:1] == ["tendons"]:
        if len(path) < 3 or not isinstance(path[1], int):
            raise InputError(f"parameter {name!r}: use tendons[k].<field>")
        tendon, path = path[1], path[2:]
    comp = path[1] if len(path) == 2 and isinstance(path[1], int) else None
    if len(path) != (1 if comp is None else 2) or not isinstance(path[0], str):
        raise InputError(f"parameter {name!r}: cannot parse it")
    table = _TENDON if tendon is not None else (_SCALAR | _VECTOR)
    if path[0] not in table:
        raise InputError(f"parameter {name!r}: the field must be one of {sorted(table)}"
                         + (" of a tendon" if tendon is not None else " of the robot (or tendons[k].<field>)"))
    vector = path[0] in _VECTOR or path[0] == "offset"
    if vector and comp is None:
        raise InputError(f"parameter {name!r}: name a component, e.g. {name}[0]")
    if not vector and comp is not None:
        raise InputError(f"parameter {name!r}: {path[0]} is a scalar")
    if comp is not None and not 0 <= comp < (2 if path[0] == "offset" else 3):
        raise InputError(f"parameter {name!r}: component {comp} out of range")
    return tendon, path[0], comp, table[path[0]]


def parameter_value(robot: Robot, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Parameter ``name``'s field as stored (its owner's array) and its value per rod (B,)."""
    tendon, fname, comp, _ = parse_parameter(name)
    if tendon is not None and not 0 <= tendon < robot.n_tendons:
        raise InputError(f"parameter {name!r}: the robot has {robot.n_tendons} tendons")
    owner = robot if tendon is None else robot.tendons[tendon]
    if fname == "angle":
        return np.zeros(()), np.zeros(robot.batch_size)
    value = np.array(getattr(owner, fname), dtype=np.float64)
    cur = value[..., comp] if comp is not None else value
    return value, np.broadcast_to(cur, (robot.batch_size,)) if cur.ndim else np.full(robot.batch_size, float(cur))


def perturbed(robot: Robot, name: str, rel: float, sign: float = 1.0) -> tuple[Robot, np.ndarray]:
    """The robot with parameter ``name`` moved by sign h, h = rel max(|value|, scale), and h (B,)."""
    tendon, fname, comp, scale = parse_parameter(name)
    B = robot.batch_size
    value, cur = parameter_value(robot, name)
    owner = robot if tendon is None else robot.tendons[tendon]
    h = rel * np.maximum(np.abs(cur), _field_scale(robot, scale, B))
    new = np.broadcast_to(value, (B,) + value.shape[-1:] if comp is not None else (B,)).copy()
    if comp is not None:
        new[:, comp] += sign * h
    else:
        new += sign * h
    if tendon is None:
        return replace(robot, **{fname: new}), h
    if fname == "helix_radius" and owner.routing != "helix":
        raise InputError(f"parameter {name!r}: tendon {tendon} is not helical")
    if fname == "angle" and owner.routing == "points":
        raise InputError(f"parameter {name!r}: tendon {tendon} is routed through points (turn them instead)")
    tendons = list(robot.tendons)
    tendons[tendon] = _turned(owner, new) if fname == "angle" else replace(owner, **{fname: new})
    return replace(robot, tendons=tuple(tendons)), h


def _turned(tendon, angle: np.ndarray):
    """The tendon with its route turned about the backbone by ``angle`` (B,) [rad]: its offsets
    (base and, for a linear route, end) rotated; a helix's phase advanced."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]

    def turn(xy):
        xy = np.broadcast_to(np.asarray(xy, dtype=np.float64), (len(angle), 2))
        return np.concatenate([c * xy[:, :1] - s * xy[:, 1:], s * xy[:, :1] + c * xy[:, 1:]], axis=1)

    fields = {"offset": turn(tendon.offset)}
    if tendon.offset_end is not None:
        fields["offset_end"] = turn(tendon.offset_end)
    if tendon.routing == "helix":
        fields["phase"] = np.asarray(tendon.phase, dtype=np.float64) + angle
    return replace(tendon, **fields)


def parameter_tables(robot: Robot, tables: Tables, names, precision: str, nodes: int, specialize: bool,
                     kink_loads: bool, lengths: bool) -> list[tuple[Tables, np.ndarray]]:
    """Per parameter the tables of the robot moved by +h and by -h (central differences: a
    parameter may move the tip little, and a step of PARAM_REL keeps its change far above the
    round-off) and h (B,). The scales of the shooting unknowns and the slack slopes stay those
    of the nominal robot (the probes hold the physical base wrench and the residual's meaning
    fixed)."""
    out = []
    for name in names:
        pair = []
        for sign in (1.0, -1.0):
            rb, h = perturbed(robot, name, PARAM_REL[precision], sign)
            pair.append(_probe_tables(rb, tables, name, nodes, specialize, kink_loads, lengths))
        out.append((*pair, h))
    return out


def _probe_tables(rb: Robot, tables: Tables, name: str, nodes: int, specialize: bool, kink_loads: bool,
                  lengths: bool) -> Tables:
    tp = Tables.of(rb, nodes, specialize, kink_loads, "solve", lengths, tables.disks)
    if tp.grid.shape[1] != tables.grid.shape[1] or tp.features != tables.features or \
            not np.array_equal(tp.term_node, tables.term_node) or not np.array_equal(tp.pnode, tables.pnode):
        raise InputError(f"parameter {name!r} changes the structure of the problem (its grid or physics)")
    if tables.features.tendons and not np.allclose(tp.tendon_len, tables.tendon_len, rtol=0, atol=0):
        raise InputError(f"parameter {name!r}: a tendon's length moves; with tendon states (displacement "
                         "control, friction) that derivative is not available")
    rod = np.array(np.broadcast_to(tp.rod, (max(tp.rod.shape[0], tables.rod.shape[0]), layout.ROD_WIDTH)))
    rod[:, layout.FORCE_SCALE] = np.broadcast_to(tables.rod[:, layout.FORCE_SCALE], rod.shape[:1])
    rod[:, layout.MOMENT_SCALE] = np.broadcast_to(tables.rod[:, layout.MOMENT_SCALE], rod.shape[:1])
    tendon = np.array(tp.tendon)
    if tendon.size:
        tendon = np.array(np.broadcast_to(tendon, (max(tendon.shape[0], tables.tendon.shape[0]),) + tendon.shape[1:]))
        tendon[..., layout.T_SLACK_SLOPE] = np.broadcast_to(tables.tendon[..., layout.T_SLACK_SLOPE],
                                                            tendon.shape[:2])
    return replace(tp, rod=rod, tendon=tendon)


def linearise(sh, tau: np.ndarray, tables: Tables, lo: int, hi: int, precision: str,
              parameters: list[tuple[Tables, np.ndarray]] = (), *, base: dict | None = None,
              shapes: bool = False) -> dict[str, np.ndarray]:
    """The sensitivities of the rods lo:hi solved by ``sh`` (a Shooting at its solution) under
    tensions ``tau`` (b, K) (as set: the columns of displaced tendons are zero).

    Returns ``tip_jacobian`` (b, 6, K): d[p(L), theta] / d(tension [N] of a tendon under
    tension control, displacement [m] of one under displacement control); ``tip_compliance``
    (b, 6, 6): d[p(L), theta] / d[F_tip, M_tip]; ``tension_jacobian`` (b, K, K): d(tension at the
    motor [N] of tendon k) / d(command of tendon l) (a slack tendon's row is the derivative of its
    unknown as if it were taut: the caller zeroes it); ``slack_jacobian`` (b, K, K): d(slack
    length [m] of displaced tendon k) / d(command of l), for the rows of slack tendons (the
    caller zeroes the others); ``parameter_jacobian`` (b, 6, P) per unit of
    each parameter; ``unknowns_jacobian`` J (b, nu, nu) at x*; ``integrations`` (b,) spent;
    with ``shapes`` also ``base`` and ``fields`` (the node arrays of x* and, per base-wrench
    unknown, of its probe above and (central differences) below or None, and their steps
    ``field_steps`` (b, 6)) for the stability test."""
    x = sh.newton.x.numpy().astype(np.float64)
    b = x.shape[0]
    K = tau.shape[1]
    spent = 0
    if base is None:
        base = sh.probe(x, shapes=shapes)
        spent += 1
    rod = np.broadcast_to(tables.rows("rod", lo, hi), (b, layout.ROD_WIDTH))
    hx = _unknown_steps(x, rod, precision)
    with np.errstate(all="ignore"):  # a rod that did not converge may probe non-finite: its rates are NaN
        J, Yx, fields, probes = _unknown_rates(sh, x, hx, base, tables.features.displaced > 0, shapes)
        D, Y, inputs = _input_rates(sh, x, tau, tables, lo, hi, rod, PROBE_REL[precision], parameters, base)
        spent += probes + inputs
        try:
            dx = -np.linalg.solve(J, D)
        except np.linalg.LinAlgError:  # a singular rod: NaN for it alone
            dx = np.stack([_solve_or_nan(J[i], D[i]) for i in range(b)])
        dY = Y + Yx @ dx
    dtau, dslack = _command_rates(dx, tables, lo, hi, rod)
    out = {"tip_jacobian": dY[:, :, :K], "tip_compliance": dY[:, :, K:K + 6], "tension_jacobian": dtau,
           "slack_jacobian": dslack, "unknowns_jacobian": J, "parameter_jacobian": dY[:, :, K + 6:],
           "integrations": np.full(b, spent)}
    if shapes:
        out |= {"base": base, "fields": fields, "field_steps": hx[:, :6]}
    return out


def _unknown_steps(x: np.ndarray, rod: np.ndarray, precision: str) -> np.ndarray:
    """(b, nu) the finite-difference step of every scaled unknown: PROBE_REL relative to max(1, |x|),
    and for the axial force at least the step of an axial strain of AXIAL_STRAIN."""
    hx = PROBE_REL[precision] * np.maximum(1.0, np.abs(x))
    # The axial force: a step of rel would stretch the rod by ~rel (r / 2L)^2, below the round-off
    # of the tip position; it takes central differences at an axial strain of AXIAL_STRAIN.
    axial = AXIAL_STRAIN[precision] * rod[:, layout.KSE + 2] / rod[:, layout.FORCE_SCALE]
    hx[:, AXIAL] = np.maximum(hx[:, AXIAL], axial)
    return hx


def _unknown_rates(sh, x: np.ndarray, hx: np.ndarray, base: dict, central: bool,
                   shapes: bool) -> tuple[np.ndarray, np.ndarray, list, int]:
    """The shooting Jacobian J = dr / dx (b, nu, nu) and the tip pose's Yx = d pose / dx (b, 6, nu)
    at x* by probes of every unknown (forward differences from ``base``; central for the axial force
    and, with ``central``, throughout), the probes' shapes (``fields``, with ``shapes``) and the
    number of integrations spent."""
    b, nu = x.shape
    J = np.empty((b, nu, nu))
    Yx = np.empty((b, 6, nu))
    fields = []
    spent = 0
    for j in range(nu):
        xp = x.copy()
        xp[:, j] += hx[:, j]
        pr = sh.probe(xp, shapes=shapes and j < 6)
        lower, h = base, hx[:, j]
        if j == AXIAL or central:
            xp[:, j] -= 2 * hx[:, j]
            lower, h = sh.probe(xp, shapes=shapes), 2 * hx[:, j]
            spent += 1
        J[:, :, j] = (pr["res"] - lower["res"]) / h[:, None]
        Yx[:, :, j] = pose_rate(lower, pr, h)
        if shapes and j < 6:
            fields.append((pr, None if lower is base else lower))
    return J, Yx, fields, spent + nu


def _input_rates(sh, x: np.ndarray, tau: np.ndarray, tables: Tables, lo: int, hi: int, rod: np.ndarray, rel: float,
                 parameters, base: dict) -> tuple[np.ndarray, np.ndarray, int]:
    """D = dr / d input (b, nu, K + 6 + P) and Y = d pose / d input (b, 6, K + 6 + P) at x*, the inputs
    being the commands (K), the tip wrench (6) and the parameters (P), and the integrations spent."""
    b, nu = x.shape
    K = tau.shape[1]
    spent = 0
    n_in = K + 6 + len(parameters)
    D = np.zeros((b, nu, n_in))  # dr / d input at x*
    Y = np.zeros((b, 6, n_in))  # d tip / d input at x*
    fs, ms, L = rod[:, layout.FORCE_SCALE], rod[:, layout.MOMENT_SCALE], rod[:, layout.LENGTH]
    tmode = tables.tmode[0]
    for k in range(K):
        if tmode[k] >= 0:  # the motor gives the tendon q less: the residual (ell0 - avail) / L grows by q / L
            D[:, 6 + tmode[k], k] = 1.0 / L
            continue
        ht = rel * np.maximum(np.abs(tau[:, k]), fs)
        tp = tau.copy()
        tp[:, k] += ht
        sh.set_tensions(tp)
        pr = sh.probe(x)
        sh.set_tensions(tau)
        D[:, :, k] = (pr["res"] - base["res"]) / ht[:, None]
        Y[:, :, k] = pose_rate(base, pr, ht)
        spent += 1
    for i in range(3):  # r = [(n(L+) - F) / fs, (m(L+) - M) / ms]
        D[:, i, K + i] = -1.0 / fs
        D[:, 3 + i, K + 3 + i] = -1.0 / ms
    for c, (up, down, h) in enumerate(parameters):
        hp = 2 * (h if len(h) > 1 else np.broadcast_to(h, (hi,)))[lo:hi]
        pu, pd = (sh.probe(x, put_model(sh.kern, sh.dev, t, lo, hi)) for t in (up, down))
        D[:, :, K + 6 + c] = (pu["res"] - pd["res"]) / hp[:, None]
        Y[:, :, K + 6 + c] = pose_rate(pd, pu, hp)
        spent += 2
    return D, Y, spent


def _command_rates(dx: np.ndarray, tables: Tables, lo: int, hi: int, rod: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d base tension / d command (b, K, K) and d slack length / d command (b, K, K) from dx / d input:
    1 for tension control, fs dx / dq for a taut displaced tendon; a slack one's unknown x measures
    its slack, -x slope L (kernels/tendons.py length_residuals)."""
    b = dx.shape[0]
    tmode = tables.tmode[0]
    K = len(tmode)
    fs, L = rod[:, layout.FORCE_SCALE], rod[:, layout.LENGTH]
    dtau, dslack = np.zeros((b, K, K)), np.zeros((b, K, K))
    slope = np.broadcast_to(tables.rows("tendon", lo, hi)[..., layout.T_SLACK_SLOPE], (b, K))
    for k in range(K):
        if tmode[k] >= 0:
            dtau[:, k] = fs[:, None] * dx[:, 6 + tmode[k], :K]
            dslack[:, k] = -(slope[:, k] * L)[:, None] * dx[:, 6 + tmode[k], :K]
        else:
            dtau[:, k, k] = 1.0
    return dtau, dslack


def _solve_or_nan(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    try:
        return -np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        return np.full(B.shape, np.nan)
