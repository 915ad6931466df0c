"""TOML scenes: one file describes a batch of robots, their actuation and the solver.

Tables and keys (SI units; see README "Scene format"):
  [robot]      length, youngs_modulus, poisson_ratio, radius, density, precurvature, disk_radius
  [[tendons]]  offset, routing ("straight" | "helix" | "linear" | "points"), radius, turns, phase,
               length, offset_end (linear), points (points: [[s, x, y], ...]), control ("tension" |
               "displacement"), compliance, pretension, friction
  [loads]      gravity, tip_force, tip_moment, [[loads.point_forces]] (s, force)
  [actuation]  tensions (B rows of K), displacements (B rows of K, m), slip (B rows of K, +1 | -1),
               [[actuation.steps]] (start, tensions) for dynamics
  [solver]     preset, nodes, integrator, model, rod, precision, tol, max_iter, max_step, jacobian,
               continuation, specialize, error_estimate, threads, driver, kink_loads, tendon_states
  [dynamics]   dt, alpha, steps, damping_shear, damping_bending, drag, shapes_every
  [control]    target (or target_tensions / target_displacements: the static tip there, or path),
               method, input_model, gain_c, gain_k, epsilon, phi, tension_max, model_every,
               gain_i, command ("tension" | "displacement"), displacement_range ([lo, hi], m)
               (see tdcr_warp.apps.control)
  [ik]         targets (B rows of 3, m), target_rotations (B 3x3 matrices), tension_max (N),
               displacement_range ([lo, hi], m), tol (m), max_iter (see tdcr_warp.apps.ik)
  [hardware]   servo_columns (the measurement CSV's column of each tendon), marker_offset and
               base_offset (world frame, m) (see tdcr_warp.apps.hardware)
  [search]     budget (closed loops), population, seed, sigma, [search.ranges] gain = [lo, hi]
               (see tdcr_warp.apps.gainsearch)
A robot scalar may be a list of B numbers and a vector a list of B vectors (per-rod values).
Every error is an :class:`InputError` naming the table, the key and the value.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from tdcr_warp.io.drawing import display_options
from tdcr_warp.model.options import COMMANDS, StaticOptions
from tdcr_warp.model.robot import (
    InputError,
    PointForce,
    Robot,
    Tendon,
    check_displacements,
    check_slip,
    check_tensions,
    require_memory,
)
from tdcr_warp.model.tippath import path_from_table

__all__ = ["DynamicsSpec", "Scene", "load_scene", "scene_from_dict"]

ROBOT_KEYS = {"length", "youngs_modulus", "poisson_ratio", "radius", "density", "precurvature", "disk_radius"}
TENDON_KEYS = {"offset", "routing", "radius", "turns", "phase", "length", "offset_end", "control", "compliance",
               "pretension", "friction", "points"}
LOAD_KEYS = {"gravity", "tip_force", "tip_moment", "point_forces"}
POINT_KEYS = {"s", "force"}
ACTUATION_KEYS = {"tensions", "displacements", "slip", "steps"}
STEP_KEYS = {"start", "tensions"}
DYNAMICS_KEYS = {"dt", "alpha", "steps", "damping_shear", "damping_bending", "drag", "shapes_every"}
CONTROL_KEYS = {"target", "target_tensions", "path", "method", "input_model", "gain_c", "gain_k", "epsilon", "phi",
                "tension_max", "model_every", "gain_i", "command", "displacement_range", "target_displacements"}
SOLVER_KEYS = {f.name for f in fields(StaticOptions)} | {"preset"}
IK_KEYS = {"targets", "target_rotations", "tension_max", "displacement_range", "tol", "max_iter"}
HARDWARE_KEYS = {"servo_columns", "marker_offset", "base_offset"}
SEARCH_KEYS = {"ranges", "budget", "population", "seed", "sigma"}
# the gains a search ranges over: control.<gain_c|gain_k|gain_i> (every component, or [c] one), epsilon, phi
SEARCH_GAINS = re.compile(r"control\.(?:(?:gain_c|gain_k|gain_i)(?:\[[0-2]\])?|epsilon|phi)")
TABLES = {"robot", "tendons", "loads", "actuation", "solver", "dynamics", "control", "sweep", "uncertainty", "ik",
          "hardware", "display", "search"}
MAX_DEPTH = 16  # tables and lists nested deeper than any scene needs (a handful) are refused


@dataclass(frozen=True)
class DynamicsSpec:
    """dt [s], alpha, steps, schedule (B, steps, K) [N] (row k: tensions of step k + 1),
    shapes_every (0: tip only)."""

    dt: float
    alpha: float
    steps: int
    schedule: np.ndarray
    shapes_every: int


@dataclass(frozen=True)
class Scene:
    """A loaded scene. robot: the batch of B rods; tensions: (B, K) [N]; options: the
    [solver] table; dynamics: the [dynamics] table (None without one); source: the parsed
    TOML as a dict; control: the [control] table (None without one); ik: the [ik] table (None
    without one, its numbers checked); displacements (B, K)
    [m] and slip (B, K): the statics commands of tendons under displacement control and the
    slip directions of friction (None: not given)."""

    robot: Robot
    tensions: np.ndarray
    options: StaticOptions
    dynamics: DynamicsSpec | None
    source: dict
    control: dict | None = None
    displacements: np.ndarray | None = None
    slip: np.ndarray | None = None
    ik: dict | None = None
    hardware: dict | None = None
    display: dict | None = None  # the [display] table, checked (tdcr_warp.io.drawing)
    search: dict | None = None  # the [search] table, checked (search_options; tdcr_warp.apps.gainsearch)
    text: str | None = None  # the TOML file's content (load_scene; None for a scene made from a dict)

    def static_command(self) -> dict:
        """The keyword arguments of solve_static for this scene's actuation."""
        return {"displacements": self.displacements, "slip": self.slip}


