"""TOML scenes: the examples, per-rod values, and errors that name the table, key and value."""

import copy
import dataclasses
import hashlib
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.io.scene import Scene, load_scene, scene_from_dict

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

BASE = {
    "robot": {"length": 0.5, "youngs_modulus": 190e9, "poisson_ratio": 0.3, "radius": 0.001, "density": 7800},
    "tendons": [{"offset": [0.01, 0.0]}, {"offset": [0.0, 0.01]}],
    "loads": {"gravity": [0.0, 0.0, -9.81]},
    "actuation": {"tensions": [[2.0, 0.5]]},
    "solver": {"nodes": 20},
}


def _set(d: dict, path: str, value) -> None:
    """d[table][key] = value for path "table__key" ("tendons__1__length": the 2nd tendon's
    length); value None deletes the key."""
    *tables, key = path.split("__")
    for name in tables:
        d = d[int(name)] if name.isdigit() else d.setdefault(name, {})
    if value is None:
        del d[key]
    else:
        d[key] = value


def nested(depth: int, value=0.0):
    """value inside ``depth`` lists."""
    for _ in range(depth):
        value = [value]
    return value


def scene(**edits) -> dict:
    """BASE with edits such as ``robot__length=-1``."""
    d = copy.deepcopy(BASE)
    for path, value in edits.items():
        _set(d, path, value)
    return d


def test_seed_example_is_the_reports_robot():
    sc = load_scene(EXAMPLES / "seed_robot.toml")
    assert isinstance(sc, Scene)
    r = sc.robot
    assert r.batch_size == 1 and r.n_tendons == 4
    assert (r.length[0], r.youngs_modulus[0], r.poisson_ratio[0], r.radius[0], r.density[0]) == \
        (0.5, 190e9, 0.3, 0.001, 17189.0)
    offsets = [t.offset[0].tolist() for t in r.tendons]
    assert offsets == [[0.01, 0.0], [0.0, 0.01], [-0.01, 0.0], [0.0, -0.01]]
    assert r.gravity[0].tolist() == [0.0, 0.0, -9.81]
    assert sc.tensions.tolist() == [[3.0, 0.0, 0.0, 0.0]]
    assert (sc.options.nodes, sc.options.integrator, sc.options.model) == (50, "rk4", "coupled")
    assert sc.source["robot"]["length"] == 0.5


def test_two_section_example_maps_tendons_and_loads():
    sc = load_scene(EXAMPLES / "helix_two_sections.toml")
    r = sc.robot
    assert sc.tensions.shape == (3, 5) and r.batch_size == 3
    assert np.allclose(r.tendon_lengths()[0], [0.25, 0.25, 0.5, 0.5, 0.5])
    helix = r.tendons[4]
    assert helix.routing == "helix" and helix.helix_radius[0] == 0.01 and helix.turns[0] == 0.5
    assert len(r.point_forces) == 1 and r.point_forces[0].s[0] == 0.4
    sol = tw.solve_static(r, sc.tensions, options=sc.options, device="cpu")
    assert sol.converged.all(), sol.failure_reasons()
    assert len({tuple(np.round(t, 9)) for t in sol.tip_position}) == 3  # three different rods


def test_per_rod_lists_equal_each_rod_alone():
    """Scalars, vectors and tendon fields given per rod in one scene == each rod's own scene."""
    per_rod = dict(robot__length=[0.5, 0.4, 0.45], robot__radius=[0.001, 0.0012, 0.001],
                   robot__precurvature=[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, -0.3, 0.0]],
                   loads__gravity=[[0.0, 0.0, -9.81], [0.0, -9.81, 0.0], [0.0, 0.0, 0.0]],
                   loads__tip_force=[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.0, -0.05]],
                   tendons__0__offset=[[0.01, 0.0], [0.008, 0.002], [0.01, 0.0]],
                   tendons__1__length=[0.3, 0.4, 0.45],
                   actuation__tensions=[[2.0, 0.5], [0.0, 1.0], [1.0, 1.0]])
    batch_scene = scene_from_dict(scene(**per_rod))
    batch = tw.solve_static(batch_scene.robot, batch_scene.tensions, options=batch_scene.options, device="cpu")
    assert batch.converged.all()
    for b in range(3):
        one = {path: [v[b]] if path == "actuation__tensions" else v[b] for path, v in per_rod.items()}
        sc = scene_from_dict(scene(**one))
        assert sc.robot.batch_size == 1
        alone = tw.solve_static(sc.robot, sc.tensions, options=sc.options, device="cpu")
        err = np.abs(alone.positions[0] - batch.positions[b]).max()
        assert err < 1e-12, f"rod {b}: batch and alone differ by {err:.2e} m"


