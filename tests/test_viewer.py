"""The interactive HTML viewer (tdcr_warp.io.viewer): what the figure holds (traces per rod, disk and
tendon, animation frames with their times, equal axes, hover text), the self-contained file and
the CLI's --html; and a real headless Chromium's screenshot of it (skipped without chromium)."""

import base64
import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scenes import two_tendon_scene

import tdcr_warp as tw
from tdcr_warp.cli import main
from tdcr_warp.io.drawing import ROD_COLOURS, TENSION_SCALE
from tdcr_warp.io.viewer import (
    MAX_FRAMES,
    RIM_POINTS,
    frame_indices,
    robot_figure,
    screenshot,
    viewer_spec,
    write_run_viewer,
    write_viewer,
)
from tdcr_warp.model.robot import InputError

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
L = 0.5


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def arcs(kappas, nodes: int = 20):
    """Constant-curvature rods bent toward +x (curvature kappa_b [1/m] about the body y axis):
    s (N+1,), positions (B, N+1, 3), rotations (B, N+1, 3, 3)."""
    s = np.linspace(0.0, L, nodes + 1)
    th = np.asarray(kappas, dtype=float)[:, None] * s[None]  # (B, N+1)
    k = np.asarray(kappas, dtype=float)[:, None]
    p = np.stack([(1 - np.cos(th)) / k, np.zeros_like(th), np.sin(th) / k], axis=-1)
    c, sn, z, o = np.cos(th), np.sin(th), np.zeros_like(th), np.ones_like(th)
    R = np.stack([np.stack([c, z, sn], -1), np.stack([z, o, z], -1), np.stack([-sn, z, c], -1)], axis=-2)
    return s, p, R


ROBOT = tw.Robot(length=L, tendons=[tw.Tendon(offset=(0.01, 0.0)), tw.Tendon(offset=(0.0, 0.01), length=0.25)])


def names(fig):
    return [t.name for t in fig.data]


def f32(a):
    return np.asarray(a, dtype=np.float64)


def test_static_figure_holds_one_trace_per_rod_part_and_the_frames():
    s, p, R = arcs([1.0, 2.0])
    tau = np.array([[2.0, 0.5], [0.0, 1.5]])
    fig = robot_figure(ROBOT, p, R, s, tau, display={"disks": 5})
    # per rod: backbone, disks, 2 tendons; then the x, y, z axes of the base and tip frames
    assert names(fig) == ["rod 0", "rod 0 disks", "rod 0 tendon 0", "rod 0 tendon 1",
                          "rod 1", "rod 1 disks", "rod 1 tendon 0", "rod 1 tendon 1", "frame x", "frame y", "frame z"]
    assert [t.showlegend for t in fig.data[:8]] == [True, False, False, False] * 2  # a legend entry per rod
    assert fig.data[0].line.color != fig.data[4].line.color and fig.data[0].line.width >= 8
    assert all(t.legendgroup == f"rod {b}" for b in range(2) for t in fig.data[4 * b:4 * b + 4])
    for b in range(2):
        bb = fig.data[4 * b]
        assert np.allclose(np.c_[f32(bb.x), f32(bb.y), f32(bb.z)], p[b] * 1e3, atol=1e-3)  # mm
        rims = np.c_[f32(fig.data[4 * b + 1].x), f32(fig.data[4 * b + 1].y), f32(fig.data[4 * b + 1].z)]
        gaps = np.isnan(rims[:, 0])
        assert gaps.sum() == 4 and len(rims) == 5 * (RIM_POINTS + 1) + 4  # 5 closed rims between 4 gaps
        loops = [seg[~np.isnan(seg[:, 0])] for seg in np.split(rims, np.flatnonzero(gaps))]
        assert all(np.allclose(r[0], r[-1]) for r in loops)  # closed
        centres = np.array([r[:-1].mean(axis=0) for r in loops])
        assert np.allclose([np.linalg.norm(r - c, axis=1).max() for r, c in zip(loops, centres)], 12.5)  # 1.25 x 10 mm
        disk_z = np.sin(np.array([1.0, 2.0])[b] * L * np.arange(1, 6) / 5) / np.array([1.0, 2.0])[b] * 1e3
        assert np.allclose(np.sort(centres[:, 2]), disk_z, atol=0.2)  # the disks' centres on the backbone
        t1 = fig.data[4 * b + 3]  # tendon 1 ends at mid-length: no point above it
        assert f32(t1.z).max() < 0.25e3 + 11 and f32(fig.data[4 * b + 2].z).max() > 0.45e3 / (1 + b)
    # a colour per tendon from its tension, one shared scale and one colour bar in N
    tendons = [fig.data[i] for i in (2, 3, 6, 7)]
    assert [float(np.asarray(t.line.color)[0]) for t in tendons] == [2.0, 0.5, 0.0, 1.5]
    assert {(t.line.cmin, t.line.cmax) for t in tendons} == {(0.0, 2.0)}
    assert [t.line.showscale for t in tendons] == [True, False, False, False]
    assert tendons[0].line.colorbar.title.text == "tension [N]"
    # base and tip frames: 2 rods x (base, tip) segments per axis, RGB
    for j, t in enumerate(fig.data[8:]):
        seg = np.c_[f32(t.x), f32(t.y), f32(t.z)]
        assert len(seg) == 4 * 2 + 3 and np.isnan(seg[:, 0]).sum() == 3
        assert np.allclose(seg[0], 0.0) and np.argmax(np.abs(seg[1] - seg[0])) == j  # base axis j along world j
        tip_dir = seg[-1] - seg[-2]  # rod 1's tip axis j is its tip rotation's column j
        assert np.allclose(tip_dir / np.linalg.norm(tip_dir), R[1, -1][:, j], atol=1e-5)
    assert [t.line.color for t in fig.data[8:]] == ["#e41a1c", "#33a02c", "#1f4fff"]


