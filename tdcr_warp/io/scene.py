"""TOML scenes: one file describes a batch of robots, their actuation and the solver.

Every table and key (type, shape, SI unit, default, meaning) is listed once, in
:mod:`tdcr_warp.model.schema`; docs/reference/scene.md is written from it. The reader below is
one small function per table, and reads keys only through the schema (:class:`Fields`), so a
key the schema does not list is refused. A robot scalar may be a list of B numbers and a vector
a list of B vectors (per-rod values). Every error is an :class:`InputError` naming the table,
the key and the value.
"""

from __future__ import annotations

import io
import math
import re
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tdcr_warp.io.drawing import display_options
from tdcr_warp.io.inputs import SCENE_LIMIT, TABLE_LIMIT, read_limited
from tdcr_warp.model.backbone import Section
from tdcr_warp.model.checks import is_number
from tdcr_warp.model.options import StaticOptions, check_model_support
from tdcr_warp.model.robot import (
    InputError,
    Obstacle,
    PointForce,
    Robot,
    Tendon,
    TipConstraint,
    check_displacements,
    check_slip,
    check_tensions,
    require_memory,
)
from tdcr_warp.model.schema import (
    REQUIRED,
    SCHEMA,
    TOP_TABLES,
    Key,
    Table,
    location,
    out_of_bounds,
    span,
)
from tdcr_warp.model.tippath import path_from_table

__all__ = ["DynamicsSpec", "Fields", "Scene", "load_scene", "read_rows", "scene_from_dict", "search_options"]

# the gains a search ranges over: control.<gain_c|gain_k|gain_i> (every component, or [c] one), epsilon, phi
SEARCH_GAINS = re.compile(r"control\.(?:(?:gain_c|gain_k|gain_i)(?:\[[0-2]\])?|epsilon|phi)")
ROW_KEYS = ("tensions", "displacements", "slip")  # the [actuation] keys that may name a per-rod table file
TABLE_FILES = (".npy", ".csv", ".parquet")
MAX_DEPTH = 16  # tables and lists nested deeper than any scene needs (a handful) are refused
SCENE = Table("scene", "A scene: its tables.", tuple(Key(name, "tables" if SCHEMA[name].array else "table", "-",
                                                        SCHEMA[name].meaning) for name in TOP_TABLES))


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
    """Read and validate a TOML scene (a regular file of at most SCENE_LIMIT bytes); every problem
    is an :class:`InputError` naming the file."""
    path = Path(path)
    raw = read_limited(path, SCENE_LIMIT, f"cannot read scene {str(path)!r}")
    try:
        text = raw.decode("utf-8")
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
        _check_depth(data)  # before anything walks or prints the tables
        _resolve_files(data, path.absolute().parent)
        return replace(scene_from_dict(data), text=text)
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _resolve_files(data: dict, folder: Path) -> None:
    """Make the file names of the per-rod tables ([actuation].tensions, .displacements, .slip and
    [[actuation.steps]].tensions) absolute, relative to the scene's folder: the scene's ``source``
    then rebuilds it from anywhere (sweeps, search, fit)."""
    act = data.get("actuation")
    if not isinstance(act, dict):
        return
    steps = act.get("steps")
    steps = list(enumerate(steps)) if isinstance(steps, list) else []
    for table, keys, where in [(act, ROW_KEYS, "[actuation]")] + [
            (e, ("tensions",), location("actuation.steps", i)) for i, e in steps if isinstance(e, dict)]:
        for key in keys:
            if isinstance(table.get(key), str):
                try:
                    table[key] = str(folder / Path(table[key]).expanduser())
                except RuntimeError as e:  # "~user/..." of no such user
                    raise InputError(f"{where}.{key} = {table[key]!r}: {e}") from None


def _rows(table: Fields, key: str) -> tuple[object, str]:
    """(the value of the "rows" key ``key``, its name for errors): the numbers the scene gives,
    or the table read from the file it names (read_rows; the name then says which file)."""
    value, where = table.get(key), f"{table.where}.{key}"
    if not isinstance(value, str):
        return value, where
    return read_rows(value, key, where), f"{where} ({Path(value).name!r})"


