"""The scene schema (tdcr_warp.model.schema) is the one list of tables and keys: the reference in
docs/reference/scene.md is its output, the reader reads no key outside it, an undocumented key
is an error naming it, and the readers and classes that take the values agree with its
defaults and allowed values."""

import ast
import copy
import inspect
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest
from tdcr_warp.kernels.variants import INTEGRATORS, MODELS, RODS

from tdcr_warp.apps import control as control_app
from tdcr_warp.apps.ik import solve_ik
from tdcr_warp.apps.jobs import CONTROLLER_KEYS
from tdcr_warp.apps.sweep import DISTRIBUTIONS, SweepSpec
from tdcr_warp.io import drawing, scene
from tdcr_warp.io.scene import SCENE, Fields, load_scene, scene_from_dict
from tdcr_warp.model import options, robot, schema, tippath
from tdcr_warp.model.robot import InputError, Tendon
from tdcr_warp.model.schema import REQUIRED, SCHEMA, TOP_TABLES

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml")) + sorted((ROOT / "examples" / "hardware").glob("*.toml"))
EVERY_KEY = {k.name for t in SCHEMA.values() for k in t.keys} | set(SCHEMA) | set(TOP_TABLES)


def test_the_committed_reference_is_the_generators_output():
    committed = (ROOT / "docs" / "reference" / "scene.md").read_text(encoding="utf-8")
    assert committed == schema.markdown(), \
        "docs/reference/scene.md is stale: python -m tdcr_warp.model.schema --markdown > docs/reference/scene.md"


def test_every_table_and_key_is_documented_once():
    text = schema.markdown()
    for t in SCHEMA.values():
        assert text.count(f"## `{t.heading}`") == 1
        assert len(set(t.names)) == len(t.names), f"{t.heading} lists a key twice"
        for k in t.keys:
            assert f"| `{k.name}` |" in text and k.meaning and k.unit, (t.name, k.name)


def test_schema_is_consistent():
    for t in SCHEMA.values():
        parent, _, child = t.name.rpartition(".")
        if parent:  # a sub-table is a key of its parent of the matching type
            assert SCHEMA[parent].key(child).type == ("tables" if t.array else "table"), t.name
        for k in t.keys:
            if k.when is not None:
                selector = t.key(k.when[0])
                assert set(k.when[1]) <= set(selector.allowed), (t.name, k.name)
            if k.allowed and k.default not in (None, REQUIRED):
                assert k.default in k.allowed, (t.name, k.name)


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_example_parses_and_uses_only_schema_keys(path):
    load_scene(path)
    data = tomllib.loads(path.read_text())
    for name, value in data.items():
        tables = value if isinstance(value, list) else [value]
        for t in tables:
            assert set(t) <= set(SCHEMA[name].names), (path.name, name, set(t) - set(SCHEMA[name].names))


def test_the_reader_cannot_read_a_key_outside_the_schema():
    robot_table = Fields({"length": 0.5}, SCHEMA["robot"], "[robot]")
    for read in (robot_table.get, robot_table.table, robot_table.tables, robot_table.given,
                 lambda name: name in robot_table):
        with pytest.raises(LookupError, match="'lenght' is not a key of \\[robot\\]"):
            read("lenght")