def test_axes_are_equal_and_hold_everything():
    s, p, R = arcs([3.0])
    fig = robot_figure(ROBOT, p, R, s, [[1.0, 0.0]])
    sc = fig.layout.scene
    assert sc.aspectmode == "data"  # one scale on x, y and z (plotly sizes the box by the ranges)
    pts = np.concatenate([np.c_[f32(t.x), f32(t.y), f32(t.z)] for t in fig.data])
    margins = []
    for axis, i in ((sc.xaxis, 0), (sc.yaxis, 1), (sc.zaxis, 2)):
        lo, hi = axis.range
        margins += [np.nanmin(pts[:, i]) - lo, hi - np.nanmax(pts[:, i])]
    # the data's ranges and one margin in mm on every side (no axis stretched to a cube)
    span = np.nanmax(pts, axis=0) - np.nanmin(pts, axis=0)
    assert np.allclose(margins, margins[0], atol=1e-3) and 0 < margins[0] < 0.05 * span.max() + 1.5
    assert not any(t.showlegend for t in fig.data)  # one rod: no legend
    assert sc.xaxis.title.text == "x [mm]" and sc.zaxis.title.text == "z [mm]"


def test_hover_shows_s_position_and_tension():
    s, p, R = arcs([1.0])
    fig = robot_figure(ROBOT, p, R, s, [[2.5, 0.25]], display={"disks": 4})
    bb, tendon = fig.data[0], fig.data[2]
    assert "s = %{customdata:.4f} m" in bb.hovertemplate and "mm" in bb.hovertemplate
    assert np.allclose(f32(bb.customdata), s)
    assert "tendon 0" in tendon.hovertemplate and "tension = %{customdata[1]:.3f} N" in tendon.hovertemplate
    cd = np.asarray(tendon.customdata, dtype=float)
    assert np.allclose(cd[:, 1], 2.5) and cd[0, 0] == 0.0 and cd[-1, 0] == pytest.approx(L)
    assert "tension = %{customdata[1]:.3f} N" in fig.data[3].hovertemplate
    assert np.allclose(np.asarray(fig.data[3].customdata, dtype=float)[:, 1], 0.25)