def read_rows(path, key: str, where: str) -> np.ndarray:
    """A per-rod table from a file, one row per rod: ``.npy`` (an array of numbers, (B, K) or
    (K,)), ``.csv`` (comma-separated numbers, one line per rod, an optional header line) or
    ``.parquet``. A CSV or Parquet table with columns ``key[0]``, ``key[1]``, ... (as
    ``tdcr-warp static`` writes them into rods.parquet) gives those, in order; otherwise every
    column, in order. The file must be a regular file of at most TABLE_LIMIT bytes, and what
    its header promises (a .npy's shape, a Parquet file's rows) must fit that too, checked before
    anything is allocated. Every problem is an InputError naming ``where``, the file and what is
    wrong."""
    path = Path(path)
    what = f"{where} = {str(path)!r}"
    suffix = path.suffix.lower()
    if suffix not in TABLE_FILES:
        raise InputError(f"{what}: a per-rod table file must end in {', '.join(TABLE_FILES)}")
    data = read_limited(path, TABLE_LIMIT, f"{what}: cannot read the file")
    try:
        table = {".npy": _npy_rows, ".csv": _csv_rows, ".parquet": _parquet_rows}[suffix](data, key)
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{what}: {e}") from None
    if table.dtype.kind not in "iuf" or table.ndim not in (1, 2) or table.size == 0:
        raise InputError(f"{what}: expected a (B, K) table of numbers, got shape {table.shape} of {table.dtype}")
    return table


def _npy_rows(data: bytearray, key: str) -> np.ndarray:
    """A .npy file's array, its header read first: numbers only (no pickled objects), of 1 or 2
    dimensions, and exactly as many data bytes as its shape and type say (a header may claim any
    shape: numpy would allocate it before reading)."""
    fmt = np.lib.format
    f = io.BytesIO(data)
    version = fmt.read_magic(f)
    readers = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0}
    if version not in readers:
        raise ValueError(f"a .npy file of format {version[0]}.{version[1]} (this reader takes 1.0 and 2.0)")
    shape, fortran, dtype = readers[version](f, max_header_size=10_000)
    if dtype.kind not in "iuf" or dtype.fields is not None or len(shape) not in (1, 2):
        raise ValueError(f"expected a (B, K) table of numbers, got shape {shape} of {dtype}")
    need, have = math.prod(shape) * dtype.itemsize, len(data) - f.tell()
    if need != have:
        raise ValueError(f"the header says shape {shape} of {dtype} ({need:,} bytes), the file holds {have:,} "
                         "bytes after it")
    return np.frombuffer(data, dtype=dtype, count=math.prod(shape), offset=f.tell()).reshape(
        shape, order="F" if fortran else "C").copy()


def _columns(names: list[str], key: str) -> list[int]:
    """The columns of a CSV or Parquet table that hold ``key``: key[0], key[1], ... when present."""
    mine = [f"{key}[{k}]" for k in range(len(names)) if f"{key}[{k}]" in names]
    return [names.index(n) for n in mine] if mine else list(range(len(names)))


def _csv_rows(data: bytearray, key: str) -> np.ndarray:
    """A CSV table's numbers; its first line is a header unless every cell is a number (as
    tdcr_warp.model.checks.is_number reads them)."""
    text = data.decode("utf-8")
    first, _, rest = text.partition("\n")
    names = [c.strip() for c in first.split(",")]
    header = not all(is_number(c) for c in names)
    if header and not rest.strip():
        raise ValueError(f"no rows of numbers: only the line {first.strip()[:200]!r}, read as a header (numbers "
                         "are written in ASCII digits, without underscores)")
    cols = _columns(names, key) if header else None
    return np.loadtxt(io.StringIO(text), delimiter=",", skiprows=int(header), usecols=cols, ndmin=2,
                      dtype=np.float64)


