"""The robot figure and animation: disks where the scene puts them, tendons through the disks at
their offsets, tensions as colours, frames, equal axes, and what the CLI writes."""

import tomllib

import numpy as np
import pytest
from scenes import two_tendon_scene

import tdcr_warp as tw
from tdcr_warp.cli import main
from tdcr_warp.io.drawing import TENSION_SCALE, display_options, robot_geometry
from tdcr_warp.io.plotting import animate_robot, plot_robot
from tdcr_warp.io.scene import scene_from_dict
from tdcr_warp.model.robot import InputError


@pytest.fixture(scope="module")
def solved():
    """Two rods of a two-tendon robot with gravity, bent by different tensions."""
    sc = scene_from_dict(tomllib.loads(two_tendon_scene("[[2.0, 0.5], [0.0, 1.5]]", nodes=16)
                                       + "[display]\ndisks = 8\n"))
    sol = tw.solve_static(sc.robot, sc.tensions, options=sc.options)
    return sc, sol, robot_geometry(sc.robot, sol.positions, sol.rotations, sol.s, sol.tendon_tension_base, sc.display)


def test_disks_and_tendon_paths_follow_the_solved_rod(solved):
    sc, sol, g = solved
    assert g.disk_centres.shape == (2, 8, 3) and np.allclose(g.disk_s[:, -1], 0.5)
    assert np.allclose(g.disk_centres[:, -1], sol.tip_position, atol=1e-12)  # the last disk is at the tip
    for k, t in enumerate(sc.robot.tendons):
        pts = g.tendon_points[k]
        assert pts.shape == (2, 9, 3)  # the base and 8 disks, the last at the tip where the tendon ends
        rel = pts[:, 1:] - g.disk_centres
        assert np.allclose(np.linalg.norm(rel, axis=-1), np.linalg.norm(t.offset), rtol=1e-9)
        assert np.abs(np.einsum("bdi,bdi->bd", rel, g.disk_frames[..., 2])).max() < 1e-12  # in the disk's plane
    assert np.allclose(g.tension, sol.tendon_tension_base)
    for R in g.disk_frames.reshape(-1, 3, 3):
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)


def test_robot_figure_draws_every_part_on_equal_axes(solved):
    _, sol, g = solved
    fig = plot_robot(g, converged=sol.converged)
    ax3, side, top = fig.axes[:3]

    def count(ax, gid):
        return sum(1 for ln in ax.lines if ln.get_gid() == gid)
    for ax in (ax3, side):
        assert count(ax, "backbone") == 2 and count(ax, "disk") == 2 * 8
        assert count(ax, "tendon") == 2 * 2 and count(ax, "frame") == 2 * 2 * 3
    # seen from above: the backbones, each rod's tip disk (not 8 stacked rims), base ring and tendon ends
    assert [count(top, gid) for gid in ("backbone", "disk", "base", "tendon", "tendon end", "frame")] == [2, 2, 2, 4,
                                                                                                          4, 0]
    tip_disk = next(ln for ln in top.lines if ln.get_gid() == "disk")
    assert np.allclose(np.c_[tip_disk.get_xdata(), tip_disk.get_ydata()].mean(axis=0),
                       g.disk_centres[0, -1, :2] * 1e3, atol=0.5)  # mm
    # the 3D box: one scale on x, y and z (box sides in proportion to the limits), holding every
    # point, fitted to the robot (a tall box, not a cube around a thin rod) and no side under a third
    # of the longest
    spans = np.array([np.diff(lim)[0] for lim in (ax3.get_xlim(), ax3.get_ylim(), ax3.get_zlim())])
    box = np.asarray(ax3.get_box_aspect())
    assert np.allclose(box / box.max(), spans / spans.max())
    pts = np.concatenate([np.stack(ln.get_data_3d(), axis=1) for ln in ax3.lines])  # mm
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    assert (lo >= [a[0] for a in (ax3.get_xlim(), ax3.get_ylim(), ax3.get_zlim())]).all()
    assert (hi <= [a[1] for a in (ax3.get_xlim(), ax3.get_ylim(), ax3.get_zlim())]).all()
    tight = hi - lo + 0.1 * (hi - lo).max()  # the data's extent with the margins
    aspect = (spans / spans.max()) / (tight / tight.max())
    assert (aspect > 0.99).all() and (aspect < 3).all(), aspect
    assert (spans / spans.max() > 0.33).all() and np.argmax(spans) == 2 and (hi - lo)[2] > 0.85 * spans[2]
    for ax in (side, top):  # equal axes, the data filling the longer one
        assert ax.get_aspect() == 1.0
        xy = np.concatenate([np.c_[ln.get_xdata(), ln.get_ydata()] for ln in ax.lines])
        extent, lims = np.ptp(xy, axis=0), np.array([np.diff(ax.get_xlim())[0], np.diff(ax.get_ylim())[0]])
        assert (extent <= lims).all() and (extent / lims).max() > 0.85
    assert side.get_xlabel() == "x [mm]" and side.get_ylabel() == "z [mm]" and top.get_ylabel() == "y [mm]"
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["rod 0", "rod 1", "spacer disks",
                                                                  "tendons (colour: tension)",
                                                                  "base and tip frames (x, y, z)"]
    tendons = [ln for ln in ax3.lines if ln.get_gid() == "tendon"]
    # one colour scale from 0 to the largest tension (2 N), in drawing order: rod 0's tendons, rod 1's
    from matplotlib.colors import LinearSegmentedColormap
    cmap = LinearSegmentedColormap.from_list("tension", TENSION_SCALE)
    want = [cmap(t / 2.0)[:3] for t in sol.tendon_tension_base.ravel()]
    assert np.allclose([matplotlib_rgb(ln.get_color()) for ln in tendons], want)
    assert len({matplotlib_rgb(ln.get_color()) for ln in tendons}) == 4
    assert "tendon tensions [N] 0: 2.00, 1: 0.50" in fig.get_suptitle()
    assert fig.axes[-1].get_xlabel() == "tendon tension [N]"