def test_shared_tension_row_is_tiled_over_per_rod_robot():
    sc = scene_from_dict(scene(robot__youngs_modulus=[190e9, 100e9]))
    assert sc.tensions.tolist() == [[2.0, 0.5], [2.0, 0.5]]


def test_helix_radius_key_and_optional_fields():
    sc = scene_from_dict(scene(tendons=[{"routing": "helix", "radius": 0.01, "turns": 0.5, "phase": 0.2,
                                         "length": 0.25, "offset": [0.001, 0.0]}],
                               actuation__tensions=[[1.0]]))
    t = sc.robot.tendons[0]
    assert (t.helix_radius[0], t.turns[0], t.phase[0], t.length[0]) == (0.01, 0.5, 0.2, 0.25)
    assert t.offset[0].tolist() == [0.001, 0.0]
    sc = scene_from_dict({k: v for k, v in scene().items() if k not in ("loads", "solver")})
    assert sc.options == tw.StaticOptions() and not sc.robot.gravity.any()


@pytest.mark.parametrize("edits,message", [
    (dict(robot__length=None), "missing key 'length' in [robot]"),
    (dict(robot__density=None), "missing key 'density' in [robot]"),
    (dict(actuation__tensions=None), "missing key 'tensions' in [actuation]"),
    (dict(robot__length=-1), "length must be positive, got -1.0"),
    (dict(robot__length=[0.5, -0.2]), "length must be positive, got -0.2 (rod 1)"),
    (dict(robot__poisson_ratio=0.7), "poisson_ratio must be in (-1, 0.5), got 0.7"),
    (dict(robot__radius="thin"), "[robot].radius: expected a number or a list of numbers, got 'thin'"),
    (dict(robot__radius=True), "[robot].radius: expected a number or a list of numbers, got True"),
    (dict(robot__youngs_modulus=[190e9, "x"]), "[robot].youngs_modulus: expected a number or a list of numbers"),
    (dict(robot__precurvature=[1.0, 2.0]), "precurvature: expected (3,) or (B, 3), got shape (2,)"),
    (dict(robot__lenght=0.5), "unknown key 'lenght' in [robot]"),
    (dict(loads__gravity="down"), "[loads].gravity: expected a number or a list of numbers, got 'down'"),
    (dict(loads__wind=[1.0, 0.0, 0.0]), "unknown key 'wind' in [loads]"),
    (dict(loads__point_forces=[{"s": 0.7, "force": [0.0, 0.0, 1.0]}]),
     "point_forces[0].s must be <= the rod length, got 0.7"),
    (dict(loads__point_forces=[{"s": -0.1, "force": [0.0, 0.0, 1.0]}]),
     "[[loads.point_forces]] #1: point force s must be positive, got -0.1"),
    (dict(loads__point_forces=[{"force": [0.0, 0.0, 1.0]}]), "missing key 's' in [[loads.point_forces]] #1"),
    (dict(loads__point_forces={"s": 0.2, "force": [0.0, 0.0, 1.0]}), "must be an array of tables"),
    (dict(tendons__1__offset="far"), "[[tendons]] #2.offset: expected a number or a list of numbers, got 'far'"),
    (dict(tendons__1__length=-0.1), "[[tendons]] #2: tendon length must be positive, got -0.1"),
    (dict(tendons__1__length=0.6), "tendons[1].length must be <= the rod length, got 0.6"),
    (dict(tendons__1__routing="zigzag"), "[[tendons]] #2.routing must be one of ('straight', 'helix', 'linear', 'points'), got 'zigzag'"),
    (dict(tendons__1__turns=1.0), "[[tendons]] #2.turns is only for routing = \"helix\""),
    (dict(tendons__1__friction=-0.2), "[[tendons]] #2: tendon friction must be >= 0 (a friction coefficient mu)"),
    (dict(tendons__1__compliance=-1e-5), "[[tendons]] #2: tendon compliance must be >= 0 (a compliance [1/N])"),
    (dict(tendons__1__control="length"), "[[tendons]] #2: tendon control must be one of ('tension', 'displacement')"),
    (dict(tendons__1__offset_end=[0.0, 0.0]), "[[tendons]] #2.offset_end is only for routing = \"linear\""),
    (dict(tendons__1__routing="linear"), "missing key 'offset_end' in [[tendons]] #2"),
    (dict(actuation__displacements=[[0.0, 0.001]]),
     "[actuation].displacements[0][1] = 0.001: tendon 1 is under tension control"),
    (dict(actuation__slip=[[1, 0]]), "[actuation].slip[0][1] must be +1 (pulled) or -1 (released), got 0.0"),
    (dict(tendons__0__offst=[0.0, 0.0]), "unknown key 'offst' in [[tendons]] #1"),
    (dict(actuation__tensions=[[2.0, -0.5]]), "[actuation].tensions[0][1] must be a finite number >= 0"),
    (dict(actuation__tensions=[[2.0, 0.5, 1.0]]), "expected shape (B, 2) for 2 tendons, got (1, 3)"),
    (dict(actuation__tensions=[[2.0, "1"]]), "[actuation].tensions: expected a number or a list of numbers"),
    (dict(robot__length=[0.5, 0.4], actuation__tensions=[[1.0, 0.0]] * 3), "3 rows for a robot batch of 2 rods"),
    (dict(robot__length=[0.5, 0.4], robot__radius=[0.001] * 3), "per-rod fields disagree on the batch size"),
    (dict(solver__nodes=0), "solver nodes must be an integer in [1, 100000], got 0"),
    (dict(solver__nodes=20.5), "solver nodes must be an integer in [1, 100000], got 20.5"),
    (dict(solver__integrator="rk5"), "solver integrator must be one of"),
    (dict(solver__precision="half"), "solver precision must be one of"),
    (dict(solver__preset=3), "[solver].preset must be a string, got 3"),
    (dict(solver__nodse=20), "unknown key 'nodse' in [solver]"),
    (dict(extra={"a": 1}), "unknown key 'extra' in the scene"),
    (dict(dynamics={"dt": 0.005, "steps": 3}, control={"target_tensions": [[1.0]]}),
     "[control].target_tensions: expected shape (B, 2) for 2 tendons, got (1, 1)"),
    (dict(robot__precurvature=nested(17)), "robot.precurvature[0]: nested more than 16 levels deep"),
])
def test_bad_scenes_name_field_and_value(edits, message):
    with pytest.raises(tw.InputError) as info:
        scene_from_dict(scene(**edits))
    assert message in str(info.value), str(info.value)