def _parquet_rows(data: bytearray, key: str) -> np.ndarray:
    """The table's numeric columns (read from their buffers: Arrow's to_numpy imports pandas);
    their types and the rows the footer declares are checked before any column is read."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        f = pq.ParquetFile(pa.BufferReader(data))
    except pa.ArrowException as e:
        raise ValueError(f"not a readable Parquet file ({e})") from None
    names = f.schema_arrow.names
    chosen = [names[i] for i in _columns(names, key)]
    kinds = {}
    for name in chosen:
        t = f.schema_arrow.field(name).type
        kinds[name] = "f" if pa.types.is_floating(t) else "i" if pa.types.is_signed_integer(t) else \
            "u" if pa.types.is_unsigned_integer(t) else None
        if kinds[name] is None:
            raise ValueError(f"column {name!r} holds {t}, not numbers")
    rows = f.metadata.num_rows
    if rows * len(chosen) * 8 > TABLE_LIMIT:
        raise ValueError(f"the file declares {rows:,} rows of {len(chosen)} columns, more than the "
                         f"{TABLE_LIMIT // 2**20} MiB of numbers a per-rod table takes")
    table = f.read(columns=chosen, use_pandas_metadata=False)
    out = np.empty((table.num_rows, len(chosen)))
    for j, name in enumerate(chosen):
        col = table.column(name).combine_chunks()
        if col.null_count:
            raise ValueError(f"column {name!r} has {col.null_count} missing values")
        values = np.frombuffer(col.buffers()[1], dtype=f"{kinds[name]}{col.type.bit_width // 8}")
        out[:, j] = values[col.offset:col.offset + len(col)]
    return out


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


def _number(value, where: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise InputError(f"{where}: expected a number, got {value!r}")
    return float(value)


def _integer(value, where: str, bounds: tuple) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        raise InputError(f"{where}: expected an integer, got {_show(value)}")
    if out_of_bounds(value, bounds):
        raise InputError(f"{where} must be an integer {span(bounds)}, got {value!r}")
    return value


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 200 else text[:200] + " ..."


class Fields:
    """One table of a scene (``raw``), read through its schema (``table``, kept as ``schema``;
    errors call it ``where``, e.g. "[[tendons]] #2"). Unknown keys, and keys without their
    selector (turns without routing = "helix"), are InputErrors naming the table, the key and
    the value; reading a key the schema does not list is a LookupError (a bug of the reader,
    never of the scene)."""

    def __init__(self, raw: dict, table: Table, where: str):
        self.raw, self.schema, self.where = raw, table, where
        for name, value in raw.items():
            if name not in table.names:
                raise InputError(f"unknown key {name!r} in {where} (set to {_show(value)}; known: "
                                 f"{', '.join(sorted(table.names))})")
        for key in table.keys:
            if key.when is not None and key.name in raw and not self._applies(key):
                sel, values = key.when
                raise InputError(f"{where}.{key.name} is only for {sel} = " + " or ".join(f'"{v}"' for v in values)
                                 + f" (here {sel} = {self.get(sel)!r}; {key.name} = {_show(raw[key.name])})")

    def _applies(self, key: Key) -> bool:
        return key.when is None or self.get(key.when[0]) in key.when[1]

    def __contains__(self, name: str) -> bool:
        return self.schema.key(name).name in self.raw

    def get(self, name: str):
        """The value of key ``name`` checked by its schema type and allowed values (unless another
        reader checks it: ``checked_by``), or its schema default when absent (a required key:
        an InputError)."""
        key = self.schema.key(name)
        if name not in self.raw:
            if key.default is REQUIRED:
                raise InputError(f"missing key {name!r} in {self.where}")
            return key.default
        value = self.raw[name]
        return value if key.checked_by is not None else _checked(value, key, f"{self.where}.{name}")

    def given(self, *names: str) -> dict:
        """{key: checked value} of the keys present and the required ones (of ``names`` only,
        if given), in schema order."""
        for name in names:
            self.schema.key(name)
        return {k.name: self.get(k.name) for k in self.schema.keys if (not names or k.name in names)
                and (k.name in self.raw or (k.default is REQUIRED and self._applies(k)))}

    def table(self, name: str) -> Fields | None:
        """The sub-table ``name`` (e.g. [control].path) read through its schema; None when absent
        (a required one: an InputError)."""
        qual = self._child(name)
        raw = self.raw.get(name)
        if raw is None:
            if SCHEMA[qual].required:
                raise InputError(f"missing table [{qual}]")
            return None
        if not isinstance(raw, dict):
            raise InputError(f"{location(qual)} must be a table, got {_show(raw)}")
        return Fields(raw, SCHEMA[qual], location(qual))

    def tables(self, name: str) -> list[Fields]:
        """The array of tables ``name`` (e.g. [[tendons]]), each read through its schema."""
        qual = self._child(name)
        raw = self.raw.get(name, [])
        if not isinstance(raw, list):
            raise InputError(f"[[{qual}]] must be an array of tables (write [[{qual}]]), got {_show(raw)}")
        out = []
        for i, t in enumerate(raw):
            if not isinstance(t, dict):
                raise InputError(f"{location(qual, i)} must be a table, got {_show(t)}")
            out.append(Fields(t, SCHEMA[qual], location(qual, i)))
        return out

    def _child(self, name: str) -> str:
        self.schema.key(name)
        return name if self.schema is SCENE else f"{self.schema.name}.{name}"


def _checked(value, key: Key, name: str):
    """``value`` checked by ``key``'s type and allowed values (a "number": as a float)."""
    kind = key.type
    if kind == "rows":
        return value if isinstance(value, str) else _numbers(value, name)
    if kind == "numbers":
        return _numbers(value, name)
    if kind == "number":
        return _number(value, name)
    if kind == "integer":
        return _integer(value, name, key.bounds)
    ok = {"string": isinstance(value, str), "bool": isinstance(value, bool), "table": isinstance(value, dict),
          "tables": isinstance(value, list) and all(isinstance(v, dict) for v in value),
          "strings": isinstance(value, list) and all(isinstance(v, str) for v in value)}[kind]
    if not ok:
        what = {"string": "a string", "bool": "true or false", "table": "a table", "tables": "an array of tables",
                "strings": "a list of strings"}[kind]
        raise InputError(f"{name} must be {what}, got {_show(value)}")
    if key.allowed and value not in key.allowed:
        raise InputError(f"{name} must be one of {key.allowed}, got {value!r}")
    return value