def matplotlib_rgb(c):
    from matplotlib.colors import to_rgb
    return to_rgb(c)


def test_animation_has_one_frame_per_stored_shape(solved, tmp_path):
    from PIL import Image
    sc, sol, g = solved
    assert animate_robot([g] * 3, np.linspace(0, 0.02, 3), tmp_path / "a.gif") == 3
    with Image.open(tmp_path / "a.gif") as im:
        assert im.n_frames == 3
    assert animate_robot([g] * 300, np.arange(300) * 1e-3, tmp_path / "b.gif", max_frames=4) == 4
    assert (tmp_path / "b.gif").stat().st_size < 2e6


@pytest.mark.parametrize("table,message", [({"disks": -1}, "disks"), ({"disks": 2.5}, "disks"),
                                           ({"disk_radius": 0}, "disk_radius"), ({"colour": 1}, "'colour'")])
def test_display_table_is_checked(table, message):
    with pytest.raises(InputError, match=message):
        display_options(table)


def test_cli_animation_needs_stored_shapes(tmp_path, capsys):
    text = two_tendon_scene("[[0.0, 0.0]]", nodes=10) + """
[dynamics]
dt = 0.005
steps = 6
damping_bending = [0.008, 0.008, 0.008]
[[actuation.steps]]
start = 1
tensions = [[2.0, 0.0]]
"""
    scene = tmp_path / "d.toml"
    scene.write_text(text)
    out = tmp_path / "o"
    assert main(["simulate", str(scene), "--out", str(out), "--quiet", "--animate"]) == 2
    assert "[dynamics].shapes_every" in capsys.readouterr().err
    scene.write_text(text.replace("steps = 6", "steps = 6\nshapes_every = 2"))
    assert main(["simulate", str(scene), "--out", str(out), "--quiet", "--animate", "--no-figures"]) == 0
    from PIL import Image
    with Image.open(out / "robot.gif") as im:
        assert im.n_frames == 4  # steps 0, 2, 4, 6
    traj = np.load(out / "trajectory.npz")
    assert traj["rotations"].shape == (4, 1, 11, 3, 3)


@pytest.fixture
def captured(monkeypatch):
    """The figures the plotting functions save, by file name (not written)."""
    import tdcr_warp.io.plotting as plotting
    figs = {}
    monkeypatch.setattr(plotting, "_save", lambda fig, path: figs.__setitem__(path.name, fig))
    return figs


def test_control_figures_show_the_limit_the_surface_and_time(captured, tmp_path):
    from tdcr_warp.apps.control import ControlRun
    from tdcr_warp.io.plotting import plot_control
    T, t = 50, np.linspace(0, 0.25, 51)
    x = 0.01 * np.exp(-20 * t)[:, None, None] * np.ones((1, 1, 3))
    run = ControlRun(time=t, tip_position=x, tip_velocity=np.gradient(x, t, axis=0), error=-x, sliding=np.zeros_like(x),
                     tensions=np.full((T, 1, 2), 1.5), converged=np.ones((T, 1), bool), target=np.zeros((1, 3)))
    plot_control(run, tmp_path, tension_max=np.full((1, 2), 4.0), gain_c=np.full((1, 3), 20.0))
    ax = captured["control_tension.png"].axes[0]
    assert any(np.allclose(ln.get_ydata(), 4.0) and ln.get_label() == "tension limit" for ln in ax.lines)
    err, phase, surface = captured["control_error_phase.png"].axes
    assert all(a.get_title() for a in (err, phase, surface))
    line = next(ln for ln in surface.lines if ln.get_label().startswith("S = e_t + C e = 0"))
    (e0, e1), (v0, v1) = line.get_xdata(), line.get_ydata()
    assert np.isclose((v1 - v0) / ((e1 - e0) / 1e3), -20.0)  # e_t = -C e, e in mm
    assert len([c for c in surface.get_children() if type(c).__name__ == "Annotation"]) == 3  # time's arrows


