"""Measured robots (tdcr_warp/apps/hardware.py, `tdcr-warp fit` and `predict`): the keypoint reader's
errors, predictions and metrics, and a calibration that recovers known parameters from
synthetic measurements (tips of this simulator plus noise) from a wrong start."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

import tdcr_warp as tw
from tdcr_warp.apps.hardware import fit, metrics, predict, read_measurements
from tdcr_warp.cli import main
from tdcr_warp.io.scene import scene_from_dict

COLS = [f"servo_{k}_mm" for k in range(6)]
HEADER = "timestamp,pattern_label," + ",".join(COLS) + ",tip_x,tip_y,tip_z"


def scene_dict(compliance=2e-4, pretension=(0.5, 1.0), angle=(0.05, -0.08), base=(2e-3, -1e-3, 5e-3)):
    """Two segments (70 and 150 mm) of three tendons each at 4.5 mm, under displacement control."""
    tendons = []
    for s, end in enumerate((0.07, 0.15)):
        for i in range(3):
            a = angle[s] + i * 2 * math.pi / 3
            tendons.append({"offset": [0.0045 * math.cos(a), 0.0045 * math.sin(a)], "length": end,
                            "control": "displacement", "compliance": compliance, "pretension": pretension[s]})
    return {"robot": {"length": 0.15, "youngs_modulus": 50e9, "poisson_ratio": 0.3, "radius": 5e-4, "density": 0.0},
            "tendons": tendons, "actuation": {"tensions": [[0.0] * 6]}, "solver": {"nodes": 10},
            "hardware": {"servo_columns": COLS, "marker_offset": [0.0, 0.0, 0.008], "base_offset": list(base)}}


def synthetic_csv(path, rows=60, noise_mm=0.05, seed=0, truth=None):
    """Keypoints of the true scene (``truth``, a scene dict; scene_dict() by default): one or two
    tendons pulled up to 1.5 mm, the others let out up to 1 mm; the measured tips are the
    predicted ones plus Gaussian noise."""
    rng = np.random.default_rng(seed)
    q = -rng.uniform(0.0, 1.0, (rows, 6))
    for r in range(rows):
        for k in rng.choice(6, size=rng.integers(1, 3), replace=False):
            q[r, k] = rng.uniform(0.2, 1.5)
    truth = scene_from_dict(truth or scene_dict())
    meas = read_measurements_from(q, np.zeros((rows, 3)))
    pred = predict(truth, meas)
    assert pred["converged"].all()
    tips = pred["point_mm"] + rng.normal(0.0, noise_mm, (rows, 3))
    lines = [HEADER] + [f"{r * 0.6},synthetic_{r % 5}," + ",".join(f"{v:.9f}" for v in q[r]) + ","
                        + ",".join(f"{v:.9f}" for v in tips[r]) for r in range(rows)]
    path.write_text("\n".join(lines) + "\n")
    return q, tips


def read_measurements_from(q, tips):
    from tdcr_warp.apps.hardware import Measurements
    n = len(q)
    return Measurements(np.array(["x"] * n), q, tips, np.array(["mem"] * n))


@pytest.mark.parametrize("detail", ["segment", "tendon"])
def test_calibration_recovers_known_parameters_within_their_uncertainty(tmp_path, detail):
    csv = tmp_path / "synthetic.csv"
    synthetic_csv(csv)
    meas = read_measurements(csv, COLS)
    wrong = scene_dict(compliance=6e-4, pretension=(1.5, 0.3), angle=(0.0, 0.0), base=(0.0, 0.0, 0.0))
    res = fit(wrong, meas, detail=detail)
    par = res["report"]["parameters"]
    # the truth relative to the wrong start's tendon angles (the fit rotates the tendons it was given)
    truth = {"pretension[0]": 0.5, "pretension[1]": 1.0, "base_offset[0]": 2e-3, "base_offset[1]": -1e-3,
             "base_offset[2]": 5e-3}
    if detail == "segment":
        truth |= {"compliance": 2e-4, "angle[0]": 0.05, "angle[1]": -0.08}
    else:
        truth |= {"compliance[0]": 2e-4, "compliance[1]": 2e-4} | {f"angle[{k}]": 0.05 if k < 3 else -0.08
                                                                   for k in range(6)}
    for name, true in truth.items():
        got, std = par[name]["value"], par[name]["std"]
        assert abs(got - true) < 4 * std + 1e-12, (name, got, true, std)
        assert std < 0.2 * max(abs(true), 0.01), (name, std)  # and the uncertainty is informative
    assert res["report"]["training"]["rmse_mm"] < 0.1  # the noise is 0.05 mm per axis
    again = fit(wrong, meas, detail=detail)  # reproducible
    assert all(abs(again["report"]["parameters"][n]["value"] - v["value"]) <= 1e-6 * max(abs(v["value"]), 1e-12)
               for n, v in par.items())


@pytest.mark.parametrize("physics", [(), ("weight", "hole_radius", "marker")])
def test_fit_jacobian_matches_central_differences_of_full_solves(physics):
    """The fit's implicit-function Jacobian (tendon compliances and angles at the motors' given
    lengths, plus the path through the reference state; with the extra physics, the weight's
    components, the hole radii and a marker carried by the tip, whose arm turns with it) against central differences of whole predictions of the scene
    with each fitted parameter moved (every parameter kind, both segments; no tendon slack, where
    the tip's derivatives have a kink)."""
    from tdcr_warp.apps import hardware as hw
    rng = np.random.default_rng(3)
    q = np.concatenate([rng.uniform(0.02, 0.2, (6, 6)) * (rng.random((6, 6)) < 0.4), np.zeros((1, 6))])
    meas = read_measurements_from(q, np.zeros((7, 3)))
    data = scene_dict()
    if physics:  # a steel backbone mounted sideways, its weight tilted
        data["robot"]["density"] = 7800.0
        data["loads"] = {"gravity": [-9.0, 2.0, -3.0]}
    spec = hw._parameter_spec(data, "tendon", physics)
    assert len(spec) == 13 + 8 * bool(physics)  # + gravity[0..2], marker_offset[0..2], a hole radius per segment
    p = np.array([sp["value"] for sp in spec])
    lo, hi = (np.array([sp[k] for sp in spec]) for k in ("lo", "hi"))
    cur = predict(scene_from_dict(hw._apply(data, spec, p)), meas, parameters=hw._jacobian_names(data, spec),
                  tol=1e-12)
    assert cur["converged"].all() and not cur["slack"].any()
    J = hw._fit_jacobian(data, spec, p, cur, np.arange(7), lo, hi)
    for j, sp in enumerate(spec):
        h = {"compliance": 1e-3, "pretension": 1e-2, "angle": 1e-5, "offset": 1e-6, "gravity": 1e-2,
             "radius": 1e-6, "marker": 1e-6}[sp["kind"]]
        up, down = p.copy(), p.copy()
        up[j], down[j] = p[j] + h, max(p[j] - h, lo[j])
        a, b = (predict(scene_from_dict(hw._apply(data, spec, x)), meas, tol=1e-12)["error_mm"] for x in (up, down))
        fd = ((a - b) * 1e-3 / (up[j] - down[j])).ravel()
        # measured, relative to the column's largest entry: angles <= 3e-5, compliances <= 1.3e-4,
        # pretensions <= 2.5e-3 (a sum over a segment's three tendons that nearly cancels in x and y,
        # each term as good as tip_jacobian's displacement columns, 1e-5 - 2.6e-5 here)
        assert np.abs(fd).max() > 0 and np.abs(J[:, j] - fd).max() < 5e-3 * np.abs(fd).max(), sp["name"]


def test_a_fit_with_weight_finds_the_mounting_and_the_scale(tmp_path):
    """A steel backbone mounted sideways (its weight along (-0.8, 0.6, 0) g, 1.5 mm of sag at the
    tip) measured with 0.05 mm noise; fitted from no weight with --physics weight, the gravity comes
    back within 4 standard deviations, and so does the scale: the Young's modulus the weight
    implies is the true one (within 4 sigma of |g|)."""
    import tomli_w
    truth = scene_dict()
    truth["robot"]["density"] = 7800.0
    truth["loads"] = {"gravity": [-0.8 * 9.81, 0.6 * 9.81, 0.0]}
    data = tmp_path / "synthetic.csv"
    synthetic_csv(data, truth=truth)
    start = scene_dict(compliance=4e-4, angle=(0.0, 0.0), base=(0.0, 0.0, 0.0))
    start["robot"]["density"] = 7800.0
    scene = tmp_path / "start.toml"
    scene.write_text(tomli_w.dumps(start))
    out = tmp_path / "fit"
    assert main(["fit", str(scene), str(data), "--out", str(out), "--physics", "weight", "--quiet"]) == 0
    rep = json.loads((out / "fit.json").read_text())
    g = np.array([rep["parameters"][f"gravity[{i}]"]["value"] for i in range(3)])
    sd = np.array([rep["parameters"][f"gravity[{i}]"]["std"] for i in range(3)])
    assert (np.abs(g - truth["loads"]["gravity"]) < 4 * sd + 1e-9).all(), (g, sd)
    # the sideways components are well determined (measured sd 0.41, 0.45 m/s^2); the axial one
    # hardly bends the rod (measured 2.4 m/s^2): the fit says so rather than guessing
    assert (sd[:2] < 0.5).all() and sd[2] > sd[:2].max()
    w = rep["weight"]
    sd_g = np.linalg.norm(g / np.linalg.norm(g) * sd)  # of |g|, correlations left out
    assert abs(w["implied_youngs_modulus_Pa"] / 50e9 - 1) < 4 * sd_g / np.linalg.norm(g)
    assert rep["training"]["rmse_mm"] < 0.1


def test_weight_fitted_needs_a_density_and_unknown_physics_is_refused():
    from tdcr_warp.apps import hardware as hw
    with pytest.raises(tw.InputError, match="density > 0"):
        hw._parameter_spec(scene_dict(), "tendon", ("weight",))
    with pytest.raises(tw.InputError, match="'friction'"):
        hw._parameter_spec(scene_dict(), "tendon", ("friction",))


def test_motion_families_and_the_family_out_splits():
    from tdcr_warp.apps.hardware import family_out_splits, motion_families
    labels = np.array(["rep1_seg1_dir60", "seg3_circle_hold", "rep2_pair12_same_dir0", "pair13_opp_dir60_hold",
                       "rep1_tendon4_id2_pull", "tendon0_id4_pull_hold", "warmup", "segment"])
    assert list(motion_families(labels)) == ["segment", "segment", "pair", "pair", "pull", "pull", "other", "other"]
    splits = family_out_splits(labels)
    assert list(splits["pairs out"]) == [False, False, True, True, False, False, False, False]
    assert list(splits["pulls out"]) == [False, False, False, False, True, True, False, False]
    assert family_out_splits(labels[:2]) == {}  # no family to hold out, or nothing left to fit on


def test_recorded_order_without_friction_is_the_batch_and_with_friction_a_loop():
    """predict_recorded: each row a quasi-static step from the last. Frictionless, the rows are
    predict's to Newton's tolerance; with capstan friction, pulling tendon 0 to 1 mm and letting it
    back passes the same displacements with other tips on the way back (hysteresis)."""
    from tdcr_warp.apps.hardware import predict_recorded
    up = np.linspace(0.0, 1.0, 6)
    q = np.zeros((11, 6))
    q[:, 0] = np.r_[up, up[-2::-1]]
    meas = read_measurements_from(q, np.zeros((11, 3)))
    smooth = scene_from_dict(scene_dict())
    a, b = predict(smooth, meas), predict_recorded(smooth, meas)
    assert a["converged"].all() and b["converged"].all()
    assert np.abs(a["point_mm"] - b["point_mm"]).max() < 1e-5
    d = scene_dict()
    for t in d["tendons"]:
        t["friction"] = 0.3
    c = predict_recorded(scene_from_dict(d), meas)
    assert c["converged"].all()
    loop = np.linalg.norm(c["point_mm"][1:4] - c["point_mm"][9:6:-1], axis=1)  # q = 0.2, 0.4, 0.6 mm up and down
    assert loop.min() > 1e-3 and np.abs(c["point_mm"][5] - a["point_mm"][5]).max() > 1e-3


def test_pattern_folds_keep_whole_patterns_in_consecutive_blocks():
    from tdcr_warp.apps.hardware import pattern_folds
    labels = np.array(["a"] * 4 + ["b"] * 3 + ["b_hold"] + ["c"] * 4 + ["d"] * 2 + ["d_hold"] * 2 + ["e"] * 4)
    fold = pattern_folds(labels, 3)
    assert sorted(set(fold)) == [0, 1, 2] and (np.diff(fold) >= 0).all()  # consecutive blocks
    for name in "abcde":  # a pattern and its hold rows in one fold
        assert len(set(fold[np.char.startswith(labels, name)])) == 1, name
    assert max(np.bincount(fold)) - min(np.bincount(fold)) <= 4  # about equal rows
    with pytest.raises(tw.InputError, match="2 <= k <= 5"):
        pattern_folds(labels, 6)


def test_predict_cli_writes_one_row_per_input_and_the_metrics(tmp_path):
    csv = tmp_path / "synthetic.csv"
    q, tips = synthetic_csv(csv, rows=12)
    scene = tmp_path / "truth.toml"
    import tomli_w
    scene.write_text(tomli_w.dumps(scene_dict()))
    out = tmp_path / "pred"
    assert main(["predict", str(scene), str(csv), "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["rows"] == 12 and m["converged"] == 12 and m["rmse_mm"] < 0.2 and m["rmse_aligned_mm"] <= m["rmse_mm"]
    for key in ("median_mm", "p95_mm", "rmse_percent_of_length", "ms_per_row"):
        assert key in m
    assert m["units"]["rmse_mm"] == "mm" and m["settings"]["scene_text"] == scene.read_text()
    doc = (Path(__file__).resolve().parents[1] / "docs" / "outputs.md").read_text()
    header = (out / "predictions.csv").read_text().splitlines()[0].split(",")
    assert [k for k in [*m, *m["units"], *(c for c in header if not c.startswith("slack_"))]
            if f"`{k}`" not in doc] == []  # documented (docs/outputs.md)
    lines = (out / "predictions.csv").read_text().splitlines()
    assert len(lines) == 13 and lines[0].startswith("row,source,pattern_label,pred_x_mm")
    assert (out / "predict.png").exists() and m["recorded_order"] is False
    assert main(["predict", str(scene), str(csv), "--out", str(tmp_path / "rec"), "--recorded-order"]) == 0
    r = json.loads((tmp_path / "rec" / "metrics.json").read_text())  # frictionless: the same tips
    assert r["recorded_order"] is True and abs(r["rmse_mm"] - m["rmse_mm"]) < 1e-5


def test_metrics_remove_the_mean_offset_for_the_aligned_rmse():
    err = np.array([[1.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    m = metrics(err, np.array([True, True]), 0.2)
    assert m["rmse_mm"] == pytest.approx(math.sqrt(5.0)) and m["rmse_aligned_mm"] == pytest.approx(1.0)
    assert m["rmse_percent_of_length"] == pytest.approx(100 * math.sqrt(5.0) / 200)


@pytest.mark.parametrize("body, words", [
    ("", "empty file"),
    ("timestamp,pattern_label,tip_x,tip_y,tip_z\n0,a,1,2,3\n", "missing column(s) ['servo_0_mm'"),
    (HEADER + "\n0,a," + ",".join(["0"] * 5) + ",nan,1,2,3\n", "row 2, column servo_5_mm: not finite"),
    (HEADER + "\n0,a,1e9," + ",".join(["0"] * 5) + ",1,2,3\n", "row 2, column servo_0_mm: 1000000000.0 mm is beyond"),
    (HEADER + "\n0,a," + ",".join(["0"] * 6) + ",1,two,3\n", "row 2, column tip_y: not a number: 'two'"),
    (HEADER + "\n", "no keypoint rows"),
    (HEADER + "\n0,a," + ",".join(["0"] * 6) + ",1,1e308,3\n", "row 2, column tip_y: 1e+308 mm is beyond +-10000 mm"),
    (HEADER + "\n0,a," + ",".join(["0"] * 6) + ",1,2,3\n1,a," + ",".join(["0"] * 6) + ",1,2,-2e4\n",
     "row 3, column tip_z: -20000.0 mm is beyond"),
    (HEADER + ",tip_y\n0,a," + ",".join(["0"] * 6) + ",1,2,3,4\n", "column(s) ['tip_y'] appear more than once"),
    ("timestamp,pattern_label,servo_0_mm," + HEADER.split(",", 2)[2] + "\n0,a,0," + ",".join(["0"] * 6) + ",1,2,3\n",
     "column(s) ['servo_0_mm'] appear more than once"),
    (b"\x89PNG\r\n\x1a\n\x00\x00", "not a UTF-8 text file (byte 0x89 at offset 0)"),
    ((HEADER + "\n0,caf\xe9," + ",".join(["0"] * 6) + ",1,2,3\n").encode("latin-1"), "not a UTF-8 text file"),
    (HEADER.encode() + b"\n0,a\x00b," + b",".join([b"0"] * 6) + b",1,2,3\n", "not a text file (NUL byte at offset"),
])
def test_bad_data_exits_2_naming_file_row_and_column(tmp_path, capsys, body, words):
    import tomli_w
    scene = tmp_path / "s.toml"
    scene.write_text(tomli_w.dumps(scene_dict()))
    data = tmp_path / "bad.csv"
    data.write_bytes(body) if isinstance(body, bytes) else data.write_text(body)
    out = tmp_path / "o"
    for cmd in ("predict", "fit"):
        assert main([cmd, str(scene), str(data), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert words in err and "bad.csv" in err, err
    assert not (out / "metrics.json").exists() and not (out / "fitted.toml").exists()


def test_hardware_table_errors(tmp_path, capsys):
    import tomli_w
    d = scene_dict()
    d["hardware"]["servo_columns"] = COLS[:3]
    scene = tmp_path / "s.toml"
    scene.write_text(tomli_w.dumps(d))
    assert main(["predict", str(scene), str(scene), "--out", str(tmp_path / "o")]) == 2
    assert "[hardware].servo_columns: expected 6 column names" in capsys.readouterr().err
    d = scene_dict()
    d["tendons"][0]["control"] = "tension"
    with pytest.raises(tw.InputError, match="not under displacement control"):
        predict(scene_from_dict(d), read_measurements_from(np.zeros((1, 6)), np.zeros((1, 3))))


def test_fit_cli_writes_a_scene_that_predict_reads(tmp_path):
    import tomli_w
    csv = tmp_path / "synthetic.csv"
    synthetic_csv(csv, rows=30)
    scene = tmp_path / "start.toml"
    scene.write_text(tomli_w.dumps(scene_dict(compliance=4e-4, angle=(0.0, 0.0), base=(0.0, 0.0, 0.0))))
    out = tmp_path / "fit"
    assert main(["fit", str(scene), str(csv), "--out", str(out), "--max-iter", "4", "--quiet"]) == 0
    rep = json.loads((out / "fit.json").read_text())
    assert set(rep["parameters"]) >= {"compliance[1]", "pretension[0]", "angle[5]", "base_offset[2]"}
    assert rep["settings"]["scene_text"] == scene.read_text()
    doc = (Path(__file__).resolve().parents[1] / "docs" / "outputs.md").read_text()
    assert [k for k in [*rep, *rep["history"][0], *rep["history"][-1], *rep["training"]]
            if f"`{k}`" not in doc] == []  # documented
    assert main(["predict", str(out / "fitted.toml"), str(csv), "--out", str(tmp_path / "p")]) == 0
    m = json.loads((tmp_path / "p" / "metrics.json").read_text())
    assert m["rmse_mm"] == pytest.approx(rep["training"]["rmse_mm"], rel=1e-6)
    assert "coverage_95" not in m and not (out / "residual.npz").exists()  # the physics alone by default


def test_fit_and_predict_with_a_learned_residual_report_each_rows_interval(tmp_path):
    """fit --residual writes residual.npz; predict --residual adds its correction and each row's
    sigma and 95% interval, and the interval's coverage in metrics.json; predict refuses a file
    that is not a residual, naming it."""
    import csv as csvlib

    import tomli_w
    data = tmp_path / "synthetic.csv"
    synthetic_csv(data, rows=40)
    scene = tmp_path / "start.toml"
    scene.write_text(tomli_w.dumps(scene_dict(compliance=4e-4, angle=(0.0, 0.0), base=(0.0, 0.0, 0.0))))
    out = tmp_path / "fit"
    assert main(["fit", str(scene), str(data), "--out", str(out), "--max-iter", "4", "--quiet", "--residual"]) == 0
    assert main(["predict", str(out / "fitted.toml"), str(data), "--out", str(tmp_path / "p"), "--residual",
                 str(out / "residual.npz"), "--quiet"]) == 0
    m = json.loads((tmp_path / "p" / "metrics.json").read_text())
    assert 0.0 <= m["coverage_95"] <= 1.0 and m["units"]["coverage_95"] == "1"
    with open(tmp_path / "p" / "predictions.csv") as f:
        rows = list(csvlib.DictReader(f))
    r = rows[0]
    for a in "xyz":
        sigma, lo, hi, pred = (float(r[f"{w}_{a}_mm"]) for w in ("sigma", "low95", "high95", "pred"))
        assert sigma > 0 and lo == pytest.approx(pred - 1.959964 * sigma, abs=2e-6) and hi > pred
    inside = np.mean([float(r[f"low95_{a}_mm"]) <= float(r[f"meas_{a}_mm"]) <= float(r[f"high95_{a}_mm"])
                      for r in rows for a in "xyz"])
    assert inside == pytest.approx(m["coverage_95"])
    assert main(["predict", str(out / "fitted.toml"), str(data), "--out", str(tmp_path / "q"), "--residual",
                 str(data)]) == 2


def test_unidentifiable_names_the_parameters_spanning_the_null_space():
    """The scaled Jacobian's null space, by name: a column of zeros (a parameter with no effect),
    two columns only their sum of which the data see (one proportional to the other), fewer rows
    than columns; a well-posed Jacobian flags none, whatever its columns' scales."""
    from tdcr_warp.apps.hardware import unidentifiable
    rng = np.random.default_rng(0)
    J = rng.normal(size=(30, 5)) * np.array([1e-6, 1.0, 1e3, 1.0, 1.0])
    assert not unidentifiable(J).any()
    dead = J.copy()
    dead[:, 1] = 0.0
    assert unidentifiable(dead).tolist() == [False, True, False, False, False]
    pair = J.copy()
    pair[:, 4] = -2.5 * pair[:, 3] * (1 + 1e-9 * rng.normal(size=30))  # beyond RANK_RTOL: still the pair
    assert unidentifiable(pair).tolist() == [False, False, False, True, True]
    assert unidentifiable(J[:3]).sum() >= 2  # 3 rows, 5 parameters: at least a 2-dimensional null space


def test_fit_refuses_fewer_coordinates_than_parameters(tmp_path, capsys):
    """3 coordinates a row: detail "tendon" has 13 parameters here (needs 5 rows), "segment" 8
    (needs 3): fewer is refused naming the counts (exit 2, nothing written), never fitted with "+- 0"."""
    import tomli_w
    csv = tmp_path / "few.csv"
    synthetic_csv(csv, rows=4)
    scene = tmp_path / "s.toml"
    scene.write_text(tomli_w.dumps(scene_dict()))
    out = tmp_path / "fit"
    assert main(["fit", str(scene), str(csv), "--out", str(out), "--quiet"]) == 2
    assert "fit: 4 rows (12 coordinates) cannot determine the 13 parameters of detail 'tendon'" in capsys.readouterr().err
    assert not (out / "fit.json").exists()
    with pytest.raises(tw.InputError, match="2 rows .6 coordinates. cannot determine the 8 parameters.*at least 3 rows"):
        fit(scene_dict(), read_measurements(csv, COLS).subset(np.arange(2)), detail="segment")


def test_fit_refuses_more_rows_than_it_holds(tmp_path, monkeypatch):
    """The fit holds every row's solution at once: beyond MAX_FIT_ROWS it refuses up front, naming
    the count and the limit (here lowered to 10 on 12 rows), before any solve."""
    from tdcr_warp.apps import hardware as hw
    csv = tmp_path / "rows.csv"
    synthetic_csv(csv, rows=12)
    monkeypatch.setattr(hw, "MAX_FIT_ROWS", 10)
    monkeypatch.setattr(hw, "solve_static", None)  # refused before any solve
    with pytest.raises(tw.InputError, match="fit: 12 rows, more than the 10 it holds in memory at once"):
        fit(scene_dict(), read_measurements(csv, COLS))


def test_fit_flags_a_parameter_without_effect_by_name(tmp_path, capsys):
    """A tendon on the backbone's axis (offset 0): rotating it changes nothing, so the data cannot
    determine its angle. The fit says so by name (fit.json ``unidentifiable``, its std null, the
    printed line) and exits 1; the other parameters keep finite uncertainties."""
    import tomli_w
    d = scene_dict(angle=(0.0, 0.0), base=(0.0, 0.0, 0.0))
    d["tendons"][0]["offset"] = [0.0, 0.0]
    csv = tmp_path / "synthetic.csv"
    synthetic_csv(csv, rows=20)
    scene = tmp_path / "axis.toml"
    scene.write_text(tomli_w.dumps(d))
    out = tmp_path / "fit"
    assert main(["fit", str(scene), str(csv), "--out", str(out), "--max-iter", "2"]) == 1
    printed = capsys.readouterr().out
    rep = json.loads((out / "fit.json").read_text())
    assert rep["unidentifiable"] == ["angle[0]"] and rep["parameters"]["angle[0]"]["std"] is None
    assert all(v["std"] is not None and v["std"] > 0 for n, v in rep["parameters"].items() if n != "angle[0]")
    assert "angle[0]" in printed.split("NOT IDENTIFIABLE")[0].splitlines()[-1] and "+- 0 " not in printed
    assert "cannot determine angle[0]" in printed and (out / "fitted.toml").exists()


def test_predict_without_a_converged_row_writes_the_metrics_and_fails(tmp_path, capsys):
    """No row converges (a solver allowed one Newton iteration): metrics.json still says so
    (converged 0, the RMSE null), predictions.csv has every row, no figure is drawn, exit 1."""
    import tomli_w
    d = scene_dict()
    d["solver"]["max_iter"] = 1
    csv = tmp_path / "synthetic.csv"
    synthetic_csv(csv, rows=8)
    scene = tmp_path / "s.toml"
    scene.write_text(tomli_w.dumps(d))
    out = tmp_path / "p"
    out.mkdir()
    (out / "predict.png").write_bytes(b"an earlier run's")  # not left to pass for this run's
    assert main(["predict", str(scene), str(csv), "--out", str(out), "--quiet"]) == 1
    m = json.loads((out / "metrics.json").read_text())
    assert m["rows"] == 8 and m["converged"] == 0 and m["rmse_mm"] is None
    assert len((out / "predictions.csv").read_text().splitlines()) == 9 and not (out / "predict.png").exists()
    assert "no predict.png: no row converged" in capsys.readouterr().out


def test_predict_in_chunks_is_predict_row_for_row():
    """Chunks of 5 rows (3 solves, the last short) give the one batch's results row for row, with
    the progress after each chunk. A row that fails is retried from the row before it across a
    chunk's start too (a solver held to 3 Newton iterations on a ramp of one tendon: row 4, the
    first of the second chunk of 4, is retried from row 3 as in the one batch)."""
    from tdcr_warp.apps import hardware as hw
    rng = np.random.default_rng(1)
    meas = read_measurements_from(rng.uniform(-0.5, 1.0, (12, 6)), np.zeros((12, 3)))
    scene = scene_from_dict(scene_dict())
    whole, seen = predict(scene, meas), []
    parts = hw.predict_in_chunks(scene, meas, chunk=5, progress=lambda done, failed: seen.append((done, failed)))
    assert "solution" not in parts and seen == [(5, 0), (10, 0), (12, 0)] and whole["converged"].all()
    for k in ("point_mm", "error_mm", "converged", "unstable", "slack", "retried"):
        np.testing.assert_allclose(parts[k], whole[k], rtol=0, atol=1e-12, err_msg=k)
    q = np.zeros((12, 6))
    q[:, 0] = np.linspace(0.0, 1.5, 12)
    ramp, d = read_measurements_from(q, np.zeros((12, 3))), scene_dict()
    d["solver"]["max_iter"] = 3
    held = scene_from_dict(d)
    whole, seen = predict(held, ramp), []
    parts = hw.predict_in_chunks(held, ramp, chunk=4, progress=lambda done, failed: seen.append((done, failed)))
    assert whole["retried"][4] and not whole["converged"].all()
    assert seen[-1] == (12, int((~whole["converged"]).sum()))
    for k in ("point_mm", "converged", "retried"):
        np.testing.assert_array_equal(parts[k], whole[k], err_msg=k)