def _build(kind, kw: dict, where: str):
    """kind(**kw), with the table's location in front of any InputError."""
    try:
        return kind(**kw)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def _tendon(t: Fields) -> Tendon:
    """One [[tendons]] entry as a Tendon (its numbers checked there)."""
    routing = t.get("routing")
    kw = {"routing": routing}
    if "offset" in t:
        kw["offset"] = t.get("offset")
    elif routing in ("straight", "linear"):
        raise InputError(f"missing key 'offset' in {t.where} ({routing} routing)")
    if routing == "points":
        kw["points"] = t.get("points")
    if routing == "linear":
        kw["offset_end"] = t.get("offset_end")
    kw |= t.given("compliance", "pretension", "friction", "control")
    if routing == "helix":
        kw |= {"helix_radius": t.get("radius"), "turns": t.get("turns"), "phase": t.get("phase")}
    kw |= t.given("length")
    return _build(Tendon, kw, t.where)


BACKBONE = ("youngs_modulus", "poisson_ratio", "radius", "density")  # [robot] keys that [[sections]] replace


def _sections(scene: Fields, robot: Fields) -> dict:
    """{"sections": [Section, ...]} from [[sections]] ({} without: then [robot] needs its four backbone
    keys); with them [robot] must leave those keys out."""
    tables = scene.tables("sections")
    given = [k for k in BACKBONE if k in robot]
    if not tables:
        missing = [k for k in BACKBONE if k not in robot]
        if missing:
            raise InputError(f"missing key {missing[0]!r} in [robot] (or describe the backbone by [[sections]])")
        return {}
    if given:
        raise InputError(f"[robot].{given[0]} = {_show(robot.raw[given[0]])} with [[sections]]: the sections give "
                         "the backbone (leave youngs_modulus, poisson_ratio, radius and density out of [robot])")
    return {"sections": [_build(Section, t.given(), t.where) for t in tables]}


def _robot(scene: Fields) -> Robot:
    """[robot], [[tendons]], [loads] (with [[loads.point_forces]]), the damping of [dynamics],
    [[obstacles]] and [tip]."""
    robot = scene.table("robot")
    kw = robot.given() | _sections(scene, robot)
    tendons = [_tendon(t) for t in scene.tables("tendons")]
    points = []
    loads = scene.table("loads")
    if loads is not None:
        kw |= loads.given("gravity", "tip_force", "tip_moment")
        points = [_build(PointForce, pf.given(), pf.where) for pf in loads.tables("point_forces")]
    dyn = scene.table("dynamics")
    if dyn is not None:
        kw |= dyn.given("damping_shear", "damping_bending", "drag")
    obstacles = [_build(Obstacle, o.given(), o.where) for o in scene.tables("obstacles")]
    tip = scene.table("tip")
    held = None if tip is None else _build(TipConstraint, tip.given(), tip.where)
    return Robot(tendons=tendons, point_forces=points, obstacles=obstacles, tip_constraint=held, **kw)


