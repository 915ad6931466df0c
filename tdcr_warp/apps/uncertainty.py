"""First-order (linearised) propagation of a scene's [[uncertainty]] to the tip.

The Monte-Carlo job (``sweep montecarlo``) solves thousands of perturbed rods; to first order
the same spread comes from one solve. With the tip pose y(p) and the parameter Jacobian
J = dy/dp at the nominal parameters p0 (:mod:`tdcr_warp.physics.sensitivity`), independent
parameters of variances s_j^2 give

    Cov[y] ~= J diag(s^2) J^T,   Var[y_i] = sum_j J_ij^2 s_j^2   (the contribution of each j).

The variance of each distribution (the params of ``[[uncertainty]]``, as the sweep draws them):
normal [mean, std]: std^2; uniform [lo, hi]: (hi - lo)^2 / 12; lognormal [mu, sigma] (of the
log): (exp(sigma^2) - 1) exp(2 mu + sigma^2), the exact variance of exp(N(mu, sigma^2)).

The nominal point p0 is the value each field has in the scene, not the distribution's mean:
J is taken there and the returned tip is the scene's own. When a mean differs from the scene
value (a lognormal's mean is exp(mu + sigma^2 / 2)), the Monte-Carlo cloud is centred near
tip + J (mean - p0) instead (``mean_offset_tip``); the spread is the same to first order.
Neither has the second-order shift of the mean (curvature of y(p) times the variance), nor
any change of the spread when the scatter is large enough for y(p) to bend over it.
"""

from __future__ import annotations

import math

import numpy as np

from tdcr_warp.apps.sweep import SweepSpec
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.fields import parse_field
from tdcr_warp.model.robot import InputError
from tdcr_warp.physics.sensitivity import parameter_value
from tdcr_warp.physics.statics import solve_static

__all__ = ["distribution_moments", "linearised_spread"]


def distribution_moments(dist: str, a: float, b: float) -> tuple[float, float]:
    """(mean, variance) of an [[uncertainty]] distribution with params [a, b]; an
    :class:`InputError` names any distribution without a closed form here."""
    if dist == "normal":
        return a, b * b
    if dist == "uniform":
        return 0.5 * (a + b), (b - a) ** 2 / 12.0
    if dist == "lognormal":
        return math.exp(a + 0.5 * b * b), math.expm1(b * b) * math.exp(2 * a + b * b)
    raise InputError(f"distribution {dist!r}: no linearised variance for it (known: normal, uniform, lognormal)")


def _sensitivity_name(field: str) -> tuple[str, int | None]:
    """The scene field's name for solve_static's ``parameters`` (a helix tendon's scene key
    ``radius`` is the robot's ``helix_radius``), or (field, k) for ``actuation.tensions[k]``
    (the tension Jacobian's column k)."""
    path = parse_field(field)
    if path[:2] == ["actuation", "tensions"] and len(path) == 3:
        return field, path[2]
    if len(path) == 3 and path[0] == "tendons" and path[2] == "radius":
        return f"tendons[{path[1]}].helix_radius", None
    return field, None


def _nominal(robot, tensions: np.ndarray, name: str, column: int | None) -> float:
    """The scene's value of a parameter (rod 0)."""
    if column is not None:
        if not 0 <= column < robot.n_tendons or robot.tendons[column].control == "displacement":
            raise InputError(f"parameter {name!r}: no tendon {column} under tension control")
        return float(tensions[0, column])
    return float(parameter_value(robot, name)[1][0])