def test_missing_tables():
    for table in ("robot", "actuation"):
        d = scene()
        del d[table]
        with pytest.raises(tw.InputError, match=rf"missing table \[{table}\]"):
            scene_from_dict(d)


def test_file_errors(tmp_path):
    with pytest.raises(tw.InputError, match="cannot read scene .*nope.toml"):
        load_scene(tmp_path / "nope.toml")
    bad = tmp_path / "broken.toml"
    bad.write_text("[robot]\nlength = \n")
    with pytest.raises(tw.InputError) as info:
        load_scene(bad)
    try:
        tomllib.loads(bad.read_text())
    except tomllib.TOMLDecodeError as e:
        toml_message = str(e)
    assert str(bad) in str(info.value) and toml_message in str(info.value)


def test_every_scene_error_names_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[robot]\nlength = 1979-05-27\n")
    with pytest.raises(tw.InputError) as info:
        load_scene(bad)
    assert str(info.value).startswith(f"{bad}: [robot].length: expected a number or a list of numbers, got "
                                      "datetime.date(1979, 5, 27)"), str(info.value)


def test_nesting_beyond_the_recursion_limit_is_an_input_error():
    """A scene dict built in Python, nested deeper than any recursive check could follow."""
    with pytest.raises(tw.InputError, match=r"robot\.length\[0\]: nested more than 16 levels deep"):
        scene_from_dict(scene(robot__length=nested(5000)))


# -- the parser's results, pinned: every example and these scenes parse to the objects that the
# -- one-function parser of commit 2a7d5ca made (tests/scene_parse_reference.json holds their digests)