def test_trajectory_has_a_frame_per_shape_with_its_time():
    F = 7
    times = np.linspace(0.0, 0.3, F)
    shapes = [arcs([0.1 + k, 0.5 + k]) for k in range(F)]
    s = shapes[0][0]
    P = np.stack([x[1] for x in shapes])
    R = np.stack([x[2] for x in shapes])
    tau = np.stack([np.full((2, 2), k / 2) for k in range(F)])
    fig = robot_figure(ROBOT, P, R, s, tau, times=times, display={"disks": 3})
    assert len(fig.frames) == F
    assert [float(fr.name) for fr in fig.frames] == pytest.approx(times.tolist())
    assert all(len(fr.data) == len(fig.data) == 2 * 4 + 3 for fr in fig.frames)
    for k in (0, 3, 6):
        bb = fig.frames[k].data[4]
        assert np.allclose(np.c_[f32(bb.x), f32(bb.y), f32(bb.z)], P[k, 1] * 1e3, atol=1e-3)
        assert float(np.asarray(fig.frames[k].data[2].line.color)[0]) == k / 2
        assert f"t = {times[k]:.4f} s" in fig.frames[k].layout.title.text
    assert {t.line.cmax for fr in fig.frames for t in fr.data[2:4]} == {3.0}  # one scale over the whole run
    slider = fig.layout.sliders[0]
    assert [list(st.args[0]) for st in slider.steps] == [[fr.name] for fr in fig.frames]
    assert [b.label for b in fig.layout.updatemenus[0].buttons] == ["play", "pause"]
    # the axes hold every frame (fixed over the animation)
    pts = np.concatenate([np.c_[f32(t.x), f32(t.y), f32(t.z)] for fr in fig.frames for t in fr.data])
    sc = fig.layout.scene
    assert sc.xaxis.range[1] > np.nanmax(pts[:, 0]) and sc.zaxis.range[0] < np.nanmin(pts[:, 2])


@pytest.mark.parametrize("per_rod", [False, True])
def test_frames_draw_robot_geometry(per_rod):
    """Every frame's tendons and disks are robot_geometry's of that shape (a robot shared by the
    batch is drawn in one call for all frames, a per-rod robot frame by frame)."""
    from tdcr_warp.io.drawing import robot_geometry

    offset = [[0.01, 0.0], [0.0, 0.008]] if per_rod else (0.01, 0.0)
    robot = tw.Robot(length=L, tendons=[tw.Tendon(offset=offset, length=0.3),
                                        tw.Tendon(routing="helix", helix_radius=0.01, turns=0.5)])
    assert robot.batch_size == (2 if per_rod else 1)
    shapes = [arcs([0.5 + k, 1.0 + k]) for k in range(3)]
    s, P, R = shapes[0][0], np.stack([x[1] for x in shapes]), np.stack([x[2] for x in shapes])
    tau = np.stack([np.full((2, 2), 1.0 + k) for k in range(3)])
    fig = robot_figure(robot, P, R, s, tau, times=[0.0, 0.1, 0.2], display={"disks": 4})
    for k, fr in enumerate(fig.frames):
        g = robot_geometry(robot, P[k], R[k], s, tau[k], {"disks": 4})
        for b in range(2):
            for j in range(2):
                t = fr.data[4 * b + 2 + j]
                assert np.allclose(np.c_[f32(t.x), f32(t.y), f32(t.z)], g.tendon_points[j][b] * 1e3, atol=1e-3)
            rims = fr.data[4 * b + 1]
            assert np.allclose(f32(rims.z)[:RIM_POINTS + 1], g.disk_rims(RIM_POINTS)[b, 0, :, 2] * 1e3, atol=1e-3)


def test_long_trajectories_are_downsampled():
    assert frame_indices(50).tolist() == list(range(50))
    idx = frame_indices(1001)
    assert len(idx) == MAX_FRAMES and idx[0] == 0 and idx[-1] == 1000 and (np.diff(idx) > 0).all()
    assert len(frame_indices(1001, rods=10)) == 100  # rods x frames bounded too
    F = 45
    s, p, R = arcs([1.0])
    spec = viewer_spec(ROBOT, np.repeat(p[None], F, 0), np.repeat(R[None], F, 0), s, np.ones((F, 1, 2)),
                       times=np.arange(F) * 0.01, display={"disks": 2}, max_frames=12)
    frames = spec["frames"]
    assert len(frames) == 12 and frames[0]["name"] == "0" and float(frames[-1]["name"]) == 0.44
    assert [st["args"][0] for st in spec["layout"]["sliders"][0]["steps"]] == [[f["name"]] for f in frames]