def load_scene(path) -> Scene:
    """Read and validate a TOML scene; every problem is an :class:`InputError` naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read scene {str(path)!r}: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not UTF-8 text (TOML files are UTF-8): byte {e.start} is {e.object[e.start]:#04x}") \
            from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise InputError(f"{path}: invalid TOML: arrays or inline tables nested too deeply to parse (a scene "
                         f"takes at most {MAX_DEPTH} levels)") from None
    try:
        return replace(scene_from_dict(data), text=text)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _check_depth(data: dict) -> None:
    """An InputError naming the key under which tables and lists nest deeper than MAX_DEPTH
    (checked without recursion: deeper values would otherwise reach Python's recursion limit
    in the checks below, or in NumPy)."""
    todo = [(data, "", 0)]
    while todo:
        value, where, depth = todo.pop()
        if depth > MAX_DEPTH:
            raise InputError(f"{where}: nested more than {MAX_DEPTH} levels deep")
        for key, v in value.items() if isinstance(value, dict) else enumerate(value):
            if isinstance(v, (dict, list)):
                name = f"{where}[{key}]" if isinstance(key, int) else f"{where}.{key}" if where else key
                todo.append((v, name if depth < 3 else where, depth + 1))


def _table(data: dict, name: str, allowed: set[str], required: bool = False) -> dict:
    t = data.get(name)
    if t is None:
        if required:
            raise InputError(f"missing table [{name}]")
        return {}
    if not isinstance(t, dict):
        raise InputError(f"[{name}] must be a table, got {t!r}")
    _no_unknown(t, allowed, f"[{name}]")
    return t


def _no_unknown(t: dict, allowed: set[str], where: str) -> None:
    for key in t:
        if key not in allowed:
            raise InputError(f"unknown key {key!r} in {where} (known: {', '.join(sorted(allowed))})")


def _numbers(value, where: str):
    """Check that value is a number or a (nested) list of numbers; return it unchanged."""
    def ok(v):
        if isinstance(v, list):
            if len(v) > 64 and all(type(x) is float for x in v):  # a sweep's per-rod column, at C speed
                return True
            return len(v) > 0 and all(ok(x) for x in v)
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    if not ok(value):
        raise InputError(f"{where}: expected a number or a list of numbers, got {value!r}")
    return value


def _required(t: dict, key: str, where: str):
    if key not in t:
        raise InputError(f"missing key {key!r} in {where}")
    return _numbers(t[key], f"{where}.{key}")


def _number(value, where: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise InputError(f"{where}: expected a number, got {value!r}")
    return float(value)


def _integer(value, where: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        raise InputError(f"{where}: expected an integer, got {value!r}")
    return value


def _build(kind, kw: dict, where: str):
    """kind(**kw), with the table's location in front of any InputError."""
    try:
        return kind(**kw)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def search_options(table: dict, where: str = "[search]") -> dict:
    """The checked options of a gain search: a scene's [search] table, or (``where`` = "") the
    same options given as arguments. ``ranges`` {gain: [lo, hi]} with 0 < lo < hi (the search is
    in log space; gains as SEARCH_GAINS, a vector gain without an index sets every component),
    ``budget`` closed loops (>= 1), ``population`` (>= 4: CMA-ES's weights need two parents;
    None: its default 4 + floor(3 ln d) for d gains), ``seed`` (0 <= seed < 2**32, default 0),
    ``sigma`` (the initial step as a fraction of each log range, in (0, 1], default 0.3).
    Returns them with ranges as {gain: (lo, hi)}; an InputError names the key and the value."""
    def name(key: str) -> str:
        return f"{where}.{key}" if where else key

    if not isinstance(table, dict):
        raise InputError(f"{where or 'the search options'} must be a table, got {table!r}")
    _no_unknown(table, SEARCH_KEYS, where or "the search options")
    where_r = f"[{where.strip('[]')}.ranges]" if where else "ranges"
    raw = table.get("ranges")
    if not isinstance(raw, dict) or not raw:
        raise InputError(f"{where_r}: expected a table of gain = [lo, hi] (at least one), got {raw!r}")
    ranges = {}
    for gain, r in raw.items():
        if not (isinstance(gain, str) and SEARCH_GAINS.fullmatch(gain)):
            raise InputError(f"{where_r}: unknown gain {gain!r} (known: control.gain_c, control.gain_k, "
                             "control.gain_i, each whole or one component [0-2], control.epsilon, control.phi)")
        if not (isinstance(r, (list, tuple)) and len(r) == 2
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in r)):
            raise InputError(f"{where_r}.{gain!r}: expected [lo, hi], got {r!r}")
        lo, hi = float(r[0]), float(r[1])
        if not (0 < lo < hi < np.inf):
            raise InputError(f"{where_r}.{gain!r}: expected 0 < lo < hi (the search is in log space), got {r!r}")
        ranges[gain] = (lo, hi)
    for gain in ranges:
        if "[" in gain and gain.split("[")[0] in ranges:
            raise InputError(f"{where_r}: {gain!r} and {gain.split('[')[0]!r} both range over that component")
    out = {"ranges": ranges}
    for key, default, least, most in (("budget", None, 1, None), ("population", None, 4, None),
                                      ("seed", 0, 0, 2**32 - 1)):
        v = table.get(key, default)
        if key == "budget" and v is None:
            raise InputError(f"missing key 'budget' in {where or 'the search options'} (closed loops to spend)")
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < least
                              or (most is not None and v > most)):
            span = f">= {least}" if most is None else f"in [{least}, {most}]"
            raise InputError(f"{name(key)} must be an integer {span}, got {v!r}")
        out[key] = v
    sigma = table.get("sigma", 0.3)
    if not (isinstance(sigma, (int, float)) and not isinstance(sigma, bool) and 0 < sigma <= 1):
        raise InputError(f"{name('sigma')} must be a number in (0, 1] (a fraction of each log range), got {sigma!r}")
    out["sigma"] = float(sigma)
    return out


