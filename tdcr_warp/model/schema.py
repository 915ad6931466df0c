"""The scene schema: every table of a TOML scene and every key it may hold (plain data).

One :class:`Table` per table (``[robot]``, ``[[tendons]]``, ``[control.path]``, ...), one
:class:`Key` per key: its type, shape, unit, default, allowed values and a one-line meaning.
The scene reader (:mod:`tdcr_warp.io.scene`) reads keys only through it, so a key it does not
list is refused, and the scene reference is written from it::

    python -m tdcr_warp.model.schema --markdown > docs/reference/scene.md

Types: "number" (int or float), "numbers" (a number or a nested list of numbers: per-rod
values), "rows" (numbers, or the name of a .npy, .csv or .parquet file holding them: per-rod
tables too large for TOML), "integer", "string", "bool", "strings" (a list of strings), "table", "tables"
(an array of tables). Shapes: B rods, K tendons; "(3,) or (B, 3)" is shared or per rod.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

__all__ = ["MAX_ROWS", "REQUIRED", "SCHEMA", "TOP_TABLES", "Key", "Table", "location", "markdown", "out_of_bounds",
           "span"]

TYPES = ("number", "numbers", "rows", "integer", "string", "bool", "strings", "table", "tables")


class _Required:
    def __repr__(self) -> str:
        return "required"


REQUIRED = _Required()  # the default of a key the scene must give


@dataclass(frozen=True)
class Key:
    """One key of a table. default: the value when absent (None: not set, REQUIRED: must be
    given); default_text: the default in words where a reader computes it; allowed: the only
    values; when (key, values): the key is only for a table whose ``key`` is one of ``values``
    (and, if REQUIRED, needed there); bounds (least, most): an integer key's range (most None:
    no upper bound; every integer key has one); checked_by: what checks the value (None: the
    scene reader, by ``type``, ``allowed`` and ``bounds``; else that checker, to the same
    bounds)."""

    name: str
    type: str
    unit: str
    meaning: str
    shape: str = ""
    default: object = None
    default_text: str = ""
    allowed: tuple = ()
    when: tuple | None = None
    checked_by: str | None = None
    bounds: tuple | None = None

    def __post_init__(self):
        if self.type not in TYPES:
            raise ValueError(f"schema key {self.name!r}: type must be one of {TYPES}, got {self.type!r}")
        if (self.type == "integer") != (self.bounds is not None):
            raise ValueError(f"schema key {self.name!r}: an integer key has bounds (least, most), no other key")


def span(bounds: tuple) -> str:
    """An integer key's bounds in words: "in [1, 100]", ">= 0"."""
    least, most = bounds
    return f">= {least}" if most is None else f"in [{least}, {most}]"


def out_of_bounds(value: int, bounds: tuple) -> bool:
    least, most = bounds
    return value < least or (most is not None and value > most)


@dataclass(frozen=True)
class Table:
    """One table: ``name`` as in TOML ("robot", "loads.point_forces"); ``array``: written
    [[name]], any number of them; ``required``: the scene must have it; ``parser``: the function
    that reads it."""

    name: str
    meaning: str
    keys: tuple[Key, ...]
    array: bool = False
    required: bool = False
    parser: str = "tdcr_warp.io.scene"

    def key(self, name: str) -> Key:
        """The key ``name`` (a LookupError if the schema does not list it: a reader's bug)."""
        for k in self.keys:
            if k.name == name:
                return k
        raise LookupError(f"{name!r} is not a key of {self.heading} in tdcr_warp.model.schema")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)

    @property
    def heading(self) -> str:
        return f"[[{self.name}]]" if self.array else f"[{self.name}]"


def location(name: str, index: int | None = None) -> str:
    """How errors name a table: "[robot]", "[[tendons]] #2" (``index`` 1), "[control].path"."""
    if index is not None:
        return f"[[{name}]] #{index + 1}"
    parent, _, child = name.rpartition(".")
    return f"[{parent}].{child}" if parent else f"[{name}]"