PARSED_REFERENCE = Path(__file__).with_name("scene_parse_reference.json")
EXTRA_SCENES = {
    "base": {},
    "per_rod": dict(robot__length=[0.5, 0.4], robot__disk_radius=0.02, loads__tip_force=[[0.0, 0.01, 0.0]] * 2,
                    loads__tip_moment=[0.0, 0.0, 0.001], tendons__0__pretension=[0.5, 1.0],
                    tendons__1__compliance=1e-5),
    "helix_points": dict(tendons=[{"routing": "helix", "radius": 0.005, "turns": 1.0},
                                  {"routing": "points", "points": [[0.0, 0.01, 0.0], [0.25, 0.0, 0.01],
                                                                   [0.5, -0.01, 0.0]]}]),
    "displacement": dict(tendons__1__control="displacement", actuation__displacements=[0.0, 0.002],
                         actuation__slip=[[1, -1]], tendons__1__friction=0.1),
    "preset": dict(solver={"preset": "fast", "tol": 1e-9, "threads": 1, "driver": "fused"}),
    "dynamics": dict(dynamics={"dt": 0.01, "steps": 4, "alpha": -0.2, "shapes_every": 2, "drag": [0.1, 0.1, 0.1],
                               "damping_shear": [0.0, 0.0, 1e-3], "damping_bending": [1e-6, 1e-6, 0.0]},
                     actuation__steps=[{"start": 2, "tensions": [1.0, 1.0]}, {"start": 4, "tensions": [[0.0, 3.0]]}],
                     control={"target": [0.05, 0.0, 0.45], "gain_c": [10.0, 10.0, 10.0], "gain_k": 5,
                              "epsilon": 0.01, "phi": 0.002, "tension_max": 6.0, "model_every": 3,
                              "method": "integral", "input_model": "alpha", "gain_i": [1.0, 1.0, 1.0]}),
    "ik": dict(ik={"targets": [[0.05, 0.0, 0.45]], "target_rotations": [[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]],
                   "tension_max": 5.0, "displacement_range": [-0.01, 0.01], "tol": 1e-8, "max_iter": 30}),
    "display_search": dict(display={"disks": 7, "disk_radius": 0.015},
                           dynamics={"dt": 0.005, "steps": 3},
                           control={"target_tensions": [[1.0, 1.0]], "gain_c": 20.0, "gain_k": [5, 5, 5]},
                           search={"ranges": {"control.gain_c": [1.0, 100.0], "control.gain_k[1]": [1, 50]},
                                   "budget": 8, "population": 4, "seed": 2, "sigma": 0.5},
                           hardware={"servo_columns": ["a", "b"], "marker_offset": [0.0, 0.0, 0.01]}),
    "path": dict(dynamics={"dt": 0.005, "steps": 3}, control={"path": {"shape": "line", "start": [0.0, 0.0, 0.45],
                                                                       "end": [0.01, 0.0, 0.45], "speed": 0.01}}),
}


def _canonical(x):
    """x as nested tuples of text: arrays by dtype, shape and bytes; dataclasses field by field
    (a Robot with its section too); dicts in order."""
    if isinstance(x, np.ndarray):
        return ("array", str(x.dtype), x.shape, x.tobytes().hex())
    if dataclasses.is_dataclass(x):
        out = [(f.name, _canonical(getattr(x, f.name))) for f in dataclasses.fields(x)]
        if isinstance(x, tw.Robot):
            out.append(("section", _canonical(x.section())))
        return (type(x).__name__, tuple(out))
    if isinstance(x, dict):
        return ("dict", tuple((repr(k), _canonical(v)) for k, v in x.items()))
    if isinstance(x, (list, tuple)):
        return (type(x).__name__, tuple(_canonical(v) for v in x))
    if isinstance(x, float):
        return ("float", x.hex())
    return (type(x).__name__, repr(x))


def parsed_digests(sc: Scene) -> dict[str, str]:
    """Per field of a Scene, the sha256 of its canonical form."""
    return {f.name: hashlib.sha256(repr(_canonical(getattr(sc, f.name))).encode()).hexdigest()
            for f in dataclasses.fields(sc)}


def parsed_scenes() -> dict[str, Scene]:
    """Every example and hardware example (loaded from its file) and the EXTRA_SCENES."""
    out = {str(p.relative_to(EXAMPLES)): load_scene(p) for p in sorted(EXAMPLES.glob("*.toml"))
           + sorted(EXAMPLES.glob("hardware/*.toml"))}
    out.update({name: scene_from_dict(scene(**edits)) for name, edits in EXTRA_SCENES.items()})
    return out


def test_every_scene_parses_as_the_reference_parser_did():
    want = json.loads(PARSED_REFERENCE.read_text())
    got = {name: parsed_digests(sc) for name, sc in parsed_scenes().items()}
    assert got.keys() == want.keys()
    for name in want:
        differ = [f for f in want[name] if got[name][f] != want[name][f]]
        assert not differ, f"{name}: {differ} differ from the reference parser's"