def embedded(html: str):
    """The figure a viewer file embeds: (data, layout, frames) as plotly.js receives them."""
    dec = json.JSONDecoder()
    m = re.search(r'Plotly\.newPlot\(\s*"([^"]+)",\s*', html)
    data, end = dec.raw_decode(html, m.end())
    layout, _ = dec.raw_decode(html, re.compile(r",\s*").match(html, end).end())
    f = re.search(r"Plotly\.addFrames\(\s*'[^']+',\s*", html)
    frames = dec.raw_decode(html, f.end())[0] if f else []
    return data, layout, frames


def array(a):
    """A plotly array from the JSON: a list or a typed array {dtype, bdata}."""
    if isinstance(a, dict):
        return np.frombuffer(base64.b64decode(a["bdata"]), dtype=np.dtype(a["dtype"]))
    return np.asarray(a, dtype=float)


def test_html_is_self_contained_and_holds_the_trajectory(tmp_path):
    F = 5
    s, p, R = arcs([1.0, 2.0])
    times = np.arange(F) * 0.05
    P = np.repeat(p[None], F, 0) * np.linspace(1, 1.1, F)[:, None, None, None]  # a growing robot
    path = write_viewer(tmp_path / "robot.html", ROBOT, P, np.repeat(R[None], F, 0), s, np.ones((F, 2, 2)),
                        times=times, display={"disks": 6})
    html = path.read_text()
    tags = re.findall(r"<script[^>]*>", html)
    assert tags and not any("src" in t for t in tags)  # plotly.js embedded, nothing fetched: opens offline
    assert "plotly.js v" in html and len(html) > 3e6 and len(html) < 8e6
    data, layout, frames = embedded(html)
    assert len(data) == 2 * 4 + 3 and layout["scene"]["aspectmode"] == "data"
    assert [float(fr["name"]) for fr in frames] == pytest.approx(times.tolist())
    assert all(len(fr["data"]) == len(data) for fr in frames)
    z = array(frames[-1]["data"][0]["z"])  # rod 0's backbone in the last frame, in mm
    assert np.allclose(z, p[0, :, 2] * 1.1e3, atol=1e-2)
    assert "s = " in data[0]["hovertemplate"] and "tension" in data[2]["hovertemplate"]


def test_input_errors():
    s, p, R = arcs([1.0])
    with pytest.raises(InputError, match="times"):
        robot_figure(ROBOT, p[None], R[None], s, np.ones((1, 1, 2)))
    with pytest.raises(InputError, match="times"):
        robot_figure(ROBOT, p, R, s, [[1.0, 1.0]], times=[0.0])
    run = SimpleNamespace(time=np.arange(3) * 0.1, tensions=np.zeros((2, 1, 2)), shape_steps=np.zeros(0, dtype=int),
                          positions=np.zeros((0, 1, 21, 3)), rotations=np.zeros((0, 1, 21, 3, 3)))
    with pytest.raises(InputError, match=r"\[dynamics\]\.shapes_every"):
        write_run_viewer("unused.html", ROBOT, run, s, np.zeros((1, 2)))


def test_cli_static_html(tmp_path, capsys):
    scene = write(tmp_path, two_tendon_scene("[[2.0, 0.5], [0.0, 1.5]]", nodes=20) + "[display]\ndisks = 8\n")
    out = tmp_path / "o"
    assert main(["static", str(scene), "--out", str(out), "--html", "--no-figures"]) == 0
    assert f"wrote {out}/robot.html (2 rods)" in capsys.readouterr().out
    data, layout, frames = embedded((out / "robot.html").read_text())
    assert [t["name"] for t in data] == ["rod 0", "rod 0 disks", "rod 0 tendon 0", "rod 0 tendon 1", "rod 1",
                                         "rod 1 disks", "rod 1 tendon 0", "rod 1 tendon 1", "frame x", "frame y",
                                         "frame z"]
    assert np.isnan(array(data[1]["x"])).sum() == 8 - 1 and frames == []
    assert array(data[2]["line"]["color"])[0] == 2.0 and array(data[7]["line"]["color"])[0] == 1.5