def test_workspace_views_in_mm_with_the_models_gap(captured, tmp_path):
    from tdcr_warp.io.plotting import plot_workspace
    rng = np.random.default_rng(0)
    tips = np.c_[rng.uniform(-0.06, 0.06, (500, 2)), 0.497 + 0.003 * rng.random(500)]
    plot_workspace(tips, rng.random(500), tips + [0.0, 0.0, 2e-6], [], tmp_path)
    fig = captured["workspace.png"]
    side = next(a for a in fig.axes if a.get_title().startswith("side"))
    lo, hi = side.get_ylim()
    assert hi - lo < 4.0 and side.get_ylabel() == "z [mm]"  # the 3 mm of z, not the 120 mm of x
    top = next(a for a in fig.axes if a.get_title().startswith("top"))
    assert top.get_aspect() == 1.0 and np.diff(top.get_xlim())[0] > 110  # mm
    gap = next(a for a in fig.axes if "models" in a.get_title())
    assert "at most 2 µm apart" in gap.get_title()
    assert np.allclose(gap.collections[0].get_offsets()[:, 1], 2.0)  # µm
    ax3 = next(a for a in fig.axes if a.name == "3d")
    box = np.asarray(ax3.get_box_aspect())
    assert np.isclose(box[0] / box[1], 1.0, rtol=0.05) and box[2] / box[0] == pytest.approx(0.5, rel=0.05)
    assert "z stretched x20" in ax3.get_title()  # 0.5 x 120 mm box height for 3 mm of z


def test_montecarlo_histogram_percentiles_and_equal_top_view(captured, tmp_path):
    from tdcr_warp.apps.jobs import ERROR_EDGES, Histogram
    from tdcr_warp.io.plotting import plot_montecarlo
    rng = np.random.default_rng(1)
    tips = np.c_[0.026 + 0.002 * rng.standard_normal(400), np.zeros(400), 0.499 + 1e-4 * rng.standard_normal(400)]
    nominal = np.array([0.026, 0.0, 0.499])
    h = Histogram(ERROR_EDGES)
    h.add(np.linalg.norm(tips - nominal, axis=1))
    plot_montecarlo(tips, nominal, h, tips.mean(axis=0), np.cov(tips.T), tmp_path)
    hist, top, side = captured["montecarlo.png"].axes
    lines = {ln.get_label().split(":")[0]: ln.get_xdata()[0] for ln in hist.lines}
    assert lines["median"] == pytest.approx(h.percentile(50) * 1e3) and "95th percentile" in lines
    bars = hist.patches[0]  # one stairs patch: about 20 bins a decade, not 200
    assert len(bars.get_path().vertices) < 200
    assert top.get_aspect() == 1.0 and top.get_xlabel() == "x [mm]" and "stretched" in side.get_title()
    assert any("sigma" in t.get_text() for t in top.get_legend().get_texts())


def test_gain_grid_marks_the_fastest_cell(captured, tmp_path):
    from tdcr_warp.io.plotting import plot_gain_grid
    cells = {(c, k): np.array([np.nan if c == k == 5.0 else 1.0 / (c + k), 1e-3 / c, 1e-9 * k])
             for c in (5.0, 10.0, 20.0) for k in (5.0, 10.0)}
    st = np.array([0.2, np.inf, 0.3])
    plot_gain_grid(cells, ("control.gain_c", "control.gain_k"), (st, np.array([1e-9, 1e-6, 1e-8])),
                   (np.array([0.2]), np.array([1e-9])), tmp_path)
    fig = captured["gain_grid.png"]
    settle, error, chatter, runs = fig.axes[:4]
    for ax in (settle, error, chatter):
        star = next(ln for ln in ax.lines if ln.get_gid() == "best")
        assert (star.get_xdata()[0], star.get_ydata()[0]) == (2.5, 1.5)  # c = 20, k = 10: the shortest settling
    assert error.get_title() == "final error [mm]" and error.images[0].norm.vmax == pytest.approx(1e-3 / 5 * 1e3)
    assert type(chatter.images[0].norm).__name__ == "LogNorm" and runs.get_yscale() == "log"
    assert "2 settled of 3" in runs.get_legend().get_texts()[0].get_text()
    never = {k: np.array([np.nan, v[1], v[2]]) for k, v in cells.items()}  # no run settled: no star, no error
    plot_gain_grid(never, ("control.gain_c", "control.gain_k"), (np.full(3, np.inf), np.ones(3)),
                   (np.zeros(0), np.zeros(0)), tmp_path)
    assert not any(ln.get_gid() == "best" for ln in captured["gain_grid.png"].axes[0].lines)