def _tensions(act: Fields, robot: Robot) -> np.ndarray:
    """[actuation].tensions as (B, K) [N]."""
    tensions = check_tensions(robot, *_rows(act, "tensions"))
    if robot.batch_size > 1 and tensions.shape[0] != robot.batch_size:
        raise InputError(f"[actuation].tensions: {tensions.shape[0]} rows for {robot.batch_size} rods")
    return tensions


def _options(scene: Fields) -> StaticOptions:
    """[solver]: a preset, overridden by the other keys (each checked by StaticOptions)."""
    solver = scene.table("solver")
    if solver is None:
        return StaticOptions()
    preset = solver.get("preset")
    kw = {k: v for k, v in solver.raw.items() if k != "preset"}
    return StaticOptions.preset(preset, **kw) if preset is not None else StaticOptions(**kw)


def _dynamics(dyn: Fields | None, act: Fields, robot: Robot, tensions: np.ndarray) -> DynamicsSpec | None:
    """[dynamics] and [[actuation.steps]] as a DynamicsSpec (None without a [dynamics] table, or
    an empty one)."""
    if dyn is None or not dyn.raw:
        if act.tables("steps"):
            raise InputError("[[actuation.steps]] needs a [dynamics] table")
        return None
    steps = dyn.get("steps")
    dt, alpha, shapes_every = dyn.get("dt"), dyn.get("alpha"), dyn.get("shapes_every")
    if shapes_every > steps:
        raise InputError(f"[dynamics].shapes_every = {shapes_every} is more than steps = {steps}: no shape would be "
                         "stored (0 stores the tips only)")
    require_memory(16.0 * steps * tensions.shape[0] * max(1, tensions.shape[1]),
                   f"[dynamics].steps = {steps} for {tensions.shape[0]} rod(s): the tension schedule")
    schedule = np.repeat(tensions[:, None, :], steps, axis=1)
    last = 0
    for entry in act.tables("steps"):
        start = entry.get("start")
        if not (1 <= start <= steps) or start <= last:
            raise InputError(f"{entry.where}.start must increase and lie in [1, {steps}], got {start}")
        last = start
        tau = check_tensions(robot, *_rows(entry, "tensions"))
        if tau.shape[0] not in (1, tensions.shape[0]):
            raise InputError(f"{entry.where}.tensions: {tau.shape[0]} rows for {tensions.shape[0]} rods")
        schedule[:, start - 1:, :] = tau[:, None, :]
    return DynamicsSpec(dt=dt, alpha=alpha, steps=steps, schedule=schedule, shapes_every=shapes_every)