def test_cli_simulate_and_control_html(tmp_path, capsys):
    dyn = (EXAMPLES / "seed_dynamics.toml").read_text()
    out = tmp_path / "none"
    assert main(["simulate", str(write(tmp_path, dyn, "a.toml")), "--out", str(out), "--html", "--quiet",
                 "--nodes", "20", "--steps", "10"]) == 2
    assert "[dynamics].shapes_every" in capsys.readouterr().err and not (out / "robot.html").exists()
    scene = write(tmp_path, dyn.replace("steps = 100\n", "steps = 100\nshapes_every = 4\n"), "b.toml")
    out = tmp_path / "sim"
    assert main(["simulate", str(scene), "--out", str(out), "--html", "--quiet", "--nodes", "20", "--steps", "12",
                 "--no-figures"]) == 0
    assert f"wrote {out}/robot.html (4 frames)" in capsys.readouterr().out
    _, _, frames = embedded((out / "robot.html").read_text())
    assert [float(fr["name"]) for fr in frames] == pytest.approx([0.0, 0.02, 0.04, 0.06])  # steps 0, 4, 8, 12
    traj = np.load(out / "trajectory.npz")
    assert traj["shape_steps"].tolist() == [0, 4, 8, 12]
    for i, fr in enumerate(frames):
        assert np.allclose(array(fr["data"][0]["x"]), traj["positions"][i, 0, :, 0] * 1e3, atol=1e-3)
    # tensions drawn: the start's 0 N, then the command of the step that ended at each shape (3 N from step 5)
    assert [array(fr["data"][2]["line"]["color"])[0] for fr in frames] == [0.0, 0.0, 3.0, 3.0]

    ctl = (EXAMPLES / "our_control.toml").read_text().replace("steps = 200\n", "steps = 200\nshapes_every = 5\n")
    out = tmp_path / "ctl"
    assert main(["control", str(write(tmp_path, ctl, "c.toml")), "--out", str(out), "--html", "--quiet", "--nodes",
                 "20", "--steps", "10"]) == 0
    _, _, frames = embedded((out / "robot.html").read_text())
    assert [float(fr["name"]) for fr in frames] == pytest.approx([0.0, 0.025, 0.05])
    assert array(frames[-1]["data"][2]["line"]["color"])[0] > 0.0  # the controller pulls tendon 0


def colour(hex_):
    return np.array([int(hex_[i:i + 2], 16) for i in (1, 3, 5)]) / 255.0


@pytest.mark.skipif(shutil.which("chromium") is None, reason="no chromium on PATH (apt-get install chromium)")
def test_headless_chromium_draws_the_robot(tmp_path):
    """A real browser renders the file (WebGL in software): both backbones' colours, the tendons'
    tension colours and a robot of a sensible size inside the plot area."""
    import matplotlib.image

    s, p, R = arcs([2.0, 4.0], nodes=30)
    # tendon 0 (in the bending plane, in view): 3 N on rod 0, 0 N on rod 1
    path = write_viewer(tmp_path / "robot.html", ROBOT, p, R, s, [[3.0, 0.0], [0.0, 3.0]], display={"disks": 6})
    png = screenshot(path, tmp_path / "shot.png", width=800, height=600, browser="chromium", budget_ms=4000)
    img = matplotlib.image.imread(png)[..., :3]  # (H, W, 3) in [0, 1]
    H, W = img.shape[:2]
    assert (H, W) == (600, 800)
    plot = img[:, int(0.15 * W):int(0.8 * W)]  # left of the colour bar, right of the legend

    def near(c, tol=0.1):
        return (np.abs(plot - colour(c)).max(axis=-1) < tol)

    rods = [near(c) for c in ROD_COLOURS[:2]]
    for mask in rods:
        assert mask.sum() > 300, mask.sum()  # a thick line, not the legend's swatch
    rows = np.flatnonzero(rods[0].any(axis=1))
    assert rows.max() - rows.min() > 0.3 * H  # the backbone spans a good part of the picture
    # the tendons' colours, unlike the rods': 3 N the scale's top (dark red), 0 N its bottom (light orange)
    dark_red = near(TENSION_SCALE[-1][1])
    light = near(TENSION_SCALE[0][1])
    assert dark_red.sum() > 150 and light.sum() > 150, (dark_red.sum(), light.sum())
    ink = (plot < 0.9).any(axis=-1)
    assert 0.005 < ink.mean() < 0.5  # a drawing, not a blank or a filled page