def test_prediction_figure_on_one_scale(captured, tmp_path):
    from tdcr_warp.io.plotting import plot_prediction
    rng = np.random.default_rng(2)
    measured = np.c_[rng.uniform(-150, 150, (300, 2)), rng.uniform(40, 180, 300)]
    predicted = measured + rng.normal(0, 2.0, (300, 3))
    ok = np.ones(300, bool)
    ok[7] = False
    plot_prediction(measured, predicted, ok, tmp_path / "predict.png")
    fig = captured["predict.png"]
    ax3 = fig.axes[0]
    box = np.asarray(ax3.get_box_aspect())
    spans = np.array([np.diff(lim)[0] for lim in (ax3.get_xlim(), ax3.get_ylim(), ax3.get_zlim())])
    assert np.allclose(box / box.max(), spans / spans.max(), rtol=0.1)  # one scale: z not stretched to a cube
    rmse = np.sqrt(np.mean(np.sum((predicted - measured)[ok] ** 2, axis=1)))
    assert f"299 of 300 rows converged: RMSE {rmse:.2f} mm" in fig.get_suptitle()


def test_search_figure_titles_the_unsettled_band(captured, tmp_path):
    from tdcr_warp.io.plotting import plot_search
    history = [{"closed_loops": 16 * g, "best_objective": 0.2 - 0.01 * g} for g in range(1, 5)]
    loops = np.repeat([16, 32, 48, 64], 4)
    plot_search(history, (loops, np.linspace(0.16, 1.5, 16)), (0.16, 1000), 1.005, tmp_path / "search.png")
    ax = captured["search.png"].axes[0]
    assert "grid" in ax.get_title() and ax.get_xscale() == ax.get_yscale() == "log"
    band = next(p for p in ax.patches if p.get_y() == pytest.approx(1.005))  # the shaded "did not settle" band
    assert band.get_height() > 0
    assert ax.yaxis.get_major_formatter()(0.2, 0) == "0.2"  # plain numbers, not 2 x 10^-1
    assert [t.get_text() for t in ax.get_legend().get_texts()][-1] == "grid: 1,000 closed loops"


def test_obstacles_are_drawn_in_the_figure_and_the_viewer():
    """Every obstacle kind as an outline on its surface: grey lines in every view of the figure
    (gid "obstacle") and a trace each in the HTML viewer."""
    from tdcr_warp.io.drawing import obstacle_outlines
    from tdcr_warp.io.viewer import robot_figure

    obstacles = [tw.Obstacle("plane", point=(0.05, 0, 0), normal=(-1, 0, 0)),
                 tw.Obstacle("sphere", center=(0.03, 0, 0.3), radius=0.01),
                 tw.Obstacle("capsule", start=(-0.03, -0.02, 0.2), end=(-0.03, 0.02, 0.2), radius=0.005),
                 tw.Obstacle("tube", start=(0, 0, -0.01), end=(0, 0, 0.2), radius=0.004),
                 tw.Obstacle("bent_tube", start=(0, 0, 0.2), direction=(0, 0, 1), toward=(1, 0, 0), bend_radius=0.3,
                             angle=0.8, radius=0.004)]
    robot = tw.Robot(length=0.5, obstacles=obstacles)
    outlines = obstacle_outlines(robot)
    on_surface = [lambda p: p[:, 0] - 0.05, lambda p: np.linalg.norm(p - [0.03, 0, 0.3], axis=1) - 0.01,
                  None, lambda p: np.hypot(p[:, 0], p[:, 1]) - 0.004,
                  lambda p: np.hypot(np.hypot(p[:, 0] - 0.3, p[:, 2] - 0.2) - 0.3, p[:, 1]) - 0.004]
    for outline, f in zip(outlines, on_surface):
        pts = outline[~np.isnan(outline[:, 0])]
        if f is not None:
            assert np.abs(f(pts)).max() < 1e-12
    s = np.linspace(0, 0.5, 11)
    P = np.stack([np.zeros(11), np.zeros(11), s], axis=1)[None]
    R = np.broadcast_to(np.eye(3), (1, 11, 3, 3))
    g = robot_geometry(robot, P, R, s, np.zeros((1, 0)))
    fig = plot_robot(g)
    assert all(sum(ln.get_gid() == "obstacle" for ln in ax.lines) == 5 for ax in fig.axes[:3])
    names = [t.name for t in robot_figure(robot, P, R, s, np.zeros((1, 0))).data]
    assert [n for n in names if n.startswith("obstacle")] == [f"obstacle {j}" for j in range(5)]
