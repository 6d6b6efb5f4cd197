"""Map and trajectory plots: headless PNGs, equal scaling, and argument checks."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ferroslam.plot import plot_map, plot_trajectories
from ferroslam.trajectory import Trajectory

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _circle_poses(n, radius=2.0, z=0.0):
    angle = np.linspace(0.0, np.pi, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = radius * np.cos(angle)
    T[:, 1, 3] = z
    T[:, 2, 3] = radius * np.sin(angle)
    return T


def _assert_png(path):
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000, f"{path}: {len(data)} bytes"


def test_plot_map_writes_png_with_equal_axes(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.normal(size=(500, 3)) * [4.0, 0.5, 1.0]
    ax = plot_map(points, _circle_poses(20), path=tmp_path / "out" / "map.png")
    _assert_png(tmp_path / "out" / "map.png")
    assert ax.name == "3d"
    spans = [np.ptp(lim) for lim in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    np.testing.assert_allclose(spans, spans[0], rtol=1e-9)
    assert spans[0] >= np.ptp(np.percentile(points[:, 0], [1, 99]))
    # The points inside the view are drawn (those beyond the 1st-99th percentiles of x may
    # not be), keyframe line present.
    inside = np.all(np.abs(points - np.mean([ax.get_xlim(), ax.get_ylim(), ax.get_zlim()],
                                            axis=1)) <= spans[0] / 2, axis=1)
    assert 490 <= inside.sum() == ax.collections[0].get_offsets().shape[0]
    assert len(ax.lines) == 1


def test_plot_map_view_ignores_a_stray_far_point():
    # KITTI 01 once mapped a point 259 km away: the view must still show the map.
    rng = np.random.default_rng(1)
    points = np.vstack([rng.normal(size=(999, 3)) * 10.0, [[259e3, 0.0, 0.0]]])
    ax = plot_map(points, _circle_poses(20))
    assert np.ptp(ax.get_xlim()) < 100.0
    drawn = ax.collections[0].get_offsets()
    assert 980 <= drawn.shape[0] < 1000 and np.abs(drawn).max() < 100.0
    assert f"{1000 - drawn.shape[0]} beyond the view" in ax.collections[0].get_label()


def test_plot_map_into_given_axes_and_subsamples(tmp_path):
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    points = np.arange(3000.0).reshape(-1, 3)
    assert plot_map(points, np.zeros((0, 4, 4)), ax=ax, max_points=100) is ax
    assert ax.collections[0].get_offsets().shape[0] == 100
    fig.savefig(tmp_path / "given.png")
    _assert_png(tmp_path / "given.png")


def test_plot_map_empty_is_fine(tmp_path):
    ax = plot_map(np.zeros((0, 3)), np.zeros((0, 4, 4)))
    ax.figure.savefig(tmp_path / "empty.png")
    assert (tmp_path / "empty.png").read_bytes().startswith(PNG_MAGIC)


@pytest.mark.parametrize(
    "points, poses, kwargs, name",
    [
        (np.zeros((5, 2)), np.zeros((0, 4, 4)), {}, "points"),
        ([[0.0, np.nan, 0.0]], np.zeros((0, 4, 4)), {}, "points"),
        (np.zeros((5, 3)), np.zeros((2, 3, 4)), {}, "keyframe_poses"),
        (np.zeros((5, 3)), np.full((1, 4, 4), np.inf), {}, "keyframe_poses"),
        (np.zeros((5, 3)), np.zeros((0, 4, 4)), {"max_points": 0}, "max_points"),
    ],
)
def test_plot_map_bad_input(points, poses, kwargs, name):
    with pytest.raises(ValueError, match=name):
        plot_map(points, poses, **kwargs)


def test_plot_map_rejects_2d_axes():
    fig = Figure()
    with pytest.raises(ValueError, match="ax"):
        plot_map(np.zeros((1, 3)), np.zeros((0, 4, 4)), ax=fig.add_subplot(1, 1, 1))


def test_plot_trajectories_top_and_side_views(tmp_path):
    reference = Trajectory(np.arange(30.0), _circle_poses(30, z=0.3))
    estimate = Trajectory(np.arange(30.0), _circle_poses(30, radius=2.1))
    fig = plot_trajectories(estimate, reference, path=tmp_path / "t" / "traj.png")
    _assert_png(tmp_path / "t" / "traj.png")
    top, side = fig.axes
    assert (top.get_title(), side.get_title()) == ("top view", "side view")
    # Widest axes: x and z on top; the side view puts the widest (x) against y.
    assert (top.get_xlabel(), top.get_ylabel()) == ("x [m]", "z [m]")
    assert (side.get_xlabel(), side.get_ylabel()) == ("x [m]", "y [m]")
    assert len(top.lines) == 3  # reference, estimate, start marker


def test_plot_trajectories_accepts_pose_arrays_without_reference():
    fig = plot_trajectories(_circle_poses(5))
    assert len(fig.axes) == 2 and len(fig.axes[0].lines) == 2


@pytest.mark.parametrize(
    "estimate, reference, name",
    [
        (np.zeros((3, 4)), None, "estimate"),
        (np.full((2, 4, 4), np.nan), None, "estimate"),
        (np.zeros((0, 4, 4)), None, "estimate"),
        (_circle_poses(3), np.zeros((3, 3, 3)), "reference"),
        (_circle_poses(3), np.full((2, 4, 4), np.nan), "reference"),
    ],
)
def test_plot_trajectories_bad_input(estimate, reference, name):
    with pytest.raises(ValueError, match=name):
        plot_trajectories(estimate, reference)


def test_no_pyplot_needed():
    # The helpers build figures directly: the backend is never switched or needed.
    backend = matplotlib.get_backend()
    plot_trajectories(_circle_poses(3))
    assert matplotlib.get_backend() == backend