def scene_from_dict(data: dict) -> Scene:
    """Validate a parsed scene (the dict tomllib returns) and build its :class:`Scene`."""
    if not isinstance(data, dict):
        raise InputError(f"a scene must be a table, got {type(data).__name__}")
    _no_unknown(data, TABLES, "the scene")
    _check_depth(data)
    rob = _table(data, "robot", ROBOT_KEYS, required=True)
    robot_kw = {k: _required(rob, k, "[robot]") for k in ("length", "youngs_modulus", "poisson_ratio",
                                                            "radius", "density")}
    if "precurvature" in rob:
        robot_kw["precurvature"] = _numbers(rob["precurvature"], "[robot].precurvature")
    if "disk_radius" in rob:
        robot_kw["disk_radius"] = _numbers(rob["disk_radius"], "[robot].disk_radius")

    tendons = []
    raw_tendons = data.get("tendons", [])
    if not isinstance(raw_tendons, list):
        raise InputError("[[tendons]] must be an array of tables")
    for i, t in enumerate(raw_tendons):
        where = f"[[tendons]] #{i + 1}"
        if not isinstance(t, dict):
            raise InputError(f"{where} must be a table, got {t!r}")
        _no_unknown(t, TENDON_KEYS, where)
        routing = t.get("routing", "straight")
        if routing not in ("straight", "helix", "linear", "points"):
            raise InputError(f"{where}.routing must be 'straight', 'helix', 'linear' or 'points', got {routing!r}")
        kw = {"routing": routing}
        if "offset" in t:
            kw["offset"] = _numbers(t["offset"], f"{where}.offset")
        elif routing in ("straight", "linear"):
            raise InputError(f"missing key 'offset' in {where} ({routing} routing)")
        if routing == "points":
            kw["points"] = _numbers(_required(t, "points", where), f"{where}.points")
        elif "points" in t:
            raise InputError(f"{where}.points is only for routing = \"points\"")
        if routing == "linear":
            kw["offset_end"] = _numbers(_required(t, "offset_end", where), f"{where}.offset_end")
        elif "offset_end" in t:
            raise InputError(f"{where}.offset_end is only for routing = \"linear\"")
        for key in ("compliance", "pretension", "friction"):
            if key in t:
                kw[key] = _numbers(t[key], f"{where}.{key}")
        if "control" in t:
            kw["control"] = t["control"]
        if routing == "helix":
            kw["helix_radius"] = _required(t, "radius", where)
            kw["turns"] = _required(t, "turns", where)
            kw["phase"] = _numbers(t.get("phase", 0.0), f"{where}.phase")
        else:
            for key in ("radius", "turns", "phase"):
                if key in t:
                    raise InputError(f"{where}.{key} is only for routing = \"helix\"")
        if "length" in t:
            kw["length"] = _numbers(t["length"], f"{where}.length")
        tendons.append(_build(Tendon, kw, where))

    loads = _table(data, "loads", LOAD_KEYS)
    for key in ("gravity", "tip_force", "tip_moment"):
        if key in loads:
            robot_kw[key] = _numbers(loads[key], f"[loads].{key}")
    points = []
    raw_points = loads.get("point_forces", [])
    if not isinstance(raw_points, list):
        raise InputError("[[loads.point_forces]] must be an array of tables (write [[loads.point_forces]])")
    for j, pf in enumerate(raw_points):
        where = f"[[loads.point_forces]] #{j + 1}"
        if not isinstance(pf, dict):
            raise InputError(f"{where} must be a table, got {pf!r}")
        _no_unknown(pf, POINT_KEYS, where)
        points.append(_build(PointForce, dict(s=_required(pf, "s", where), force=_required(pf, "force", where)),
                             where))

    dyn = _table(data, "dynamics", DYNAMICS_KEYS)
    for key in ("damping_shear", "damping_bending", "drag"):
        if key in dyn:
            robot_kw[key] = _numbers(dyn[key], f"[dynamics].{key}")
    robot = Robot(tendons=tendons, point_forces=points, **robot_kw)

    act = _table(data, "actuation", ACTUATION_KEYS, required=True)
    tensions = check_tensions(robot, _required(act, "tensions", "[actuation]"), "[actuation].tensions")
    if robot.batch_size > 1 and tensions.shape[0] != robot.batch_size:
        raise InputError(f"[actuation].tensions: {tensions.shape[0]} rows for {robot.batch_size} rods")

    solver = dict(_table(data, "solver", SOLVER_KEYS))
    preset = solver.pop("preset", None)
    if preset is not None and not isinstance(preset, str):
        raise InputError(f"[solver].preset must be a string, got {preset!r}")
    options = StaticOptions.preset(preset, **solver) if preset is not None else StaticOptions(**solver)

    dynamics = None
    if dyn:
        steps = _integer(_required(dyn, "steps", "[dynamics]"), "[dynamics].steps")
        if steps < 1:
            raise InputError(f"[dynamics].steps must be >= 1, got {steps}")
        dt = _number(_required(dyn, "dt", "[dynamics]"), "[dynamics].dt")
        alpha = _number(dyn.get("alpha", 0.0), "[dynamics].alpha")
        shapes_every = _integer(dyn.get("shapes_every", 0), "[dynamics].shapes_every")
        require_memory(16.0 * steps * tensions.shape[0] * max(1, tensions.shape[1]),
                       f"[dynamics].steps = {steps} for {tensions.shape[0]} rod(s): the tension schedule")
        schedule = np.repeat(tensions[:, None, :], steps, axis=1)
        plan = act.get("steps", [])
        if not isinstance(plan, list):
            raise InputError("[[actuation.steps]] must be an array of tables")
        last = 0
        for j, entry in enumerate(plan):
            where = f"[[actuation.steps]] #{j + 1}"
            if not isinstance(entry, dict):
                raise InputError(f"{where} must be a table, got {entry!r}")
            _no_unknown(entry, STEP_KEYS, where)
            start = _integer(_required(entry, "start", where), f"{where}.start")
            if not (1 <= start <= steps) or start <= last:
                raise InputError(f"{where}.start must increase and lie in [1, {steps}], got {start}")
            last = start
            tau = check_tensions(robot, _required(entry, "tensions", where), f"{where}.tensions")
            if tau.shape[0] not in (1, tensions.shape[0]):
                raise InputError(f"{where}.tensions: {tau.shape[0]} rows for {tensions.shape[0]} rods")
            schedule[:, start - 1:, :] = tau[:, None, :]
        dynamics = DynamicsSpec(dt=dt, alpha=alpha, steps=steps, schedule=schedule, shapes_every=shapes_every)
    elif act.get("steps"):
        raise InputError("[[actuation.steps]] needs a [dynamics] table")
    control = _table(data, "control", CONTROL_KEYS) or None
    if control is not None:
        if dynamics is None:
            raise InputError("[control] needs a [dynamics] table (dt, steps, ...)")
        if sum(k in control for k in ("target", "target_tensions", "target_displacements", "path")) != 1:
            raise InputError("[control] needs exactly one of 'target' (m), 'target_tensions' (N), "
                             "'target_displacements' (m) or 'path' (a desired tip trajectory)")
        if "path" in control:
            path_from_table(control["path"])  # checked here, built where it is used
        for key in ("target", "target_tensions", "target_displacements", "gain_c", "gain_k", "epsilon", "phi",
                    "tension_max", "gain_i", "displacement_range"):
            if key in control:
                _numbers(control[key], f"[control].{key}")
        if "target_tensions" in control:
            check_tensions(robot, control["target_tensions"], "[control].target_tensions")
        if "target_displacements" in control:
            check_displacements(robot, _numbers(control["target_displacements"], "[control].target_displacements"),
                                tensions.shape[0], "[control].target_displacements")
        if control.get("command", "tension") not in COMMANDS:
            raise InputError(f"[control].command must be one of {COMMANDS}, got {control['command']!r}")
        if "model_every" in control:
            _integer(control["model_every"], "[control].model_every")
    B = tensions.shape[0]
    displacements = slip = None
    if "displacements" in act:
        displacements = check_displacements(robot, _numbers(act["displacements"], "[actuation].displacements"), B,
                                            "[actuation].displacements")
    if "slip" in act:
        slip = check_slip(robot, _numbers(act["slip"], "[actuation].slip"), B, "[actuation].slip")
    ik = _table(data, "ik", IK_KEYS) or None
    if ik is not None:
        ik = dict(ik)
        _required(ik, "targets", "[ik]")
        for key in ("targets", "target_rotations", "tension_max", "displacement_range", "tol"):
            if key in ik:
                ik[key] = _numbers(ik[key], f"[ik].{key}")
        if "max_iter" in ik:
            _integer(ik["max_iter"], "[ik].max_iter")
    hardware = _table(data, "hardware", HARDWARE_KEYS) or None
    if hardware is not None:
        if "servo_columns" not in hardware:
            raise InputError("missing key 'servo_columns' in [hardware]")
        cols = hardware["servo_columns"]
        if not (isinstance(cols, list) and len(cols) == robot.n_tendons and all(isinstance(c, str) for c in cols)):
            raise InputError(f"[hardware].servo_columns: expected {robot.n_tendons} column names (one per tendon), "
                             f"got {cols!r}")
        for key in ("marker_offset", "base_offset"):
            v = _numbers(hardware.get(key, [0.0, 0.0, 0.0]), f"[hardware].{key}")
            if not (isinstance(v, list) and len(v) == 3):
                raise InputError(f"[hardware].{key}: expected [x, y, z] in m, got {v!r}")
    display = display_options(data.get("display")) if "display" in data else None
    search = search_options(data["search"]) if "search" in data else None
    if search is not None:
        if control is None:
            raise InputError("[search] needs a [control] table (the controller whose gains it searches)")
        for gain in search["ranges"]:
            key = gain.split(".")[1].split("[")[0]
            if key not in control:
                raise InputError(f"[search.ranges].{gain!r}: give [control].{key} a value (the search varies it)")
    return Scene(robot=robot, tensions=tensions, options=options, dynamics=dynamics, source=data, control=control,
                 displacements=displacements, slip=slip, ik=ik, hardware=hardware, display=display, search=search)