def _commands(act: Fields, robot: Robot, B: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """[actuation].displacements (B, K) [m] and .slip (B, K), None where not given."""
    displacements = slip = None
    if "displacements" in act:
        value, name = _rows(act, "displacements")
        displacements = check_displacements(robot, value, B, name)
    if "slip" in act:
        value, name = _rows(act, "slip")
        slip = check_slip(robot, value, B, name)
    return displacements, slip


def _control(scene: Fields, robot: Robot, B: int, dynamics: DynamicsSpec | None) -> dict | None:
    """The [control] table, checked (None without one, or an empty one); the controller reads it."""
    ctl = scene.table("control")
    if ctl is None or not ctl.raw:
        return None
    if dynamics is None:
        raise InputError("[control] needs a [dynamics] table (dt, steps, ...)")
    if sum(k in ctl for k in ("target", "target_tensions", "target_displacements", "path")) != 1:
        raise InputError("[control] needs exactly one of 'target' (m), 'target_tensions' (N), "
                         "'target_displacements' (m) or 'path' (a desired tip trajectory)")
    if "path" in ctl:
        path_from_table(ctl.table("path").raw)  # checked here, built where it is used
    ctl.given()
    if "target_tensions" in ctl:
        check_tensions(robot, ctl.get("target_tensions"), "[control].target_tensions")
    if "target_displacements" in ctl:
        check_displacements(robot, ctl.get("target_displacements"), B, "[control].target_displacements")
    return ctl.raw


def _ik(scene: Fields) -> dict | None:
    """The [ik] table with its numbers checked (None without one, or an empty one)."""
    ik = scene.table("ik")
    return None if ik is None or not ik.raw else dict(ik.raw) | ik.given()


def _hardware(scene: Fields, robot: Robot) -> dict | None:
    """The [hardware] table, checked (None without one, or an empty one)."""
    hw = scene.table("hardware")
    if hw is None or not hw.raw:
        return None
    cols = hw.get("servo_columns")
    if len(cols) != robot.n_tendons:
        raise InputError(f"[hardware].servo_columns: expected {robot.n_tendons} column names (one per tendon), "
                         f"got {cols!r}")
    for key in ("marker_offset", "base_offset"):
        v = hw.get(key)
        if not (isinstance(v, list) and len(v) == 3):
            raise InputError(f"[hardware].{key}: expected [x, y, z] in m, got {v!r}")
    return hw.raw


def _ranges(raw, where_r: str) -> dict:
    """[search.ranges] as {gain: (lo, hi)}."""
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
    return ranges


def search_options(table: dict, where: str = "[search]") -> dict:
    """The checked options of a gain search: a scene's [search] table, or (``where`` = "") the
    same options given as arguments. ``ranges`` {gain: [lo, hi]} with 0 < lo < hi (the search is
    in log space; gains as SEARCH_GAINS, a vector gain without an index sets every component),
    ``budget`` closed loops (>= 1), ``population`` (>= 4: CMA-ES's weights need two parents;
    None: its default 4 + floor(3 ln d) for d gains), ``seed`` (0 <= seed < 2**32, default 0),
    ``sigma`` (the initial step as a fraction of each log range, in (0, 1], default 0.3).
    Returns them with ranges as {gain: (lo, hi)}; an InputError names the key and the value."""
    label = where or "the search options"
    if not isinstance(table, dict):
        raise InputError(f"{label} must be a table, got {table!r}")
    s = Fields(table, SCHEMA["search"], label)
    ranges = s.get("ranges") if "ranges" in s else None
    out = {"ranges": _ranges(ranges, f"[{where.strip('[]')}.ranges]" if where else "ranges")}
    if "budget" not in s:
        raise InputError(f"missing key 'budget' in {label} (closed loops to spend)")
    for key, least, most in (("budget", 1, None), ("population", 4, None), ("seed", 0, 2**32 - 1)):
        v = s.get(key)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < least
                              or (most is not None and v > most)):
            span = f">= {least}" if most is None else f"in [{least}, {most}]"
            raise InputError(f"{f'{where}.{key}' if where else key} must be an integer {span}, got {v!r}")
        out[key] = v
    sigma = s.get("sigma")
    if not (isinstance(sigma, (int, float)) and not isinstance(sigma, bool) and 0 < sigma <= 1):
        raise InputError(f"{f'{where}.sigma' if where else 'sigma'} must be a number in (0, 1] (a fraction of each "
                         f"log range), got {sigma!r}")
    out["sigma"] = float(sigma)
    return out


def _search(scene: Fields, control: dict | None) -> dict | None:
    """[search], checked against [control] (None without one)."""
    if "search" not in scene:
        return None
    search = search_options(scene.raw["search"])
    if control is None:
        raise InputError("[search] needs a [control] table (the controller whose gains it searches)")
    for gain in search["ranges"]:
        key = gain.split(".")[1].split("[")[0]
        if key not in control:
            raise InputError(f"[search.ranges].{gain!r}: give [control].{key} a value (the search varies it)")
    return search


def scene_from_dict(data: dict) -> Scene:
    """Validate a parsed scene (the dict tomllib returns) and build its :class:`Scene`."""
    if not isinstance(data, dict):
        raise InputError(f"a scene must be a table, got {type(data).__name__}")
    _check_depth(data)
    scene = Fields(data, SCENE, "the scene")
    robot = _robot(scene)
    act = scene.table("actuation")
    tensions = _tensions(act, robot)
    options = _options(scene)
    check_model_support(robot, options.model)
    dynamics = _dynamics(scene.table("dynamics"), act, robot, tensions)
    B = tensions.shape[0]
    control = _control(scene, robot, B, dynamics)
    displacements, slip = _commands(act, robot, B)
    ik = _ik(scene)
    hardware = _hardware(scene, robot)
    display = scene.table("display")
    display = display_options(display.raw) if display is not None else None
    search = _search(scene, control)
    scene.table("sweep"), scene.tables("uncertainty")  # their keys (tdcr_warp.apps.sweep reads them)
    return Scene(robot=robot, tensions=tensions, options=options, dynamics=dynamics, source=data, control=control,
                 displacements=displacements, slip=slip, ik=ik, hardware=hardware, display=display, search=search)