MAX_ROWS = 10**9  # rows of one sweep (a bound on typing errors: 1e9 rods are days of work)
PER_ROD = "() or (B,)"
VECTOR = "(3,) or (B, 3)"
ROWS = "(K,) or (B, K)"
ROUTINGS = ("straight", "helix", "linear", "points")
WITHOUT_SECTIONS = "required without [[sections]] (with them: not given)"
PAIR = "() or (2,)"
HELIX = ("routing", ("helix",))
PATHS = ("circle", "line", "waypoints")
DISPLACEMENT_RANGE = Key("displacement_range", "numbers", "m", "the motors' range [lo, hi] (tendons under "
                         "displacement control)", "[lo, hi], each a number, (K,) or (B, K)", default_text="+- L / 20")

_TABLES = (
    Table("robot", "The rods: a batch of B, clamped at the origin and leaving along +z.", required=True, keys=(
        Key("length", "numbers", "m", "rod length L", PER_ROD, REQUIRED),
        Key("youngs_modulus", "numbers", "Pa", "Young's modulus E", PER_ROD, default_text=WITHOUT_SECTIONS),
        Key("poisson_ratio", "numbers", "-", "Poisson's ratio, in (-1, 0.5)", PER_ROD, default_text=WITHOUT_SECTIONS),
        Key("radius", "numbers", "m", "backbone radius", PER_ROD, default_text=WITHOUT_SECTIONS),
        Key("density", "numbers", "kg/m^3", "backbone density", PER_ROD, default_text=WITHOUT_SECTIONS),
        Key("precurvature", "numbers", "1/m", "precurvature u* (body frame)", VECTOR, default_text="[0, 0, 0]"),
        Key("disk_radius", "numbers", "m", "spacer disks' radius: every tendon route must stay inside it",
            PER_ROD, default_text="unchecked"),
        Key("disks", "numbers", "m", "spacer disks for [solver] model = \"disks\": their arc lengths, or an "
            "integer D for D evenly spaced disks per section (sections end where tendons end)", "(D,) or an integer",
            default_text="none"),
        Key("disk_mass", "number", "kg", "each spacer disk's mass (its weight acts at the disk, model \"disks\")",
            "", 0.0),
    )),
    Table("sections", "A backbone that varies along s: one table per section, base to tip, each from the previous "
          "one's end; a value is a number or [at its start, at its end], linear in s between (a taper), and may jump "
          "between sections. Shared by the batch; statics, \"coupled\" and \"point\" models, without friction, "
          "displacement control, obstacles or [tip] (docs/physics.md).", array=True, parser="tdcr_warp.io.scene",
          keys=(
        Key("end", "number", "m", "arc length where the section ends (increasing; the last: the rod length)", "",
            REQUIRED),
        Key("radius", "numbers", "m", "outer radius", PAIR, REQUIRED),
        Key("inner_radius", "numbers", "m", "inner radius of a tube (0: solid), below radius", PAIR, 0.0),
        Key("youngs_modulus", "numbers", "Pa", "Young's modulus E", PAIR, REQUIRED),
        Key("poisson_ratio", "numbers", "-", "Poisson's ratio, in (-1, 0.5): G = E / (2 (1 + nu)) at each end", PAIR,
            default_text="exactly one of poisson_ratio and shear_modulus"),
        Key("shear_modulus", "numbers", "Pa", "shear modulus G", PAIR,
            default_text="exactly one of poisson_ratio and shear_modulus"),
        Key("density", "numbers", "kg/m^3", "density", PAIR, REQUIRED),
    )),
    Table("tendons", "One table per tendon, in order (routing in the body/disk frame).", array=True, keys=(
        Key("offset", "numbers", "m", "[x, y] of the route at the base", "(2,) or (B, 2)",
            default_text="required for straight and linear routing, else [0, 0]"),
        Key("routing", "string", "-", "the route's shape: constant offset, helix, straight line to offset_end, "
            "spline through points", default="straight", allowed=ROUTINGS),
        Key("radius", "numbers", "m", "helix radius", PER_ROD, REQUIRED, when=HELIX),
        Key("turns", "numbers", "-", "helix turns over the tendon's length", PER_ROD, REQUIRED, when=HELIX),
        Key("phase", "numbers", "rad", "helix phase at the base", PER_ROD, 0.0, when=HELIX),
        Key("length", "numbers", "m", "termination arc length", PER_ROD, default_text="the rod length"),
        Key("offset_end", "numbers", "m", "[x, y] of the route at the termination", "(2,) or (B, 2)", REQUIRED,
            when=("routing", ("linear",))),
        Key("points", "numbers", "m", "[[s, x, y], ...] the route's points from s = 0 to the termination (a "
            "not-a-knot cubic spline)", "(M, 3), M >= 2", REQUIRED, when=("routing", ("points",))),
        Key("control", "string", "-", "what commands the tendon: its tension [N] or its motor displacement [m]",
            default="tension", allowed=("tension", "displacement"), checked_by="Tendon"),
        Key("compliance", "numbers", "1/N", "1 / (E_t A_t) of the wire (0: inextensible)", PER_ROD, 0.0),
        Key("pretension", "numbers", "N", "tension of the displacement reference state", PER_ROD, 0.0),
        Key("friction", "numbers", "-", "tendon-disk friction coefficient mu (capstan law)", PER_ROD, 0.0),
    )),
    Table("loads", "External loads (world frame).", keys=(
        Key("gravity", "numbers", "m/s^2", "gravitational acceleration", VECTOR, default_text="[0, 0, 0]"),
        Key("tip_force", "numbers", "N", "force at the tip", VECTOR, default_text="[0, 0, 0]"),
        Key("tip_moment", "numbers", "N m", "moment at the tip", VECTOR, default_text="[0, 0, 0]"),
        Key("point_forces", "tables", "-", "point forces along the rod: [[loads.point_forces]]"),
    )),
    Table("loads.point_forces", "A point force along the rod.", array=True, keys=(
        Key("s", "numbers", "m", "arc length where it acts, in (0, L]", PER_ROD, REQUIRED),
        Key("force", "numbers", "N", "the force (world frame)", VECTOR, REQUIRED),
    )),
    Table("obstacles", "One table per obstacle the backbone touches (world frame; statics).", array=True, keys=(
        Key("kind", "string", "-", "what it is: a half-space, a ball, a cylinder with round ends, a straight "
            "lumen, a lumen along a circular arc", REQUIRED, allowed=("plane", "sphere", "capsule", "tube", "bent_tube"),
            checked_by="Obstacle"),
        Key("point", "numbers", "m", "a point on the plane", VECTOR, REQUIRED, when=("kind", ("plane",))),
        Key("normal", "numbers", "-", "the plane's normal, toward the rod's side", VECTOR, REQUIRED,
            when=("kind", ("plane",))),
        Key("center", "numbers", "m", "the sphere's centre", VECTOR, REQUIRED, when=("kind", ("sphere",))),
        Key("start", "numbers", "m", "the axis' start (capsule, tube) or the bent tube's start", VECTOR, REQUIRED,
            when=("kind", ("capsule", "tube", "bent_tube"))),
        Key("end", "numbers", "m", "the axis' end", VECTOR, REQUIRED, when=("kind", ("capsule", "tube"))),
        Key("direction", "numbers", "-", "the bent tube's tangent at its start", VECTOR, REQUIRED,
            when=("kind", ("bent_tube",))),
        Key("toward", "numbers", "-", "from the bent tube's start toward the centre of its bend", VECTOR, REQUIRED,
            when=("kind", ("bent_tube",))),
        Key("radius", "numbers", "m", "radius (sphere, capsule) or inner radius (tube, bent tube)", PER_ROD, REQUIRED,
            when=("kind", ("sphere", "capsule", "tube", "bent_tube"))),
        Key("bend_radius", "numbers", "m", "radius of the bent tube's centre line", PER_ROD, REQUIRED,
            when=("kind", ("bent_tube",))),
        Key("angle", "numbers", "rad", "the bent tube's arc, in (0, 2 pi]", PER_ROD, REQUIRED,
            when=("kind", ("bent_tube",))),
        Key("stiffness", "numbers", "N/m^2", "a compliant obstacle's penalty stiffness per length of rod",
            PER_ROD, default_text="rigid"),
        Key("damping", "numbers", "s/m", "the contact's Hunt-Crossley damping in dynamics: the force grows by "
            "1 + damping x the rate of penetration", PER_ROD, default=0.0),
    )),
    Table("tip", "A constrained tip: held at a point, on a plane or along a line, free to rotate.",
          keys=(
        Key("kind", "string", "-", "what holds the tip", "", REQUIRED, allowed=("point", "plane", "line"),
            checked_by="TipConstraint"),
        Key("point", "numbers", "m", "the point (on the plane, on the line)", VECTOR, REQUIRED),
        Key("normal", "numbers", "-", "the plane's normal", VECTOR, REQUIRED, when=("kind", ("plane",))),
        Key("direction", "numbers", "-", "the line's direction", VECTOR, REQUIRED, when=("kind", ("line",))),
    )),
    Table("actuation", "The commands of the statics (and the start of dynamics).", required=True, keys=(
        Key("tensions", "rows", "N", "tendon tensions, one row per rod (B rows: B rods), each >= 0", ROWS,
            REQUIRED),
        Key("displacements", "rows", "m", "motor displacements (pull positive) of tendons under displacement "
            "control", ROWS),
        Key("slip", "rows", "-", "friction's slip direction per tendon: +1 pulled, -1 released", ROWS),
        Key("steps", "tables", "-", "a tension schedule for dynamics: [[actuation.steps]]"),
    )),
    Table("actuation.steps", "From step `start` on (until the next entry), these tensions.", array=True, keys=(
        Key("start", "integer", "-", "first step (1-based, increasing, <= [dynamics].steps)", "", REQUIRED,
            bounds=(1, None)),
        Key("tensions", "rows", "N", "tendon tensions from that step on", ROWS, REQUIRED),
    )),
    Table("solver", "The static solver (StaticOptions; a preset first, the other keys override it).", keys=(
        Key("preset", "string", "-", "named settings", default=None, allowed=("fast", "balanced", "accurate")),
        Key("nodes", "integer", "-", "integration intervals N along s (shapes have N + 1 nodes)",
            default=50, checked_by="StaticOptions", bounds=(1, 100_000)),
        Key("integrator", "string", "-", "the ODE integrator", default="rk4", allowed=("rk4", "midpoint", "euler"),
            checked_by="StaticOptions"),
        Key("model", "string", "-", "tendon loads: distributed, at the terminations only, at spacer disks, or "
            "closed form",
            default="coupled", allowed=("coupled", "point", "disks", "constant_curvature"), checked_by="StaticOptions"),
        Key("precision", "string", "-", "floating point of the kernels", default="float64",
            allowed=("float64", "float32"), checked_by="StaticOptions"),
        Key("tol", "number", "m", "Newton stops below this tip-like residual L |r|", default=None,
            default_text="1e-10 (float64), 1e-6 (float32)", checked_by="StaticOptions"),
        Key("max_iter", "integer", "-", "Newton iterations per rod", default=50,
            checked_by="StaticOptions", bounds=(1, 10_000)),
        Key("max_step", "number", "-", "bound on a Newton step in scaled unknowns", default=10.0,
            checked_by="StaticOptions"),
        Key("jacobian", "string", "-", "finite differences once then rank-one updates, or at every iterate",
            default="broyden", allowed=("broyden", "newton"), checked_by="StaticOptions"),
        Key("continuation", "integer", "-", "homotopy steps for hard rods (0: off)", default=8,
            checked_by="StaticOptions", bounds=(0, 10_000)),
        Key("rod", "string", "-", "with shear and extension, or inextensible and unshearable",
            default="cosserat", allowed=("cosserat", "kirchhoff"), checked_by="StaticOptions"),
        Key("specialize", "bool", "-", "compile out the physics the batch does not contain", default=True,
            checked_by="StaticOptions"),
        Key("error_estimate", "bool", "-", "also solve with N/2 nodes and report a tip error estimate [m]",
            default=False, checked_by="StaticOptions"),
        Key("threads", "integer", "-", "CPU threads", default=None, default_text="all cores",
            checked_by="StaticOptions", bounds=(1, 10**9)),
        Key("driver", "string", "-", "one launch per solve, or one per Newton iteration", default=None,
            default_text="the device's", allowed=("fused", "probes"), checked_by="StaticOptions"),
        Key("kink_loads", "bool", "-", "point loads where a tendon kinks (exact global balance)", default=True,
            checked_by="StaticOptions"),
        Key("tendon_states", "bool", "-", "integrate and report every tendon's path and unstretched length",
            default=False, checked_by="StaticOptions"),
        Key("sensitivities", "bool", "-", "also return the tip Jacobian and compliance per rod", default=False,
            checked_by="StaticOptions"),
        Key("stability", "string", "-", "the Jacobi stability test: flag unstable rods (check), also search a "
            "stable branch (stable), or none (off)", default="check", allowed=("off", "check", "stable"),
            checked_by="StaticOptions"),
        Key("contact_tolerance", "number", "-", "the penetration of a rigid obstacle allowed, a fraction of the "
            "rod's radius", default=0.01, checked_by="StaticOptions"),
        Key("contact_steps", "integer", "-", "the most rounds of stiffening rigid obstacles", default=8,
            checked_by="StaticOptions", bounds=(0, 100)),
        Key("segments", "integer", "-", "multiple shooting: every rod in this many segments (at most nodes), 1: "
            "never", default=None, default_text="only the rods single shooting cannot resolve, in as many as they "
            "need", checked_by="StaticOptions", bounds=(1, 10**9)),
        Key("energy_tolerance", "number", "-", "dynamics: flag a step of unforced motion that gains mechanical energy "
            "beyond this fraction of the rod's kinetic plus elastic energy (0: off)", default=0.01,
            checked_by="StaticOptions"),
    )),
    Table("dynamics", "Time stepping (`tdcr-warp simulate`, `control`); an empty table is none.", keys=(
        Key("dt", "number", "s", "time step", "", REQUIRED),
        Key("alpha", "number", "-", "BDF-alpha parameter of the implicit time discretisation", "", 0.0),
        Key("steps", "integer", "-", "time steps", "", REQUIRED, bounds=(1, None)),
        Key("damping_shear", "numbers", "N s", "Bse diagonal", VECTOR, default_text="[0, 0, 0]"),
        Key("damping_bending", "numbers", "N m^2 s", "Bbt diagonal", VECTOR, default_text="[0, 0, 0]"),
        Key("drag", "numbers", "kg/m^2", "air drag C diagonal", VECTOR, default_text="[0, 0, 0]"),
        Key("shapes_every", "integer", "-", "store full shapes every k steps (0: the tips only), at most steps",
            "", 0, bounds=(0, None)),
    )),
    Table("control", "The tip controller (`tdcr-warp control`; needs [dynamics]); exactly one of target, "
          "target_tensions, target_displacements or path.", keys=(
        Key("target", "numbers", "m", "the tip's target", VECTOR),
        Key("target_tensions", "numbers", "N", "the target: the static tip under these tensions", ROWS),
        Key("target_displacements", "numbers", "m", "the target: the static tip under these displacements", ROWS),
        Key("path", "table", "-", "a desired tip trajectory: [control.path]"),
        Key("method", "string", "-", "sliding mode law: sgn(S), a boundary layer, or with an error integral",
            default="boundary_layer", allowed=("smc", "boundary_layer", "integral"), checked_by="TipController"),
        Key("input_model", "string", "-", "the input matrix: the statics' Jacobian, or the report's alpha model",
            default="jacobian", allowed=("jacobian", "alpha"), checked_by="TipController"),
        Key("gain_c", "numbers", "1/s", "C diagonal", "() or (3,) or (B, 3)", 20.0),
        Key("gain_k", "numbers", "1/s", "k diagonal", "() or (3,) or (B, 3)", 20.0),
        Key("epsilon", "numbers", "m/s^2", "reaching gain", PER_ROD, 0.005),
        Key("phi", "numbers", "m/s", "boundary layer width", PER_ROD, 1e-3),
        Key("tension_max", "numbers", "N", "tension bound", "() or " + ROWS, 8.0),
        Key("model_every", "integer", "-", "steps between re-linearisations of the statics", "", 5,
            bounds=(1, None)),
        Key("gain_i", "numbers", "1/s^2", "integral gain (method integral)", "() or (3,) or (B, 3)",
            default_text="gain_c^2 / 4"),
        Key("command", "string", "-", "what the controller commands", default="tension",
            allowed=("tension", "displacement")),
        DISPLACEMENT_RANGE,
    )),
    Table("control.path", "A desired tip trajectory (world frame); its keys depend on its shape.",
          parser="tdcr_warp.model.tippath.path_from_table", keys=(
        Key("shape", "string", "-", "the trajectory's shape", default=REQUIRED, allowed=PATHS),
        Key("centre", "numbers", "m", "circle centre", VECTOR, REQUIRED, when=("shape", ("circle",))),
        Key("radius", "numbers", "m", "circle radius", PER_ROD, REQUIRED, when=("shape", ("circle",))),
        Key("frequency", "numbers", "Hz", "revolutions per second (negative: clockwise)", PER_ROD, REQUIRED,
            when=("shape", ("circle",))),
        Key("axis", "string", "-", "the circle's normal", default="z", allowed=("x", "y", "z"),
            when=("shape", ("circle",)), checked_by="TipPath"),
        Key("phase", "numbers", "rad", "angle at t = 0", PER_ROD, 0.0, when=("shape", ("circle",))),
        Key("start", "numbers", "m", "line start", VECTOR, REQUIRED, when=("shape", ("line",))),
        Key("end", "numbers", "m", "line end (held once reached)", VECTOR, REQUIRED, when=("shape", ("line",))),
        Key("speed", "numbers", "m/s", "speed along the line", PER_ROD, REQUIRED, when=("shape", ("line",))),
        Key("times", "numbers", "s", "waypoint times, increasing", "(M,)", REQUIRED,
            when=("shape", ("waypoints",))),
        Key("points", "numbers", "m", "waypoints (a cubic spline through them)", "(M, 3)", REQUIRED,
            when=("shape", ("waypoints",))),
    )),
    Table("ik", "Inverse kinematics (`tdcr-warp ik`): commands that put each tip at its target.", keys=(
        Key("targets", "numbers", "m", "tip targets", VECTOR, REQUIRED),
        Key("target_rotations", "numbers", "-", "tip frame targets (rotation matrices)", "(3, 3) or (B, 3, 3)"),
        Key("tension_max", "numbers", "N", "tension bound", "() or " + ROWS, default_text="inf"),
        DISPLACEMENT_RANGE,
        Key("tol", "numbers", "m", "position error to reach (and L times the orientation error)", "", 1e-9),
        Key("max_iter", "integer", "-", "iterations", "", 40, bounds=(1, 10_000)),
    )),
    Table("hardware", "A robot on the bench (`tdcr-warp fit`, `predict`): measurement columns and frames.", keys=(
        Key("servo_columns", "strings", "-", "the measurement CSV's column of each tendon, in tendon order",
            "(K,)", REQUIRED),
        Key("marker_offset", "numbers", "m", "the marker's offset from the tip, in marker_frame", "(3,)",
            [0.0, 0.0, 0.0]),
        Key("marker_frame", "string", "-", "the frame of marker_offset: fixed in the world (\"world\") or carried "
            "by the tip (\"tip\": the tip's body frame, the marker turning with it)", default="world",
            allowed=("world", "tip")),
        Key("base_offset", "numbers", "m", "the mocap frame's offset from the base (world frame)", "(3,)",
            [0.0, 0.0, 0.0]),
    )),
    Table("display", "How shapes are drawn (`tdcr-warp draw`, `view`).", parser="tdcr_warp.io.drawing.display_options",
          keys=(
        Key("disks", "integer", "-", "spacer disks drawn", "", 20, checked_by="display_options", bounds=(0, 1000)),
        Key("disk_radius", "number", "m", "drawn disk radius", "", default_text="from the tendon routes",
            checked_by="display_options"),
    )),
    Table("search", "A gain search (`tdcr-warp search`: CMA-ES over [control] gains; needs [control]).", keys=(
        Key("ranges", "table", "-", "gain = [lo, hi], 0 < lo < hi (log space); gains control.gain_c, gain_k, "
            "gain_i (whole, or one component [0-2]), control.epsilon, control.phi", "", REQUIRED,
            checked_by="search_options"),
        Key("budget", "integer", "-", "closed loops to spend", "", REQUIRED, checked_by="search_options",
            bounds=(1, None)),
        Key("population", "integer", "-", "CMA-ES population", "", default_text="4 + floor(3 ln d)",
            checked_by="search_options", bounds=(4, None)),
        Key("seed", "integer", "-", "random seed", "", 0, checked_by="search_options", bounds=(0, 2**32 - 1)),
        Key("sigma", "number", "-", "initial step as a fraction of each log range, in (0, 1]", "", 0.3,
            checked_by="search_options"),
    )),
    Table("sweep", "A sweep over scene fields (`tdcr-warp sweep`, `workspace`, `montecarlo`).",
          parser="tdcr_warp.apps.sweep.SweepSpec", keys=(
        Key("chunk", "integer", "-", "rods per chunk (memory bound)", "", 1024, checked_by="SweepSpec",
            bounds=(1, MAX_ROWS)),
        Key("seed", "integer", "-", "seed of the random draws", "", 0, checked_by="SweepSpec", bounds=(0, None)),
        Key("samples", "integer", "-", "random samples (without a grid)", "", checked_by="SweepSpec",
            bounds=(1, MAX_ROWS)),
        Key("grid", "table", "-", "field = [start, stop, count]: a cartesian product, first field slowest", "",
            checked_by="SweepSpec"),
        Key("max_total_tension", "number", "N", "drop rows whose tensions sum above it", "",
            checked_by="SweepSpec"),
    )),
    Table("uncertainty", "A random per-rod perturbation of one scene field (sweeps, `montecarlo`, `spread`).",
          array=True, parser="tdcr_warp.apps.sweep.SweepSpec", keys=(
        Key("field", "string", "-", "the field, e.g. robot.youngs_modulus or tendons[0].offset[0]", "", REQUIRED,
            checked_by="SweepSpec"),
        Key("distribution", "string", "-", "the distribution", "", REQUIRED,
            allowed=("normal", "uniform", "lognormal"), checked_by="SweepSpec"),
        Key("params", "numbers", "-", "finite: normal [mean, std >= 0], uniform [low, high] with low <= high, lognormal "
            "[mu, sigma >= 0] of the log",
            "(2,)", REQUIRED, checked_by="SweepSpec"),
    )),
)