def _string_reads(tree: ast.AST):
    """String constants the reader uses as keys: subscripts, ``in`` tests and the arguments of
    get, given, table, tables and key calls."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            yield node.slice.value, node.lineno
        elif isinstance(node, ast.Compare) and isinstance(node.ops[0], ast.In) \
                and isinstance(node.left, ast.Constant):
            yield node.left.value, node.lineno
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and node.func.attr in ("get", "given", "table", "tables", "key"):
            for arg in node.args:
                if isinstance(arg, ast.Constant):
                    yield arg.value, node.lineno


def test_every_key_the_reader_names_is_in_the_schema():
    source = inspect.getsource(scene)
    names = [(v, line) for v, line in _string_reads(ast.parse(source)) if isinstance(v, str) and v.isidentifier()]
    assert len(names) > 30  # the scan sees the reader's keys
    unknown = [(v, line) for v, line in names if v not in EVERY_KEY]
    assert not unknown, f"tdcr_warp/io/scene.py reads keys the schema does not list: {unknown}"


def _full_scene() -> dict:
    """A scene with every table of the schema."""
    d = tomllib.loads((ROOT / "examples" / "gain_search.toml").read_text())
    d["loads"]["point_forces"] = [{"s": 0.2, "force": [0.0, 0.0, 0.01]}]
    d["actuation"]["steps"] = [{"start": 1, "tensions": d["actuation"]["tensions"]}]
    d["control"].pop("target", None), d["control"].pop("target_tensions", None)
    d["control"]["path"] = {"shape": "line", "start": [0.0, 0.0, 0.49], "end": [0.01, 0.0, 0.49], "speed": 0.01}
    d["ik"] = {"targets": [[0.0, 0.0, 0.49]]}
    d["hardware"] = {"servo_columns": [f"m{k}" for k in range(len(d["tendons"]))]}
    d["display"] = {"disks": 5}
    d["uncertainty"] = [{"field": "robot.youngs_modulus", "distribution": "normal", "params": [190e9, 1e9]}]
    d["obstacles"] = [{"kind": "plane", "point": [0.1, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "damping": 2.0}]
    d["tip"] = {"kind": "plane", "point": [0.0, 0.0, 0.4], "normal": [1.0, 0.0, 0.0]}
    return d


def _sections_scene() -> dict:
    """The full scene with [[sections]] in place of [robot]'s backbone keys, without what sections are not
    solved with (obstacles, a held tip)."""
    d = _full_scene()
    robot = d["robot"]
    d["sections"] = [{"end": robot["length"], "radius": [robot.pop("radius"), 1e-3], "inner_radius": 0.0,
                      "youngs_modulus": robot.pop("youngs_modulus"), "poisson_ratio": robot.pop("poisson_ratio"),
                      "density": robot.pop("density")}]
    del d["obstacles"], d["tip"]
    return d


def _tables_of(d: dict, name: str) -> list:
    node = d
    for part in name.split("."):
        node = node[part]
    return node if isinstance(node, list) else [node]


@pytest.mark.parametrize("table", list(SCHEMA))
def test_an_undocumented_key_is_an_error_naming_it(table):
    d = _sections_scene() if table == "sections" else _full_scene()
    scene_from_dict(copy.deepcopy(d))
    _tables_of(d, table)[-1]["undocumented_key"] = 1.25
    with pytest.raises(InputError) as info:
        scene_from_dict(d)
    message = str(info.value)
    assert "unknown key 'undocumented_key'" in message and "1.25" in message, message
    heading = schema.location(table, len(_tables_of(d, table)) - 1 if SCHEMA[table].array else None)
    assert heading in message, message


def test_an_unknown_table_is_an_error_naming_it():
    d = _full_scene()
    d["robots"] = {"length": 0.5}
    with pytest.raises(InputError, match=r"unknown key 'robots' in the scene \(set to \{'length': 0.5\}"):
        scene_from_dict(d)
    assert set(SCENE.names) == set(TOP_TABLES)


def _known(message: str) -> set[str]:
    return set(message.split("known: ")[1].rstrip(")").split(", "))


def test_the_other_readers_know_the_schemas_keys():
    """[display], [sweep], [[uncertainty]] and [control].path are read elsewhere: their own key
    checks name the same keys as the schema."""
    assert drawing.DISPLAY_KEYS == set(SCHEMA["display"].names)
    with pytest.raises(InputError) as info:
        SweepSpec({"sweep": {"undocumented": 1}})
    assert _known(str(info.value)) == set(SCHEMA["sweep"].names)
    with pytest.raises(InputError, match="expected keys field, distribution, params"):
        SweepSpec({"uncertainty": [{"undocumented": 1}]})
    assert set(SCHEMA["uncertainty"].names) == {"field", "distribution", "params"}
    path = SCHEMA["control.path"]
    for shape in path.key("shape").allowed:
        with pytest.raises(InputError) as info:
            tippath.path_from_table({"shape": shape, "undocumented": 1})
        assert _known(str(info.value)) == {k.name for k in path.keys if k.when and shape in k.when[1]}


def _defaults(fn) -> dict:
    return {n: p.default for n, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}


def test_defaults_and_allowed_values_agree_with_the_code():
    solver = SCHEMA["solver"]
    option_fields = {f.name: f.default for f in fields(options.StaticOptions)}
    assert set(solver.names) == set(option_fields) | {"preset"}
    for name, default in option_fields.items():
        assert solver.key(name).default == default, name
    allowed = {"integrator": INTEGRATORS, "model": MODELS + ("constant_curvature",), "rod": RODS,
               "precision": options.PRECISIONS, "driver": options.DRIVERS, "stability": options.STABILITY,
               "preset": tuple(options.PRESETS), "jacobian": ("broyden", "newton")}
    for name, values in allowed.items():
        assert set(solver.key(name).allowed) == set(values), name
    ctl, controller = SCHEMA["control"], _defaults(control_app.TipController.__init__)
    assert set(CONTROLLER_KEYS) <= set(ctl.names)
    for name in CONTROLLER_KEYS:
        if ctl.key(name).default is not None or not ctl.key(name).default_text:
            assert ctl.key(name).default == controller[name], name
    assert ctl.key("method").allowed == control_app.METHODS
    assert ctl.key("input_model").allowed == control_app.INPUT_MODELS
    assert ctl.key("command").allowed == options.COMMANDS
    ik = _defaults(solve_ik)
    assert (SCHEMA["ik"].key("tol").default, SCHEMA["ik"].key("max_iter").default) == (ik["tol"], ik["max_iter"])
    tendon = {f.name: f.default for f in fields(Tendon)}
    tendons = SCHEMA["tendons"]
    for name in ("routing", "phase", "control", "compliance", "pretension", "friction"):
        assert tendons.key(name).default == tendon[name], name
    assert tendons.key("routing").allowed == robot.ROUTINGS and tendons.key("control").allowed == robot.CONTROLS
    assert SCHEMA["control.path"].key("axis").allowed == tuple(tippath.AXES)
    assert SCHEMA["display"].key("disks").default == drawing.DEFAULT_DISKS
    assert SCHEMA["uncertainty"].key("distribution").allowed == DISTRIBUTIONS
    spec = SweepSpec({"sweep": {"samples": 1},
                      "uncertainty": [{"field": "robot.radius", "distribution": "normal", "params": [1.0, 0.0]}]})
    assert (spec.chunk, spec.seed) == (SCHEMA["sweep"].key("chunk").default, SCHEMA["sweep"].key("seed").default)
    search = scene.search_options({"ranges": {"control.phi": [1e-3, 1e-2]}, "budget": 1})
    assert (search["seed"], search["sigma"]) == (SCHEMA["search"].key("seed").default,
                                                 SCHEMA["search"].key("sigma").default)