def linearised_spread(data: dict, device=None) -> dict:
    """The linearised tip spread of a single-rod scene dict (as tomllib parses a TOML scene)
    under its independent [[uncertainty]] entries: one nominal solve with parameter
    sensitivities (the scene's tensions, displacements and slip, as ``static_job`` solves).

    Fields: those of the sweep (``robot.<key>``, ``loads.<key>[c]``, ``tendons[i].<key>``,
    ``actuation.tensions[k]``) that the sensitivity code can differentiate; any other is the
    :class:`InputError` it raises. [sweep] (seed, samples, chunk) is not used; a [sweep.grid]
    is refused (there is no single nominal rod).

    Returns (numpy arrays, P parameters in the order of the entries):
      ``parameters`` [P field names]; ``nominal_values`` (P,) the scene's values, where J is
      taken; ``means`` (P,) and ``variances`` (P,) of the distributions; ``nominal_tip`` (3,)
      [m]; ``jacobian`` (6, P) d[tip position (m), tip rotation vector (rad)] / d parameter;
      ``pose_covariance`` (6, 6) J Sigma J^T; ``tip_covariance`` (3, 3) [m^2] its position
      block; ``tip_std`` (3,) [m]; ``contributions`` (P, 3) [m^2] each parameter's share
      J_ij^2 s_j^2 of the variance of axis i (summing over P to diag(tip_covariance));
      ``mean_offset_tip`` (3,) nominal_tip + J (means - nominal_values) (first order).
    """
    if not isinstance(data, dict):
        raise InputError(f"a scene must be a table, got {type(data).__name__}")
    entries = data.get("uncertainty")
    if not entries:
        raise InputError("linearised_spread needs [[uncertainty]] entries (field, distribution, params)")
    sweep = data.get("sweep", {})
    if isinstance(sweep, dict) and sweep.get("grid"):
        raise InputError("linearised_spread: the scene has a [sweep.grid]; linearise one nominal rod (drop the grid)")
    if isinstance(entries, list):  # name an unknown distribution before the sweep's generic check
        for i, u in enumerate(entries):
            if isinstance(u, dict) and u.get("distribution") not in ("normal", "uniform", "lognormal"):
                raise InputError(f"[[uncertainty]] #{i + 1} ({u.get('field')!r}): distribution "
                                 f"{u.get('distribution')!r} has no linearised variance (known: normal, uniform, "
                                 "lognormal)")
    spec = SweepSpec({k: v for k, v in data.items() if k != "sweep"} | {"sweep": {"samples": 1}})  # validates
    fields = [name for name, _, _ in spec.uncertainty]
    twice = sorted({f for f in fields if fields.count(f) > 1})
    if twice:
        raise InputError(f"[[uncertainty]]: field(s) {twice} listed more than once")
    scene = scene_from_dict(data)
    if scene.tensions.shape[0] != 1 or scene.robot.batch_size != 1:
        raise InputError("linearised_spread needs a single-rod scene: [actuation].tensions with one row")
    names, columns = zip(*(_sensitivity_name(f) for f in fields))
    params = [n for n, c in zip(names, columns) if c is None]
    nominal = np.array([_nominal(scene.robot, scene.tensions, n, c) for n, c in zip(names, columns)])
    sol = solve_static(scene.robot, scene.tensions, options=scene.options, device=device, parameters=params,
                       sensitivities=True, **scene.static_command())
    if not sol.converged[0]:
        raise InputError(f"linearised_spread: the nominal rod did not converge ({sol.failure_reasons()[0]})")
    by_name = dict(zip(sol.parameter_names, sol.parameter_jacobian[0].T)) if params else {}
    J = np.stack([sol.tip_jacobian[0, :, c] if c is not None else by_name[n] for n, c in zip(names, columns)],
                 axis=1)
    moments = np.array([distribution_moments(d, a, b) for _, d, (a, b) in spec.uncertainty])
    means, var = moments[:, 0], moments[:, 1]
    cov = (J * var) @ J.T
    tip = sol.tip_position[0]
    return {"parameters": fields, "nominal_values": nominal, "means": means, "variances": var,
            "nominal_tip": tip, "jacobian": J, "pose_covariance": cov, "tip_covariance": cov[:3, :3],
            "tip_std": np.sqrt(np.diag(cov[:3, :3])), "contributions": (J[:3] ** 2 * var).T,
            "mean_offset_tip": tip + J[:3] @ (means - nominal)}