SCHEMA: dict[str, Table] = {t.name: t for t in _TABLES}
TOP_TABLES = tuple(name for name in SCHEMA if "." not in name)


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def _default(key: Key) -> str:
    if key.default is REQUIRED:
        return "required"
    if key.default_text:
        return key.default_text
    return "not set" if key.default is None else f"`{_toml(key.default)}`"


def _meaning(key: Key) -> str:
    text = key.meaning
    if key.allowed:
        text += "; one of " + ", ".join(f"`{_toml(a)}`" for a in key.allowed)
    if key.bounds:
        text += f"; an integer {span(key.bounds)}"
    if key.when:
        sel, values = key.when
        text += f"; only with {sel} = " + " or ".join(f'"{v}"' for v in values)
    return text


def markdown() -> str:
    """The scene reference (Markdown): one section per table, a row per key."""
    lines = ["# Scene reference", "",
             ("<!-- Generated by `python -m tdcr_warp.model.schema --markdown > docs/reference/scene.md` from "
              "tdcr_warp/model/schema.py; do not edit by hand. -->"), "",
             ("A scene is a TOML file (SI units). A robot number may be a list of B numbers and a vector a list of "
              "B vectors: per-rod values for a batch of B rods; K is the number of tendons. A key the schema does "
              "not list is an error naming the table, the key and its value."), "",
             ("Types: *number*; *numbers*: a number or a (nested) list of numbers, of the shape given; *rows*: "
              "numbers, or the name of a `.npy`, `.csv` or `.parquet` file that holds them (relative to the scene "
              "file's folder; [Outputs: per-rod tables as input](../outputs.md#per-rod-tables-as-input)); *integer*; "
              "*string*; *bool* (true or false); *strings*: a list of strings; *table*; *tables*: an array of "
              "tables. A key \"only with\" another key's value is an error elsewhere; \"required\" there means "
              "required where it applies."), ""]
    for t in _TABLES:
        lines += [f"## `{t.heading}`", "", t.meaning + (" Required." if t.required else ""), "",
                  "| key | type | shape | unit | default | meaning |", "|---|---|---|---|---|---|"]
        for k in t.keys:
            lines.append(f"| `{k.name}` | {k.type} | {_cell(k.shape or '-')} | {_cell(k.unit)} | "
                         f"{_cell(_default(k))} | {_cell(_meaning(k))} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:] != ["--markdown"]:
        sys.exit("usage: python -m tdcr_warp.model.schema --markdown > docs/reference/scene.md")
    sys.stdout.write(markdown())
